"""The VAE half that is thrown away after training: an encoder ``maps -> (mu, log var)`` and the loss.

The generator (:class:`~bayes_brdf.models.stylegan.Generator`) is the decoder:
``z ~ N(mu, var)``, ``w = mapping(z)`` repeated over W+, random noise maps, and
``loss = mean |G(w, noise) - x| + kl_weight * KL(q(z|x) || N(0, I)) / (9 R²)``:
the negative ELBO of a Laplace likelihood per channel value, scaled by the value count.
"""
from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor, nn


class Encoder(nn.Module):
    """A plain strided CNN from channel maps ``[n, 9, R, R]`` to ``(mu, logvar)``, each ``[n, z_dim]``."""

    def __init__(self, resolution: int, z_dim: int, width: int = 32, max_width: int = 128):
        super().__init__()
        layers, c, r = [], 9, resolution
        while r > 4:
            c_out = min(max_width, width)
            layers += [nn.Conv2d(c, c_out, 3, stride=2, padding=1), nn.LeakyReLU(0.2)]
            c, r, width = c_out, r // 2, width * 2
        self.features = nn.Sequential(*layers)
        self.head = nn.Linear(c * 16, 2 * z_dim)

    def forward(self, x: Tensor) -> tuple[Tensor, Tensor]:
        h = self.head(self.features(x).flatten(1))
        mu, logvar = h.chunk(2, dim=-1)
        return mu, logvar.clamp(-12.0, 6.0)


def vae_loss(recon: Tensor, target: Tensor, mu: Tensor, logvar: Tensor, kl_weight: float) -> tuple[Tensor, Tensor, Tensor]:
    """``(loss, l1, kl)``: ``l1`` the mean absolute channel error, ``kl`` the mean KL per material (nats)."""
    l1 = F.l1_loss(recon, target)
    kl = 0.5 * (mu.pow(2) + logvar.exp() - 1 - logvar).sum(-1).mean()
    return l1 + kl_weight * kl / target[0].numel(), l1, kl
