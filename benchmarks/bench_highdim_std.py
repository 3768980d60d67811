"""High-dimensional truth check: per-texel std ratios (estimated / exact) of every sampler at n = 20 particles.

Usage:
    python benchmarks/bench_highdim_std.py --noise                           # all samplers, their presets
    python benchmarks/bench_highdim_std.py --noise --resolution 64 --samplers iid spos   # the default at 64^2
    python benchmarks/bench_highdim_std.py --samplers spos sgld --steps 2000 \\
        --params '{"spos": {"beta": 1, "step_size": 0.03}, "sgld": {"step_size": 0.003}}'
    python benchmarks/bench_highdim_std.py --grid spos --steps 1000 \\
        --grid-params '{"beta": [1, 10], "step_size": [0.01, 0.03]}'           # a sweep: one row per combination

Setting (see :mod:`bayes_brdf.experiments.highdim`): a ``per_texel`` gray model,
32 x 32 texels (D = 2048), 5 rectified collocated views, sigma 0.01, noiseless
observations, no smoothness prior, so the posterior factorises per texel and
each texel's exact mean and std come from quadrature. Rows ``iid`` (20 exact
independent draws: the best any 20 samples can do) and ``prior`` (the initial
particles) frame the samplers. Prints numbers only (no asserts): a ratio near
1 for both maps is calibrated, far below 1 is collapse, far above 1 is not
converged / over-dispersed. The tails matter as much as the median: the
q10-q90 range and the fraction of texels whose std is off by more than 2x
(what a user looking at one texel meets).
"""
from __future__ import annotations

import argparse
import itertools
import json
import os
import time
from dataclasses import asdict

import torch

from bayes_brdf.experiments import highdim as H


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=None, help="steps for every sampler (default: each preset's)")
    ap.add_argument("--samplers", nargs="+", default=["iid", "prior", *H.SAMPLERS])
    ap.add_argument("--params", type=json.loads, default={}, help="JSON {sampler: {param: value}}")
    ap.add_argument("--grid", default=None, help="sweep this sampler over --grid-params instead")
    ap.add_argument("--grid-params", type=json.loads, default={}, help="JSON {param: [values]} for --grid")
    ap.add_argument("--grid-steps", type=int, nargs="+", default=None, help="steps values to sweep with --grid")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--particles", type=int, default=20)
    ap.add_argument("--threads", type=int, default=0, help="torch threads (0: torch's default)")
    ap.add_argument("--noise", action="store_true", help="seeded Laplace noise instead of noiseless observations")
    ap.add_argument("--init-margin", type=float, default=None,
                    help="clamp the initial prior draws to the central 1 - 2 m of each range "
                         "(default: each preset's init_margin; 0: plain prior draws)")
    ap.add_argument("--resolution", type=int, default=32, help="texels per side (D = 2 R^2)")
    ap.add_argument("--json", default=None, help="also write the rows to this JSON file")
    ap.add_argument("--truth-cache", default=None, help="load / save the exact posterior here (torch.save)")
    a = ap.parse_args()
    if a.threads:
        torch.set_num_threads(a.threads)

    prob = H.setup(H.HighDimSetup(noise=a.noise, seed=a.seed, resolution=a.resolution))
    ex = None
    if a.truth_cache and os.path.exists(a.truth_cache):
        ex = torch.load(a.truth_cache, weights_only=False)
        if ex.get("setup") != asdict(prob.setup):
            ex = None
    if ex is None:
        ex = H.exact_std(prob)
        if a.truth_cache:
            torch.save({**ex, "setup": asdict(prob.setup)}, a.truth_cache)
    print(H.describe(prob, ex))
    print()
    if a.grid is None:
        table = H.compare(a.samplers, steps=a.steps, seed=a.seed, params=a.params, problem=prob, exact=ex,
                          particles=a.particles, init_margin=a.init_margin)
        print(H.markdown(table))
        for name, v in table.items():
            if v["params"]:
                print(f"{name}: {json.dumps(v['params'], default=str)}")
        rows = list(table.values())
    else:
        keys = list(a.grid_params)
        base = {**H.DEFAULT_PARAMS.get(a.grid, {}), **a.params.get(a.grid, {})}
        rows, table = [], {}
        print(f"| {' | '.join(keys)} | steps | std ratio albedo | std ratio roughness | |mean err|/std albedo | "
              f"|mean err|/std roughness | MAD/std albedo | MAD/std roughness | seconds |")
        print("|" + "---|" * (len(keys) + 8))
        for steps in a.grid_steps or [a.steps]:
            for combo in itertools.product(*(a.grid_params[k] for k in keys)):
                p = {**base, **dict(zip(keys, combo))}
                t0 = time.perf_counter()
                v = H.std_ratios(a.grid, p, steps, a.seed, particles=a.particles, problem=prob, exact=ex,
                                 init_margin=a.init_margin)
                v["wall"] = time.perf_counter() - t0
                rows.append(v)
                cells = " | ".join(str(c) for c in combo)
                if "error" in v:
                    print(f"| {cells} | {steps} | failed: {v['error'][:60]} | | | | | | {v['seconds']:.1f} |", flush=True)
                else:
                    print(f"| {cells} | {steps} | {v['ratio_albedo']:.3g} | {v['ratio_roughness']:.3g} | "
                          f"{v['mean_err_albedo']:.3g} | {v['mean_err_roughness']:.3g} | {v['mad_albedo']:.2g} | "
                          f"{v['mad_roughness']:.2g} | {v['seconds']:.1f} |", flush=True)
    if a.json:
        with open(a.json, "w") as f:
            json.dump(rows, f, indent=1, default=str)


if __name__ == "__main__":
    main()
