"""Projection of held-out procedural materials into the latent decoder: render PSNR per schedule.

For each of the six generators at a held-out seed (``HELD_OUT_SEED``, never in training) at 64²:
7 collocated flash views (Sobol, within 60 degrees zenith; Laplace noise ``--noise``), the model's
projection (``LatentDecoder.project``: Adam on the model's own energy, lr 0.02, from ``w_avg`` and zero
noise) for ``--steps`` steps under three schedules:

* ``alternate``  -- MaterialGAN's: from ``w_avg``, 10 steps on W+, then 10 on the noise, in turn
  (``project_alternate = 10``);
* ``joint``      -- both sites every step, from ``w_avg`` (the model's default, ``project_alternate = 0``);
* ``w_only``     -- W+ alone (noise fixed at zero), from ``w_avg``.

Observations are clipped at 1 as a camera's (clipped pixels censored by the likelihood). Prints the render
PSNR (dB, linear radiance clipped to [0, 1] as a photo's) of the projection on the 7 observed views and on
Fig. 4's two novel views (``grazing``, ``opposite``), the map errors and the seconds.

    python benchmarks/bench_projection.py [--steps 300] [--noise 0.0]
"""
from __future__ import annotations

import argparse
import math
import time

import torch

import bayes_brdf as bb
from bayes_brdf.experiments.common import camera_clip, synthetic
from bayes_brdf.experiments.fig4_image_space import novel_views
from bayes_brdf.materials import MATERIALS
from bayes_brdf.materials.augment import HELD_OUT_SEED
from bayes_brdf.potential import Potential
from bayes_brdf.render.gbuffer import GBuffer
from bayes_brdf.render.shade import render


def psnr(a, b, mask):
    """PSNR of images as a camera records them (clipped to [0, 1]: a highlight's linear peak would decide it)."""
    a, b = a.clamp(0, 1), b.clamp(0, 1)
    m = mask[..., None].expand_as(a)
    mse = float(((a - b) ** 2)[m].mean())
    return 10 * math.log10(1 / max(mse, 1e-12))


def project(model, data, steps, schedule):
    pot = Potential(model, (data,))
    model.project_steps = steps
    model.project_alternate = 10 if schedule == "alternate" else 0
    z = model.project_capture(pot)
    return model.maps({k: v for k, v in pot.to_constrained(z).items()}).particle(0)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--steps", type=int, default=300)
    ap.add_argument("--noise", type=float, default=0.0)
    ap.add_argument("--materials", default=",".join(sorted(MATERIALS)))
    ap.add_argument("--schedules", default="alternate,joint,w_only")
    a = ap.parse_args()
    torch.set_num_threads(2)
    novel = novel_views(64)
    print(f"projection, {a.steps} steps, 7 views at 64², noise {a.noise}; PSNR dB on the observed / novel views")
    print("| material | schedule | observed | novel | albedo MAE | roughness MAE | s |")
    print("|---|---|---|---|---|---|---|")
    rows = {}
    for name in a.materials.split(","):
        truth, obs = synthetic(name, 64, 7, seed=HELD_OUT_SEED, noise_sigma=a.noise)
        obs = camera_clip(obs)
        data = bb.models.ModelData.from_observations(obs)
        clean = render(truth, obs.views, obs.surface)[0]
        tn = render(truth, novel, obs.surface)[0]
        g = GBuffer.build(obs.views, obs.surface).mask
        gn = GBuffer.build(novel, obs.surface).mask
        for sch in a.schedules.split(","):
            model = bb.models.latent_decoder(noise="zero" if sch == "w_only" else "infer")
            t = time.perf_counter()
            m = project(model, data, a.steps, sch)
            secs = time.perf_counter() - t
            p_obs = psnr(render(m, obs.views, obs.surface)[0], clean, g)
            p_nov = psnr(render(m, novel, obs.surface)[0], tn, gn)
            ea = float((m.albedo - truth.albedo).abs().mean())
            er = float((m.roughness - truth.roughness).abs().mean())
            rows.setdefault(sch, []).append((p_obs, p_nov))
            print(f"| {name} | {sch} | {p_obs:.1f} | {p_nov:.1f} | {ea:.3f} | {er:.3f} | {secs:.0f} |", flush=True)
    for sch, r in rows.items():
        obs_db, nov_db = sum(x for x, _ in r) / len(r), sum(y for _, y in r) / len(r)
        print(f"mean {sch}: observed {obs_db:.1f} dB, novel {nov_db:.1f} dB")


if __name__ == "__main__":
    main()
