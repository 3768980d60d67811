"""Tileable procedural noise and patterns in torch (vectorised, seeded).

Everything here works on *texture coordinates* ``u, v`` in ``[0, 1)`` (``u``
along columns, ``v`` along rows; see :func:`texel_grid`) so a pattern is defined
in fractions of the sample, not in pixels: the same seed gives the same
material at any resolution, just sampled more or less finely.

All patterns are periodic over the unit square (integer lattice periods), so
the maps tile seamlessly. Randomness comes only from the explicit CPU
:class:`torch.Generator` passed in (see :func:`make_generator`); the global RNG
is never read or advanced.

Example:
    >>> g = make_generator("doc", 0)
    >>> u, v = texel_grid(32)
    >>> n = fbm(u, v, g, period=4, octaves=3)
    >>> n.shape, bool(n.abs().max() < 1)
    (torch.Size([32, 32]), True)
"""
from __future__ import annotations

import hashlib
import math
from typing import NamedTuple

import kornia
import torch
from torch import Tensor

__all__ = [
    "make_generator",
    "texel_grid",
    "smoothstep",
    "gradient_noise",
    "value_noise",
    "fbm",
    "domain_warp",
    "Voronoi",
    "voronoi",
    "segment_field",
    "blur",
]

DTYPE = torch.float64  # internal working precision (results are cast at the end)


def make_generator(*keys) -> torch.Generator:
    """A CPU generator seeded from a stable hash of ``keys`` (e.g. material, seed, component).

    The hash is independent of Python's ``hash()`` randomisation, so the same keys
    give the same stream in every process.
    """
    digest = hashlib.sha256(":".join(map(str, ("bayes_brdf.materials", *keys))).encode()).digest()
    g = torch.Generator(device="cpu")
    g.manual_seed(int.from_bytes(digest[:8], "little") & ((1 << 63) - 1))
    return g


def texel_grid(resolution: int, dtype: torch.dtype = DTYPE) -> tuple[Tensor, Tensor]:
    """Texel-centre coordinates ``(u, v)``, each ``[R, R]``: ``u`` grows along columns, ``v`` along rows."""
    t = (torch.arange(resolution, dtype=dtype) + 0.5) / resolution
    v, u = torch.meshgrid(t, t, indexing="ij")
    return u, v


def smoothstep(e0: float, e1: float, x: Tensor) -> Tensor:
    """Hermite step from 0 at ``e0`` to 1 at ``e1``."""
    t = ((x - e0) / (e1 - e0)).clamp(0, 1)
    return t * t * (3 - 2 * t)


def _periods(period) -> tuple[int, int]:
    if isinstance(period, (tuple, list)):
        pu, pv = (int(p) for p in period)
    else:
        pu = pv = int(period)
    if pu < 1 or pv < 1:
        raise ValueError(f"noise period must be >= 1, got {period}")
    return pu, pv


def _fade(t: Tensor) -> Tensor:
    return t * t * t * (t * (t * 6 - 15) + 10)  # quintic, C2


def _lattice_noise(u: Tensor, v: Tensor, periods: list[tuple[int, int]], table: Tensor, kind: str) -> Tensor:
    """Evaluate several periodic lattice noises at once: ``[len(periods), H, W]``.

    ``table`` holds the random lattice values of all periods, concatenated
    (row-major ``[pv, pu]`` each): angles for gradient noise, values for value noise.
    """
    sizes = [pu * pv for pu, pv in periods]
    shape = (-1,) + (1,) * u.dim()
    pu = torch.tensor([p[0] for p in periods]).view(shape)
    pv = torch.tensor([p[1] for p in periods]).view(shape)
    base = torch.tensor([0] + sizes[:-1]).cumsum(0).view(shape)
    x, y = u[None] * pu, v[None] * pv
    x0, y0 = torch.floor(x), torch.floor(y)
    fx, fy = x - x0, y - y0
    i0 = x0.long().remainder(pu)
    j0 = y0.long().remainder(pv)
    i1 = (i0 + 1).remainder(pu)
    r0, r1 = base + j0 * pu, base + ((j0 + 1).remainder(pv)) * pu
    idx = torch.stack([r0 + i0, r0 + i1, r1 + i0, r1 + i1])  # corners 00, 10, 01, 11
    if kind == "gradient":
        dx = torch.stack([fx, fx - 1, fx, fx - 1])
        dy = torch.stack([fy, fy, fy - 1, fy - 1])
        c = torch.cos(table)[idx] * dx + torch.sin(table)[idx] * dy
        scale = math.sqrt(2)
    else:
        c = table[idx]
        scale = 1.0
    sx, sy = _fade(fx), _fade(fy)
    top = torch.lerp(c[0], c[1], sx)
    bot = torch.lerp(c[2], c[3], sx)
    return torch.lerp(top, bot, sy) * scale


def _draw(periods: list[tuple[int, int]], generator: torch.Generator, kind: str, dtype) -> Tensor:
    """Random lattice tables, drawn period by period (so the stream does not depend on batching)."""
    tabs = [torch.rand(pv, pu, generator=generator, dtype=DTYPE).reshape(-1) for pu, pv in periods]
    t = torch.cat(tabs).to(dtype)
    return t * (2 * math.pi) if kind == "gradient" else t * 2 - 1


def gradient_noise(u: Tensor, v: Tensor, period, generator: torch.Generator) -> Tensor:
    """Periodic 2-D gradient (Perlin) noise, roughly in ``[-1, 1]``, zero at lattice points.

    ``period`` (int or ``(pu, pv)``) is the number of lattice cells across the unit
    square along ``u`` and ``v``; unequal periods give stretched (anisotropic) noise.
    """
    p = [_periods(period)]
    return _lattice_noise(u, v, p, _draw(p, generator, "gradient", u.dtype), "gradient")[0]


def value_noise(u: Tensor, v: Tensor, period, generator: torch.Generator) -> Tensor:
    """Periodic 2-D value noise in ``[-1, 1]`` (smoothly interpolated random lattice values)."""
    p = [_periods(period)]
    return _lattice_noise(u, v, p, _draw(p, generator, "value", u.dtype), "value")[0]


def fbm(u: Tensor, v: Tensor, generator: torch.Generator, period=4, octaves: int = 5,
        lacunarity: int = 2, gain: float = 0.5, kind: str = "gradient",
        resolution: int | None = None) -> Tensor:
    """Fractional Brownian motion: ``octaves`` of noise, each ``lacunarity`` x finer and ``gain`` x weaker.

    The sum is divided by the total amplitude, so it stays roughly in ``[-1, 1]``
    (typical standard deviation 0.15-0.3). With ``resolution`` given, octaves whose
    lattice is finer than 2 texels are skipped (band limiting, so low resolutions do
    not alias); their random lattices are still drawn so the remaining octaves are
    identical at every resolution. All octaves are evaluated in one batched pass.
    """
    if kind not in ("gradient", "value"):
        raise ValueError(f"unknown noise kind {kind!r}")
    pu, pv = _periods(period)
    lac = int(lacunarity)
    periods = [(pu * lac ** o, pv * lac ** o) for o in range(octaves)]
    amps = [gain ** o for o in range(octaves)]
    table = _draw(periods, generator, kind, u.dtype)
    keep = [o for o, (a, b) in enumerate(periods) if resolution is None or max(a, b) <= resolution / 2]
    total = sum(amps)
    if not keep:
        return torch.zeros_like(u)
    offs = [0]
    for a, b in periods:
        offs.append(offs[-1] + a * b)
    sub = torch.cat([table[offs[o]:offs[o + 1]] for o in keep])
    n = _lattice_noise(u, v, [periods[o] for o in keep], sub, kind)
    w = torch.tensor([amps[o] / total for o in keep], dtype=u.dtype).view((-1,) + (1,) * u.dim())
    return (n * w).sum(0)


def domain_warp(u: Tensor, v: Tensor, generator: torch.Generator, amount: float, period=2,
                octaves: int = 4, resolution: int | None = None) -> tuple[Tensor, Tensor]:
    """Displace ``(u, v)`` by ``amount`` x an fBm vector field (periodic, so tiling is kept)."""
    du = fbm(u, v, generator, period, octaves, resolution=resolution)
    dv = fbm(u, v, generator, period, octaves, resolution=resolution)
    return u + amount * du, v + amount * dv


class Voronoi(NamedTuple):
    """Worley/cellular noise: distances (in cell units) to the nearest and second-nearest
    feature points, and the flat index (``row * cells + col``) of the nearest point's cell."""

    f1: Tensor
    f2: Tensor
    cell: Tensor

    @property
    def edge(self) -> Tensor:
        """``f2 - f1``: 0 on cell borders, growing towards cell centres."""
        return self.f2 - self.f1


def voronoi(u: Tensor, v: Tensor, cells: int, generator: torch.Generator, jitter: float = 1.0) -> Voronoi:
    """Periodic Voronoi cells: one random feature point per cell of a ``cells x cells`` grid.

    ``jitter`` in ``[0, 1]`` moves the points from the cell centres (0, a regular
    grid) to anywhere in their cell (1).
    """
    n = int(cells)
    pts = 0.5 + float(jitter) * (torch.rand(n, n, 2, generator=generator, dtype=DTYPE).to(u.dtype) - 0.5)
    x, y = u * n, v * n
    cx, cy = torch.floor(x), torch.floor(y)
    dists, ids = [], []
    for dj in (-1, 0, 1):
        for di in (-1, 0, 1):
            ni, nj = cx + di, cy + dj
            ii, jj = ni.long().remainder(n), nj.long().remainder(n)
            p = pts[jj, ii]
            dists.append(torch.hypot(ni + p[..., 0] - x, nj + p[..., 1] - y))
            ids.append(jj * n + ii)
    d = torch.stack(dists)
    ds, order = torch.sort(d, dim=0)
    cell = torch.gather(torch.stack(ids), 0, order[:1])[0]
    return Voronoi(ds[0], ds[1], cell)


def segment_field(u: Tensor, v: Tensor, centers: Tensor, angles: Tensor, lengths: Tensor,
                  widths: Tensor, weights: Tensor, chunk: int = 16) -> Tensor:
    """Max over line segments of ``weight * exp(-d^2 / (2 width^2))``, ``d`` the (periodic) distance
    to the segment; e.g. scratches. Segments are ``[K]`` tensors (``centers`` is ``[K, 2]`` in
    ``(u, v)``), lengths below 1/2 so the minimum-image wrap is exact."""
    out = torch.zeros_like(u)
    for s in range(0, centers.shape[0], chunk):
        c = centers[s:s + chunk, :, None, None]
        a = angles[s:s + chunk, None, None]
        half = lengths[s:s + chunk, None, None] / 2
        du = u - c[:, 0]
        dv = v - c[:, 1]
        du = du - torch.round(du)  # minimum image: the pattern tiles
        dv = dv - torch.round(dv)
        tu, tv = torch.cos(a), torch.sin(a)
        t = (du * tu + dv * tv).clamp(-half, half)
        d2 = (du - t * tu) ** 2 + (dv - t * tv) ** 2
        w = widths[s:s + chunk, None, None]
        f = weights[s:s + chunk, None, None] * torch.exp(-0.5 * d2 / (w * w))
        out = torch.maximum(out, f.amax(0))
    return out


def blur(x: Tensor, sigma: float) -> Tensor:
    """Periodic Gaussian blur of a ``[H, W]`` or ``[C, H, W]`` field; ``sigma`` in texels (kornia)."""
    if sigma <= 0:
        return x
    size = min(2 * math.ceil(3 * sigma) + 1, 2 * (min(x.shape[-2:]) // 2) - 1)
    if size < 3:
        return x
    squeeze = x.dim() == 2
    y = x[None, None] if squeeze else x[None]
    y = kornia.filters.gaussian_blur2d(y, (size, size), (sigma, sigma), border_type="circular")
    return y[0, 0] if squeeze else y[0]
