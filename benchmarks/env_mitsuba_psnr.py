"""PSNR of our environment shading against Mitsuba 3 (its ``envmap`` emitter, its ``direct`` integrator with MIS,
our BRDF as a Python BSDF): the plane, the bunny and a shape that shadows itself, roughness 0.05 to 1.

Usage:
    python benchmarks/env_mitsuba_psnr.py                       # 64^2 views, 4096 spp in Mitsuba
    python benchmarks/env_mitsuba_psnr.py --res 32 --spp 1024 --roughness 0.1 0.5

Each scene: the views of :func:`~bayes_brdf.render.mitsuba_reference.check_views` (cameras around the object)
lit by ``ballroom_1k.exr`` alone (z-up, turned 30 degrees), a constant material (albedo (0.6, 0.45, 0.3),
specular 0.04 and, in a second row, 0.3) at each roughness. Ours: :func:`~bayes_brdf.render.shade.render`
(the precomputed transfer); the plane is our analytic :class:`PlanarSample` and, in Mitsuba, a two-triangle
mesh of the same square. Mitsuba: :func:`~bayes_brdf.render.mitsuba_reference.render_reference` with our
pixel-centre rays and ``--spp`` samples per pixel. PSNR on linear radiance over all pixels, views and channels,
peak = the maximum of our render; the Monte Carlo noise of the reference alone caps it (the column ``noise
cap``: the PSNR of one reference against a second with another seed, plus 3 dB).
"""
from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import torch

from bayes_brdf.render import SVBRDF, PlanarSample
from bayes_brdf.render.environment import EnvironmentLight, z_up
from bayes_brdf.render.mesh import Mesh
from bayes_brdf.render.mitsuba_reference import check_views, psnr, render_reference
from bayes_brdf.render.shade import render
from bayes_brdf.render.views import View

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "psdr_assets"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--res", type=int, default=64)
    ap.add_argument("--spp", type=int, default=4096)
    ap.add_argument("--views", type=int, default=2, help="views per scene (default 2)")
    ap.add_argument("--roughness", type=float, nargs="+", default=[0.05, 0.1, 0.3, 0.6, 1.0])
    ap.add_argument("--scenes", nargs="+", default=["plane", "bunny", "block_on_plane"])
    a = ap.parse_args(argv)
    env = EnvironmentLight.from_file(DATA / "ballroom_1k.exr", to_world=z_up(30.0))
    meshes = {"plane": Mesh.plane(2.0), "bunny": Mesh.load(DATA / "bunny_low.obj", up="y"),
              "block_on_plane": Mesh.block_on_plane(), "bowl": Mesh.bowl()}
    kinds = {"plane": "block_on_plane", "bunny": "bunny", "block_on_plane": "block_on_plane", "bowl": "bowl"}
    print(f"{a.res}^2 views, Mitsuba {a.spp} spp; PSNR dB (specular 0.04 / 0.3)")
    print(f"{'scene':16s}{'roughness':>10s}{'PSNR ks .04':>13s}{'PSNR ks .3':>12s}{'noise cap':>11s}{'ours s':>8s}"
          f"{'mitsuba s':>11s}")
    for name in a.scenes:
        mesh = meshes[name]
        views = [View(v.camera, (env,), name=v.name) for v in check_views(mesh, kinds[name], a.res)][:a.views]
        surface = PlanarSample(2.0) if name == "plane" else mesh
        for r in a.roughness:
            cells = []
            for ks in (0.04, 0.3):
                maps = SVBRDF.constant(albedo=(0.6, 0.45, 0.3), roughness=r, specular=ks).to(torch.float64)
                t0 = time.perf_counter()
                ours = render(maps, views, surface)[0]
                t1 = time.perf_counter()
                ref = render_reference(maps, views, mesh, spp=a.spp, seed=0)
                t2 = time.perf_counter()
                cells.append(psnr(ours, ref))
                if ks == 0.04:
                    ref2 = render_reference(maps, views, mesh, spp=a.spp, seed=1)
                    cap = psnr(ref, ref2, peak=float(ours.max())) + 10 * math.log10(2)
                    times = (t1 - t0, t2 - t1)
            print(f"{name:16s}{r:10.2f}{cells[0]:13.1f}{cells[1]:12.1f}{cap:11.1f}{times[0]:8.1f}{times[1]:11.1f}")


if __name__ == "__main__":
    main()
