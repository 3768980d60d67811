"""A per-texel SPOS step on a mesh under an environment light against the same step under a collocated flash.

Usage:
    python benchmarks/bench_env_step.py                  # the bunny: 128^2 texture, 20 views of 128^2, 20 particles
    python benchmarks/bench_env_step.py --views 5 --res 64 --tex 64

Both rows: the bunny (``../shared/data``, y-up, xatlas atlas), the ``per_texel(tex, albedo="rgb")`` model, the same
20 perspective views around it; row ``flash``: each view lit by its collocated flash; row ``environment``: each view
lit by ``ballroom_1k.exr`` (z-up, turned 30 degrees) alone, shadows included. Printed: the time to build each row's
G-buffer (the environment's transfer is computed there, once), its memory, ``Potential.value_and_grad`` and one
``spos`` step (median ms over rounds that run each row once in turn), and their ratios environment / flash, which
the issue bounds (the step at most 1.5x). Peak RSS of the process at the end.
"""
from __future__ import annotations

import argparse
import resource
import time
from pathlib import Path

import torch

from bayes_brdf.render import collocated_views
from bayes_brdf.render.environment import EnvironmentLight, z_up
from bayes_brdf.render.gbuffer import GBUFFERS
from bayes_brdf.render.mesh import Mesh
from bayes_brdf.render.views import View
from bayes_brdf.memory import keep_freed_memory

try:
    from bench_mesh_step import interleaved, setup
except ImportError:                                    # run from the repository root
    from benchmarks.bench_mesh_step import interleaved, setup


DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "psdr_assets"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--views", type=int, default=20)
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--tex", type=int, default=128)
    ap.add_argument("--particles", type=int, default=20)
    ap.add_argument("--repeats", type=int, default=11)
    a = ap.parse_args(argv)
    keep_freed_memory()   # as the sampling driver does in a run (bayes_brdf.memory; BAYES_BRDF_KEEP_MEMORY=0: off)
    mesh = Mesh.load(DATA / "bunny_low.obj", up="y")
    flash = collocated_views(a.views, 2.6 * mesh.radius, resolution=a.res, target=mesh.center, fov=45,
                             method="sobol", power=(2.6 * mesh.radius) ** 2)
    env = EnvironmentLight.from_file(DATA / "ballroom_1k.exr", to_world=z_up(30.0))
    lit = [View(v.camera, (env,), name=v.name) for v in flash]
    rows = {}
    for name, views in (("flash", flash), ("environment", lit)):
        t0 = time.perf_counter()
        rows[name] = setup(mesh, views, a.tex, a.particles, flat_normals=True)
        g = GBUFFERS.get(tuple(views), mesh)
        rows[name] += (time.perf_counter() - t0, g.nbytes)
    pixels = int(rows["flash"][0].weight.count_nonzero())
    rng = torch.Generator().manual_seed(0)
    f, e = rows["flash"], rows["environment"]
    vg, vg_ratio = interleaved([lambda: e[1].value_and_grad(e[3].z), lambda: f[1].value_and_grad(f[3].z)],
                               a.repeats)
    st, st_ratio = interleaved([lambda: e[2].step(e[3], 0, e[1], rng), lambda: f[2].step(f[3], 0, f[1], rng)],
                               a.repeats)
    print(f"bunny: {mesh.num_faces} faces, texture {a.tex}^2, {a.views} views of {a.res}^2 -> {pixels} valid pixels; "
          f"{a.particles} particles, {torch.get_num_threads()} threads")
    print(f"{'':13s}{'setup s':>9s}{'G-buffer MB':>13s}{'value_and_grad ms':>19s}{'spos step ms':>14s}")
    for k, name in ((1, "flash"), (0, "environment")):
        r = rows[name]
        print(f"{name:13s}{r[4]:9.1f}{r[5] / 2**20:13.1f}{vg[k]:19.1f}{st[k]:14.1f}")
    print(f"{'ratio':13s}{'':22s}{vg_ratio[0]:19.2f}{st_ratio[0]:14.2f}   (median of the rounds' environment / flash)")
    print(f"peak RSS {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20:.2f} GB")


if __name__ == "__main__":
    main()
