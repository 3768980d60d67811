"""Where one SPOS step goes: the parts of the per-texel step at 128^2 x 20 views x 20 particles, timed one by one.

Usage:
    OMP_WAIT_POLICY=passive python benchmarks/bench_step_breakdown.py [--res 128] [--views 20] [--repeats 30]
    BAYES_BRDF_KEEP_MEMORY=0 ...     # without bayes_brdf.memory (freed blocks returned to the OS)

The case of ``bench_samplers.py`` (``make_data``: rectified collocated views of "tiles", ``per_texel(R,
albedo="rgb")``). Rows, median ms over ``--repeats`` calls each:

* ``step``: one ``SPOS.step`` of the default sampler's preset without its texel sweep (``texel_moves = 0``): the
  Stein update, everything included;
* ``value_and_grad``: the potential's energies and gradients (the model run under Pyro, the bijections, the
  likelihood and its backward);
* ``shading kernel``: the fused native shading + L1 loss and its gradient alone (``shade_loss`` on the same
  maps): the part with the flops;
* ``rest of the potential`` = value_and_grad - shading kernel (Pyro's trace, the interval bijections, the
  censored likelihood's own terms, the gradient's assembly);
* ``kernel matrix``: ``rbf_matrix`` (a Gram product and the median);
* ``noise``: the step's normal draws (``standard_normal``);
* ``update``: the fused SPOS update (``_native_spos.c``) or, with ``BAYES_BRDF_NO_NATIVE=1``, the torch one;
* ``rest of the step`` = step - the others (Python, the annealing schedule, small tensors);
* ``texel sweep``: the preset's texel-local Metropolis sweep (``texel_moves.texel_move``), which runs every
  ``texel_moves`` steps (every step since 2026-12-07) on models that offer texel energies and is not in ``step``;
  the last line gives the mean step with it.

The bound: one pixel evaluation forward and backward is about 62 flops (docs/performance.md), so a
value_and_grad is ``62 * n * V * R^2`` flops; the last line divides it by the step's time.
"""
from __future__ import annotations

import argparse
import os
import statistics
import time
from dataclasses import replace

import torch

from bench_samplers import make_data
from bayes_brdf.memory import keep_freed_memory
from bayes_brdf.models import per_texel
from bayes_brdf.potential import Potential
from bayes_brdf.render.native import ptr
from bayes_brdf.samplers import make_sampler
from bayes_brdf.samplers.kernels import rbf_matrix
from bayes_brdf.samplers.numerics import standard_normal
from bayes_brdf.samplers.texel_moves import texel_layout, texel_move


def med(fn, repeats: int) -> float:
    for _ in range(3):
        fn()
    ts = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t)
    return statistics.median(ts) * 1e3


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--views", type=int, default=20)
    ap.add_argument("--particles", type=int, default=20)
    ap.add_argument("--repeats", type=int, default=30)
    a = ap.parse_args(argv)
    keep = keep_freed_memory()
    data = make_data(a.res, a.views)
    model = per_texel(a.res, albedo="rgb")
    pot = Potential(model, (data,))
    z = pot.init(a.particles, seed=0)
    preset, _ = make_sampler("spos")
    sampler = replace(preset, texel_moves=0)           # the Stein update alone; the sweep is its own row
    rng = torch.Generator().manual_seed(0)
    state = sampler.init(z, pot, rng, steps=2000)
    vals = pot.to_constrained(z)
    maps = model.maps({k: v.detach() for k, v in vals.items()})
    from bayes_brdf.render.shade import shade_loss

    def kernel_only():       # the albedo and roughness as leaves: the kernel's forward and its gradient
        m = replace(maps, albedo=maps.albedo.detach().requires_grad_(True),
                    roughness=maps.roughness.detach().requires_grad_(True))
        shade_loss(m, data.gbuffer, data.images, data.weight).sum().backward()

    rows = {
        "step": med(lambda: sampler.step(state, 10**6, pot, rng), a.repeats),
        "value_and_grad": med(lambda: pot.value_and_grad(z), a.repeats),
        "shading kernel": med(kernel_only, a.repeats),
        "kernel matrix": med(lambda: rbf_matrix(z, 1), a.repeats),
        "noise": med(lambda: standard_normal(z.shape, rng, z.dtype), a.repeats),
    }
    from bayes_brdf.samplers import spos as S
    if S._native_update(z.dtype) is not None:
        K, h = rbf_matrix(z, 1)
        ks, c2h = K.sum(-1).contiguous(), (2 / h).contiguous()
        g = pot.value_and_grad(z)[1]
        noise = standard_normal(z.shape, rng, z.dtype)
        out, v1, v2 = torch.empty_like(z), torch.empty_like(state.precond.v), torch.empty_like(state.precond.v)
        D = z.shape[1]     # the preset's update after the annealing (what the "step" row times): its scope and units
        args = [1, a.particles, D, torch.get_num_threads(), *(ptr(t) for t in (
            z, g, noise, K.contiguous(), ks, c2h, state.precond.v, state.precond_noise.v, out, v1, v2)),
            int(sampler.preconditioner == "adam"), int(sampler.per_particle(D)), 0,
            int(sampler.step_units == "spread"), 1.0, sampler.beta_for(D), sampler.eps_for(D), sampler.adam_beta2,
            0.5, 0.5, sampler.step_size, sampler.min_spread]
        rows["update"] = med(lambda: S._native_update(z.dtype)(*args), a.repeats)
    every = getattr(preset, "texel_moves", 0)
    if every and texel_layout(pot) is not None:     # the preset's texel sweep, every `every` steps (not in "step")
        rows["texel sweep"] = med(lambda: texel_move(z, pot, rng), max(3, a.repeats // 3))
    rows["rest of the potential"] = rows["value_and_grad"] - rows["shading kernel"]
    rows["rest of the step"] = rows["step"] - rows["value_and_grad"] - rows["kernel matrix"] - rows["noise"] - \
        rows.get("update", 0.0)
    print(f"# SPOS step, per_texel {a.res}^2 x {a.views} views x {a.particles} particles; torch {torch.__version__}, "
          f"{torch.get_num_threads()} threads, load average {', '.join(f'{x:.1f}' for x in os.getloadavg())}, "
          f"keep_freed_memory {keep}, native {'off' if os.environ.get('BAYES_BRDF_NO_NATIVE') else 'on'}")
    print("\n| part | ms | share of the step |\n|---|---|---|")
    for k in ("step", "value_and_grad", "shading kernel", "rest of the potential", "kernel matrix", "noise", "update",
              "rest of the step"):
        if k in rows:
            print(f"| {k} | {rows[k]:.2f} | {rows[k] / rows['step']:.0%} |")
    if "texel sweep" in rows:
        print(f"| texel sweep (every {every} steps; not in the step) | {rows['texel sweep']:.2f} | "
              f"{rows['texel sweep'] / rows['step']:.0%} |")
        print(f"\nmean step with the sweep: {rows['step'] + rows['texel sweep'] / every:.2f} ms")
    flops = 62 * a.particles * a.views * a.res ** 2
    print(f"\n{flops / 1e9:.2f} Gflop per value_and_grad: {flops / rows['step'] / 1e6:.1f} Gflop/s over the step, "
          f"{flops / rows['shading kernel'] / 1e6:.1f} Gflop/s in the shading kernel")


if __name__ == "__main__":
    main()
