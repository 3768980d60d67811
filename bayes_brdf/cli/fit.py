"""``bayes-brdf fit CAPTURE``: fit on some views, hold out the rest, and check the uncertainty against them.

Writes to ``--out``: the posterior and its MAP / mean maps, per-site std maps (EXR + PNG), and for every
held-out view the image-space std (Eq. 11), the MAP render and its absolute error against the photo
(EXR + PNG), plus ``summary.json``: Pearson and Spearman correlation between predicted std and absolute
error over the held-out pixels, the coverage of the central 50 % and 90 % posterior-predictive intervals,
and the wall time of each stage, and ``report.html`` (self-contained: the views with how each is lit -- flash,
environment or both -- the held-out numbers and maps). The coverage is also given with the noise level the fitted photos show
(the Laplace scale of the MAP's residuals there) in place of the model's ``sigma``: when that fixes the
coverage, the model's noise was set too low; when it does not, the error is model mismatch. Saturated (clipped) pixels are left out of every held-out number: they
only bound the radiance from below.
"""
from __future__ import annotations

import sys
import time

from .common import check_views, view_list
from .infer import add_sampling_args, convergence_note, load, sample, timing, write_posterior


def add_parser(sub):
    f = sub.add_parser("fit", help="fit on chosen views, hold out the rest, and measure uncertainty vs error",
                       description=__doc__.split("\n\n")[0] + " Held-out views get image-space std, error maps and "
                                   "correlation / coverage numbers in summary.json. A rerun resumes the sampler "
                                   "from the checkpoint in --out.")
    add_sampling_args(f, "out/fit")
    add_holdout_arg(f)
    f.set_defaults(func=run)


def add_holdout_arg(f):
    """``--holdout`` (``fit`` and ``fit-many``)."""
    f.add_argument("--holdout", type=view_list, default=None,
                   help="comma-separated view indices to hold out (default: every view not in --views)")


def _split(n: int, views, holdout):
    if views is None and holdout is not None:
        views = [i for i in range(n) if i not in holdout]
        if not views:
            from ..errors import InputError
            raise InputError("--holdout holds out every view: nothing is left to fit", fix="hold out fewer views")
    fit = list(range(n)) if views is None else list(views)
    held = [i for i in range(n) if i not in fit] if holdout is None else list(holdout)
    from ..errors import InputError
    for i in fit + held:
        if not 0 <= i < n:
            raise InputError(f"view index {i} out of range for {n} views", fix=f"use 0..{n - 1}")
    if set(fit) & set(held):
        raise InputError(f"views {sorted(set(fit) & set(held))} are both fitted and held out",
                         fix="give disjoint --views and --holdout")
    return fit, held


def run(a) -> int:
    import torch

    from ..io.outputs import write_json
    from ..runs.heldout import fitted_noise, heldout_report

    t0 = time.perf_counter()
    _, full, out = load(a, "fit", full=True)
    check_views(a.holdout, len(full), "--holdout")
    fit_idx, held_idx = _split(len(full), a.views, a.holdout)
    if a.views is None and a.holdout is not None:
        a.views = fit_idx          # --holdout alone: fit the other views (and say so in the run's fingerprint)
    obs = full.subset(fit_idx)
    times = {"load": time.perf_counter() - t0}
    t = time.perf_counter()
    post = sample(a, obs, out)
    times["fit"] = time.perf_counter() - t
    t = time.perf_counter()
    mean_std = write_posterior(post, out)
    times["write_maps"] = time.perf_counter() - t
    summary = {"capture": str(a.capture), "fit_views": fit_idx, "heldout_views": held_idx,
               "resolution": obs.resolution[0], "resumed_from": post.log.get("resumed_from", 0),
               "model": post.meta["model"], "sampler": post.meta["sampler"],
               "params": post.meta["params"], "run": post.meta["run"], "seed": a.seed,
               "mean_param_std": mean_std, "best_energy": float(post.energies.min()),
               "device": str(torch.device(a.device)), "diagnostics": post.diagnostics}
    if held_idx:
        t = time.perf_counter()
        held = full.subset(held_idx)
        held.meta["indices"] = held_idx
        summary["model_sigma"] = getattr(post.model, "sigma", None)
        summary["noise_sigma"] = post.noise_sigma
        summary["heldout"] = heldout_report(post, held, out, fitted_noise(post, obs))
        times["heldout"] = time.perf_counter() - t
    times["total"] = time.perf_counter() - t0
    summary["seconds"] = times
    write_json(out / "summary.json", summary)
    write_report(out, summary, full, post)
    msg = f"{post} from views {fit_idx} {timing(post)}"
    if held_idx:
        h = summary["heldout"]
        msg += (f"; held-out views {held_idx}: std vs |error| Pearson {h['pearson']:.2f}, Spearman "
                f"{h['spearman']:.2f}; coverage 50% {h['coverage']['50']:.2f}, 90% {h['coverage']['90']:.2f} "
                f"(with the fitted noise {h['fitted_sigma']:.3f} instead of sigma {summary['noise_sigma']:.3g}: "
                f"{h['coverage_with_fitted_sigma']['50']:.2f}, {h['coverage_with_fitted_sigma']['90']:.2f})")
    else:
        msg += "; every view was fitted, so nothing is held out (give --views or --holdout to check against photos)"
    print(msg + f" -> {out}/ (report.html, summary.json, map/, mean/, std/{', heldout/' if held_idx else ''})")
    hint = sigma_hint(summary)
    if hint:
        print(hint)
    note = convergence_note(post)
    if note:
        print(note, file=sys.stderr)
    return 0


def sigma_hint(summary: dict) -> str:
    """A line advising a larger model sigma when the fitted photos' residuals are over twice its value
    (the predictive intervals are then too narrow: real photos differ from the model by more than sigma)."""
    fitted, model = summary.get("heldout", {}).get("fitted_sigma"), summary.get("model_sigma")
    if not fitted or not isinstance(model, (int, float)) or fitted <= 2 * model:
        return ""
    return (f"note: the fitted photos differ from the MAP render by a Laplace scale of {fitted:.3f}, "
            f"{fitted / model:.1f}x the model's sigma {model:g}, so the intervals are too narrow; "
            f"rerun with --model-param sigma={fitted:.2f} for calibrated ones (see docs/guidance.md)")


def write_report(out, summary: dict, full, post):
    """``out/report.html``: the run, the views with their lighting, the held-out numbers and maps."""
    from pathlib import Path

    from ..report import Report, lighting

    fit_idx, held_idx = summary["fit_views"], summary["heldout_views"]
    name = Path(str(summary["capture"])).resolve().name
    rep = Report(f"bayes-brdf fit: '{name}'")
    model = summary["model"].get("model", "model") if isinstance(summary["model"], dict) else summary["model"]
    d = summary.get("diagnostics") or {}
    rep.text(f"{model} sampled by {summary['sampler']} from views {fit_idx} at {summary['resolution']}x"
             f"{summary['resolution']}; noise sigma {float(post.noise_sigma or 0):.4g}; convergence checks "
             + ("passed." if d.get("converged", True) else "failed (see summary.json: diagnostics)."))
    rep.heading("Views and their lighting")
    idx = fit_idx + held_idx
    views = [full.views[i] for i in idx]
    envs = {v.environment for v in views if v.environment is not None}
    if envs:
        lit = sum(v.environment is not None for v in views)
        alone = sum(v.environment is not None and not v.point_lights for v in views)
        rep.text(f"{lit} of the {len(views)} views are lit by an environment light "
                 f"({', '.join(repr(e.name or e.digest) for e in envs)}), {alone} of them by the environment alone; "
                 "the environment is shaded by its precomputed per-pixel transfer (docs/environment.md).")
    else:
        rep.text("Every view is lit by point lights only (no environment).")
    rep.views(views, ["fitted"] * len(fit_idx) + ["held out"] * len(held_idx), indices=idx)
    h = summary.get("heldout")
    if h:
        rep.heading("Held-out views: predicted uncertainty against the actual error")
        rep.table([["held-out pixels", h["pixels"]], ["clipped pixels left out", h["saturated_left_out"]],
                   ["coverage of the 50 % interval", h["coverage"]["50"]],
                   ["coverage of the 90 % interval", h["coverage"]["90"]],
                   ["coverage 50 % / 90 % with the fitted noise "
                    f"{h.get('fitted_sigma', float('nan')):.3g}",
                    f"{h['coverage_with_fitted_sigma']['50']:.3f} / {h['coverage_with_fitted_sigma']['90']:.3f}"
                    if "coverage_with_fitted_sigma" in h else None],
                   ["Pearson(std, |error|)", h["pearson"]], ["Spearman(std, |error|)", h["spearman"]]],
                  header=["held-out check", "value"])
        for v, i in zip(h["views"], held_idx):
            tag = v["view"]
            rep.text(f"{tag} ({lighting(full.views[i])}): mean |error| {v['mean_abs_error']:.4g}, mean std "
                     f"{v['mean_std']:.4g}, Spearman {v['spearman']:.2f}, coverage 50 % {v['coverage']['50']:.2f}, "
                     f"90 % {v['coverage']['90']:.2f}")
            rep.images([(out / "heldout" / f"{tag}_photo.png", "photo"),
                        (out / "heldout" / f"{tag}_map_render.png", "MAP render"),
                        (out / "heldout" / f"{tag}_error.png", "|MAP render - photo|"),
                        (out / "heldout" / f"{tag}_std.png", "predicted std (Eq. 11)")], width=200)
    else:
        rep.text("Every view was fitted: nothing is held out.", cls="note")
    rep.heading("Posterior std of the maps (Eq. 9)")
    rep.images([(p, p.stem) for p in sorted((out / "std").glob("*.png"))], width=200)
    return rep.write(out / "report.html")
