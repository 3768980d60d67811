"""``steps="auto"`` against the preset's fixed run: the same answer in less time?

Usage:
    python benchmarks/bench_auto_steps.py                      # the three real captures at 64^2 and the exact-truth problem
    python benchmarks/bench_auto_steps.py --resolution 128 --captures card_blue

For each case, ``bayes-brdf fit`` twice with defaults: once with the preset's steps (2000), once with
``--steps auto`` (a quarter of them, annealed over that, then half as many again until the convergence checks
pass; bayes_brdf.inference.auto_steps). Printed per case: the steps each ran, the sampling seconds, the
held-out 50 % / 90 % coverage and Spearman(std, |error|) of each, and how far the auto run's std maps are
from the fixed run's: the median over texels of ``|std_auto - std_fixed| / std_fixed`` per map, and the
same between two fixed runs of other seeds (``--seeds``: the Monte Carlo spread of the std itself, the
tolerance it is judged by).

The exact-truth problem: a rendered capture of the procedural "tiles" material (9 rectified flash views of
64^2, views 0,2,4,6,8 fitted), where the true maps are known: the table adds each run's mean absolute error
of the posterior mean against them.
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from bayes_brdf.cli.main import main as cli
from bayes_brdf.io.images import read_image as read_exr   # EXR as float32 [H, W, C], linear

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data" / "captures"
SPLIT = "0,2,4,6,8"


def fit(capture: Path, out: Path, resolution: int, steps: str | None, seed: int) -> dict:
    args = ["fit", str(capture), "--views", SPLIT, "--resolution", str(resolution), "--seed", str(seed),
            "--out", str(out)] + (["--steps", steps] if steps else [])
    t = time.perf_counter()
    code = cli(args)
    wall = time.perf_counter() - t
    if code != 0:
        sys.exit(f"fit failed: {' '.join(args)}")
    s = json.loads((out / "summary.json").read_text())
    h = s["heldout"]
    return {"steps": s["diagnostics"]["steps"] if s.get("diagnostics") else None, "wall": wall,
            "cov50": h["coverage"]["50"],
            "cov90": h["coverage"]["90"],
            "spearman": h["spearman"], "converged": (s.get("diagnostics") or {}).get("converged"),
            "std": {m: read_exr(out / "std" / f"{m}.exr") for m in ("albedo", "roughness")}, "out": out}


def std_gap(a: dict, b: dict) -> dict:
    return {m: float(np.median(np.abs(a["std"][m] - b["std"][m]) / np.maximum(b["std"][m], 1e-6)))
            for m in ("albedo", "roughness")}


def truth_error(run: dict, truth: Path) -> float:
    errs = []
    for m in ("albedo", "roughness"):
        est, true = read_exr(run["out"] / "mean" / f"{m}.exr"), read_exr(truth / f"{m}.exr")
        errs.append(float(np.abs(est.reshape(true.shape) - true).mean()))
    return float(np.mean(errs))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--captures", nargs="+", default=["card_blue", "bath_tile", "yellow_box", "exact"])
    ap.add_argument("--resolution", type=int, default=64)
    ap.add_argument("--seeds", type=int, nargs=2, default=[0, 1], help="the fixed runs' seeds (default 0 1)")
    a = ap.parse_args(argv)
    tmp = Path(tempfile.mkdtemp(prefix="auto_steps_"))
    rows = []
    for name in a.captures:
        truth = None
        if name == "exact":
            cap = tmp / "exact_capture"
            cli(["render", "tiles", "--views", "sobol:9", "--camera", "rectified", "--resolution",
                 str(a.resolution), "--out", str(cap)])
            truth = cap / "maps" if (cap / "maps").is_dir() else None
        else:
            cap = SHARED / name
        fixed = fit(cap, tmp / f"{name}_fixed", a.resolution, None, a.seeds[0])
        other = fit(cap, tmp / f"{name}_fixed_seed", a.resolution, None, a.seeds[1])
        auto = fit(cap, tmp / f"{name}_auto", a.resolution, "auto", a.seeds[0])
        row = {"case": name, "fixed": fixed, "auto": auto, "gap": std_gap(auto, fixed),
               "seed_gap": std_gap(other, fixed)}
        if truth is not None:
            row["truth"] = (truth_error(fixed, truth), truth_error(auto, truth))
        rows.append(row)
        print(f"# {name} done", file=sys.stderr)
    print(f"\n{a.resolution}^2, views {SPLIT} fitted, defaults; wall = the whole fit command in-process\n")
    print("| case | run | steps | wall s | 50 % | 90 % | Spearman | std gap albedo / roughness (seeds: ...) |")
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        for k in ("fixed", "auto"):
            x = r[k]
            gap = (f"{r['gap']['albedo']:.3f} / {r['gap']['roughness']:.3f} (seeds: {r['seed_gap']['albedo']:.3f} / "
                   f"{r['seed_gap']['roughness']:.3f})") if k == "auto" else ""
            tr = f"; |mean - truth| {r['truth'][0 if k == 'fixed' else 1]:.4f}" if "truth" in r else ""
            print(f"| {r['case']} | {k} | {x['steps']} | {x['wall']:.1f} | {x['cov50']:.2f} | {x['cov90']:.2f} | "
                  f"{x['spearman']:.2f} | {gap}{tr} |")


if __name__ == "__main__":
    main()
