"""Per-step cost of the censored likelihood: potential value and gradient, censored vs dropped clipped pixels.

Usage:
    python benchmarks/bench_censored_cost.py                               # card_blue at 64^2 and 128^2
    python benchmarks/bench_censored_cost.py --capture ../shared/data/captures/bath_tile --resolutions 128

Five fit views of a real capture, 20 particles, the default model (RGB per-texel, sigma "auto"); rows
alternate so both see the same machine load. Prints ms per value-and-gradient call and the number of
clipped pixels (the only ones the censored term shades).
"""
from __future__ import annotations

import argparse
import time

import bayes_brdf as bb
from bayes_brdf.io import load_capture
from bayes_brdf.models.data import ModelData
from bayes_brdf.potential import Potential


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--capture", default="../shared/data/captures/card_blue")
    ap.add_argument("--resolutions", type=int, nargs="+", default=[64, 128])
    ap.add_argument("--calls", type=int, default=30)
    a = ap.parse_args()
    for R in a.resolutions:
        obs = load_capture(a.capture, resolution=R).subset([0, 2, 4, 6, 8])
        data = ModelData.from_observations(obs)
        pots = {tr: Potential(bb.models.per_texel(R, saturated=tr), (data,)) for tr in ("censored", "drop")}
        z = pots["drop"].init(20, seed=0, margin=0.05)
        k = 0 if data.censored is None else data.censored.count
        best = {}
        for _ in range(3):
            for tr, pot in pots.items():
                for _ in range(3):
                    pot.value_and_grad(z)
                t = time.perf_counter()
                for _ in range(a.calls):
                    pot.value_and_grad(z)
                best[tr] = min(best.get(tr, 1e9), (time.perf_counter() - t) / a.calls * 1e3)
        print(f"{R}^2, {k} clipped pixels of {int(data.weight.sum()) + k}: censored {best['censored']:.1f} ms, "
              f"drop {best['drop']:.1f} ms per call ({best['censored'] / best['drop']:.2f}x; best of 3)")


if __name__ == "__main__":
    main()
