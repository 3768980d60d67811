"""Lights. A point light has an RGB power and (by default) inverse-square falloff:

``radiance = brdf * cos(theta_l) * power / distance^2``  (the captures' convention).

With ``falloff=False`` the light only sets the direction ("directions only" mode:
``radiance = brdf * cos(theta_l) * power``), as some synthetic data sets use.
A collocated flash is a point light at the camera position (see
:meth:`bayes_brdf.render.views.View.collocated`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from ..errors import InputError
from .cameras import _vec3


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
        object.__setattr__(self, "position", _vec3(self.position, "light position"))
        p = self.power
        if isinstance(p, (int, float)):
            p = (p, p, p)
        p = _vec3(p, "light power")
        if min(p) < 0 or not all(math.isfinite(x) for x in p):
            raise InputError(f"light power must be finite and non-negative, got {p}")
        object.__setattr__(self, "power", p)
