"""Mesh G-buffer time per view: Mitsuba ray casting (camera rays + one shadow ray per light) and the
per-light incident terms, as :meth:`GBuffer.build` does it.

Usage:
    python benchmarks/bench_mesh_gbuffer.py                     # the bunny, 256^2, 4 lights, 8 views
    python benchmarks/bench_mesh_gbuffer.py --res 128 --lights 1 --views 20 --mesh sphere

Prints milliseconds per view (median over repeats, after a warm-up that compiles Mitsuba's kernels),
split into the ray casting (hits + shadows) and the whole build. Needs ../shared/data for the bunny.
"""
from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import torch

from bayes_brdf.render import PointLight, View, collocated_views
from bayes_brdf.render.gbuffer import GBuffer
from bayes_brdf.render.mesh import Mesh

BUNNY = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "psdr_assets" / "bunny_low.obj"


def views_for(mesh, n, res, lights):
    cams = [v.camera for v in collocated_views(n, 3 * mesh.radius, resolution=res, target=mesh.center, fov=40,
                                                method="sobol")]
    ring = collocated_views(lights, 4 * mesh.radius, target=mesh.center, method="fibonacci", resolution=4)
    ls = tuple(PointLight(v.camera.position, 1000.0) for v in ring)
    return [View(c, ls) for c in cams]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mesh", default="bunny", choices=("bunny", "sphere", "bowl", "block"))
    ap.add_argument("--res", type=int, default=256)
    ap.add_argument("--lights", type=int, default=4)
    ap.add_argument("--views", type=int, default=8)
    ap.add_argument("--repeats", type=int, default=5)
    a = ap.parse_args(argv)
    mesh = {"bunny": lambda: Mesh.load(BUNNY, up="y"), "sphere": Mesh.sphere, "bowl": Mesh.bowl,
            "block": Mesh.block_on_plane}[a.mesh]()
    vs = views_for(mesh, a.views, a.res, a.lights)
    t0 = time.perf_counter()
    GBuffer.build(vs[:1], mesh)
    warm = time.perf_counter() - t0
    cast, total = [], []
    for r in range(a.repeats):
        t = time.perf_counter()
        hits = mesh.intersect([v.camera for v in vs])
        lp = torch.tensor([[l.position for l in v.lights] for v in vs], dtype=torch.float64)
        mesh.occluded(hits, lp)
        cast.append(time.perf_counter() - t)
        t = time.perf_counter()
        GBuffer.build(vs, mesh)
        total.append(time.perf_counter() - t)
    per = lambda xs: statistics.median(xs) / len(vs) * 1e3  # noqa: E731
    print(f"mesh {a.mesh} ({mesh.num_faces} faces), {a.views} views of {a.res}^2, {a.lights} lights, "
          f"{torch.get_num_threads()} threads; first build {warm:.2f} s (kernel compilation)")
    print(f"ray casting (hits + shadow rays): {per(cast):7.1f} ms per view")
    print(f"whole G-buffer build:             {per(total):7.1f} ms per view")


if __name__ == "__main__":
    main()
