"""The whole story on a built-in synthetic material, with an HTML report: ``bayes-brdf demo``.

1. capture: a procedural material seen by a few flash photos (rendered, with a little noise);
2. fit: sample the posterior of per-texel maps (SPOS), MAP maps and parameter-space std (Eq. 9);
3. check: image-space std (Eq. 11) on held-out novel views next to the MAP's actual error there;
4. recommend: score candidate views by mutual information (Eq. 18) and pick the next ones;
5. guide: a few rounds of guided capture (Algorithm 1) against the low-discrepancy baseline, over
   ``seeds`` seeds (capture noise and initial views), with the spread and one sentence of conclusion;
6. real photos (``capture=PATH``): fit some views of a real capture, hold out the rest, compare the
   predicted std with the actual error there and rank the held-out views by mutual information;
7. an object (``mesh``: the bowl by default, a shape name, a mesh file, or ``"none"``): the same on a mesh
   (:mod:`bayes_brdf.demo_mesh`): texture-space std with the unseen texels, novel views, recommended cameras.

Everything lands in ``out`` with ``report.html`` (self-contained) on top; every map in it carries its
value range, every interval claim is checked by coverage (reliability diagram) and by std vs error.
"""
from __future__ import annotations

import json
import time
import warnings
from pathlib import Path

import torch

from .errors import ConvergenceWarning
from . import plots
from .experiments.common import SURFACE
from .guidance import Evaluation, SyntheticCapture, guided_acquisition, low_discrepancy, recommend, score_views
from .inference import infer
from .io import write_png
from .io.outputs import write_text
from .materials import make_material
from .models.material import per_texel
from .render.shade import render
from .render.views import collocated_views
from .report import Report
from .uncertainty import correlations, coverage, image_std, interval_coverage, predictive_cdf

DEFAULTS = dict(material="wood", resolution=32, views=5, candidates=300, novel=4, k=3, rounds=2, steps=1500,
                guided_steps=None, seeds=3, particles=20, noise=0.005, radius=10.0, seed=0, capture=None,
                capture_resolution=32, mesh="bowl", mesh_up="z", mesh_texels=None, mesh_resolution=None, mesh_views=8,
                mesh_steps=None, mesh_candidates=200)   # mesh texels and pixels: 2 x resolution; steps: min(600, steps)
LEVELS = (0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9)


def _fit(model, obs, cfg, seed, progress, steps=None):
    with warnings.catch_warnings():              # the verdict goes into the log line and the report
        warnings.simplefilter("ignore", ConvergenceWarning)
        return infer(model, obs, "spos", seed=seed, particles=int(cfg["particles"]),
                     steps=int(steps or cfg["steps"]), progress=progress)


def _verdict(post) -> str:
    d = post.diagnostics or {}
    return "passed" if d.get("converged") else "failed " + ", ".join(d.get("failed", []))


def _diagnostics_table(rep, post):
    d = post.diagnostics or {}
    rep.table([[name, c.get("value"), c.get("threshold"), {True: "pass", False: "FAIL", None: "reported"}[c.get("ok")]]
               for name, c in d.get("checks", {}).items()],
              header=["convergence check (docs/samplers.md)", "value", "limit", "verdict"])
    rep.text(("The sampler's convergence checks passed." if d.get("converged") else
              f"Not converged: {', '.join(d.get('failed', []))}; a longer run (--steps) would be needed to trust "
              "the std maps fully."), cls="note")


def _guided(cfg, truth, cands, novel, ev, out, progress, log):
    """Guided (MI) and baseline rounds over ``cfg["seeds"]`` seeds: ``{label: {"views", "runs": [[err]]}}``."""
    R, seed = int(cfg["resolution"]), int(cfg["seed"])
    curves = {"guided (MI)": {"method": "mi", "runs": [], "std": [], "rows": []},
              "baseline (low-discrepancy)": {"method": "sobol", "runs": [], "std": [], "rows": []}}
    unconverged = 0
    for s in range(int(cfg["seeds"])):
        cap = SyntheticCapture(truth, SURFACE, noise_sigma=float(cfg["noise"]), seed=seed + s)
        init_idx = low_discrepancy(cands, int(cfg["views"]), seed=seed + s)
        initial = cap([cands[i] for i in init_idx])
        for label, c in curves.items():
            with warnings.catch_warnings(record=True) as caught:      # one summary line, not one per round
                warnings.simplefilter("always", ConvergenceWarning)
                res = guided_acquisition(per_texel(R), initial, cands, cap, rounds=int(cfg["rounds"]),
                                         k=int(cfg["k"]), method=c["method"], radius=float(cfg["radius"]),
                                         steps=int(cfg["guided_steps"] or min(800, int(cfg["steps"]))),
                                         particles=int(cfg["particles"]),
                                         seed=seed + s, initial_indices=init_idx, evaluation=ev, progress=progress,
                                         out=out / "guided" / f"{c['method']}_seed{seed + s}")
            unconverged += sum(issubclass(w.category, ConvergenceWarning) for w in caught)
            c["views"] = [v for v, _ in res.series("novel_error")]
            c["runs"].append([e for _, e in res.series("novel_error")])
            c["std"].append([e for _, e in res.series("mean_image_std")])
            c["rows"] += [[label, seed + s, r["views"], r["metrics"]["novel_error"], r["metrics"]["mean_image_std"],
                           r["metrics"]["param_error"]["roughness"]] for r in res.rounds]
        log(f"demo: section 5: guided and baseline rounds, seed {s + 1} of {cfg['seeds']} done")
    return curves, unconverged


def _mean_sd(curves, key: str) -> dict:
    """``{label: (views, mean over seeds, sd over seeds)}`` of one per-round series (``"runs"``: novel error)."""
    out = {}
    for lab, c in curves.items():
        t = torch.tensor(c[key])
        out[lab] = (c["views"], t.mean(0).tolist(), (t.std(0) if len(t) > 1 else torch.zeros(t.shape[1])).tolist())
    return out


def _conclusion(curves) -> str:
    (gl, g), (bl, b) = curves.items()
    ge = torch.tensor(g["runs"])[:, -1]
    be = torch.tensor(b["runs"])[:, -1]
    n, wins = len(ge), int((ge < be).sum())
    d = ge - be
    sd = float(d.std()) if n > 1 else float("nan")
    se = sd / n ** 0.5 if n > 1 else float("inf")
    at = g["views"][-1]
    nums = (f"at {at} views the guided MAP's novel-view error is {float(ge.mean()):.4f} ± {float(ge.std()) if n > 1 else 0:.4f} "
            f"against {float(be.mean()):.4f} ± {float(be.std()) if n > 1 else 0:.4f} for the baseline (mean ± sd over {n} "
            f"seeds; guided lower in {wins} of {n})")
    if n > 1 and abs(float(d.mean())) > 2 * se:
        verdict = "guided capture is better" if float(d.mean()) < 0 else "guided capture is worse"
        return f"Conclusion: {verdict} here: {nums}; the difference is over two standard errors."
    return (f"Conclusion: no measurable difference on this material: {nums}; the difference is within two standard "
            "errors of the seed-to-seed spread, so more seeds or rounds would be needed to tell them apart.")


def _real_capture(rep, path, out: Path, cfg, progress, log) -> dict:
    """Section 6: fit half the views of a real capture, check the uncertainty on the other half, rank them."""
    from .io import load_capture
    from .runs.heldout import fitted_noise, heldout_report

    t = time.perf_counter()
    full = load_capture(path, resolution=int(cfg["capture_resolution"]))
    fit_idx = list(range(0, len(full), 2))
    held_idx = [i for i in range(len(full)) if i not in fit_idx]
    obs = full.subset(fit_idx)
    R = full.resolution[0]
    post = _fit(per_texel(R), obs, cfg, int(cfg["seed"]), progress)
    held = full.subset(held_idx)
    held.meta["indices"] = held_idx
    h = heldout_report(post, held, out / "real", fitted_noise(post, obs))
    scores = score_views(post, held.views, full.surface, seed=int(cfg["seed"]))
    secs = time.perf_counter() - t
    name = Path(path).resolve().name
    log(f"demo: section 6: real capture '{name}': fitted views {fit_idx}, held out {held_idx}: coverage 50% "
        f"{h['coverage']['50']:.2f}, 90% {h['coverage']['90']:.2f}, Spearman {h['spearman']:.2f} ({secs:.0f} s)")
    rep.heading(f"6. Real photos: '{name}' ({len(full)} flash photos at {R}x{R})")
    rep.text(f"Fitted on photos {fit_idx}, held out {held_idx}, at {R}x{R} with the defaults. The noise level was "
             f"inferred (sigma {post.noise_sigma:.3f}); the sampler's checks {_verdict(post)}.")
    pred = render(post.maps("map"), held.views, held.surface)[0]
    err = (pred - held.images.to(pred)).abs()
    sd = image_std(post, held.views, held.surface)
    sat = held.saturated if held.saturated is not None else torch.zeros(err.shape[:3], dtype=torch.bool)
    vmax = h["map_range"][1]
    grid = plots.panel_grid(out / "real" / "heldout_views.png", [
        [plots.rgb_panel(held.images[j], f"held-out photo {i}"), plots.rgb_panel(pred[j], "MAP render"),
         plots.map_panel(err[j], "|MAP render - photo|", vmax=vmax, masks={"clipped (left out)": sat[j]}),
         plots.map_panel(sd[j], "predicted std (Eq. 11)", vmax=vmax, masks={"clipped (left out)": sat[j]})]
        for j, i in enumerate(held_idx)])
    rep.images([(grid, "per held-out photo: the photo, the MAP's render, its error and the predicted std on one "
                       "shared range; cyan: clipped pixels, left out of every number")], width=1060)
    rep.table([["held-out pixels", h["pixels"]], ["clipped pixels left out", h["saturated_left_out"]],
               ["coverage of the 50 % interval", h["coverage"]["50"]],
               ["coverage of the 90 % interval", h["coverage"]["90"]],
               ["Pearson(std, |error|)", h["pearson"]], ["Spearman(std, |error|)", h["spearman"]]],
              header=["held-out check", "value"])
    order = sorted(range(len(held_idx)), key=lambda i: -float(scores.mi[i]))
    rep.table([[held_idx[i], float(scores.mi[i]), h["views"][i]["mean_abs_error"], h["views"][i]["mean_std"]]
               for i in order],
              header=["held-out photo (ranked by MI)", "MI score (nats; only differences matter)", "MAP error there",
                      "mean predicted std"])
    rep.text("The ranking is what `bayes-brdf recommend` would say about these photos had they not been taken: the "
             "photos it ranks first are those whose pixels the current posterior predicts least well.", cls="note")
    return {"capture": str(path), "fit_views": fit_idx, "heldout_views": held_idx, "seconds": secs,
            "coverage": h["coverage"], "pearson": h["pearson"], "spearman": h["spearman"],
            "mi": {held_idx[i]: float(scores.mi[i]) for i in range(len(held_idx))}}


def run(out, *, progress: bool = False, log=print, **overrides) -> Path:
    """Run the demo into ``out`` and return the path of ``report.html``."""
    cfg = {**DEFAULTS, **overrides}
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    R, seed = int(cfg["resolution"]), int(cfg["seed"])
    t_all = time.perf_counter()
    times = {}

    # 1. capture
    truth = make_material(cfg["material"], R, seed=seed).to(torch.float32)
    cap = SyntheticCapture(truth, SURFACE, noise_sigma=float(cfg["noise"]), seed=seed)
    cands = collocated_views(int(cfg["candidates"]), 3.0, method="sobol", camera="rectified", resolution=R,
                             power=10.0, max_zenith=60, seed=seed)
    init_idx = low_discrepancy(cands, int(cfg["views"]), seed=seed)
    obs = cap([cands[i] for i in init_idx])
    novel = collocated_views(int(cfg["novel"]), 3.0, method="random", camera="rectified", resolution=R, power=10.0,
                             max_zenith=60, seed=10_000 + seed)
    novel_truth = render(truth, novel, SURFACE)[0]
    novel_photos = SyntheticCapture(truth, SURFACE, noise_sigma=float(cfg["noise"]), seed=20_000 + seed)(novel)
    inputs = []
    for i, im in enumerate(obs.images):
        p = out / "capture" / f"photo_{i}.png"
        write_png(p, im.clamp(0, 1).numpy())
        inputs.append((p, f"photo {i} (flash at {tuple(round(c, 1) for c in obs.views[i].camera.position)})"))
    log(f"demo: section 1: captured {len(obs)} flash photos of '{cfg['material']}' at {R}x{R}")

    # 2. fit
    t = time.perf_counter()
    post = _fit(per_texel(R), obs, cfg, seed, progress)
    times["fit"] = time.perf_counter() - t
    post.save(out / "fit" / "posterior.safetensors")
    m = post.maps("map")
    std = post.std()
    err_a = (m.albedo - truth.albedo).abs()
    err_r = (m.roughness - truth.roughness).abs()
    va = float(torch.quantile(torch.cat([std["albedo"].flatten(), err_a.flatten()]), 0.99))
    vr = float(torch.quantile(torch.cat([std["roughness"].flatten(), err_r.flatten()]), 0.99))
    maps_png = plots.panel_grid(out / "fit" / "maps.png", [
        [plots.rgb_panel(truth.albedo, "true albedo"), plots.rgb_panel(m.albedo, "MAP albedo"),
         plots.map_panel(std["albedo"], "posterior std: albedo", vmax=va),
         plots.map_panel(err_a, "|MAP - truth|: albedo", vmax=va)],
        [plots.map_panel(truth.roughness, "true roughness", vmax=1.0),
         plots.map_panel(m.roughness, "MAP roughness", vmax=1.0),
         plots.map_panel(std["roughness"], "posterior std: roughness", vmax=vr),
         plots.map_panel(err_r, "|MAP - truth|: roughness", vmax=vr)]])
    log(f"demo: section 2: sampled the posterior ({post.num_particles} particles, {cfg['steps']} steps) in "
        f"{times['fit']:.0f} s; mean std: albedo {float(std['albedo'].mean()):.3f}, "
        f"roughness {float(std['roughness'].mean()):.3f}; convergence checks: {_verdict(post)}")

    # 3. check on novel views: std vs error, and coverage of noisy photos there
    t = time.perf_counter()
    F, sd, _ = predictive_cdf(post, novel, novel_photos.images, SURFACE)
    pred = render(m, novel, SURFACE)[0]
    err = (pred - novel_truth).abs()
    corr = correlations(sd, err)
    corr_r = correlations(std["roughness"], err_r)
    vmax = float(torch.quantile(torch.cat([sd.flatten(), err.flatten()]), 0.99))
    novel_png = plots.panel_grid(out / "novel" / "novel_views.png", [
        [plots.rgb_panel(novel_truth[j], f"novel view {j}: truth"), plots.rgb_panel(pred[j], "MAP render"),
         plots.map_panel(err[j], "|MAP render - truth|", vmax=vmax),
         plots.map_panel(sd[j], "predicted std (Eq. 11)", vmax=vmax)] for j in range(len(novel))])
    cov_img = coverage(F, LEVELS)
    cov_a = interval_coverage(post.particles["albedo"], truth.albedo, LEVELS)
    cov_r = interval_coverage(post.particles["roughness"], truth.roughness, LEVELS)
    rel_png = plots.reliability(out / "novel" / "reliability.png", {
        "novel-view photos (posterior predictive)": (LEVELS, [cov_img[f"{round(100 * q)}"] for q in LEVELS]),
        "true albedo texels (particle intervals)": (LEVELS, cov_a),
        "true roughness texels (particle intervals)": (LEVELS, cov_r)})
    sve_png = plots.std_vs_error(out / "novel" / "std_vs_error.png", [
        (sd, err, "novel views: pixels"), (std["roughness"], err_r, "roughness: texels")])
    times["novel"] = time.perf_counter() - t
    log(f"demo: section 3: novel views: predicted std vs actual error Pearson {corr['pearson']:.2f}, "
        f"Spearman {corr['spearman']:.2f}; 90 % intervals cover {cov_img['90']:.2f} of the novel photos' pixels")

    # 4. recommend
    t = time.perf_counter()
    scores = score_views(post, cands, SURFACE, seed=seed)
    rec = recommend(post, cands, int(cfg["k"]), radius=float(cfg["radius"]), exclude=init_idx, scores=scores)
    times["recommend"] = time.perf_counter() - t
    cand_png = out / "recommend" / "candidates.png"
    plots.plot_candidates(cand_png, cands, scores.mi.numpy(), rec.indices, f"{len(cands)} candidate flash views, MI")
    log(f"demo: section 4: scored {len(cands)} candidate views in {scores.seconds:.1f} s; recommended "
        + ", ".join(f"{tuple(round(c, 1) for c in cands[i].camera.position)}" for i in rec.indices))

    # 5. guided rounds vs baseline, over seeds
    t = time.perf_counter()
    ev = Evaluation(novel, novel_truth, truth)
    curves, unconverged = _guided(cfg, truth, cands, novel, ev, out, progress, log)
    if unconverged:
        log(f"demo: note: {unconverged} guided-round posteriors did not pass every convergence check")
    times["guided"] = time.perf_counter() - t
    err_png = plots.line_plot(out / "guided" / "novel_error.png", _mean_sd(curves, "runs"), spread="band",
                              style="report", xlabel="number of views", ylabel="novel-view error of the MAP",
                              title=f"guided vs baseline: mean ± sd over {cfg['seeds']} seeds")
    std_png = plots.line_plot(out / "guided" / "mean_image_std.png", _mean_sd(curves, "std"), spread="band",
                              style="report", xlabel="number of views", ylabel="mean image-space std",
                              title=f"mean ± sd over {cfg['seeds']} seeds")
    conclusion = _conclusion(curves) if int(cfg["rounds"]) > 0 else "No guided rounds were run (--rounds 0)."
    log(f"demo: section 5: {cfg['rounds']} guided rounds of {cfg['k']} views and the baseline, {cfg['seeds']} seeds, in "
        f"{times['guided']:.0f} s. {conclusion}")

    # report
    rep = Report(f"bayes-brdf demo: how sure can we be of '{cfg['material']}'?")
    rep.text(f"A {R}x{R} procedural '{cfg['material']}' material photographed with a flash from {len(obs)} "
             f"low-discrepancy directions (noise sigma {cfg['noise']}). bayes-brdf sampled the posterior over its "
             f"per-texel albedo and roughness with SPOS ({post.num_particles} particles), measured where the maps "
             "are uncertain, checked the uncertainty against the real error on novel views, and recommended the "
             "next views by mutual information.")
    rep.heading("1. The capture")
    rep.images(inputs, width=170)
    rep.heading("2. The posterior: MAP maps and parameter-space uncertainty (Eq. 9)")
    rep.images([(maps_png, "top: albedo (RGB, linear 0–1 shown sRGB; std and error on one range); bottom: "
                           "roughness (0–1; std and error on one range)")], width=1060)
    rep.text("Bright texels in the std maps are ambiguous: the photos do not pin them down. The roughness error "
             "of the MAP is large where the std is large.", cls="note")
    _diagnostics_table(rep, post)
    rep.heading("3. Image-space uncertainty (Eq. 11) on novel views vs the actual error")
    rep.images([(novel_png, "per novel view: truth, MAP render, its error and the predicted std (error and std "
                            "on one shared range)")], width=1060)
    rep.images([(rel_png, "reliability: nominal vs observed coverage of central intervals at 10 … 90 %")],
               width=520)
    rep.images([(sve_png, "predicted std against the actual error: left, the novel views' pixels; right, the "
                          "roughness texels (binned means in orange)")], width=1000)
    rep.table([["novel-view pixels (photos with noise)", cov_img["50"], cov_img["90"], corr["pearson"],
                corr["spearman"]],
               ["albedo texels vs truth", cov_a[4], cov_a[8], "", ""],
               ["roughness texels vs truth", cov_r[4], cov_r[8], corr_r["pearson"], corr_r["spearman"]]],
              header=["what", "50 % interval covers", "90 % interval covers", "Pearson(std, |error|)",
                      "Spearman(std, |error|)"])
    rep.text(f"With {post.num_particles} particles an empirical central interval is coarse (its end points are "
             "order statistics), so the texel rows of the reliability diagram step; the image-space row uses the "
             "exact predictive CDF of each pixel.", cls="note")
    rep.heading("4. Where to look next: mutual information of candidate views (Eq. 18)")
    rep.images([(cand_png, "each dot a candidate flash direction seen from above, coloured by its mutual "
                           "information with the posterior; circles: the recommended views. Without photo noise "
                           "in the score, MI is a differential entropy in nats and can be negative: only the "
                           "order matters.")], width=460)
    rep.heading("5. Guided capture vs a low-discrepancy baseline (Algorithm 1)")
    rep.images([(err_png, "novel-view error of the MAP"), (std_png, "mean image-space std")], width=520)
    rep.text(conclusion)
    n_fits = 2 * int(cfg["seeds"]) * (int(cfg["rounds"]) + 1)
    if unconverged:
        rep.text(f"{unconverged} of the {n_fits} guided-round posteriors failed a convergence check (each round runs "
                 f"{int(cfg['guided_steps'] or min(800, int(cfg['steps'])))} steps warm-started from the round "
                 "before; the failures are the split-R̂ / energy-drift limits): their std maps are indicative, the "
                 "MAP errors above do not depend on it.", cls="note")
    rep.table([row for c in curves.values() for row in c["rows"]],
              header=["method", "seed", "views", "novel error", "mean image std", "roughness error"])
    real = None
    if cfg.get("capture"):
        real = _real_capture(rep, cfg["capture"], out, cfg, progress, log)
        times["real_capture"] = real["seconds"]
    obj = None
    if cfg.get("mesh") and cfg["mesh"] != "none":
        from .demo_mesh import mesh_section
        obj = mesh_section(rep, out, cfg, progress, log)
        times["mesh"] = obj["seconds"]
    times["total"] = time.perf_counter() - t_all
    rep.heading("Timings")
    rep.text(f"This demo took {times['total']:.0f} s on this machine ({_machine()}).")
    rep.table([[k, v] for k, v in times.items()], header=["stage", "seconds"])
    rep.heading("Reproduce")
    rep.code(f"bayes-brdf demo --out {out}" + (f" --capture {cfg['capture']}" if cfg.get("capture") else "") + "\n"
             "bayes-brdf fit ../shared/data/captures/card_blue --views 0,2,4,6,8\n"
             "bayes-brdf recommend ../shared/data/captures/card_blue --views 0,2,4 --k 2")
    write_text(out / "demo.json", json.dumps({"config": cfg, "seconds": times, "novel_correlation": corr,
                                              "coverage_novel": cov_img, "coverage_albedo": dict(zip(LEVELS, cov_a)),
                                              "coverage_roughness": dict(zip(LEVELS, cov_r)),
                                              "recommended": rec.indices, "conclusion": conclusion,
                                              "guided": {lab: {"views": c["views"], "novel_error": c["runs"]}
                                                         for lab, c in curves.items()},
                                              "real_capture": real, "mesh": obj},
                                             indent=1, default=float))
    return rep.write(out / "report.html")


def _machine() -> str:
    import os
    import platform

    return f"{platform.machine()}, {os.cpu_count()} CPU cores, torch threads {torch.get_num_threads()}"
