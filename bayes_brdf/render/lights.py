"""Lights. A point light has an RGB power and (by default) inverse-square falloff:

``radiance = brdf * cos(theta_l) * power / distance^2``  (the captures' convention).

With ``falloff=False`` the light only sets the direction ("directions only" mode:
``radiance = brdf * cos(theta_l) * power``), as some synthetic data sets use.
A collocated flash is a point light at the camera position (see
:meth:`bayes_brdf.render.views.View.collocated`).
"""
from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from ..checks import rgb, vec3
from ..errors import InputError


@dataclass
class Incident:
    """What one light delivers to each pixel of one view: unit ``direction [3, H, W]`` towards the light,
    squared distance ``dist2 [1, H, W]`` and RGB ``scale [3, H, W]`` -- power / distance^2 (or power alone
    without falloff), times visibility (0 in shadow) and the valid mask."""

    direction: Tensor
    dist2: Tensor
    scale: Tensor


@dataclass(frozen=True)
class PointLight:
    """Point light at ``position`` with RGB ``power`` (a scalar is gray).

    Example:
        >>> PointLight(position=(0, 0, 20), power=1500).power
        (1500.0, 1500.0, 1500.0)
    """

    position: tuple[float, float, float]
    power: tuple[float, float, float] = (1.0, 1.0, 1.0)
    falloff: bool = True

    def __post_init__(self):
        object.__setattr__(self, "position", vec3(self.position, "light position"))
        object.__setattr__(self, "power", rgb(self.power, "light power"))

    def incident(self, position: Tensor, mask: Tensor, visible: Tensor | None = None, where: str = "") -> Incident:
        """The light at surface points ``position [3, H, W]`` (float64) where ``mask [H, W]``; ``visible [H, W]``
        (shadow rays, None: unoccluded) zeroes the pixels it cannot reach.

        Example:
            >>> p = torch.zeros(3, 1, 1, dtype=torch.float64)
            >>> PointLight((0, 0, 2.0), 8.0).incident(p, torch.ones(1, 1, dtype=torch.bool)).scale.flatten().tolist()
            [2.0, 2.0, 2.0]
        """
        lv = torch.tensor(self.position, dtype=torch.float64)[:, None, None] - position
        dd = (lv * lv).sum(0, keepdim=True)
        if bool((dd <= 0).any() & mask.any()):
            raise InputError(f"light {where}lies on the surface", fix="move the light off the surface")
        pw = torch.tensor(self.power, dtype=torch.float64)[:, None, None]
        scale = pw / dd.clamp_min(1e-30) if self.falloff else pw.expand(3, *position.shape[-2:])
        scale = scale * mask
        if visible is not None:
            scale = scale * visible
        return Incident(lv / dd.clamp_min(1e-30).sqrt(), dd, scale)
