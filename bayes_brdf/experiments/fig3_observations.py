"""Fig. 3: parameter-space uncertainty (Eq. 9) of roughness against the number of observations.

Setup (the paper's Sec. 4.1, "Parameter-space uncertainty"): the procedural ``material`` (wood) at
``resolution^2`` texels, noiseless, observed in each lighting configuration of ``configs`` with each count
of ``counts`` (3, 10, 100 in the paper):

* ``collocated``: camera and flash together, rectified cameras at distance 3, Sobol directions within
  60 degrees of the zenith (the first ``k`` Sobol points, so the smaller sets are subsets of the larger);
* ``light_stage``: the light is not at the camera: ``C`` rectified cameras times ``L`` point lights, both
  at distance 3 on Sobol directions within 60 degrees, ``C * L = count`` (``C`` the largest divisor
  ``<= sqrt(count)``: 1 x 3, 2 x 5, 10 x 10): a third configuration, the light off the camera;
* ``environment`` (the paper's second lighting): the collocated rectified cameras (the same Sobol directions),
  lit by the known environment ``env`` alone (no flash; ``"ballroom"``, the psdr-cuda ballroom map of
  ``../shared/data``, the built-in ``studio()`` with a warning where that file is missing, ``"studio"``, or a
  map's path), its zenith on ``+z`` turned by ``env_rotate`` degrees, radiance times ``env_scale``. The truth's
  normal map is made flat (the environment's precomputed transfer is for the surface's own normals), so this
  configuration's wood differs from the others' by its board grooves' bevelled normals only.

Normals and specular albedo are known (the truth's; flat under the environment); RGB albedo and roughness are inferred per texel with
``FIGURE_SAMPLER`` (the former ``spos_maps``) (``particles`` particles, ``steps`` steps of size ``step_size``), started from prior draws kept
``init_margin`` off the bounds. Two independent runs (sampler seeds ``2 seed`` and ``2 seed + 1``) give the
two point estimates (the MAP particle of each, Eq. 7, not refined) and their L1 roughness error maps; the
std map is Eq. 9 of run 1 (``particles`` particles).

Numbers per configuration and count: the mean std (mean of both runs), the mean L1 error of the two
estimates, the Spearman correlation between std (run 1) and each estimate's error, and the mean error on
the texels in the lowest and in the highest quartile of the std (the paper: std and error do not correlate
closely, but low std goes with low error). Diagnostics: the robust spread (1.4826 x the median absolute
deviation over the particles, per texel) and ``far_fraction``, the fraction of (particle, texel) pairs whose
roughness is more than 0.1 from the truth. With many observations some particles stay in local modes of the
per-texel energy far from the truth (e.g. roughness ~0.1 for a true 0.34; energy ~50 above the mode, so of
negligible posterior mass): those inflate the Eq. 9 std while the robust spread keeps falling (see
docs/experiments.md).
"""
from __future__ import annotations

import math
import time

import numpy as np
import torch

from .common import (FIGURE_SAMPLER, PAPER_SIGMA, SURFACE, environment_light, prepare, say, synthetic,
                     write_json)
from .fig2_particles import _ints, start
from ..errors import InputError
from ..executor import using
from ..inference import infer
from ..models.material import per_texel
from ..plots import line_plot, map_panel, panel_grid
from ..render.views import View, collocated_views, hemisphere_directions, light_stage_views
from ..uncertainty import correlations

DESCRIPTION = "Fig. 3: parameter-space std (Eq. 9) and MAP errors of roughness vs number of observations"

_ENV = {"env": "ballroom", "env_scale": 1.0, "env_rotate": 0.0}
PRESETS = {
    "small": {"material": "wood", "resolution": 16, "counts": "3,10,100", "configs": "collocated,light_stage",
              "particles": 20, "steps": 500, "step_size": 0.02, "init_margin": 0.05, "far": 0.1, **_ENV},
    "full": {"material": "wood", "resolution": 64, "counts": "3,10,100", "configs": "collocated,light_stage",
             "particles": 20, "steps": 4000, "step_size": 0.005, "init_margin": 0.05, "far": 0.1, **_ENV},
    # the environment-lit rows alone (their transfer is precomputed per pixel: about 0.5 ms per pixel of a plane,
    # 3.5 minutes for the 113 views of 64^2 of the full counts): ``env_small`` is what the test runs (seconds),
    # ``env_full`` the full preset's settings (docs/experiments.md)
    "env_small": {"material": "wood", "resolution": 8, "counts": "3,10,100", "configs": "environment",
                  "particles": 20, "steps": 400, "step_size": 0.02, "init_margin": 0.05, "far": 0.1, **_ENV},
    "env_full": {"material": "wood", "resolution": 64, "counts": "3,10,100", "configs": "environment",
                 "particles": 20, "steps": 4000, "step_size": 0.005, "init_margin": 0.05, "far": 0.1, **_ENV},
}
CONFIGS = ("collocated", "light_stage", "environment")
RADIUS, POWER, MAX_ZENITH = 3.0, 10.0, 60.0


def observations(config: str, material: str, resolution: int, count: int, seed: int, env=None):
    """``(truth, Observations)`` of ``count`` views in lighting configuration ``config`` (``env``: the
    :class:`~bayes_brdf.render.environment.EnvironmentLight` of ``"environment"``)."""
    from ..guidance.acquisition import SyntheticCapture

    if config == "collocated":
        return synthetic(material, resolution, views=count, seed=seed, radius=RADIUS, power=POWER,
                         max_zenith=MAX_ZENITH)
    if config not in CONFIGS:
        raise InputError(f"unknown lighting configuration '{config}'", fix=f"use one of {', '.join(CONFIGS)}")
    truth, _ = synthetic(material, resolution, views=1, seed=seed)
    if config == "environment":
        if env is None:
            raise InputError("the environment configuration needs its environment light", fix="pass env=...")
        truth = truth.with_flat_normals()
        vs = [View(v.camera, (env,), name=f"env_{v.name}")
              for v in collocated_views(count, RADIUS, method="sobol", camera="rectified", resolution=resolution,
                                        power=POWER, max_zenith=MAX_ZENITH, seed=seed)]
        return truth, SyntheticCapture(truth, SURFACE, seed=seed)(vs)
    c = max(d for d in range(1, int(math.isqrt(count)) + 1) if count % d == 0)
    vs = light_stage_views(hemisphere_directions(c, "sobol", MAX_ZENITH, seed=seed),
                           hemisphere_directions(count // c, "sobol", MAX_ZENITH, seed=seed + 1),
                           RADIUS, RADIUS, camera="rectified", resolution=resolution, power=POWER)
    return truth, SyntheticCapture(truth, SURFACE, seed=seed)(vs)


def _quartiles(std: torch.Tensor, err: torch.Tensor) -> tuple[float, float]:
    s, e = std.flatten(), err.flatten()
    lo, hi = torch.quantile(s, 0.25), torch.quantile(s, 0.75)
    return float(e[s <= lo].mean()), float(e[s >= hi].mean())


def _spearman(a: torch.Tensor, b: torch.Tensor) -> float:
    return correlations(a, b)["spearman"]


def _fit(job: tuple, shared: tuple) -> tuple:
    """One run of the figure: configuration ``config`` with ``k`` observations ``obs`` of ``truth``, sampler seed
    ``s``: ``(MAP roughness, its L1 error, std (Eq. 9), the run's numbers)``."""
    config, k, s, truth, obs = job
    cfg, progress = shared
    R, far = int(cfg["resolution"]), float(cfg["far"])
    model = per_texel(R, specular=truth.specular, normals=truth.normal, sigma=PAPER_SIGMA)
    tr = truth.roughness[0]
    t = time.perf_counter()
    post = infer(model, obs, FIGURE_SAMPLER, map_steps=0, seed=s, steps=int(cfg["steps"]),
                 params={"step_size": float(cfg["step_size"])}, particles=int(cfg["particles"]),
                 z0=start(model, obs, int(cfg["particles"]), s, float(cfg["init_margin"])), progress=progress)
    parts = post.particles["roughness"][:, 0]                       # [n, R, R]
    est = post.map()["roughness"][0]
    err = (est - tr).abs()
    std = post.std("roughness")[0]
    mad = 1.4826 * (parts - parts.median(0).values).abs().median(0).values
    say("fig3: %s, %d observations, seed %d done in %.0f s", config, k, s, time.perf_counter() - t)
    return est, err, std, {"seed": s, "seconds": time.perf_counter() - t, "mean_std": float(std.mean()),
                           "median_std": float(std.median()), "mean_error": float(err.mean()),
                           "mean_robust_spread": float(mad.mean()),
                           "far_fraction": float(((parts - tr).abs() > far).float().mean()),
                           "mean_std_albedo": float(post.std("albedo").mean())}


def run(out, preset: str = "small", seed: int = 0, progress: bool = False, executor=None, **overrides) -> dict:
    """Run the experiment; write ``fig3_<config>.png`` per configuration, ``fig3_std_vs_observations.png``
    and ``fig3.json`` (``lighting``: each configuration's lights in words, also in its ``summary``).

    The runs (a configuration, a count, a seed) are independent: they go through ``executor``
    (:mod:`bayes_brdf.executor`: ``None`` in this process, ``True`` a local Ray, an address, or an executor),
    with the same numbers; a configuration's ``seconds`` are its observations' and its runs' own."""
    cfg, out = prepare(__name__, preset, overrides, out)
    counts = _ints(cfg["counts"])
    configs = [c for c in str(cfg["configs"]).replace(" ", "").split(",") if c]
    for c in configs:
        if c not in CONFIGS:
            raise InputError(f"unknown lighting configuration '{c}'", fix=f"configs: {', '.join(CONFIGS)}")
    if not counts or min(counts) < 1:
        raise InputError(f"counts must be positive integers, got {cfg['counts']!r}", fix="e.g. counts=3,10,100")
    R = int(cfg["resolution"])
    seeds = (2 * seed, 2 * seed + 1)
    t_all = time.perf_counter()
    env, env_text = environment_light(cfg["env"], cfg["env_scale"], cfg["env_rotate"]) \
        if "environment" in configs else (None, None)
    lighting = {"collocated": f"collocated flash (power {POWER:g}, distance {RADIUS:g})",
                "light_stage": f"light stage: point lights (power {POWER:g}, distance {RADIUS:g}) off the cameras",
                "environment": f"environment alone: {env_text}"}
    # every (configuration, count, seed) is one independent run: the runs go through the executor
    t_obs, problems = {}, {}
    for config in configs:
        t = time.perf_counter()
        for k in counts:
            problems[config, k] = observations(config, cfg["material"], R, k, seed, env=env)
        t_obs[config] = time.perf_counter() - t
    keys = [(config, k, s) for config in configs for k in counts for s in seeds]
    with using(executor) as ex:
        done = ex.map(_fit, [(c, k, s, *problems[c, k]) for c, k, s in keys], shared=(cfg, progress),
                      seeds=[s for _, _, s in keys])
    runs = dict(zip(keys, done))
    results, summary = {}, {}
    for config in configs:
        rows, maps = {}, {}
        for k in counts:
            obs = problems[config, k][1]
            ests, errs, stds = ([runs[config, k, s][i] for s in seeds] for i in range(3))
            row = {"runs": [runs[config, k, s][3] for s in seeds]}
            q = [_quartiles(stds[0], e) for e in errs]
            row.update({
                "views": len(obs.views),
                "mean_radiance": float(obs.images.mean()),
                "mean_std": float(np.mean([r["mean_std"] for r in row["runs"]])),
                "mean_error": float(np.mean([float(e.mean()) for e in errs])),
                "mean_robust_spread": float(np.mean([r["mean_robust_spread"] for r in row["runs"]])),
                "far_fraction": float(np.mean([r["far_fraction"] for r in row["runs"]])),
                "spearman_std_error": [_spearman(stds[0], e) for e in errs],
                "error_low_std_quartile": float(np.mean([a for a, _ in q])),
                "error_high_std_quartile": float(np.mean([b for _, b in q])),
            })
            rows[k], maps[k] = row, (ests, errs, stds[0])
        # the grid: rows estimate 1, error 1, estimate 2, error 2, std; columns the counts
        e_max = max(float(np.percentile(e.numpy(), 99)) for k in counts for e in maps[k][1])
        s_max = max(float(np.percentile(maps[k][2].numpy(), 99)) for k in counts)
        panels = []
        for name, pick, vm in (("estimate 1", lambda m: m[0][0], 1.0), ("L1 error 1", lambda m: m[1][0], e_max),
                               ("estimate 2", lambda m: m[0][1], 1.0), ("L1 error 2", lambda m: m[1][1], e_max),
                               ("std (Eq. 9)", lambda m: m[2], s_max)):
            for k in counts:
                panels.append(map_panel(pick(maps[k]), f"{name}, {k} obs.", vmax=vm))
        panel_grid(out / f"fig3_{config}.png", panels, ncols=len(counts), style="compact",
                   title=f"Fig. 3 ({config}): roughness, {cfg['material']} {R}x{R}, {cfg['particles']} particles, "
                         f"{cfg['steps']} steps" + (f"\nlit by {env_text}" if config == "environment" else ""))
        results[config] = {str(k): rows[k] for k in counts}
        ms = [rows[k]["mean_std"] for k in counts]
        summary[config] = {
            "mean_std": {str(k): round(rows[k]["mean_std"], 4) for k in counts},
            "mean_error": {str(k): round(rows[k]["mean_error"], 4) for k in counts},
            "mean_robust_spread": {str(k): round(rows[k]["mean_robust_spread"], 4) for k in counts},
            "error_low_vs_high_std_quartile": {str(k): [round(rows[k]["error_low_std_quartile"], 4),
                                                        round(rows[k]["error_high_std_quartile"], 4)]
                                               for k in counts},
            "spearman_std_error": {str(k): round(float(np.mean(rows[k]["spearman_std_error"])), 3) for k in counts},
            "std_falls": all(a > b for a, b in zip(ms, ms[1:])),
            "lighting": lighting[config],
            "seconds": round(t_obs[config] + sum(r["seconds"] for k in counts for r in rows[k]["runs"]), 1),
        }
    series, styles = {}, {}
    quantities = (("std", "mean_std", "-"), ("robust spread", "mean_robust_spread", "--"),
                  ("MAP error", "mean_error", ":"))
    for i, config in enumerate(configs):           # one colour per configuration, one dash per quantity
        for name, key, dash in quantities:
            label = f"{name}, {config.replace('_', ' ')}"
            series[label] = (counts, [results[config][str(k)][key] for k in counts])
            styles[label] = {"color": f"C{i}", "ls": dash}
    line_plot(out / "fig3_std_vs_observations.png", series, xlabel="observations (log scale)",
              ylabel="roughness, mean over texels", logx=True, line_styles=styles, legend="right",
              title="Fig. 3: roughness std (Eq. 9), robust spread\n(1.4826 MAD) and MAP L1 error")
    summary["seconds"] = round(time.perf_counter() - t_all, 1)
    res = {"experiment": "fig3", "preset": preset, "seed": seed, "config": cfg, "rows": results, "summary": summary,
           "lighting": {c: lighting[c] for c in configs},
           "paper": "parameter-space uncertainty falls as observations increase; it does not correlate closely "
                    "with the point estimates' errors, but low uncertainty goes with low error"}
    write_json(out, "fig3", res)
    return res
