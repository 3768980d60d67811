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

On a mesh (``surface``: ``"bowl"``, ``"sphere"``, ``"block"``, ``"bunny"`` or a mesh file; presets ``mesh_small``
and ``mesh``) the material covers the object through its uv and every camera is perspective, aimed at
``mesh.center`` from 2.6 radii (:func:`~.common.mesh_rig`, ``image_resolution^2`` pixels), within
``MESH_ZENITH`` of +z (the object is seen from the side too): collocated candidates and novel views as above;
in the light stage the cameras sit on that sphere and the lights on one ``LIGHT_DISTANCE`` times larger (power by
the square of the distance, so the object is as bright as under the flash). The low-discrepancy directions of
the baseline are measured from ``mesh.center``; the novel-view metrics count the pixels that see the object.

At every round, both methods' posteriors are measured on held-out novel views (same views for both): the
rendering error of the MAP estimate and the mean image-space std (Eq. 11). Numbers are averaged over
``seeds`` runs; the figure shows both methods against the number of views, one plot per setting and metric.
"""
from __future__ import annotations

import math
import statistics
import time
from pathlib import Path

import torch

from ..executor import using
from ..guidance.acquisition import Evaluation, SyntheticCapture, guided_acquisition
from ..guidance.recommend import low_discrepancy
from ..guidance.scores import parse_noise_var
from ..models.material import per_texel
from ..render.views import collocated_views, hemisphere_directions, light_stage_views
from ..plots import line_plot, views_polar
from .common import (PAPER_SIGMA, SURFACE, SURFACES, is_mesh, mesh_rig, prepare, sampler_of, say, scene_surface,
                     write_json)

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
for _p in PRESETS.values():   # the planar sample; ``image_resolution`` is for meshes (0: twice the map resolution)
    _p.update(surface="plane", image_resolution=0, sampler="figure")
# on a mesh (``camera`` and ``fov`` are the plane's: a mesh is seen by perspective cameras, see the docstring)
# and scored with the observation noise: noise-free (``noise_var=0``) every counted pixel adds its log spread, a
# negative number for a pixel the particles agree on, so on a mesh, where the number of texels a view sees
# varies, the sum prefers views that see few texels (on the bowl its top 5 are side views with 28-39 counted
# pixels where the median candidate has 116; see docs/experiments.md, "Fig. 7 on a mesh")
PRESETS["mesh_small"] = dict(PRESETS["small"], surface="bowl", resolution=16, image_resolution=32, candidates=100,
                             cameras_ls=20, lights_ls=5, novel=4, steps=250, seeds=1, sampler="spos",
                             noise_var="observation")
PRESETS["mesh"] = dict(PRESETS["full"], surface="bunny", resolution=32, image_resolution=48, candidates=1000,
                       cameras_ls=70, lights_ls=30, novel=10, steps=800, seeds=3, sampler="spos",
                       noise_var="observation")
#: cameras on a mesh stay within this zenith angle (degrees from +z about ``mesh.center``), lights too
MESH_ZENITH = 85.0
#: light-stage lights on a mesh: on a sphere this many times the cameras' distance
LIGHT_DISTANCE = 4.0 / 3.0
METHODS = {"mi": "guided (mutual information)", "sobol": "baseline (low-discrepancy)"}


def _mesh_setting(cfg, kind: str, seed: int, mesh):
    dist, kw = mesh_rig(mesh, int(cfg["image_resolution"]) or 2 * int(cfg["resolution"]))
    z = MESH_ZENITH
    if kind == "collocated":
        cands = collocated_views(int(cfg["candidates"]), dist, method="sobol", seed=seed, max_zenith=z, **kw)
        novel = collocated_views(int(cfg["novel"]), dist, method="random", seed=10_000 + seed, max_zenith=z, **kw)
        return cands, novel, int(cfg["initial"]), [int(cfg["k_first"])] + [int(cfg["k"])] * (int(cfg["rounds"]) - 1)
    ld = LIGHT_DISTANCE * dist
    kw = dict(kw, power=kw["power"] * LIGHT_DISTANCE ** 2)
    cams = hemisphere_directions(int(cfg["cameras_ls"]), "sobol", z, seed=seed)
    lights = hemisphere_directions(int(cfg["lights_ls"]), "fibonacci", z)
    cands = light_stage_views(cams, lights, dist, ld, **kw)
    g = torch.Generator().manual_seed(10_000 + seed)
    ncam = hemisphere_directions(int(cfg["novel"]), "random", z, seed=10_000 + seed)
    nl = lights[torch.randint(len(lights), (int(cfg["novel"]),), generator=g)]
    novel = [v for i, v in enumerate(light_stage_views(ncam, nl, dist, ld, **kw)) if i % (len(nl) + 1) == 0]
    return cands, novel, int(cfg["initial_ls"]), [int(cfg["k_ls"])] * int(cfg["rounds_ls"])


def _setting(cfg, kind: str, seed: int, surface=SURFACE):
    if is_mesh(surface):
        return _mesh_setting(cfg, kind, seed, surface)
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
    """Both methods on one setting and seed: ``{method: [{"views", "novel_error", "mean_image_std", "param_error",
    "picks"}, ...], "initial": [candidate indices]}`` (``picks``: the candidates recommended after that round)."""
    from ..materials import make_material

    surface = scene_surface(cfg["surface"])
    truth = make_material(cfg["material"], int(cfg["resolution"]), seed=seed).to(torch.float32)
    cap = SyntheticCapture(truth, surface, noise_sigma=float(cfg["noise"]), seed=seed)
    cands, novel, n0, ks = _setting(cfg, kind, seed, surface)
    ev = Evaluation.synthetic(SyntheticCapture(truth, surface), novel)   # noiseless truth for the error
    init_idx = (low_discrepancy(cands, n0, seed=seed, target=surface.center) if is_mesh(surface)
                else low_discrepancy(cands, n0, seed=seed))
    initial = cap([cands[i] for i in init_idx])
    res = {}
    for method in METHODS:
        r = guided_acquisition(per_texel(int(cfg["resolution"]), sigma=PAPER_SIGMA), initial, cands, cap, rounds=len(ks), k=ks,
                               method=method, radius=float(cfg["radius"]), steps=int(cfg["steps"]),
                               sampler=sampler_of(cfg["sampler"]), map_steps=0,
                               particles=int(cfg["particles"]), seed=seed, initial_indices=init_idx,
                               evaluation=ev, progress=progress,
                               on_round=lambda rec, post, m=method: say(
                                   "fig7: %s, seed %d, %s: round %d done (%d views, novel error %.4f)", kind, seed,
                                   METHODS[m], rec["round"], rec["views"],
                                   rec["metrics"].get("novel_error", float("nan"))),
                               out=None if out is None else out / f"{kind}_{method}_seed{seed}",
                               score_kw={"estimator": cfg["estimator"], "noise_var": cfg["noise_var"]})
        res[method] = [{"views": rec["views"], **{k: rec["metrics"][k] for k in ("novel_error", "mean_image_std")},
                        "param_error": rec["metrics"].get("param_error"),
                        "picks": rec["picks"]["indices"] if rec.get("picks") else []} for rec in r.rounds]
    res["initial"] = [int(i) for i in init_idx]
    return res


def _directions(view, centre) -> tuple[tuple[float, float], tuple[float, float]]:
    """``((camera zenith, azimuth), (light zenith, azimuth))`` in degrees, seen from ``centre``."""
    out = []
    for p in (view.camera.position, view.lights[0].position):
        d = [a - b for a, b in zip(p, centre)]
        r = math.sqrt(sum(x * x for x in d))
        out.append((math.degrees(math.acos(max(-1.0, min(1.0, d[2] / r)))), math.degrees(math.atan2(d[1], d[0]))))
    return out[0], out[1]


def _seeds(n) -> str:
    return f"{int(n)} seed{'' if int(n) == 1 else 's'}"


def _views_figure(path, cfg, kind: str, runs: list, seed: int, surface, name: str):
    """Where each method's views went (all seeds): camera directions seen from the centre, polar (radius: zenith
    angle), coloured by the round that added them; light-stage lights as crosses of the same colour."""
    centre = tuple(surface.center)
    panels = {}
    for m, title in METHODS.items():
        panels[title] = []
        for s, run in enumerate(runs):
            cands = _setting(cfg, kind, seed + s, surface)[0]
            groups = [run["initial"]] + [row["picks"] for row in run[m][:-1]]
            panels[title].append([(r, [_directions(cands[i], centre) for i in idx]) for r, idx in enumerate(groups)])
    what = "cameras (dots) and lights (crosses)" if kind == "light_stage" else "cameras"
    return views_polar(path, panels, rounds=max(len(runs[0]["mi"]) - 1, 1), lights=kind == "light_stage",
                       title=f"Fig. 7, {kind.replace('_', ' ')} on the {name}: {what} of {_seeds(len(runs))}, "
                             f"seen from above (radius: zenith angle)")


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
            out[method][key + "_sd"] = [statistics.stdev(v) if len(v) > 1 else 0.0 for v in vals]
    return out


def _run_setting(job: tuple, shared: tuple) -> dict:
    """One ``(setting, seed)`` of the figure, timed (an executor's piece of work)."""
    kind, s = job
    cfg, out, progress = shared
    t = time.perf_counter()
    res = run_setting(cfg, kind, s, out, progress)
    return {**res, "seconds": time.perf_counter() - t}


def run(out, preset: str = "small", seed: int = 0, progress: bool = False, executor=None, **overrides) -> dict:
    """Run the figure; write ``fig7_<setting>_<metric>.png`` and ``fig7.json``. The ``(setting, seed)`` runs are
    independent: they go through ``executor`` (:mod:`bayes_brdf.executor`: ``None`` in this process, ``True`` a
    local Ray, an address, or an executor), with the same numbers; a setting's ``seconds`` are its runs' own."""
    cfg, out = prepare(__name__, preset, overrides, out)
    t0 = time.perf_counter()
    result = {"preset": preset, "config": cfg, "settings": {}}
    summary, seconds = {}, {}
    kinds = ("collocated", "light_stage")
    jobs = [(kind, seed + s) for kind in kinds for s in range(int(cfg["seeds"]))]
    with using(executor) as ex:
        done = ex.map(_run_setting, jobs, shared=(cfg, (out / "runs").resolve(), progress),
                      seeds=[s for _, s in jobs])
    for kind in kinds:
        runs = [d for (k, _), d in zip(jobs, done) if k == kind]
        seconds[kind] = sum(r.pop("seconds") for r in runs)
        curves = _mean_curves(runs)
        surface = scene_surface(cfg["surface"])
        name = cfg["surface"] if cfg["surface"] in SURFACES else surface.name
        result["settings"][kind] = {"runs": runs, "mean": curves}
        for key, label in (("novel_error", "novel-view error of the MAP"),
                           ("mean_image_std", "mean image-space std (Eq. 11)")):
            line_plot(out / f"fig7_{kind}_{key}.png",
                      {METHODS[m]: (curves[m]["views"], curves[m][key], curves[m][key + "_sem"]) for m in METHODS},
                      xlabel="number of views", ylabel=label,
                      title=(f"Fig. 7, {kind.replace('_', ' ')} on the {name}:\nmean of {_seeds(cfg['seeds'])} "
                             f"(bars: s.e.)" if is_mesh(surface) else
                             f"Fig. 7, {kind.replace('_', ' ')}: mean of {cfg['seeds']} seeds (bars: s.e.)"))
        if is_mesh(surface):
            _views_figure(out / f"fig7_{kind}_views.png", cfg, kind, runs, seed, surface, name)
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
            # the last round: mean and sd over seeds, per seed, and in how many seeds guided is lower
            "final": {m: {"error_mean": curves[m]["novel_error"][-1], "error_sd": curves[m]["novel_error_sd"][-1],
                          "std_mean": curves[m]["mean_image_std"][-1], "std_sd": curves[m]["mean_image_std_sd"][-1],
                          "error_per_seed": [r[m][-1]["novel_error"] for r in runs]} for m in METHODS},
            "guided_lower_final_error_seeds": sum(r["mi"][-1]["novel_error"] < r["sobol"][-1]["novel_error"]
                                                  for r in runs),
        }
    result["summary"] = summary
    result["seconds"] = {**seconds, "total": time.perf_counter() - t0}
    write_json(out, "fig7", result)
    return result
