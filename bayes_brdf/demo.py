"""The whole story on a built-in synthetic material, with an HTML report: ``bayes-brdf demo``.

1. capture: a procedural material seen by a few flash photos (rendered, with a little noise);
2. fit: sample the posterior of per-texel maps (SPOS), MAP maps and parameter-space std (Eq. 9);
3. check: image-space std (Eq. 11) on held-out novel views next to the MAP's actual error there;
4. recommend: score candidate views by mutual information (Eq. 18) and pick the next ones;
5. guide: a few rounds of guided capture (Algorithm 1) against the low-discrepancy baseline.

Everything lands in ``out`` with ``report.html`` (self-contained) on top.
"""
from __future__ import annotations

import json
import time
import warnings
from pathlib import Path

import torch

from .errors import ConvergenceWarning
from .experiments.common import SURFACE, line_plot
from .guidance import Evaluation, SyntheticCapture, guided_acquisition, low_discrepancy, recommend, score_views
from .inference import infer
from .io import write_png
from .io.outputs import write_text
from .materials import make_material
from .models.material import per_texel
from .render.shade import render
from .render.views import collocated_views
from .report import Report
from .uncertainty import correlations, image_std, write_map

DEFAULTS = dict(material="wood", resolution=32, views=5, candidates=300, novel=4, k=3, rounds=2, steps=1500,
                particles=20, noise=0.005, radius=10.0, seed=0)


def _maps_pngs(maps, folder: Path, prefix: str):
    folder.mkdir(parents=True, exist_ok=True)
    a = folder / f"{prefix}_albedo.png"
    r = folder / f"{prefix}_roughness.png"
    write_png(a, maps.albedo.detach().float().cpu().permute(1, 2, 0).clamp(0, 1).numpy())
    write_png(r, maps.roughness.detach().float().cpu()[0].clamp(0, 1).numpy(), linear=False)
    return a, r


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
    inputs = []
    for i, im in enumerate(obs.images):
        p = out / "capture" / f"photo_{i}.png"
        write_png(p, im.clamp(0, 1).numpy())
        inputs.append((p, f"photo {i} (flash at {tuple(round(c, 1) for c in obs.views[i].camera.position)})"))
    log(f"demo: 1/5 captured {len(obs)} flash photos of '{cfg['material']}' at {R}x{R}")

    # 2. fit
    t = time.perf_counter()
    with warnings.catch_warnings():              # the verdict goes into the log line below
        warnings.simplefilter("ignore", ConvergenceWarning)
        post = infer(per_texel(R), obs, "spos", seed=seed, particles=int(cfg["particles"]),
                     steps=int(cfg["steps"]), progress=progress)
    times["fit"] = time.perf_counter() - t
    post.save(out / "fit" / "posterior.safetensors")
    m = post.maps("map")
    truth_pngs = _maps_pngs(truth, out / "fit", "truth")
    map_pngs = _maps_pngs(m, out / "fit", "map")
    std = post.std()
    std_pngs = [write_map(out / "fit" / f"std_{k}", v, title=f"posterior std: {k}") for k, v in std.items()]
    err_r = write_map(out / "fit" / "error_roughness", (m.roughness - truth.roughness).abs(),
                      title="|MAP - truth|: roughness")
    log(f"demo: 2/5 sampled the posterior ({post.num_particles} particles, {cfg['steps']} steps) in "
        f"{times['fit']:.0f} s; mean std: albedo {float(std['albedo'].mean()):.3f}, "
        f"roughness {float(std['roughness'].mean()):.3f}; convergence checks: "
        f"{'passed' if post.diagnostics['converged'] else 'failed ' + ', '.join(post.diagnostics['failed'])}")

    # 3. check on novel views
    t = time.perf_counter()
    sd = image_std(post, novel, SURFACE)
    pred = render(m, novel, SURFACE)[0]
    err = (pred - novel_truth).abs()
    corr = correlations(sd, err)
    vmax = float(torch.quantile(torch.cat([sd.flatten(), err.flatten()]), 0.99))
    novel_rows = []
    for j in range(len(novel)):
        a = out / "novel" / f"view_{j}_truth.png"
        write_png(a, novel_truth[j].clamp(0, 1).numpy())
        b = out / "novel" / f"view_{j}_map.png"
        write_png(b, pred[j].clamp(0, 1).numpy())
        c = write_map(out / "novel" / f"view_{j}_error", err[j], title="|MAP render - truth|", vmax=vmax)
        d = write_map(out / "novel" / f"view_{j}_std", sd[j], title="image-space std (Eq. 11)", vmax=vmax)
        novel_rows.append([(a, f"novel view {j}: truth"), (b, "MAP render"), (c, "its error"),
                           (d, "predicted std")])
    times["novel"] = time.perf_counter() - t
    log(f"demo: 3/5 novel views: predicted std vs actual error Pearson {corr['pearson']:.2f}, "
        f"Spearman {corr['spearman']:.2f}")

    # 4. recommend
    t = time.perf_counter()
    scores = score_views(post, cands, SURFACE, seed=seed)
    rec = recommend(post, cands, int(cfg["k"]), radius=float(cfg["radius"]), exclude=init_idx, scores=scores)
    times["recommend"] = time.perf_counter() - t
    from .cli.recommend import _plot
    cand_png = out / "recommend" / "candidates.png"
    cand_png.parent.mkdir(parents=True, exist_ok=True)
    _plot(cand_png, cands, scores.mi.numpy(), rec.indices, f"{len(cands)} candidate flash views, MI")
    log(f"demo: 4/5 scored {len(cands)} candidate views in {scores.seconds:.1f} s; recommended "
        + ", ".join(f"{tuple(round(c, 1) for c in cands[i].camera.position)}" for i in rec.indices))

    # 5. guided rounds vs baseline
    t = time.perf_counter()
    ev = Evaluation(novel, novel_truth, truth)
    curves = {}
    unconverged = []
    for method, label in (("mi", "guided (MI)"), ("sobol", "baseline (low-discrepancy)")):
        with warnings.catch_warnings(record=True) as caught:      # one summary line, not a warning per round
            warnings.simplefilter("always", ConvergenceWarning)
            res = guided_acquisition(per_texel(R), obs, cands, cap, rounds=int(cfg["rounds"]), k=int(cfg["k"]),
                                     method=method, radius=float(cfg["radius"]), steps=int(cfg["steps"]),
                                     particles=int(cfg["particles"]), seed=seed, initial_indices=init_idx,
                                     evaluation=ev, out=out / "guided" / method)
        unconverged += [f"{label}: {w.message}" for w in caught if issubclass(w.category, ConvergenceWarning)]
        curves[label] = res
    if unconverged:
        log(f"demo: note: {len(unconverged)} guided-round posteriors did not pass every convergence check "
            f"(first: {unconverged[0]})")
    times["guided"] = time.perf_counter() - t
    err_png = line_plot(out / "guided" / "novel_error.png",
                        {lab: tuple(zip(*r.series("novel_error"))) for lab, r in curves.items()},
                        xlabel="number of views", ylabel="novel-view error of the MAP", title="guided vs baseline")
    std_png = line_plot(out / "guided" / "mean_image_std.png",
                        {lab: tuple(zip(*r.series("mean_image_std"))) for lab, r in curves.items()},
                        xlabel="number of views", ylabel="mean image-space std", title="guided vs baseline")
    times["total"] = time.perf_counter() - t_all
    log(f"demo: 5/5 {cfg['rounds']} guided rounds of {cfg['k']} views, and the baseline, in {times['guided']:.0f} s")

    # report
    rep = Report(f"bayes-brdf demo: how sure can we be of '{cfg['material']}'?")
    rep.text(f"A {R}x{R} procedural '{cfg['material']}' material photographed with a flash from {len(obs)} "
             f"low-discrepancy directions (noise sigma {cfg['noise']}). bayes-brdf sampled the posterior over its "
             f"per-texel albedo and roughness with SPOS ({post.num_particles} particles), measured where the maps "
             "are uncertain, checked the uncertainty against the real error on novel views, and recommended the "
             "next views by mutual information.")
    rep.heading("1. The capture")
    rep.images(inputs, width=160)
    rep.heading("2. The posterior: MAP maps and parameter-space uncertainty (Eq. 9)")
    rep.images([(truth_pngs[0], "true albedo"), (map_pngs[0], "MAP albedo"), (truth_pngs[1], "true roughness"),
                (map_pngs[1], "MAP roughness")], width=200)
    rep.images([(p, f"std of {k}") for p, k in zip(std_pngs, std)] + [(err_r, "actual roughness error")], width=260)
    rep.text("Bright texels in the std maps are ambiguous: the photos do not pin them down. The roughness error "
             "of the MAP is large where the std is large.", cls="note")
    d = post.diagnostics or {}
    rep.table([[name, c.get("value"), c.get("threshold"), {True: "pass", False: "FAIL", None: "reported"}[c.get("ok")]]
               for name, c in d.get("checks", {}).items()],
              header=["convergence check (docs/samplers.md)", "value", "limit", "verdict"])
    rep.text(("The sampler's convergence checks passed." if d.get("converged") else
              f"Not converged: {', '.join(d.get('failed', []))}; a longer run (--steps) would be needed to trust "
              "the std maps fully."), cls="note")
    rep.heading("3. Image-space uncertainty (Eq. 11) on novel views vs the actual error")
    for row in novel_rows:
        rep.images(row, width=200)
    rep.table([["Pearson", corr["pearson"]], ["Spearman", corr["spearman"]]],
              header=["correlation of predicted std with |error|", "value"])
    rep.heading("4. Where to look next: mutual information of candidate views (Eq. 18)")
    rep.images([(cand_png, "each dot a candidate flash direction seen from above; circles: recommended")], width=380)
    rep.heading("5. Guided capture vs a low-discrepancy baseline (Algorithm 1)")
    rep.images([(err_png, "novel-view error"), (std_png, "mean image-space std")], width=380)
    rows = []
    for lab, r in curves.items():
        for rec_ in r.rounds:
            rows.append([lab, rec_["views"], rec_["metrics"]["novel_error"], rec_["metrics"]["mean_image_std"],
                         rec_["metrics"]["param_error"]["roughness"]])
    rep.table(rows, header=["method", "views", "novel error", "mean image std", "roughness error"])
    rep.heading("Timings (seconds, this machine)")
    rep.table([[k, v] for k, v in times.items()], header=["stage", "seconds"])
    rep.heading("Reproduce")
    rep.code("bayes-brdf demo --out " + str(out) + "\n"
             "bayes-brdf fit ../shared/data/captures/card_blue --views 0,2,4,6,8 --out out/fit_card_blue\n"
             "bayes-brdf recommend ../shared/data/captures/card_blue --views 0,2,4 --k 2")
    write_text(out / "demo.json", json.dumps({"config": cfg, "seconds": times, "novel_correlation": corr,
                                              "recommended": rec.indices,
                                              "rounds": {lab: r.rounds for lab, r in curves.items()}},
                                             indent=1, default=float))
    return rep.write(out / "report.html")
