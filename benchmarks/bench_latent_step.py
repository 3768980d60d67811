"""The latent_decoder model's energy-and-gradient and SPOS step: the generator as computed now against its reference.

Usage:
    python benchmarks/bench_latent_step.py                 # card_blue, views 0,2,4,6,8 at 64^2, 20 particles
    python benchmarks/bench_latent_step.py --reference     # the reference generator only (the code before issue 26)
    python benchmarks/bench_latent_step.py --fast          # the current generator only

The capture is ``../shared/data/captures/card_blue`` (as ``bayes-brdf fit ... --resolution 64 --model latent_decoder``
loads it). Rows: ``fast`` is :meth:`Synthesis.forward <bayes_brdf.models.stylegan.Synthesis.forward>` (what the model
runs), ``reference`` is :meth:`Synthesis.reference` (the straightforward implementation the tests compare against);
both are timed in the same process, in turn each round (medians; ratio = reference / fast per round). Printed:
``Potential.value_and_grad`` of all particles, one ``spos`` step, the generator's forward+backward alone, the
shading loss of the decoded maps with its gradients (a normal map per particle: the native per-particle-normals
kernel since 2026-12-07, eager torch before), and the projection's single-row ``value_and_grad`` (``project_steps``
of them start a fit). The header gives the thread count
and the load average, which moves these numbers on a shared machine.
"""
from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import torch

from bayes_brdf.errors import InputError
from bayes_brdf.inference import resolve_model
from bayes_brdf.io import load_capture
from bayes_brdf.memory import keep_freed_memory
from bayes_brdf.models import ModelData
from bayes_brdf.models import stylegan
from bayes_brdf.potential import Potential
from bayes_brdf.presets import load_preset
from bayes_brdf.render import SVBRDF
from bayes_brdf.render.shade import shade_loss
from bayes_brdf.samplers import SAMPLERS, make_sampler

try:
    from bench_mesh_step import interleaved
except ImportError:                                    # run from the repository root
    from benchmarks.bench_mesh_step import interleaved

CAPTURE = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "captures" / "card_blue"
IMPLS = {"fast": stylegan.Synthesis.forward, "reference": stylegan.Synthesis.reference}


def using(name, fn):
    """``fn`` run with the generator's synthesis set to implementation ``name``."""
    def run():
        stylegan.Synthesis.forward = IMPLS[name]
        try:
            return fn()
        finally:
            stylegan.Synthesis.forward = IMPLS["fast"]
    return run


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--capture", default=str(CAPTURE))
    ap.add_argument("--views", default="0,2,4,6,8")
    ap.add_argument("--resolution", type=int, default=64)
    ap.add_argument("--particles", type=int, default=20)
    ap.add_argument("--repeats", type=int, default=7)
    g = ap.add_mutually_exclusive_group()
    g.add_argument("--reference", action="store_true", help="time the reference generator only")
    g.add_argument("--fast", action="store_true", help="time the current generator only")
    a = ap.parse_args(argv)
    keep_freed_memory()   # as the sampling driver does in a run
    names = ["reference"] if a.reference else ["fast"] if a.fast else ["reference", "fast"]
    cap = load_capture(a.capture, resolution=a.resolution, max_resolution=2 * a.resolution)
    cap = cap.subset([int(v) for v in a.views.split(",")])
    model = resolve_model("latent_decoder")
    pot = Potential(model, (ModelData.from_observations(cap),))
    z = pot.init(a.particles, seed=0)
    try:
        sampler, _ = make_sampler("spos")
    except InputError:            # a preset with [run] keys this checkout does not know yet: its [params] alone
        sampler = SAMPLERS["spos"].from_params(load_preset("samplers", "spos").get("params", {}))
    rng = torch.Generator().manual_seed(0)
    state = sampler.init(z, pot, rng, steps=1000)
    gen = model.generator
    w = (gen.w_avg + 0.1 * torch.randn(a.particles, gen.num_ws, gen.cfg.w_dim, generator=rng)).requires_grad_(True)
    nz = torch.randn(a.particles, model.noise_size(), generator=rng).requires_grad_(True)

    def gen_fb():
        y = gen(w, model.split_noise(nz))
        y.backward(torch.ones_like(y))

    data = pot.args[0]
    maps = model.maps({"w_plus": w.detach(), "noise": nz.detach()})
    leaves = [t.detach().clone().requires_grad_(True) for t in (maps.albedo, maps.roughness, maps.specular,
                                                                 maps.normal)]

    def shading_fb():          # the likelihood's shading of the decoded maps, normals per particle: loss and gradients
        e = shade_loss(SVBRDF(*leaves), data.gbuffer, data.images, data.noise_weight("laplace"), kind="l1")
        e.sum().backward()

    z1 = z[:1].clone()
    rows = {
        "value_and_grad": lambda: pot.value_and_grad(z),
        "spos step": lambda: sampler.step(state, 0, pot, rng),
        "generator fwd+bwd": gen_fb,
        "shading loss fwd+bwd": shading_fb,
        "projection v&g (1 row)": lambda: pot.value_and_grad(z1, jacobian=False),
    }
    load = os.getloadavg()
    print(f"latent_decoder {model.resolution}^2, {len(cap.views)} views of {a.resolution}^2, {a.particles} particles, "
          f"dim {z.shape[1]}; torch {torch.__version__}, {torch.get_num_threads()} threads, "
          f"load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}")
    print(f"{'ms (median)':24s}" + "".join(f"{n:>12s}" for n in names) + ("   ratio" if len(names) == 2 else ""))
    for label, fn in rows.items():
        ms, ratio = interleaved([using(n, fn) for n in names], a.repeats)
        tail = f"{ratio[0]:8.2f}" if len(names) == 2 else ""
        print(f"{label:24s}" + "".join(f"{m:12.1f}" for m in ms) + tail)
    load = os.getloadavg()
    print(f"load average at the end {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}")


if __name__ == "__main__":
    main()
