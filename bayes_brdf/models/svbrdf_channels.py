"""MaterialGAN's 9-channel SVBRDF encoding: a generator's output in ``[-1, 1]`` to maps, and back.

Channels ``[..., 9, H, W]``: ``0:3`` diffuse albedo, ``3:5`` normal x, y, ``5`` roughness,
``6:9`` specular albedo. Decoding, exactly as MaterialGAN's renderer reads a generator's output:

* albedo ``((clamp(t, -1, 1) + 1) / 2) ** 2.2``
* normal ``x, y = clamp(t, -1, 1)``, ``z = sqrt(1 - clamp(x² + y², 0, 1 - 1e-6))``, normalised
* roughness ``max(((clamp(t, -0.3, 1) + 1) / 2) ** 2.2, 1e-6)`` (perceptual roughness, ``alpha = r²``)
* specular ``((clamp(t, -1, 1) + 1) / 2) ** 2.2``

:func:`encode` is the inverse on the decodable range (used to train a generator on
procedural materials): roughness below ``0.35 ** 2.2 = 0.099``, MaterialGAN's floor,
cannot be encoded and is clamped there.

Example:
    >>> import torch
    >>> t = torch.zeros(9, 2, 2)
    >>> m = decode(t)
    >>> round(float(m.albedo[0, 0, 0]), 4), [round(float(v), 3) for v in m.normal[:, 0, 0]]
    (0.2176, [0.0, 0.0, 1.0])
"""
from __future__ import annotations

import torch
from torch import Tensor

from ..errors import InputError
from ..render.maps import SVBRDF, unit_vectors

GAMMA = 2.2
#: the lowest roughness the encoding reaches: ((-0.3 + 1) / 2) ** 2.2
ROUGHNESS_FLOOR = 0.35 ** GAMMA
CHANNELS = {"albedo": slice(0, 3), "normal": slice(3, 5), "roughness": slice(5, 6), "specular": slice(6, 9)}


def _check(t: Tensor) -> None:
    if t.dim() < 3 or t.shape[-3] != 9:
        raise InputError(f"SVBRDF channels must be [..., 9, H, W], got {list(t.shape)}")


def decode(t: Tensor) -> SVBRDF:
    """``[..., 9, H, W]`` generator output to an :class:`SVBRDF` (albedo, roughness, specular, normal)."""
    _check(t)
    g = lambda x, lo: ((x.clamp(lo, 1.0) + 1) * 0.5) ** GAMMA  # noqa: E731
    albedo = g(t[..., 0:3, :, :], -1.0)
    xy = t[..., 3:5, :, :].clamp(-1.0, 1.0)
    z = (1 - (xy * xy).sum(-3, keepdim=True).clamp(0.0, 1 - 1e-6)).sqrt()
    n = unit_vectors(torch.cat([xy, z], dim=-3))
    rough = g(t[..., 5:6, :, :], -0.3).clamp_min(1e-6)
    spec = g(t[..., 6:9, :, :], -1.0)
    return SVBRDF(albedo, rough, spec, n)


def encode(maps: SVBRDF) -> Tensor:
    """The channels ``[..., 9, H, W]`` that :func:`decode` maps back to ``maps`` (on the decodable range).

    Gray or single-channel maps are expanded to 3 channels; a normal must have ``z > 0``.
    """
    inv = lambda x, lo: (2 * x.clamp(0.0, 1.0) ** (1 / GAMMA) - 1).clamp(lo, 1.0)  # noqa: E731
    a = maps.albedo
    shape = a.shape[:-3] + (3,) + a.shape[-2:]
    e = lambda x: x.expand(*x.shape[:-3], 3 if x.shape[-3] == 1 else x.shape[-3], *shape[-2:])  # noqa: E731
    n = e(maps.normal)
    n = n / n.norm(dim=-3, keepdim=True)
    r = maps.roughness.expand(*shape[:-3], 1, *shape[-2:])
    return torch.cat([inv(e(a), -1.0), n[..., 0:2, :, :], inv(r, -0.3), inv(e(maps.specular), -1.0)], dim=-3)
