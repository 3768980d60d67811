"""A per-texel SPOS step on a mesh against the plane's at the same number of pixels.

Usage:
    python benchmarks/bench_mesh_step.py                 # the bunny: 128^2 texture, 20 views of 128^2, 20 particles
    python benchmarks/bench_mesh_step.py --mesh sphere --views 10 --res 64 --tex 64

Mesh row: the bunny (``../shared/data``; y-up, xatlas atlas) under 20 collocated perspective views of
128^2 around it, the ``per_texel(128, albedo="rgb")`` model (albedo and roughness per texel), 20
particles; the pixels that see the mesh are what the likelihood sums over. Plane row: the planar
sample under rectified collocated views (one pixel per texel: the fused native kernel's fast path),
with the views' resolution chosen so the plane has the same number of pixels as the mesh's valid
ones: views of the texture's resolution (one pixel per texel), as many as make the mesh's pixel count
(5 views of 128^2 for the bunny's 81k valid pixels), so both rows have the same texels (the same
latent dimension) and the same pixels. Both rows: ``Potential.value_and_grad`` (energies and
gradients of all particles) and one ``spos`` step without the preset's texel sweep (``texel_moves = 0``: the plane
would sweep, the mesh cannot), median ms over repeats after warm-up, the two rows
timed in turn in each round; the ratio (the median over rounds of mesh / plane) is the number the issue
bounds (at most 1.2; 1.5 is the environment light's bound, bench_env_step.py).
"""
from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import torch

from bayes_brdf.materials import make_material
from bayes_brdf.models import ModelData, per_texel
from bayes_brdf.observations import Observations
from bayes_brdf.potential import Potential
from bayes_brdf.render import SVBRDF, PlanarSample, collocated_views
from bayes_brdf.render.mesh import Mesh
from bayes_brdf.render.shade import render
from bayes_brdf.samplers import make_sampler
from bayes_brdf.memory import keep_freed_memory

BUNNY = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "psdr_assets" / "bunny_low.obj"


def setup(surface, views, tex, particles, flat_normals: bool = False):
    """Photos of the tiles material (``flat_normals``: its normal map flattened, as an environment light needs),
    the model, the sampler and its initial state."""
    truth = make_material("tiles", tex, seed=0)
    if flat_normals:
        truth = SVBRDF(truth.albedo, truth.roughness, truth.specular,
                       torch.tensor([0, 0, 1.0])[:, None, None].expand(3, tex, tex))
    img = render(truth, views, surface)[0]
    data = ModelData.from_observations(Observations(views, img, surface))
    pot = Potential(per_texel(tex, albedo="rgb"), (data,))
    # the Stein step alone: the plane's rectified views would also get the preset's texel sweep (every step since
    # 2026-12-07), which a mesh cannot have (its pixels read up to four texels): like with like
    smp, cfg = make_sampler("spos", params={"texel_moves": 0}, run={"particles": particles})
    state = smp.init(pot.init(particles, seed=0), pot, torch.Generator().manual_seed(0), steps=cfg.steps)
    return data, pot, smp, state


def interleaved(fns, repeats, warmup=2):
    """Median ms of each of ``fns`` over ``repeats`` rounds that run each once, in turn (so a machine that
    slows down or speeds up mid-run moves every row alike), and the per-round ratios to the last one."""
    for _ in range(warmup):
        for fn in fns:
            fn()
    ts = [[] for _ in fns]
    for _ in range(repeats):
        for t, fn in zip(ts, fns):
            t0 = time.perf_counter()
            fn()
            t.append(time.perf_counter() - t0)
    ratios = [statistics.median(a / b for a, b in zip(t, ts[-1])) for t in ts]
    return [statistics.median(t) * 1e3 for t in ts], ratios


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mesh", default="bunny", choices=("bunny", "sphere", "bowl"))
    ap.add_argument("--views", type=int, default=20)
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--tex", type=int, default=128)
    ap.add_argument("--particles", type=int, default=20)
    ap.add_argument("--repeats", type=int, default=15)
    a = ap.parse_args(argv)
    keep_freed_memory()   # as the sampling driver does in a run (bayes_brdf.memory; BAYES_BRDF_KEEP_MEMORY=0: off)
    mesh = {"bunny": lambda: Mesh.load(BUNNY, up="y"), "sphere": Mesh.sphere, "bowl": Mesh.bowl}[a.mesh]()
    mviews = collocated_views(a.views, 2.6 * mesh.radius, resolution=a.res, target=mesh.center, fov=45,
                              method="sobol", power=(2.6 * mesh.radius) ** 2)
    md, mpot, msmp, mstate = setup(mesh, mviews, a.tex, a.particles)
    pixels = int(md.weight.count_nonzero())
    nplane = max(1, round(pixels / a.tex ** 2))
    pviews = collocated_views(nplane, 15.0, camera="rectified", resolution=a.tex, power=1500.0, method="sobol")
    pd, ppot, psmp, pstate = setup(PlanarSample(10.0), pviews, a.tex, a.particles)
    rng = torch.Generator().manual_seed(0)
    vg, vg_ratio = interleaved([lambda: mpot.value_and_grad(mstate.z), lambda: ppot.value_and_grad(pstate.z)],
                               a.repeats)
    st, st_ratio = interleaved([lambda: msmp.step(mstate, 0, mpot, rng), lambda: psmp.step(pstate, 0, ppot, rng)],
                               a.repeats)
    print(f"{a.mesh}: {mesh.num_faces} faces, texture {a.tex}^2, {a.views} views of {a.res}^2 -> {pixels} valid pixels; "
          f"plane: {nplane} rectified views of {a.tex}^2 = {nplane * a.tex ** 2} pixels; {a.particles} particles, "
          f"{torch.get_num_threads()} threads")
    print(f"{'':8s}{'value_and_grad ms':>20s}{'spos step ms':>16s}")
    for k, name in enumerate(("mesh", "plane")):
        print(f"{name:8s}{vg[k]:20.1f}{st[k]:16.1f}")
    print(f"{'ratio':8s}{vg_ratio[0]:20.2f}{st_ratio[0]:16.2f}   (median of the rounds' mesh / plane)")


if __name__ == "__main__":
    main()
