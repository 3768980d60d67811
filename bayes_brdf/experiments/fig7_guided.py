"""Fig. 7: guided capture (mutual information, Algorithm 1 batched) vs a low-discrepancy baseline.

Two settings on a synthetic per-texel material, both with rectified cameras at map resolution:

* **collocated** -- candidates are flash views on a Sobol hemisphere; both methods start from the same
  ``initial`` low-discrepancy views; the guided one then adds ``k_first`` recommended views, then ``k``
  per round (the paper: 1000 candidates, 5 uniform + 5 recommended, then +10 per round);
* **light stage** -- candidates are every (camera, light) pair of a camera set and a light set; the
  baseline pairs each low-discrepancy camera with a random light; start from ``initial_ls`` views and add
  ``k_ls`` per round (the paper: 5000 cameras x 30 lights, 3 uniform, +3 per round).

Candidates are scored with ``noise_var=0`` (the paper's Eq. 18 for a deterministic renderer). Measured on
the full preset, seed 0: with the model's observation noise in the score (``noise_var="observation"``) the
guided views went to grazing mirror configurations (roughness learnt well, albedo badly) and the guided
novel-view error was 1.18x the baseline's in the light stage; noise-free it is lower than the baseline's.

At every round, both methods' posteriors are measured on held-out novel views (same views for both): the
rendering error of the MAP estimate and the mean image-space std (Eq. 11). Numbers are averaged over
``seeds`` runs; the figure shows both methods against the number of views, one plot per setting and metric.
"""
from __future__ import annotations

import statistics
from pathlib import Path

import torch

from ..guidance.acquisition import Evaluation, SyntheticCapture, guided_acquisition
from ..guidance.recommend import low_discrepancy
from ..guidance.scores import parse_noise_var
from ..models.material import per_texel
from ..render.views import collocated_views, hemisphere_directions, light_stage_views
from .common import FIGURE_SAMPLER, PAPER_SIGMA, SURFACE, line_plot, prepare, say, write_json

DESCRIPTION = "guided capture (MI) vs low-discrepancy baseline: novel-view error and image-space std vs views"

PRESETS = {
    "small": dict(material="wood", resolution=16, candidates=300, initial=3, k_first=3, k=3, rounds=2,
                  cameras_ls=60, lights_ls=8, initial_ls=3, k_ls=3, rounds_ls=2, novel=8, steps=800,
                  particles=20, seeds=2, noise=0.005, radius=10.0, estimator="mc", noise_var=0.0,
                  camera="rectified", fov=40.0),
    "full": dict(material="wood", resolution=64, candidates=1000, initial=5, k_first=5, k=10, rounds=3,
                 cameras_ls=500, lights_ls=30, initial_ls=3, k_ls=3, rounds_ls=4, novel=20, steps=4000,
                 particles=20, seeds=3, noise=0.005, radius=10.0, estimator="mc", noise_var=0.0,
                 camera="rectified", fov=40.0),
}
METHODS = {"mi": "guided (mutual information)", "sobol": "baseline (low-discrepancy)"}


def _setting(cfg, kind: str, seed: int):
    R = int(cfg["resolution"])
    common = dict(camera=str(cfg["camera"]), resolution=R, power=10.0, fov=float(cfg["fov"]))
    if kind == "collocated":
        cands = collocated_views(int(cfg["candidates"]), 3.0, method="sobol", seed=seed, max_zenith=60, **common)
        novel = collocated_views(int(cfg["novel"]), 3.0, method="random", seed=10_000 + seed, max_zenith=60, **common)
        return cands, novel, int(cfg["initial"]), [int(cfg["k_first"])] + [int(cfg["k"])] * (int(cfg["rounds"]) - 1)
    cams = hemisphere_directions(int(cfg["cameras_ls"]), "sobol", 60.0, seed=seed)
    lights = hemisphere_directions(int(cfg["lights_ls"]), "fibonacci", 70.0)
    cands = light_stage_views(cams, lights, 3.0, 4.0, **common)
    g = torch.Generator().manual_seed(10_000 + seed)
    ncam = hemisphere_directions(int(cfg["novel"]), "random", 60.0, seed=10_000 + seed)
    nl = lights[torch.randint(len(lights), (int(cfg["novel"]),), generator=g)]
    novel = [v for i, v in enumerate(light_stage_views(ncam, nl, 3.0, 4.0, **common)) if i % (len(nl) + 1) == 0]
    return cands, novel, int(cfg["initial_ls"]), [int(cfg["k_ls"])] * int(cfg["rounds_ls"])


def run_setting(cfg, kind: str, seed: int, out: Path | None = None, progress: bool = False) -> dict:
    """Both methods on one setting and seed: ``{method: [{"views", "novel_error", "mean_image_std"}, ...]}``."""
    from ..materials import make_material

    truth = make_material(cfg["material"], int(cfg["resolution"]), seed=seed).to(torch.float32)
    cap = SyntheticCapture(truth, SURFACE, noise_sigma=float(cfg["noise"]), seed=seed)
    cands, novel, n0, ks = _setting(cfg, kind, seed)
    ev = Evaluation.synthetic(SyntheticCapture(truth, SURFACE), novel)   # noiseless truth for the error
    init_idx = low_discrepancy(cands, n0, seed=seed)
    initial = cap([cands[i] for i in init_idx])
    res = {}
    for method in METHODS:
        r = guided_acquisition(per_texel(int(cfg["resolution"]), sigma=PAPER_SIGMA), initial, cands, cap, rounds=len(ks), k=ks,
                               method=method, radius=float(cfg["radius"]), steps=int(cfg["steps"]),
                               sampler=FIGURE_SAMPLER, map_steps=0,
                               particles=int(cfg["particles"]), seed=seed, initial_indices=init_idx,
                               evaluation=ev, progress=progress,
                               on_round=lambda rec, post, m=method: say(
                                   "fig7: %s, seed %d, %s: round %d done (%d views, novel error %.4f)", kind, seed,
                                   METHODS[m], rec["round"], rec["views"],
                                   rec["metrics"].get("novel_error", float("nan"))),
                               out=None if out is None else out / f"{kind}_{method}_seed{seed}",
                               score_kw={"estimator": cfg["estimator"], "noise_var": cfg["noise_var"]})
        res[method] = [{"views": rec["views"], **{k: rec["metrics"][k] for k in ("novel_error", "mean_image_std")},
                        "param_error": rec["metrics"].get("param_error")} for rec in r.rounds]
    return res


SETTING_TYPES = {"noise_var": parse_noise_var}


def _mean_curves(runs: list[dict]) -> dict:
    out = {}
    for method in METHODS:
        rows = [r[method] for r in runs]
        views = [x["views"] for x in rows[0]]
        out[method] = {"views": views}
        for key in ("novel_error", "mean_image_std"):
            vals = [[row[i][key] for row in rows] for i in range(len(views))]
            out[method][key] = [statistics.fmean(v) for v in vals]
            out[method][key + "_sem"] = [statistics.stdev(v) / len(v) ** 0.5 if len(v) > 1 else 0.0 for v in vals]
    return out


def run(out, preset: str = "small", seed: int = 0, progress: bool = False, **overrides) -> dict:
    cfg, out = prepare(__name__, preset, overrides, out)
    result = {"preset": preset, "config": cfg, "settings": {}}
    summary = {}
    for kind in ("collocated", "light_stage"):
        runs = [run_setting(cfg, kind, seed + s, out / "runs", progress) for s in range(int(cfg["seeds"]))]
        curves = _mean_curves(runs)
        result["settings"][kind] = {"runs": runs, "mean": curves}
        for key, label in (("novel_error", "novel-view error of the MAP"),
                           ("mean_image_std", "mean image-space std (Eq. 11)")):
            line_plot(out / f"fig7_{kind}_{key}.png",
                      {METHODS[m]: (curves[m]["views"], curves[m][key]) for m in METHODS},
                      errors={METHODS[m]: curves[m][key + "_sem"] for m in METHODS},
                      xlabel="number of views", ylabel=label,
                      title=f"Fig. 7, {kind.replace('_', ' ')}: mean of {cfg['seeds']} seeds (bars: s.e.)")
        # after the first recommendation (equal view counts, both methods)
        g, b = curves["mi"], curves["sobol"]
        later = range(1, len(g["views"]))
        summary[kind] = {
            "views": g["views"],
            "guided_error": g["novel_error"], "baseline_error": b["novel_error"],
            "guided_std": g["mean_image_std"], "baseline_std": b["mean_image_std"],
            "error_ratio_after_guidance": statistics.fmean(g["novel_error"][i] / b["novel_error"][i] for i in later),
            "std_ratio_after_guidance": statistics.fmean(g["mean_image_std"][i] / b["mean_image_std"][i]
                                                         for i in later),
        }
    result["summary"] = summary
    write_json(out, "fig7", result)
    return result
