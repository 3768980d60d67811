"""Our mesh renders against Mitsuba's own ``direct`` integrator (bayes_brdf.render.mitsuba_reference), per scene.

Usage:
    python benchmarks/mitsuba_equivalence.py                     # block_on_plane, bowl, bunny at 128^2, 64 spp
    python benchmarks/mitsuba_equivalence.py --res 64 --spp 256 --scenes block_on_plane bowl

For each scene (the views of ``check_views``, the maps of ``sinusoid_maps``) it prints, on linear radiance
with the peak the maximum of our image, over all pixels:

* ``rays``: PSNR of Mitsuba shading our pixel-centre rays (``camera="rays"``), and the fraction of pixels
  that agree within 1e-4 of the peak;
* ``no-shadow``: PSNR of ours with every light visible against the same reference (how much the shadows weigh);
* ``sensor``: PSNR of Mitsuba's perspective sensor (box filter, ``--spp``) against our pixel centres, and
  against ours rendered 4 x 4 supersampled and box-averaged (the same pixel-area integral);
* seconds: ours, the reference (first call, compiling Mitsuba's kernels, then warm), the sensor render.

The bunny needs ../shared/data (skipped when absent).
"""
from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

import torch

from bayes_brdf.render.gbuffer import GBuffer
from bayes_brdf.render.mesh import Mesh
from bayes_brdf.render.mitsuba_reference import Unshadowed, check_views, psnr, render_reference, sinusoid_maps
from bayes_brdf.render.shade import render, shade

BUNNY = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "psdr_assets" / "bunny_low.obj"
SCENES = {"block_on_plane": Mesh.block_on_plane, "bowl": Mesh.bowl, "bunny": lambda: Mesh.load(BUNNY, up="y")}


def timed(f):
    t = time.perf_counter()
    out = f()
    return out, time.perf_counter() - t


def run(kind: str, res: int, spp: int, supersample: int = 4) -> None:
    mesh = SCENES[kind]()
    views, maps = check_views(mesh, kind, res), sinusoid_maps()
    ours, t_ours = timed(lambda: render(maps, views, mesh)[0])
    ref, t_first = timed(lambda: render_reference(maps, views, mesh))
    _, t_warm = timed(lambda: render_reference(maps, views, mesh))
    peak = float(ours.max())
    agree = float(((ours - ref).abs().amax(-1) <= 1e-4 * peak).double().mean())
    unshadowed = shade(maps, GBuffer.build(views, Unshadowed(mesh), dtype=torch.float64))[0]
    sensor, t_sensor = timed(lambda: render_reference(maps, views, mesh, camera="sensor", spp=spp))
    s = supersample
    big = [dataclasses.replace(v, camera=dataclasses.replace(v.camera, resolution=(res * s, res * s))) for v in views]
    ss = render(maps, big, mesh)[0].reshape(len(views), res, s, res, s, 3).mean((2, 4))
    lights = sum(len(v.lights) for v in views)
    print(f"{kind:15s} {len(views)} views {lights} lights {res}^2 | rays {psnr(ours, ref):6.1f} dB "
          f"(agree {agree:.5f}) | no-shadow {psnr(unshadowed, ref, peak):5.1f} dB | sensor {spp} spp "
          f"{psnr(ours, sensor):5.1f} dB vs centres, {psnr(ss, sensor, peak):5.1f} dB vs {s}x{s} supersampled | "
          f"s: ours {t_ours:.2f}, ref {t_first:.2f} first / {t_warm:.2f} warm, sensor {t_sensor:.2f}", flush=True)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--scenes", nargs="+", default=list(SCENES), choices=list(SCENES))
    a = ap.parse_args(argv)
    for kind in a.scenes:
        if kind == "bunny" and not BUNNY.is_file():
            print(f"bunny: skipped ({BUNNY} not found)")
            continue
        run(kind, a.res, a.spp)


if __name__ == "__main__":
    main()
