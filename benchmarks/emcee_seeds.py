"""emcee on a narrow 2-D posterior, seed after seed: does every run converge, and where do its walkers end?

Usage:
    python benchmarks/emcee_seeds.py [--seeds 10] [--relocate 0.5]

The problem is ``tests/models/test_view_gains.py``'s: one grey BRDF (albedo 0.5, roughness 0.3) seen by
five 16x16 collocated views whose photos carry known per-view gains, fitted with
``homogeneous(albedo="gray", view_gain="estimated")`` and emcee's defaults. Prints per seed: converged,
failed checks, the largest error of the estimated log gains, the posterior means. ``--relocate 0`` is
emcee without the burn-in relocation of walkers left behind (docs/samplers.md). Numbers only.
"""
from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

import torch

import bayes_brdf as bb

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "models"))
from test_view_gains import TRUE_LOG_GAIN, photos_with_gains  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--relocate", type=float, default=None, help="emcee's relocate (default: the preset's)")
    ap.add_argument("--steps", type=int, default=None)
    a = ap.parse_args()
    obs, _ = photos_with_gains(TRUE_LOG_GAIN)
    model = bb.models.homogeneous(albedo="gray", view_gain="estimated")
    want = TRUE_LOG_GAIN - TRUE_LOG_GAIN.mean()
    params = {} if a.relocate is None else {"relocate": a.relocate}
    ok = 0
    print("seed converged failed max|log gain error| albedo roughness")
    for seed in range(a.seeds):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            post = bb.infer(model, obs, "emcee", progress=False, seed=seed, steps=a.steps, params=params)
        g = post.view_gains
        err = float((torch.tensor(g.log_gain) - want).abs().max()) if g is not None else float("nan")
        d = post.diagnostics
        ok += d["converged"]
        print(f"{seed} {d['converged']} {','.join(d['failed']) or '-'} {err:.4f} "
              f"{float(post.mean('albedo')):.4f} {float(post.mean('roughness')):.4f}", flush=True)
    print(f"converged: {ok} of {a.seeds}")


if __name__ == "__main__":
    main()
