"""Fig. 2: ablation of the particle count n of SPOS for the parameter-space uncertainty (Eq. 9).

Setup (the paper's Sec. 4, "Ablation of particle count"): the procedural ``material`` (wood) at
``resolution^2`` texels, observed under ``views`` collocated flash views (20 in the paper; rectified cameras,
zenith within 60 degrees, Sobol directions), noiseless. Normals and specular albedo are known (the truth's);
RGB albedo and roughness are inferred per texel with ``FIGURE_SAMPLER`` (the former ``spos_maps``) (step ``step_size``, ``steps`` steps; the
same for every n), started from prior draws kept ``init_margin`` of each range away from its bounds (plain
prior draws near the bounds sit where the logit saturates and, with the preconditioner shared by the
particles, stay there for thousands of steps: they inflate the mean albedo std 5-6x, see
``experiments/highdim.py``). One run per n in ``particles`` (default 2, 4, 8, 16, 32), all from the same
observations; run ``i`` uses sampler seed ``seed``.

Reported per n: the mean over texels (and RGB) of the Eq. 9 std of roughness and albedo, the relative
change of that mean to the largest n, and the per-texel difference to the largest n's std map
(``mean |std_n - std_max| / mean std_max``). The paper's claim: the estimate converges for ``n >= 16``.
Sampling noise alone puts a floor under the per-texel difference (the std of n i.i.d. draws has a relative
spread of about ``1 / sqrt(2 (n - 1))``: 0.18 at n = 16), so the headline is the mean std.
"""
from __future__ import annotations

import time

import torch

from .common import FIGURE_SAMPLER, PAPER_SIGMA, prepare, say, synthetic, write_json
from ..errors import InputError
from ..inference import infer
from ..models.data import ModelData
from ..models.material import per_texel
from ..plots import line_plot, map_panel, panel_grid
from ..potential import Potential

DESCRIPTION = "Fig. 2: particle-count ablation: parameter-space std (Eq. 9) for n = 2..32 SPOS particles"

PRESETS = {
    "small": {"material": "wood", "resolution": 16, "views": 20, "particles": "2,4,8,16,32", "steps": 1000,
              "step_size": 0.02, "init_margin": 0.05, "maps": "2,4,32"},
    "full": {"material": "wood", "resolution": 64, "views": 20, "particles": "2,4,8,16,32", "steps": 4000,
             "step_size": 0.005, "init_margin": 0.05, "maps": "2,4,32"},
}


def _ints(s) -> list[int]:
    return [int(x) for x in str(s).replace(" ", "").split(",") if x]


def start(model, obs, n: int, seed: int, margin: float) -> torch.Tensor:
    """``[n, D]`` prior draws (unconstrained) with each parameter kept ``margin`` of its range off the bounds."""
    pot = Potential(model, (ModelData.from_observations(obs),))
    x = pot.to_constrained(pot.init(n, seed=seed))
    if margin > 0:
        lo, hi = model.roughness_range
        x["albedo"] = x["albedo"].clamp(margin, 1 - margin)
        x["roughness"] = x["roughness"].clamp(lo + margin * (hi - lo), hi - margin * (hi - lo))
    return pot.to_unconstrained(x)


def run(out, preset: str = "small", seed: int = 0, progress: bool = False, **overrides) -> dict:
    """Run the ablation; write ``fig2_std_vs_particles.png``, ``fig2_roughness_std_maps.png`` and ``fig2.json``."""
    cfg, out = prepare(__name__, preset, overrides, out)
    ns = sorted(set(_ints(cfg["particles"])))
    if len(ns) < 2 or ns[0] < 2:
        raise InputError(f"particles must list at least two counts >= 2, got {cfg['particles']!r}",
                         fix="e.g. --set particles=2,4,8,16,32")
    R = int(cfg["resolution"])
    truth, obs = synthetic(cfg["material"], R, views=int(cfg["views"]), seed=seed)
    model = per_texel(R, specular=truth.specular, normals=truth.normal, sigma=PAPER_SIGMA)
    params = {"step_size": float(cfg["step_size"])}

    rows, std_r, std_a = {}, {}, {}
    t_all = time.perf_counter()
    for n in ns:
        t = time.perf_counter()
        post = infer(model, obs, FIGURE_SAMPLER, map_steps=0, seed=seed, steps=int(cfg["steps"]), params=params,
                     z0=start(model, obs, n, seed, float(cfg["init_margin"])), progress=progress)
        std_r[n], std_a[n] = post.std("roughness")[0], post.std("albedo")
        say("fig2: %d particles done in %.0f s", n, time.perf_counter() - t)
        rows[n] = {"seconds": time.perf_counter() - t,
                   "mean_std_roughness": float(std_r[n].mean()), "mean_std_albedo": float(std_a[n].mean()),
                   "median_std_roughness": float(std_r[n].median()), "median_std_albedo": float(std_a[n].median()),
                   "mean_abs_error_roughness": float((post.mean("roughness")[0] - truth.roughness[0]).abs().mean())}
    big = ns[-1]
    for n in ns:
        for site, s in (("roughness", std_r), ("albedo", std_a)):
            ref = rows[big][f"mean_std_{site}"]
            rows[n][f"rel_change_{site}"] = rows[n][f"mean_std_{site}"] / ref - 1
            rows[n][f"map_diff_{site}"] = float((s[n] - s[big]).abs().mean() / s[big].mean())

    xs = ns
    line_plot(out / "fig2_std_vs_particles.png",
              {"roughness": (xs, [rows[n]["mean_std_roughness"] / rows[big]["mean_std_roughness"] for n in ns]),
               "albedo (RGB)": (xs, [rows[n]["mean_std_albedo"] / rows[big]["mean_std_albedo"] for n in ns])},
              xlabel="particles n", ylabel=f"mean std / mean std at n = {big}", logx=True,
              title=f"Fig. 2: Eq. 9 std vs particle count\n(at n = {big}: roughness "
                    f"{rows[big]['mean_std_roughness']:.3f}, albedo {rows[big]['mean_std_albedo']:.4f})")
    shown = [n for n in _ints(cfg["maps"]) if n in std_r] or [ns[0], ns[-1]]
    panel_grid(out / "fig2_roughness_std_maps.png",
               [map_panel(truth.roughness[0], "true roughness", vmax=1.0)]
               + [map_panel(std_r[n], f"roughness std, n = {n}") for n in shown], share=True, style="compact",
               title=f"{cfg['material']} {R}x{R}, {cfg['views']} views, {cfg['steps']} steps "
                     f"(std maps share one range)")

    summary = {"mean_std_roughness": {str(n): round(rows[n]["mean_std_roughness"], 5) for n in ns},
               "mean_std_albedo": {str(n): round(rows[n]["mean_std_albedo"], 5) for n in ns},
               f"rel_change_roughness_vs_n{big}": {str(n): round(rows[n]["rel_change_roughness"], 4) for n in ns},
               f"rel_change_albedo_vs_n{big}": {str(n): round(rows[n]["rel_change_albedo"], 4) for n in ns},
               # the smallest n from which every larger n is within 10% of the largest, both maps
               "converged_from": next((n for n in ns if all(
                   abs(rows[m][f"rel_change_{s}"]) <= 0.1 for m in ns if m >= n for s in ("roughness", "albedo"))),
                   big),
               "seconds": round(time.perf_counter() - t_all, 1)}
    res = {"experiment": "fig2", "preset": preset, "seed": seed, "config": cfg,
           "rows": {str(n): rows[n] for n in ns}, "summary": summary,
           "paper": "the estimated uncertainty approximately converges for n >= 16 (the paper then uses n = 20)"}
    write_json(out, "fig2", res)
    return res
