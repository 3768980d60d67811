"""``bayes-brdf recommend CAPTURE``: rank candidate views by mutual information with the posterior (Eq. 18)."""
from __future__ import annotations

import json
import math
import time
from pathlib import Path

from .common import positive_int
from .infer import add_sampling_args, load, sample


def add_parser(sub):
    r = sub.add_parser("recommend", help="rank candidate views by how much they would reduce the uncertainty",
                       description="Fit the posterior on --views of a capture (or load one with --posterior), then "
                                   "score candidate views by mutual information (Eq. 18) and print the best --k, "
                                   "with hypersphere exclusion of --radius degrees between picks. Candidates: the "
                                   "capture's views that were not fitted ('heldout', e.g. to replay a session), or "
                                   "generated flash views (fibonacci:N, sobol:N) at the capture's camera distance, "
                                   "or a JSON file of views. Writes recommend.json and a plot of the candidates.")
    add_sampling_args(r, "out/recommend")
    r.add_argument("--posterior", default=None,
                   help="a posterior.safetensors written by fit/infer (skips fitting; its model must be a preset)")
    r.add_argument("--candidates", default="heldout",
                   help="heldout, fibonacci:N, sobol:N or a JSON file of views (default: %(default)s)")
    r.add_argument("--k", type=positive_int, default=3, help="views to recommend (default: %(default)s)")
    r.add_argument("--radius", type=float, default=10.0,
                   help="exclusion radius between picks, degrees (default: %(default)s)")
    r.add_argument("--method", default="mi", choices=["mi", "std", "sobol", "fibonacci", "random"],
                   help="mi (ours), std (max image-space std), sobol, fibonacci or random baselines "
                        "(default: %(default)s)")
    r.add_argument("--estimator", default="mc", choices=["mc", "quadrature"],
                   help="entropy estimator: mc (Eq. 21) or quadrature (deterministic, slower) (default: %(default)s)")
    r.add_argument("--noise-var", default="0",
                   help="noise variance in the score: a number (0, the default, is the paper's noise-free renderer) "
                        "or 'observation' (the model's photo noise; see docs/guidance.md)")
    r.set_defaults(func=run)


def _candidates(spec: str, full, fitted):
    from ..errors import InputError
    from ..render.surface import PlanarSample
    from ..render.views import View, collocated_views

    if spec == "heldout":
        idx = [i for i in range(len(full)) if i not in fitted]
        if not idx:
            raise InputError("no held-out views to rank: every view is fitted",
                             fix="fit fewer --views, or use --candidates fibonacci:N")
        return [full.views[i] for i in idx], idx
    p = Path(spec)
    if p.suffix.lower() == ".json":
        if not p.is_file():
            raise InputError("candidate views file not found", where=p)
        try:
            data = json.loads(p.read_text())
        except (OSError, json.JSONDecodeError) as e:
            raise InputError(f"unreadable views JSON ({e})", where=p) from None
        data = data.get("views", data) if isinstance(data, dict) else data
        views = [View.from_dict(d.get("view", d), where=f"{p}[{i}]") for i, d in enumerate(data)]
        return views, list(range(len(views)))
    kind, _, num = spec.partition(":")
    if kind not in ("fibonacci", "sobol") or not num.isdigit() or int(num) < 1:
        raise InputError(f"bad --candidates '{spec}'", fix="use heldout, fibonacci:N, sobol:N or a JSON file of views")
    from ..render.cameras import PerspectiveCamera

    v0 = full.views[0]
    centre = full.surface.center
    dist = sorted(math.dist(v.camera.position, centre) for v in full.views)[len(full.views) // 2]
    if not v0.point_lights:
        raise InputError(f"--candidates {spec}: the capture's views have no flash to copy onto the generated views",
                         fix="give a JSON file of candidate views")
    light = v0.point_lights[0]
    if isinstance(v0.camera, PerspectiveCamera):    # like the capture's cameras, around its geometry's centre
        kw = dict(camera="perspective", fov=v0.camera.fov, target=centre,
                  max_zenith=60 if isinstance(full.surface, PlanarSample) else 90)
    else:
        kw = dict(camera="rectified", max_zenith=60)
    views = collocated_views(int(num), dist, method=kind, resolution=v0.resolution, power=light.power,
                             falloff=light.falloff, **kw)
    return views, list(range(len(views)))


def run(a) -> int:
    from ..errors import InputError
    from ..guidance import recommend, score_views
    from ..guidance.scores import parse_noise_var
    from ..io.outputs import write_json
    from ..plots import plot_candidates
    from ..posterior import Posterior

    nv = parse_noise_var(a.noise_var)           # checked before any fitting
    t0 = time.perf_counter()
    obs, full, out = load(a, "recommend", full=True)
    fitted = list(range(len(full))) if a.views is None else list(a.views)
    cands, labels = _candidates(a.candidates, full, fitted)      # a bad --candidates fails before the fit
    if any(v.environment is not None for v in cands):
        raise InputError("recommend cannot rank views lit by an environment map yet (view configurations are "
                         "made of point-light positions)", fix="rank flash-only candidate views (fibonacci:N, "
                                                               "sobol:N or a JSON file of views)")
    if a.posterior:
        post = Posterior.load(a.posterior)
        if post.model is None:
            raise InputError("this posterior's model cannot be rebuilt from its file", where=a.posterior,
                             fix="refit with --views instead of --posterior")
        if post.surface is None:
            post.surface = full.surface
    else:
        post = sample(a, obs, out)
        post.save(out / "posterior.safetensors")
    t_fit = time.perf_counter() - t0
    scores = None
    if a.method in ("mi", "std"):
        scores = score_views(post, cands, full.surface, estimator=a.estimator, seed=a.seed, noise_var=nv)
    rec = recommend(post, cands, a.k, method=a.method, radius=a.radius, surface=full.surface, seed=a.seed,
                    scores=scores, offset=len(fitted))
    result = {"capture": str(a.capture), "fitted_views": fitted, "candidates": a.candidates, "method": a.method,
              "k": a.k, "radius_deg": a.radius, "estimator": a.estimator, "noise_var": nv,
              "fit_seconds": t_fit,
              "recommended": [labels[i] for i in rec.indices], **rec.to_dict()}
    if scores is not None:
        result["all"] = [{"candidate": labels[i], "mi": float(scores.mi[i]), "mean_std": float(scores.mean_std[i]),
                          "pixels": int(scores.pixels[i])} for i in range(len(cands))]
        plot_candidates(out / "candidates.png", cands,
                        scores.mi.numpy() if a.method == "mi" else scores.mean_std.numpy(),
                        rec.indices, f"{len(cands)} candidates, {a.k} recommended ({a.method})",
                        centre=full.surface.center)
    write_json(out / "recommend.json", result)
    what = "view" if a.candidates == "heldout" else "candidate"
    print(f"recommended ({a.method}, from {len(cands)} candidates): "
          + ", ".join(f"{what} {labels[i]}" + (f" (MI {float(scores.mi[i]):.0f} nats)" if scores is not None else "")
                      for i in rec.indices) + f" -> {out}/recommend.json")
    if scores is not None and a.candidates == "heldout":
        order = sorted(range(len(cands)), key=lambda i: -float(scores.mi[i]))
        print("ranking by mutual information: " + " > ".join(str(labels[i]) for i in order))
    if scores is not None and nv == 0 and bool((scores.mi < 0).any()):
        print("(the noise-free score is a differential entropy, so it can be negative: only the order matters)")
    return 0
