"""The microfacet BRDF of MaterialGAN / Deschaintre et al., as small named terms.

All functions take broadcastable tensors of cosines (already clamped to be
positive) and material parameters, and are differentiable. With ``r`` the
perceptual roughness, ``alpha = r^2``:

* :func:`ggx_d`     -- ``D = alpha^2 / (pi ((n.h)^2 (alpha^2 - 1) + 1)^2)``
* :func:`smith_g1`  -- ``G1(c) = c / (c (1 - k) + k)`` with ``k = alpha / 2``
* :func:`smith_g`   -- ``G = G1(n.l) G1(n.v)``
* :func:`fresnel`   -- ``F = ks + (1 - ks) 2^((-5.55473 v.h - 6.98316) v.h)``
* :func:`diffuse`   -- ``kd (1 - ks) / pi`` (or ``kd / pi`` without the factor)
* :func:`microfacet` -- ``f = diffuse + D F G / (4 (n.l)(n.v))``
"""
from __future__ import annotations

import math

from torch import Tensor

INV_PI = 1.0 / math.pi


def ggx_d(nh: Tensor, alpha: Tensor) -> Tensor:
    """GGX / Trowbridge-Reitz normal distribution ``D(n.h; alpha)``.

    Example:
        >>> import torch
        >>> round(float(ggx_d(torch.tensor(1.0), torch.tensor(1.0))) * math.pi, 6)   # alpha = 1: D = 1/pi
        1.0
    """
    a2 = alpha * alpha
    den = nh * nh * (a2 - 1) + 1
    return a2 * INV_PI / (den * den)


def smith_g1(c: Tensor, k: Tensor) -> Tensor:
    """Schlick's approximation of Smith's masking ``G1(c) = c / (c (1 - k) + k)``."""
    return c / (c * (1 - k) + k)


def smith_g(nl: Tensor, nv: Tensor, alpha: Tensor) -> Tensor:
    """Smith-Schlick shadowing-masking ``G1(n.l) G1(n.v)`` with ``k = alpha / 2``.

    Example:
        >>> import torch
        >>> float(smith_g(torch.tensor(1.0), torch.tensor(1.0), torch.tensor(0.3)))
        1.0
    """
    k = alpha * 0.5
    return smith_g1(nl, k) * smith_g1(nv, k)


def fresnel_weight(vh: Tensor) -> Tensor:
    """The spherical-Gaussian Schlick weight ``2^((-5.55473 v.h - 6.98316) v.h)`` (1 at grazing)."""
    return (((-5.55473) * vh - 6.98316) * vh * math.log(2.0)).exp()


def fresnel(vh: Tensor, ks: Tensor) -> Tensor:
    """Schlick Fresnel (Unreal's spherical-Gaussian form) ``ks + (1 - ks) w(v.h)``.

    Example:
        >>> import torch
        >>> round(float(fresnel(torch.tensor(1.0), torch.tensor(0.04))), 4)   # normal incidence ~ F0
        0.0402
    """
    return ks + (1 - ks) * fresnel_weight(vh)


def diffuse(kd: Tensor, ks: Tensor, ks_factor: bool = True) -> Tensor:
    """Lambertian term ``kd (1 - ks) / pi`` (``kd / pi`` with ``ks_factor=False``)."""
    return kd * (1 - ks) * INV_PI if ks_factor else kd * INV_PI


def microfacet(kd: Tensor, roughness: Tensor, ks: Tensor, nl: Tensor, nv: Tensor, nh: Tensor, vh: Tensor,
               ks_factor: bool = True) -> Tensor:
    """The full BRDF value ``f`` (without the cosine) for positive cosines.

    ``kd, ks`` are RGB, ``roughness`` perceptual; all arguments broadcast.

    Example:
        >>> import torch
        >>> one = torch.tensor(1.0)
        >>> f = microfacet(torch.tensor(0.5), torch.tensor(0.5), torch.tensor(0.0), one, one, one, one)
        >>> round(float(f), 5)   # 0.5 / pi + D(1; alpha=0.25) F(1; ks=0) / 4
        0.15937
    """
    alpha = roughness * roughness
    spec = ggx_d(nh, alpha) * fresnel(vh, ks) * smith_g(nl, nv, alpha) / (4 * nl * nv)
    return diffuse(kd, ks, ks_factor) + spec
