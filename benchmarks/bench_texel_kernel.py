"""The native texel kernel (mesh pixels) by particle count: the loss with its gradient, and the images.

Usage:
    python benchmarks/bench_texel_kernel.py                       # the bunny, 20 views of 128^2, 128^2 texels
    python benchmarks/bench_texel_kernel.py --particles 1 8 20 64 --repeats 9

The bunny (``../shared/data``; y-up, xatlas atlas) under 20 collocated perspective views of 128^2,
per-particle albedo and roughness maps of 128^2 texels and a constant specular, the ``compiled``
backend (the native texel kernel on CPU). For each particle count: median ms of ``shade_loss`` with
the gradients of albedo and roughness, and of ``shade`` (the images ``[n, 20, 128, 128, 3]``,
no gradient), the two timed in turn in each round. Its particles are the kernel's SIMD lanes (8
floats, or 16 where float32 vectors are 64 bytes and that takes fewer passes: ``native.texel_lanes``), so 1-4
particles leave most lanes empty.
"""
from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import torch

from bayes_brdf.materials import make_material
from bayes_brdf.render import SVBRDF, collocated_views
from bayes_brdf.render.gbuffer import GBUFFERS
from bayes_brdf.render.mesh import Mesh
from bayes_brdf.render.shade import shade, shade_loss

BUNNY = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "psdr_assets" / "bunny_low.obj"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--particles", type=int, nargs="+", default=[1, 4, 20, 64])
    ap.add_argument("--views", type=int, default=20)
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--tex", type=int, default=128)
    ap.add_argument("--repeats", type=int, default=7)
    a = ap.parse_args(argv)
    mesh = Mesh.load(BUNNY, up="y")
    views = collocated_views(a.views, 2.6 * mesh.radius, resolution=a.res, target=mesh.center, fov=45,
                             method="sobol", power=(2.6 * mesh.radius) ** 2)
    g = GBUFFERS.get(tuple(views), mesh, dtype=torch.float32)
    target = shade(make_material("tiles", a.tex, seed=0), g)[0]
    print(f"bunny, {a.views} views of {a.res}^2 ({int(g.mask.sum())} pixels on the object), {a.tex}^2 texels, "
          f"{torch.get_num_threads()} threads; median ms over {a.repeats} rounds")
    print(f"{'particles':>10s}{'loss + gradient':>18s}{'images':>10s}")
    for n in a.particles:
        gen = torch.Generator().manual_seed(0)
        kd = torch.rand(n, 3, a.tex, a.tex, generator=gen, requires_grad=True)
        r = (torch.rand(n, 1, a.tex, a.tex, generator=gen) * .7 + .2).requires_grad_()
        maps = SVBRDF(kd, r, torch.full((3, 1, 1), 0.04), torch.tensor([0., 0, 1]).view(3, 1, 1))

        def loss():
            torch.autograd.grad(shade_loss(maps, g, target, backend="compiled").sum(), (kd, r))

        def images():
            with torch.no_grad():
                shade(maps, g, backend="compiled")

        fns = (loss, images)
        for fn in fns:
            fn()
        ts = [[] for _ in fns]
        for _ in range(a.repeats):
            for t, fn in zip(ts, fns):
                t0 = time.perf_counter()
                fn()
                t.append(time.perf_counter() - t0)
        print(f"{n:10d}" + "".join(f"{statistics.median(t) * 1e3:{w}.1f}" for t, w in zip(ts, (18, 10))))


if __name__ == "__main__":
    main()
