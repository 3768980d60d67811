"""Training materials for a latent decoder: the six procedural generators plus augmentations.

A *base set* is ``count`` procedural materials (the generators in turn, one seed
each) made at twice the training resolution and stored in MaterialGAN's channel
encoding (:func:`bayes_brdf.models.svbrdf_channels.encode`). :func:`augmented_batch`
draws from it, every draw from an explicit seeded generator:

* **scale** -- the whole material area-downsampled to ``R`` (as made), or a random
  ``R × R`` crop (2× zoom);
* **rotation** -- one of the 8 symmetries of the square (quarter turns and mirrors),
  with the normals' ``x, y`` turned with the map (``x`` along columns, ``y`` up the rows);
* **colour** -- hue rotation, saturation and brightness of the diffuse albedo (kornia,
  on the gamma-encoded albedo), and a gray-level change of the specular albedo;
* **blends** -- with probability ``blend``, two materials mixed by a smooth random mask
  (every channel linearly, the normals' ``x, y`` included; ``z`` follows from them when decoded).

Held-out materials use seeds from :data:`HELD_OUT_SEED` on, which no base set below that many
materials per generator reaches.

Example:
    >>> base = base_set(6, 16, seed=0)
    >>> x = augmented_batch(base, 4, torch.Generator().manual_seed(0))
    >>> x.shape
    torch.Size([4, 9, 8, 8])
"""
from __future__ import annotations

import math

import kornia
import torch
import torch.nn.functional as F
from torch import Tensor

from ..models.svbrdf_channels import GAMMA, encode
from .procedural import MATERIALS, make_material

#: seeds of held-out (test) materials start here; training seeds are ``0 .. count / 6``
HELD_OUT_SEED = 100_000


def base_set(count: int, resolution: int, seed: int = 0) -> Tensor:
    """``count`` procedural materials ``[count, 9, resolution, resolution]`` (channel space, float32).

    Material ``i`` is generator ``i mod 6`` with seed ``seed * 1_000_000 + i // 6``.
    """
    names = sorted(MATERIALS)
    out = torch.empty(count, 9, resolution, resolution)
    for i in range(count):
        m = make_material(names[i % len(names)], resolution, seed=seed * 1_000_000 + i // len(names))
        out[i] = encode(m)
    return out


def held_out(resolution: int, per_generator: int = 1) -> tuple[list[str], Tensor]:
    """Materials no base set contains: ``(names, [k, 9, R, R])``, each generator with seeds from ``HELD_OUT_SEED``."""
    names, maps = [], []
    for name in sorted(MATERIALS):
        for j in range(per_generator):
            names.append(f"{name}/{HELD_OUT_SEED + j}")
            maps.append(encode(make_material(name, resolution, seed=HELD_OUT_SEED + j)))
    return names, torch.stack(maps)


def dihedral(x: Tensor, k: int) -> Tensor:
    """Symmetry ``k`` in 0..7 of the square on channel maps ``[n, 9, H, W]``, normals turned along."""
    if k & 4:     # transpose rows <-> columns: (x, y) -> (-y, -x)
        x = x.transpose(-1, -2)
        x = torch.cat([x[:, :3], -x[:, 4:5], -x[:, 3:4], x[:, 5:]], 1)
    if k & 2:     # mirror the columns: x -> -x
        x = x.flip(-1)
        x = torch.cat([x[:, :3], -x[:, 3:4], x[:, 4:]], 1)
    if k & 1:     # mirror the rows: y -> -y
        x = x.flip(-2)
        x = torch.cat([x[:, :4], -x[:, 4:5], x[:, 5:]], 1)
    return x


def _renormal_xy(xy: Tensor) -> Tensor:
    """Normal ``x, y`` kept inside ``(-1, 1)`` after averaging (decoding clamps ``x² + y²`` below 1 anyway)."""
    return xy.clamp(-0.999, 0.999)


def _scale(x: Tensor, r: int, g: torch.Generator) -> Tensor:
    n, _, h, _ = x.shape
    if h == r:
        return x
    out = torch.empty(n, 9, r, r, dtype=x.dtype)
    crop = torch.rand(n, generator=g) < 0.5
    for i in range(n):
        if crop[i]:
            oy, ox = (int(v) for v in torch.randint(0, h - r + 1, (2,), generator=g))
            out[i] = x[i, :, oy:oy + r, ox:ox + r]
        else:
            out[i] = F.adaptive_avg_pool2d(x[i:i + 1], r)[0]
    out[:, 3:5] = _renormal_xy(out[:, 3:5])
    return out


def _colour(x: Tensor, g: torch.Generator) -> Tensor:
    n = x.shape[0]
    srgbish = (x[:, 0:3] + 1) * 0.5                                      # gamma-encoded albedo in [0, 1]
    hue = (torch.rand(n, generator=g) * 2 - 1) * math.pi
    sat = torch.exp((torch.rand(n, generator=g) * 2 - 1) * 0.5)
    bright = torch.exp((torch.rand(n, generator=g) * 2 - 1) * 0.4 / GAMMA)
    a = kornia.enhance.adjust_hue(srgbish, hue)
    a = kornia.enhance.adjust_saturation(a, sat)
    a = (a * bright[:, None, None, None]).clamp(0.0, 1.0)
    spec_gain = torch.exp((torch.rand(n, generator=g) * 2 - 1) * 0.3)
    spec = (((x[:, 6:9] + 1) * 0.5) * spec_gain[:, None, None, None]).clamp(0.0, 1.0)
    return torch.cat([a * 2 - 1, x[:, 3:6], spec * 2 - 1], 1)


def _mask(n: int, r: int, g: torch.Generator) -> Tensor:
    """Smooth random blend masks ``[n, 1, r, r]`` in [0, 1]: upsampled low-resolution noise, sharpened."""
    lo = torch.randn(n, 1, 4, 4, generator=g)
    m = F.interpolate(lo, size=(r, r), mode="bicubic", align_corners=False)
    return torch.sigmoid(4 * m)


def _blend(x: Tensor, y: Tensor, m: Tensor) -> Tensor:
    out = x * (1 - m) + y * m
    out[:, 3:5] = _renormal_xy(out[:, 3:5])
    return out


def augmented_batch(base: Tensor, n: int, g: torch.Generator, *, resolution: int | None = None,
                    blend: float = 0.25) -> Tensor:
    """``n`` augmented training materials ``[n, 9, R, R]`` drawn from ``base`` with generator ``g``.

    ``R`` defaults to half the base resolution.
    """
    r = resolution or base.shape[-1] // 2
    idx = torch.randint(0, base.shape[0], (n,), generator=g)
    x = _scale(base[idx], r, g)
    mixed = torch.rand(n, generator=g) < blend
    if mixed.any():
        k = int(mixed.sum())
        other = _scale(base[torch.randint(0, base.shape[0], (k,), generator=g)], r, g)
        x[mixed] = _blend(x[mixed], other, _mask(k, r, g))
    ks = torch.randint(0, 8, (n,), generator=g)
    x = torch.cat([dihedral(x[i:i + 1], int(ks[i])) for i in range(n)])
    return _colour(x, g)
