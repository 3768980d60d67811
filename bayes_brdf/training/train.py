"""The training loop of ``bayes-brdf train-decoder``: a VAE whose decoder is the StyleGAN2 generator.

Why a VAE (and not a GAN or GLO): on two CPU cores it trains stably in under an
hour from one seed with plain Adam (a GAN's two-player game needs many times the
steps and tuning to avoid collapse), and its ``z ~ N(0, I)`` prior gives a sampling
distribution for free (the sample grid, ``w_avg`` and the Gaussian W+ prior), which
generative latent optimisation (GLO) would have to fit afterwards. Its decoder is
blurrier than a GAN's; at inference the W+ and noise inputs are free, which gives
back the detail (see docs/latent_decoder.md for the measured projection PSNR).

Deterministic by seed on one machine: the data, the augmentations and the
initialisation come from seeded generators, and a checkpoint every
``checkpoint_every`` steps holds the model, the optimiser and every generator's
state, so an interrupted run resumes to the same weights.
"""
from __future__ import annotations

import json
import math
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import torch

from ..materials.augment import augmented_batch, base_set
from ..models.decoder_file import save_decoder
from ..models.stylegan import PRESETS, Generator
from .vae import Encoder, vae_loss


@dataclass
class TrainConfig:
    """Everything that determines the weights (saved in the weights file's header)."""

    preset: str = "cpu64"
    steps: int = 8000
    batch: int = 16
    lr: float = 2e-3
    kl_weight: float = 0.1
    base_materials: int = 1200       # procedural materials (200 seeds of each of the 6 generators)
    blend: float = 0.25
    seed: int = 0
    threads: int = 2


def _lr(cfg: TrainConfig, step: int) -> float:
    """Linear warm-up over 100 steps, then cosine decay to 10 %."""
    if step < 100:
        return cfg.lr * (step + 1) / 100
    t = (step - 100) / max(1, cfg.steps - 100)
    return cfg.lr * (0.1 + 0.45 * (1 + math.cos(math.pi * t)))


def train_decoder(cfg: TrainConfig, out: Path, *, checkpoint: Path | None = None, checkpoint_every: int = 100,
                  log=print) -> dict:
    """Train, write the weights to ``out`` and the curve to ``out`` with ``.curve.json``; return the summary."""
    torch.set_num_threads(cfg.threads)
    gcfg = PRESETS[cfg.preset]
    R = gcfg.resolution
    torch.manual_seed(cfg.seed)
    g = Generator(gcfg)
    enc = Encoder(R, gcfg.z_dim)
    params = list(g.parameters()) + list(enc.parameters())
    opt = torch.optim.Adam(params, lr=cfg.lr, betas=(0.9, 0.99))
    data_rng = torch.Generator().manual_seed(cfg.seed + 1)
    noise_rng = torch.Generator().manual_seed(cfg.seed + 2)
    curve, start, seconds = [], 0, 0.0
    checkpoint = Path(checkpoint) if checkpoint else Path(str(out) + ".ckpt")
    if checkpoint.is_file():
        st = torch.load(checkpoint, weights_only=False)
        if st["config"] == asdict(cfg):
            g.load_state_dict(st["g"]), enc.load_state_dict(st["enc"]), opt.load_state_dict(st["opt"])
            data_rng.set_state(st["data_rng"]), noise_rng.set_state(st["noise_rng"])
            curve, start, seconds = st["curve"], st["step"], st["seconds"]
            log(f"resumed from step {start} ({checkpoint})")
    t0 = time.perf_counter()
    base = base_set(cfg.base_materials, 2 * R, seed=cfg.seed)
    data_seconds = time.perf_counter() - t0
    log(f"{cfg.base_materials} base materials at {2 * R}² in {data_seconds:.0f} s")
    t0 = time.perf_counter() - seconds
    for step in range(start, cfg.steps):
        for group in opt.param_groups:
            group["lr"] = _lr(cfg, step)
        x = augmented_batch(base, cfg.batch, data_rng, resolution=R, blend=cfg.blend)
        mu, logvar = enc(x)
        eps = torch.randn(mu.shape, generator=noise_rng)
        z = mu + eps * (0.5 * logvar).exp()
        w = g.mapping(z)[:, None].expand(-1, g.num_ws, -1)
        noise = [torch.randn(cfg.batch, 1, *s, generator=noise_rng) for s in g.noise_shapes()]
        recon = g(w, noise)
        loss, l1, kl = vae_loss(recon, x, mu, logvar, cfg.kl_weight)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        curve.append({"step": step + 1, "loss": loss.item(), "l1": l1.item(), "kl": kl.item(),
                      "seconds": round(time.perf_counter() - t0, 2)})
        if (step + 1) % 50 == 0 or step + 1 == cfg.steps:
            log(f"step {step + 1}/{cfg.steps}  l1 {l1:.4f}  kl {kl:.1f}  {time.perf_counter() - t0:.0f} s")
        if (step + 1) % checkpoint_every == 0 and step + 1 < cfg.steps:
            tmp = checkpoint.with_suffix(".tmp")
            torch.save({"config": asdict(cfg), "g": g.state_dict(), "enc": enc.state_dict(), "opt": opt.state_dict(),
                        "data_rng": data_rng.get_state(), "noise_rng": noise_rng.get_state(), "curve": curve,
                        "step": step + 1, "seconds": time.perf_counter() - t0}, tmp)
            tmp.replace(checkpoint)
    w_avg, w_std = g.w_stats(seed=cfg.seed)
    g.w_avg.copy_(w_avg)
    total = time.perf_counter() - t0
    summary = {"config": asdict(cfg), "method": "vae", "seconds": round(total + data_seconds, 1),
               "final_l1": sum(c["l1"] for c in curve[-50:]) / len(curve[-50:]), "steps": cfg.steps,
               "torch": torch.__version__}
    save_decoder(g, out, training=summary, w_std=w_std)
    Path(str(out) + ".curve.json").write_text(json.dumps(curve))
    if checkpoint.is_file():
        checkpoint.unlink()
    log(f"wrote {out} ({out.stat().st_size / 1e6:.1f} MB) in {total + data_seconds:.0f} s")
    return summary


def read_curve(weights) -> list[dict]:
    """The training curve that :func:`train_decoder` wrote beside ``weights`` (``WEIGHTS.curve.json``): one
    ``{"step", "loss", "l1", "kl", "seconds", ...}`` per step (drawn by :func:`bayes_brdf.plots.decoder_curve`)."""
    return json.loads(Path(str(weights) + ".curve.json").read_text())


def decoded_samples(weights, n: int = 8, seed: int = 0) -> list[tuple[str, torch.Tensor]]:
    """``n`` decoded samples ``z ~ N(0, I)`` (zero noise) of ``weights`` as rows ``(name, [n, H, W, 3])`` in
    display values: albedo (gamma 2.2), normal, roughness and a flash render (drawn by
    :func:`bayes_brdf.plots.decoder_samples`)."""
    from ..models.decoder_file import load_decoder
    from ..models.svbrdf_channels import decode
    from ..render import PlanarSample, collocated_views
    from ..render.shade import render

    g = load_decoder(weights)
    z = torch.randn(n, g.cfg.z_dim, generator=torch.Generator().manual_seed(seed))
    with torch.no_grad():
        w = g.mapping(z)[:, None].expand(-1, g.num_ws, -1)
        maps = decode(g(w, g.zero_noise(n)))
        view = collocated_views(1, 3.0, camera="rectified", resolution=g.cfg.resolution, power=12.0, max_zenith=20.0)
        img = render(maps, view, PlanarSample(2.0))[:, 0]
    return [("albedo", maps.albedo.permute(0, 2, 3, 1) ** (1 / 2.2)),
            ("normal", maps.normal.permute(0, 2, 3, 1) * 0.5 + 0.5),
            ("roughness", maps.roughness.permute(0, 2, 3, 1).expand(-1, -1, -1, 3)),
            ("flash render", img.clamp(0, 1) ** (1 / 2.2))]
