"""Figures of a trained latent decoder (``train-decoder --figures DIR``): its training curve and a grid of its
samples; :mod:`bayes_brdf.training.train` reads the curve and decodes the samples."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .base import pyplot, save_figure


def decoder_curve(curve: list[dict], path) -> Path:
    """The training curve (L1 of the channels and KL per material, 50-step running means): ``curve`` is the
    list of ``{"step", "l1", "kl", "seconds"}`` of ``WEIGHTS.curve.json``."""
    step = np.array([c["step"] for c in curve])
    smooth = lambda x: np.convolve(x, np.ones(50) / 50, mode="valid")  # noqa: E731
    fig, ax = pyplot().subplots(1, 2, figsize=(9, 3.2))
    for a, key, label in ((ax[0], "l1", "mean |G(z) - x| (channels in [-1, 1])"),
                          (ax[1], "kl", "KL(q(z|x) || N(0, I)), nats")):
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


def decoder_samples(rows: list[tuple], path) -> Path:
    """A grid of decoded samples: ``rows = [(name, tensor [n, H, W, 3] in display values)]``, one row each."""
    n = len(rows[0][1])
    fig, axes = pyplot().subplots(len(rows), n, figsize=(1.3 * n, 1.4 * len(rows)), squeeze=False)
    for r, (name, t) in enumerate(rows):
        for c in range(n):
            axes[r, c].imshow(t[c].clamp(0, 1).numpy())
            axes[r, c].set_xticks([]), axes[r, c].set_yticks([])
        axes[r, 0].set_ylabel(name, fontsize=8)
    fig.suptitle("decoder samples, z ~ N(0, I), zero noise", fontsize=9)
    return save_figure(fig, path, tight=True)
