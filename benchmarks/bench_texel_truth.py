"""The default sampler's roughness maps on real photos against each texel's exact posterior (quadrature).

    python benchmarks/bench_texel_truth.py [--capture card_blue] [--views 0,3,4,6,7] [--resolution 64]
        [--runs "default" "texel_moves=0" "texel_moves=0 steps=4000" ...]

Each run is a ``per_texel`` fit with the default model (as ``bayes-brdf fit``), the sampler's preset plus the
run's ``key=value`` overrides (``steps=N`` sets the run length). The truth is
:func:`bayes_brdf.experiments.texel_truth.roughness_marginals` at the first run's median noise scale. The texels
are split into quarters by their exact roughness std; per quarter the table gives the exact mean roughness and
std, each run's (std over its particles, ddof 1), and the share of particle values that sit where the exact
posterior density is under 1 % of the texel's peak ("stranded": in a weak second mode, or on the way out of it).
"""
from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bayes_brdf.errors import ConvergenceWarning  # noqa: E402
from bayes_brdf.experiments.texel_truth import roughness_marginals  # noqa: E402
from bayes_brdf.inference import infer  # noqa: E402
from bayes_brdf.io import load_capture  # noqa: E402
from bayes_brdf.runs.fingerprint import model_table  # noqa: E402
from bayes_brdf.samplers.texel_moves import texel_energy  # noqa: E402

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "captures"


def parse_run(spec: str) -> tuple[dict, "int | None"]:
    params, steps = {}, None
    for kv in spec.split():
        if kv == "default":
            continue
        k, v = kv.split("=", 1)
        try:
            v = json.loads(v)
        except json.JSONDecodeError:
            pass
        if k == "steps":
            steps = v
        else:
            params[k] = v
    return params, steps


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--capture", default="card_blue")
    ap.add_argument("--views", default="0,3,4,6,7")
    ap.add_argument("--resolution", type=int, default=64)
    ap.add_argument("--runs", nargs="+", default=["default", "texel_moves=0", "texel_moves=0 steps=4000"])
    a = ap.parse_args(argv)
    warnings.simplefilter("ignore", ConvergenceWarning)
    cap = load_capture(DATA / a.capture, resolution=a.resolution, max_resolution=128)
    obs = cap.subset([int(v) for v in a.views.split(",")])
    table = model_table("per_texel", {}, obs.resolution[0])
    runs, truth = [], None
    for spec in a.runs:
        params, steps = parse_run(spec)
        t = time.perf_counter()
        post = infer(table, obs, "spos", steps=steps, params=params or None, progress=False)
        secs = time.perf_counter() - t
        pot = post.potential
        r = post.particles["roughness"].reshape(post.num_particles, -1).double()
        if truth is None:
            _, (sig, kap) = texel_energy(pot, post.z)
            s, k = float(sig.median()), float(kap.median())
            truth = roughness_marginals(pot.model, pot.args[0], s, k)
            q = torch.quantile(truth["std"], torch.tensor([0.25, 0.5, 0.75], dtype=torch.float64))
            quarter = torch.bucketize(truth["std"], q)
            print(f"{a.capture} views {a.views} at {a.resolution}²: exact roughness posteriors at sigma {s:.4f} "
                  f"(kappa sigma {k * s:.3f}); texel quarters by exact std, edges {[round(float(x), 3) for x in q]}")
        p, grid = truth["p"], truth["grid"]
        cell = torch.bucketize(r, (grid[1:] + grid[:-1]) / 2)                           # [n, T]
        dens = torch.gather(p.T, 1, cell.T).T                                            # [n, T]
        stranded = dens < 0.01 * p.max(0).values[None]
        runs.append((spec, post.meta["steps"], secs, r.mean(0), r.std(0), stranded))
    print("| quarter | exact mean | exact std | " + " | ".join(f"{s} ({st} steps, {sec:.0f} s): mean / std / stranded"
                                                         for s, st, sec, *_ in runs) + " |")
    print("|---" * (3 + len(runs)) + "|")
    for b in range(4):
        m = quarter == b
        cells = [f"{float(mu[m].mean()):.3f} / {float(sd[m].mean()):.3f} / {100 * float(st[:, m].float().mean()):.1f} %"
                 for _, _, _, mu, sd, st in runs]
        print(f"| {b + 1} | {float(truth['mean'][m].mean()):.3f} | {float(truth['std'][m].mean()):.3f} | "
              + " | ".join(cells) + " |")
    allm = [f"{float(sd.mean()):.3f}" for *_, sd, _ in runs]
    print(f"| all (mean std) | | {float(truth['std'].mean()):.3f} | " + " | ".join(allm) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
