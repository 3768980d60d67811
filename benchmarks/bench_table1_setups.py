"""The default sampler on Table 1 and eight other 2-D setups: MSE of the mean / variance over the i.i.d. floor.

Usage:
    python benchmarks/bench_table1_setups.py                                  # spos, its preset
    python benchmarks/bench_table1_setups.py --params '{"precond_cap": "none"}' --steps 4000

Each row is :func:`bayes_brdf.experiments.table1.compare` (dense quadrature truth, 20 runs of 16
samples, the sampler's preset steps unless ``--steps``) for one setup: the angles of the collocated
views (the first is ``angle``, the rest ``observations``), the true albedo and roughness, sigma.
A ratio below 1 is better than 16 independent exact draws; the issue's bar is 2 (1.2 for Table 1).
Numbers only, no asserts.
"""
from __future__ import annotations

import argparse
import json
import time

from bayes_brdf.experiments.table1 import Table1Setup, compare

SETUPS = {
    "table1":         Table1Setup(),
    "0/30":           Table1Setup(observations=[30.0]),
    "20 r0.3 a0.2":   Table1Setup(angle=20.0, albedo=0.2, roughness=0.3),
    "10/25/40/15 s.05": Table1Setup(angle=10.0, observations=[25.0, 40.0, 15.0], albedo=0.8, roughness=0.7,
                                    sigma=0.05),
    "40 s.005":       Table1Setup(angle=40.0, albedo=0.3, roughness=0.2, sigma=0.005),
    "0 a.9 r.9 s.05": Table1Setup(albedo=0.9, roughness=0.9, sigma=0.05),
    "0/20/40 s.02":   Table1Setup(observations=[20.0, 40.0], sigma=0.02),
    "0/40 r.15":      Table1Setup(observations=[40.0], albedo=0.7, roughness=0.15),
    "0/15/30/45 a.1 r.4 s.01": Table1Setup(observations=[15.0, 30.0, 45.0], albedo=0.1, roughness=0.4),
    "0/2 a.4 r.3":    Table1Setup(observations=[2.0], albedo=0.4, roughness=0.3),
}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sampler", default="spos")
    ap.add_argument("--params", type=json.loads, default={}, help="JSON {param: value} for the sampler")
    ap.add_argument("--steps", type=int, default=None)
    ap.add_argument("--only", nargs="+", default=None, help="run only these setups (names as printed)")
    ap.add_argument("--json", default=None)
    a = ap.parse_args()
    rows = {}
    print(f"{'setup':26s} {'var albedo':>10s} {'var rough':>10s} {'mean ratio':>10s} {'var ratio':>10s} {'s':>5s}")
    for name, setup in SETUPS.items():
        if a.only and name not in a.only:
            continue
        t = time.perf_counter()
        res = compare(setup, samplers=(a.sampler,), steps=a.steps, params={a.sampler: a.params} if a.params else None)
        r, f = res[a.sampler], res["iid"]
        rows[name] = {"mean_ratio": r["mse_mean"] / f["mse_mean"], "var_ratio": r["mse_var"] / f["mse_var"],
                      "exact_var": res["_truth"]["var"], "seconds": time.perf_counter() - t}
        v = res["_truth"]["var"]
        print(f"{name:26s} {v[0]:10.2g} {v[1]:10.2g} {rows[name]['mean_ratio']:10.2f} {rows[name]['var_ratio']:10.2f} "
              f"{rows[name]['seconds']:5.0f}", flush=True)
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(rows, fh, indent=2)


if __name__ == "__main__":
    main()
