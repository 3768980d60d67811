"""Time to score candidate views by mutual information (Eq. 18): 1000 candidates at 64^2, 20 particles.

Prints, in seconds: building the candidates' G-buffers (geometry, once per candidate set), scoring with
the MC estimator (Eq. 21) and with the quadrature estimator, and a naive torch version (render all,
quantile-based Silverman bandwidth, Eq. 21 with torch ops) for reference.

    python benchmarks/bench_guidance.py [--candidates 1000] [--resolution 64] [--particles 20] [--repeat 3]
"""
from __future__ import annotations

import argparse
import math
import statistics
import time

import torch

from bayes_brdf.guidance.scores import score_views
from bayes_brdf.render import PlanarSample, SVBRDF, collocated_views
from bayes_brdf.render.gbuffer import GBuffer
from bayes_brdf.render.shade import shade
from bayes_brdf.render.gbuffer import GBUFFERS as _CACHE


def particles(n, R, seed=0):
    g = torch.Generator().manual_seed(seed)
    return SVBRDF(torch.rand(n, 3, R, R, generator=g), 0.2 + 0.6 * torch.rand(n, 1, R, R, generator=g),
                  torch.full((3, 1, 1), 0.04), torch.tensor([0.0, 0, 1]).view(3, 1, 1).expand(3, R, R).contiguous())


def naive(maps, views, surface):
    """Render every candidate, Silverman via torch.quantile, Eq. 21 with plain torch ops (no footprint)."""
    g = GBuffer.build(views, surface)
    total = []
    for s in range(0, len(views), 50):
        r = shade(maps, g.views_slice(s, s + 50), channels_last=False).flatten(2)   # [n, v, P]
        n = r.shape[0]
        sd = r.std(0)
        q = torch.quantile(r, torch.tensor([0.25, 0.75]), dim=0)
        bw = (0.9 * n ** -0.2 * torch.minimum(sd, (q[1] - q[0]) / 1.34)).clamp_min(1e-6)
        c = torch.randint(0, n, sd.shape)
        x = r.gather(0, c[None])[0] + bw * torch.randn_like(sd)
        lp = torch.logsumexp(-0.5 * ((x[None] - r) / bw) ** 2, 0) - math.log(n) - bw.log() - 0.5 * math.log(2 * math.pi)
        total.append(-lp.sum(-1))
    return torch.cat(total)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--candidates", type=int, default=1000)
    ap.add_argument("--resolution", type=int, default=64)
    ap.add_argument("--particles", type=int, default=20)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--skip-naive", action="store_true")
    a = ap.parse_args()
    surface = PlanarSample(2.0)
    views = collocated_views(a.candidates, 3.0, method="sobol", camera="rectified", resolution=a.resolution,
                             power=10.0, max_zenith=60)
    maps = particles(a.particles, a.resolution)
    t = time.perf_counter()
    _CACHE.get(tuple(views), surface)
    print(f"candidates: {a.candidates} rectified collocated views at {a.resolution}^2, {a.particles} particles, "
          f"{torch.get_num_threads()} threads")
    print(f"  G-buffers (geometry, once per candidate set): {time.perf_counter() - t:.2f} s")
    for est in ("mc", "quadrature"):
        times = []
        for _ in range(a.repeat if est == "mc" else 1):
            s = score_views(maps, views, surface, estimator=est)
            times.append(s.seconds)
        print(f"  score_views estimator={est:10s}: median {statistics.median(times):.2f} s over {len(times)} "
              f"(min {min(times):.2f})")
    if not a.skip_naive:
        t = time.perf_counter()
        naive(maps, views, surface)
        print(f"  naive torch (render + quantile Silverman + Eq. 21): {time.perf_counter() - t:.2f} s")


if __name__ == "__main__":
    main()
