"""Figures of a trained decoder: its training curve and a grid of samples (``train-decoder --figures DIR``)."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import torch

from ..experiments.common import save_figure
from ..models.decoder_file import load_decoder
from ..models.svbrdf_channels import decode


def curve_figure(weights, path) -> Path:
    """The training curve (L1 of the channels and KL per material, 50-step running means) of ``weights``."""
    import matplotlib.pyplot as plt
    curve = json.loads(Path(str(weights) + ".curve.json").read_text())
    step = np.array([c["step"] for c in curve])
    smooth = lambda x: np.convolve(x, np.ones(50) / 50, mode="valid")  # noqa: E731
    fig, ax = plt.subplots(1, 2, figsize=(9, 3.2))
    for a, key, label in ((ax[0], "l1", "mean |G(z) - x| (channels in [-1, 1])"), (ax[1], "kl", "KL(q(z|x) || N(0, I)), nats")):
        v = np.array([c[key] for c in curve])
        a.plot(step, v, color="0.8", lw=0.6, label="per step")
        a.plot(step[49:], smooth(v), color="C0", lw=1.5, label="50-step mean")
        a.set_xlabel("step (16 materials each)")
        a.set_ylabel(label, fontsize=8)
        a.grid(alpha=0.3)
    ax[0].set_yscale("log")
    ax[0].legend(fontsize=7)
    secs = curve[-1]["seconds"]
    fig.suptitle(f"training the latent decoder (VAE), {len(curve)} steps in {secs / 60:.0f} min", fontsize=9)
    return save_figure(fig, path, tight=True)


def sample_grid(weights, path, n: int = 8, seed: int = 0) -> Path:
    """``n`` decoded samples ``z ~ N(0, I)`` (zero noise): albedo, normal, roughness, and a flash render."""
    import matplotlib.pyplot as plt

    from ..render import PlanarSample, collocated_views
    from ..render.shade import render
    g = load_decoder(weights)
    z = torch.randn(n, g.cfg.z_dim, generator=torch.Generator().manual_seed(seed))
    with torch.no_grad():
        w = g.mapping(z)[:, None].expand(-1, g.num_ws, -1)
        maps = decode(g(w, g.zero_noise(n)))
        view = collocated_views(1, 3.0, camera="rectified", resolution=g.cfg.resolution, power=12.0, max_zenith=20.0)
        img = render(maps, view, PlanarSample(2.0))[:, 0]
    rows = [("albedo", maps.albedo.permute(0, 2, 3, 1) ** (1 / 2.2)),
            ("normal", maps.normal.permute(0, 2, 3, 1) * 0.5 + 0.5),
            ("roughness", maps.roughness.permute(0, 2, 3, 1).expand(-1, -1, -1, 3)),
            ("flash render", img.clamp(0, 1) ** (1 / 2.2))]
    fig, axes = plt.subplots(len(rows), n, figsize=(1.3 * n, 1.4 * len(rows)), squeeze=False)
    for r, (name, t) in enumerate(rows):
        for c in range(n):
            axes[r, c].imshow(t[c].clamp(0, 1).numpy())
            axes[r, c].set_xticks([]), axes[r, c].set_yticks([])
        axes[r, 0].set_ylabel(name, fontsize=8)
    fig.suptitle("decoder samples, z ~ N(0, I), zero noise", fontsize=9)
    return save_figure(fig, path, tight=True)
