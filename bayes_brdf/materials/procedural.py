"""Procedural SVBRDF materials for synthetic experiments and the demo.

Every generator has the signature ``fn(resolution=128, seed=0, *, dtype=torch.float32,
device=None) -> SVBRDF`` and returns channel-first ``[C, R, R]`` maps in the
ranges of :mod:`bayes_brdf.render.maps`:

* albedo in ``[0.02, 0.95]`` (linear RGB),
* perceptual roughness in ``[0.05, 1]`` (GGX ``alpha = r^2``),
* specular F0 ``~0.04`` for dielectrics, coloured and high for metal,
* unit tangent-space normals with ``z > 0`` (from a height field, via kornia).

Features are sized in fractions of the sample (not pixels), so a material looks
the same at 128^2 and 256^2, and all maps tile seamlessly. Results depend only
on ``(material, seed)``: each pattern component draws from its own CPU
:class:`torch.Generator` (see :func:`~bayes_brdf.materials.noise.make_generator`),
the global RNG is neither read nor advanced, and everything is computed in
float64 on the CPU and cast at the end.

Example:
    >>> from bayes_brdf.materials import make_material
    >>> m = make_material("tiles", resolution=64, seed=3)
    >>> m.albedo.shape, m.roughness.dtype
    (torch.Size([3, 64, 64]), torch.float32)
"""
from __future__ import annotations

import math
from typing import Callable

import kornia
import torch
from torch import Tensor

from ..errors import InputError
from ..render.maps import SVBRDF
from .noise import (DTYPE, blur, domain_warp, fbm, make_generator, segment_field,
                    smoothstep, texel_grid, voronoi)

__all__ = [
    "MATERIALS",
    "make_material",
    "height_to_normal",
    "wood",
    "tiles",
    "marble",
    "scratched_metal",
    "leather",
    "fabric",
]

ALBEDO_RANGE = (0.02, 0.95)
ROUGHNESS_RANGE = (0.05, 1.0)
SPECULAR_RANGE = (0.02, 1.0)
DIELECTRIC_F0 = 0.04


# ----------------------------------------------------------------------------- helpers
def _gradient(field: Tensor) -> tuple[Tensor, Tensor]:
    """``(d/du, d/dv)`` of a periodic ``[H, W]`` field per unit of texture space (kornia
    normalised Sobel, circular borders); ``u`` along columns, ``v`` down the rows."""
    f = field.reshape(1, 1, *field.shape[-2:])
    kernel = kornia.filters.get_spatial_gradient_kernel2d("sobel", 1, device=f.device, dtype=f.dtype)
    g = kornia.filters.filter2d(f.expand(2, 1, -1, -1), kernel, border_type="circular", normalized=True)
    return g[0, 0] * f.shape[-1], g[1, 0] * f.shape[-2]


def height_to_normal(height: Tensor, strength: float = 1.0) -> Tensor:
    """Unit tangent-space normals ``[3, H, W]`` from a height field ``[H, W]`` (or ``[1, H, W]``).

    ``height`` is in units of the sample's side length (texture space ``[0, 1]``),
    so slopes do not depend on the resolution. Gradients are normalised Sobel
    filters (kornia) with circular borders (the maps tile). Row 0 is the ``+v``
    / ``+y`` edge of the sample (see :class:`~bayes_brdf.render.surface.PlanarSample`),
    so ``n = (-dh/dx, -dh/dy, 1) = (-R dh/dcol, +R dh/drow, 1)``, normalised.
    """
    d_col, d_row = _gradient(height)
    n = torch.stack([-strength * d_col, strength * d_row, torch.ones_like(d_col)])
    return n / n.norm(dim=0, keepdim=True)


def _level_distance(f: Tensor, grad: tuple[Tensor, Tensor] | None = None, level: float = 0.0) -> Tensor:
    """Approximate distance (texture units) to the contour ``f = level``: ``|f - level| / |grad f|``."""
    gu, gv = _gradient(f) if grad is None else grad
    return (f - level).abs() / (torch.hypot(gu, gv) + 1e-6)


def _rgb(c, like: Tensor) -> Tensor:
    return torch.as_tensor(c, dtype=like.dtype).reshape(3, 1, 1)


def _mix(a, b, t: Tensor) -> Tensor:
    """Blend RGB colours/maps ``a`` -> ``b`` by a ``[H, W]`` weight."""
    a = _rgb(a, t) if not isinstance(a, Tensor) or a.dim() == 1 else a
    b = _rgb(b, t) if not isinstance(b, Tensor) or b.dim() == 1 else b
    return a + (b - a) * t[None]


def _check(name: str, resolution, seed) -> None:
    if isinstance(resolution, bool) or not isinstance(resolution, int) or resolution < 8:
        raise InputError(f"material '{name}': resolution must be an integer >= 8, got {resolution!r}",
                         fix="pass e.g. resolution=128")
    if isinstance(seed, bool) or not isinstance(seed, int):
        raise InputError(f"material '{name}': seed must be an integer, got {seed!r}", fix="pass e.g. seed=0")


def _finish(albedo: Tensor, roughness: Tensor, specular: Tensor, height: Tensor, dtype, device) -> SVBRDF:
    """Clamp to the physical ranges, derive normals, cast and move."""
    if roughness.dim() == 2:
        roughness = roughness[None]
    if specular.dim() == 2:
        specular = specular[None].expand(3, -1, -1)
    maps = SVBRDF(
        albedo=albedo.clamp(*ALBEDO_RANGE),
        roughness=roughness.clamp(*ROUGHNESS_RANGE),
        specular=specular.clamp(*SPECULAR_RANGE),
        normal=height_to_normal(height),
    )
    maps = maps.to(dtype=dtype or torch.float32, device=device)
    if maps.normal.dtype != DTYPE:  # re-normalise after rounding
        maps.normal = maps.normal / maps.normal.norm(dim=0, keepdim=True)
    return SVBRDF(**{k: t.contiguous() for k, t in maps.items()})


class _Streams:
    """One independent generator per named pattern component of a material."""

    def __init__(self, material: str, seed: int):
        self.material, self.seed = material, seed

    def __call__(self, component: str) -> torch.Generator:
        return make_generator(self.material, self.seed, component)

    def uniform(self, component: str, *shape, low=0.0, high=1.0) -> Tensor:
        return low + (high - low) * torch.rand(*shape, generator=self(component), dtype=DTYPE)

    def choice(self, component: str, n: int) -> int:
        return int(torch.randint(n, (1,), generator=self(component)))


# ----------------------------------------------------------------------------- materials
def wood(resolution: int = 128, seed: int = 0, *, dtype=torch.float32, device=None) -> SVBRDF:
    """Flat-sawn wood floor: three rows of boards with cathedral growth rings, fine grain
    streaks and pores along the boards, dark grooves between boards; satin finish."""
    _check("wood", resolution, seed)
    R, rs = resolution, _Streams("wood", seed)
    u, v = texel_grid(R)
    rows = 3
    pw = 1.0 / rows
    row = torch.floor(v * rows).long().clamp(max=rows - 1)
    pv = v * rows - row  # across the board, [0, 1)

    # one end joint per row (boards wrap around the tile); per-board "log" geometry
    joint = rs.uniform("joint", rows)
    a = torch.remainder(u - joint[row], 1.0)  # along the board, [0, 1)
    pith = rs.uniform("pith", rows, low=-0.6, high=0.6)[row] * pw  # pith offset across the board
    depth = rs.uniform("depth", rows, low=0.01, high=0.06)[row]
    tilt = rs.uniform("tilt", rows, low=-0.12, high=0.12)[row]
    spacing = rs.uniform("spacing", rows, low=0.022, high=0.032)[row]
    tone = (rs.uniform("tone", rows, low=0.85, high=1.12)[:, None]
            * rs.uniform("hue", rows, 3, low=0.96, high=1.04))[row].permute(2, 0, 1)

    wu, wv = domain_warp(u, v, rs("warp"), 0.03, period=(2, 6), octaves=3, resolution=R)
    b = (pv - 0.5) * pw - pith + 0.006 * fbm(wu, wv, rs("wobble"), (2, 8), 3, resolution=R)
    dep = depth + tilt * (a - 0.5) + 0.01 * fbm(wu, wv, rs("bend"), (2, 3), 3, resolution=R)
    r = torch.sqrt(b * b + dep * dep)
    phase = r / spacing + 0.35 * fbm(wu, wv, rs("ringnoise"), (3, 12), 3, resolution=R)
    f = torch.remainder(phase, 1.0)
    late = smoothstep(0.5, 0.85, f) * (1 - smoothstep(0.93, 1.0, f))  # dark latewood band

    grain = fbm(u, v, rs("grain"), (2, 64), 3, resolution=R)  # streaks along u
    pores = smoothstep(0.25, 0.55, -fbm(u, v, rs("pores"), (16, 128), 2, resolution=R))
    pores = pores * (0.4 + 0.6 * late)

    light, dark = (0.52, 0.30, 0.14), (0.22, 0.10, 0.04)
    albedo = _mix(light, dark, (0.85 * late + 0.6 * grain + 0.5 * pores).clamp(0, 1))
    albedo = albedo * tone * (1 + 0.15 * fbm(u, v, rs("stain"), (2, 4), 3, resolution=R))[None]

    # grooves between board rows and at the end joints
    gap_w = 0.004
    across = torch.minimum(pv, 1 - pv) * pw
    along = torch.minimum(a, 1 - a)
    edge = torch.minimum(across, along)
    groove = 1 - smoothstep(gap_w * 0.5, gap_w * 1.5, edge)
    bevel = smoothstep(0.0, 0.012, edge)
    albedo = _mix(albedo, (0.05, 0.03, 0.018), groove)

    rough = 0.42 - 0.08 * late + 0.12 * grain + 0.1 * pores
    rough = rough + (0.95 - rough) * groove
    height = 0.004 * bevel - 0.0006 * pores + 0.0004 * late + 0.0003 * grain
    return _finish(albedo, rough, torch.full_like(u, DIELECTRIC_F0), height, dtype, device)


_TILE_COLOURS = [
    (0.78, 0.76, 0.70),   # white ceramic
    (0.08, 0.20, 0.45),   # cobalt glaze
    (0.45, 0.16, 0.07),   # terracotta
    (0.12, 0.32, 0.22),   # green glaze
]


def tiles(resolution: int = 128, seed: int = 0, *, dtype=torch.float32, device=None) -> SVBRDF:
    """Glazed ceramic tiles (4 x 4) with per-tile colour jitter and glaze mottling, bevelled
    edges and slightly tilted faces; rough, sandy grout lines. Glossy tiles, rough grout."""
    _check("tiles", resolution, seed)
    R, rs = resolution, _Streams("tiles", seed)
    u, v = texel_grid(R)
    n = 4
    x, y = u * n, v * n
    ti, tj = torch.floor(x).long(), torch.floor(y).long()
    fx, fy = x - ti, y - tj
    tile = tj * n + ti

    base = _rgb(_TILE_COLOURS[rs.choice("palette", len(_TILE_COLOURS))], u)
    jitter = rs.uniform("jitter", n * n, 3, low=0.88, high=1.1)
    shade = rs.uniform("shade", n * n, low=0.85, high=1.12)
    tile_col = base * (jitter[tile] * shade[tile][..., None]).permute(2, 0, 1)
    mottle = fbm(u, v, rs("mottle"), 8, 4, resolution=R)
    tile_col = tile_col * (1 + 0.25 * mottle)[None]

    # distance to the tile's border, in sample units
    edge = torch.minimum(torch.minimum(fx, 1 - fx), torch.minimum(fy, 1 - fy)) / n
    gw = 0.008 + 0.0015 * fbm(u, v, rs("groutw"), 16, 2, resolution=R)  # half grout width
    grout = 1 - smoothstep(gw - 0.0015, gw + 0.0015, edge)
    sand = fbm(u, v, rs("sand"), 32, 3, resolution=R)
    grout_col = _rgb((0.32, 0.31, 0.29), u) * (1 + 0.6 * sand)[None]
    albedo = _mix(tile_col, grout_col, grout)

    tilt = rs.uniform("tilt", n * n, 2, low=-0.01, high=0.01)[tile]
    bevel = smoothstep(gw, gw + 0.014, edge)
    face = bevel * (0.006 + tilt[..., 0] * (fx - 0.5) / n + tilt[..., 1] * (fy - 0.5) / n
                    + 0.00015 * fbm(u, v, rs("peel"), 16, 3, resolution=R))
    height = face + (1 - bevel) * 0.0008 * sand

    glaze = fbm(u, v, rs("glaze"), 6, 4, resolution=R)
    rough_tile = 0.14 + 0.12 * glaze + 0.04 * smoothstep(0.0, 0.5, -mottle)
    rough = rough_tile + (0.92 + 0.08 * sand - rough_tile) * grout
    spec = DIELECTRIC_F0 + (0.035 - DIELECTRIC_F0) * grout
    return _finish(albedo, rough, spec, height, dtype, device)


def marble(resolution: int = 128, seed: int = 0, *, dtype=torch.float32, device=None) -> SVBRDF:
    """Polished white (or seed-tinted) marble: cloudy base, long domain-warped grey veins of
    varying width with soft halos, and a web of fine hairline veins; glossy, veins slightly
    rougher and recessed."""
    _check("marble", resolution, seed)
    R, rs = resolution, _Streams("marble", seed)
    u, v = texel_grid(R)
    base_choices = [(0.82, 0.81, 0.77), (0.80, 0.74, 0.66), (0.70, 0.72, 0.74)]
    base = _rgb(base_choices[rs.choice("palette", len(base_choices))], u)
    vein_col = _rgb((0.12, 0.12, 0.13), u)

    # main veins: zero crossings of sin(pi k (u +- v) + A * turbulence), at an even width
    wu, wv = domain_warp(u, v, rs("warp"), 0.08, period=2, octaves=4, resolution=R)
    turb = fbm(wu, wv, rs("turb"), 2, 6, resolution=R)
    k = 2 * (1 + rs.choice("bands", 2))  # even, so sin(t) tiles
    sign = 1.0 if rs.choice("diagonal", 2) else -1.0
    amp = 4.0
    t = math.pi * k / 2 * (u + sign * v) + amp * turb
    tu, tv = _gradient(turb)
    grad_t = (math.pi * k / 2 + amp * tu, math.pi * k / 2 * sign + amp * tv)
    d_main = _level_distance(torch.sin(t), (torch.cos(t) * grad_t[0], torch.cos(t) * grad_t[1]))
    width = 0.0035 * (1 + 0.9 * fbm(u, v, rs("width"), 4, 3, resolution=R)).clamp(min=0.15)
    width = width.clamp(min=0.6 / R)
    main = torch.exp(-0.5 * (d_main / width) ** 2)
    halo = torch.exp(-d_main / 0.03)
    strength = 0.5 + 0.5 * smoothstep(-0.25, 0.2, fbm(u, v, rs("fade"), 3, 3, resolution=R))
    main, halo = main * strength, halo * strength

    # fine veins: a contour of a second warped fBm
    su, sv = domain_warp(u, v, rs("warp2"), 0.1, period=3, octaves=4, resolution=R)
    fine_n = fbm(su, sv, rs("fine"), 3, 5, resolution=R)
    d_fine = _level_distance(fine_n, level=0.05)
    fine = torch.exp(-0.5 * (d_fine / max(0.0012, 0.5 / R)) ** 2)
    fine = fine * smoothstep(-0.15, 0.25, fbm(u, v, rs("finemask"), 2, 3, resolution=R))

    cloud = fbm(wu, wv, rs("cloud"), 2, 5, resolution=R)
    albedo = base * (1 + 0.10 * cloud)[None]
    albedo = albedo * (1 - 0.18 * halo - 0.08 * smoothstep(0.0, 0.4, turb))[None]
    albedo = _mix(albedo, vein_col * 3.0, 0.5 * fine)
    albedo = _mix(albedo, vein_col, 0.9 * main)

    veins = torch.maximum(main, 0.6 * fine)
    rough = 0.07 + 0.025 * fbm(u, v, rs("polish"), 8, 3, resolution=R) + 0.12 * veins
    height = -0.0003 * veins + 0.00005 * fbm(u, v, rs("bump"), 16, 3, resolution=R)
    return _finish(albedo, rough, torch.full_like(u, 0.045), height, dtype, device)


_METALS = {  # typical Fresnel F0 of metals (linear sRGB)
    "brass": (0.91, 0.78, 0.42),
    "copper": (0.95, 0.64, 0.54),
    "gold": (0.97, 0.78, 0.34),
    "steel": (0.56, 0.57, 0.60),
}


def scratched_metal(resolution: int = 128, seed: int = 0, *, dtype=torch.float32, device=None) -> SVBRDF:
    """Brushed metal (brass, copper, gold or steel, picked by seed) with fine brushing streaks,
    random scratches (rough, recessed) and faint grime patches; very low diffuse, high coloured F0."""
    _check("scratched_metal", resolution, seed)
    R, rs = resolution, _Streams("scratched_metal", seed)
    u, v = texel_grid(R)
    names = list(_METALS)
    f0 = _rgb(_METALS[names[rs.choice("metal", len(names))]], u)

    brushed = fbm(u, v, rs("brush"), (1, 24), 4, resolution=R)  # streaks along u
    K = 140
    centers = rs.uniform("centers", K, 2)
    main_dir = float(rs.uniform("dir", 1, low=-0.4, high=0.4))
    wild = rs.uniform("wild", K) < 0.3  # most scratches follow one direction, some go anywhere
    spread = torch.where(wild, math.pi, 0.35).to(DTYPE)
    angles = main_dir + spread * (rs.uniform("angles", K) * 2 - 1)
    lengths = rs.uniform("lengths", K, low=0.04, high=0.45)
    # widths in sample units, but never below ~half a texel (no aliasing at low resolution)
    widths = rs.uniform("widths", K, low=0.0012, high=0.0035).clamp(min=0.45 / R)
    weights = rs.uniform("weights", K, low=0.25, high=1.0)
    scratch = segment_field(u, v, centers, angles, lengths, widths, weights)

    grime = 0.6 * smoothstep(0.1, 0.45, fbm(u, v, rs("grime"), 3, 5, resolution=R))
    albedo = _rgb((0.03, 0.028, 0.025), u) * (1 + 0.3 * scratch)[None]
    albedo = _mix(albedo, (0.06, 0.05, 0.04), grime)
    spec = f0 * (1 + 0.25 * brushed - 0.2 * grime)[None]

    rough = 0.17 + 0.3 * brushed + 0.45 * scratch + 0.15 * grime
    height = -0.0012 * scratch + 0.00008 * brushed
    return _finish(albedo, rough, spec, height, dtype, device)


_LEATHERS = [
    (0.20, 0.085, 0.035),   # brown
    (0.40, 0.21, 0.09),     # tan
    (0.035, 0.032, 0.030),  # black
    (0.14, 0.025, 0.02),    # oxblood
]


def leather(resolution: int = 128, seed: int = 0, *, dtype=torch.float32, device=None) -> SVBRDF:
    """Pebble-grain leather (brown, tan, black or oxblood by seed): irregular rounded pebbles
    separated by meandering creases, finer secondary creases and pores; medium roughness,
    glossier worn pebble tops."""
    _check("leather", resolution, seed)
    R, rs = resolution, _Streams("leather", seed)
    u, v = texel_grid(R)
    base = _rgb(_LEATHERS[rs.choice("palette", len(_LEATHERS))], u)

    cells = 18
    wu, wv = domain_warp(u, v, rs("warp"), 0.015, period=6, octaves=3, resolution=R)
    big = voronoi(wu, wv, cells, rs("cells"), jitter=0.85)
    su, sv = domain_warp(u, v, rs("warp2"), 0.01, period=12, octaves=2, resolution=R)
    small = voronoi(su, sv, 34, rs("cells2"), jitter=0.9)
    cell_h = rs.uniform("cellh", cells * cells, low=0.7, high=1.0)[big.cell]
    # rounded pebble: flat-ish near the border (edge), domed towards the feature point (f1)
    dome = smoothstep(0.0, 0.5, big.edge) ** 0.6 * (1 - 0.5 * big.f1 ** 2) * cell_h
    crease_w = 0.10 + 0.06 * fbm(u, v, rs("creasew"), 6, 2, resolution=R)
    crease = 1 - smoothstep(0.0, crease_w, big.edge)
    fine_crease = (1 - smoothstep(0.0, 0.1, small.edge)) * smoothstep(0.05, 0.3, big.edge)
    pores = smoothstep(0.3, 0.6, fbm(u, v, rs("pores"), 96, 2, resolution=R))
    mottle = fbm(u, v, rs("mottle"), 4, 4, resolution=R)

    albedo = base * (1 + 0.3 * mottle + 0.3 * (dome - 0.5))[None]
    albedo = albedo * (1 - 0.3 * crease - 0.12 * fine_crease - 0.2 * pores)[None]

    rough = 0.62 - 0.16 * dome + 0.15 * crease + 0.05 * fine_crease + 0.08 * mottle
    height = 0.003 * dome - 0.0004 * fine_crease - 0.00015 * pores
    height = blur(height, 0.003 * R)
    return _finish(albedo, rough, torch.full_like(u, DIELECTRIC_F0), height, dtype, device)


def fabric(resolution: int = 128, seed: int = 0, *, dtype=torch.float32, device=None) -> SVBRDF:
    """Denim: 3/1 twill of indigo warp threads (running down the sample) over paler weft,
    giving diagonal ribs; slubby, unevenly faded yarn and fibre streaks; very rough, ``F0 = 0.04``."""
    _check("fabric", resolution, seed)
    R, rs = resolution, _Streams("fabric", seed)
    u, v = texel_grid(R)
    n = 24  # threads across the sample (a multiple of 4 so the twill tiles)
    x, y = u * n, v * n
    i, j = torch.floor(x).long(), torch.floor(y).long()
    fx, fy = x - i, y - j
    k = torch.remainder(j + i, 4)
    warp_over = k != 3
    t_warp = (k.clamp(max=2) + fy) / 3  # along the warp float (3 cells)
    t_weft = fx  # along the weft float (1 cell)

    def cross(f, w):  # rounded thread cross-section, 0 in the gaps
        return torch.sqrt((1 - ((2 * f - 1) / w) ** 2).clamp(min=0))

    arch_warp = torch.sin(math.pi * t_warp).clamp(min=0) ** 0.6
    arch_weft = torch.sin(math.pi * t_weft).clamp(min=0) ** 0.6
    low = 0.2 * torch.ones_like(fx)
    h_warp = cross(fx, 0.95) * torch.where(warp_over, 0.3 + 0.7 * arch_warp, low)
    h_weft = cross(fy, 0.8) * torch.where(~warp_over, 0.3 + 0.7 * arch_weft, low)
    top_warp = (h_warp >= h_weft).to(u.dtype)
    height_n = torch.maximum(h_warp, h_weft)

    # yarn: twist striations and slubs (thickness/brightness varying along each thread)
    slub_warp = fbm(u, v, rs("slubw"), (n, 4), 3, resolution=R)
    slub_weft = fbm(u, v, rs("slubf"), (4, n), 3, resolution=R)
    twist_w = torch.sin(2 * math.pi * (fx + 2.0 * fy))
    twist_f = torch.sin(2 * math.pi * (fy + 2.0 * fx))
    fibre = fbm(u, v, rs("fibre"), 64, 2, resolution=R)

    indigo = _rgb((0.025, 0.055, 0.16), u) * rs.uniform("indigo", 1, low=0.8, high=1.3)
    fade = fbm(u, v, rs("fade"), 3, 4, resolution=R)
    warp_col = indigo * (1 + 0.6 * slub_warp + 0.1 * twist_w + 0.8 * fade.clamp(min=0))[None]
    weft_col = _rgb((0.26, 0.265, 0.25), u) * (1 + 0.25 * slub_weft + 0.08 * twist_f)[None]
    albedo = _mix(weft_col, warp_col, top_warp) * (1 + 0.2 * fibre)[None]
    albedo = albedo * (0.3 + 0.7 * smoothstep(0.0, 0.8, height_n))[None]  # dark gaps, float ends

    wear = fbm(u, v, rs("wear"), 2, 4, resolution=R)  # rubbed, slightly smoother patches
    rough = 0.84 + 0.06 * fibre + 0.12 * (1 - height_n) + 0.25 * wear
    height = 0.07 / n * (height_n + 0.1 * (top_warp * twist_w + (1 - top_warp) * twist_f))
    height = blur(height, 0.05 * R / n)
    return _finish(albedo, rough, torch.full_like(u, DIELECTRIC_F0), height, dtype, device)


# ----------------------------------------------------------------------------- registry
MATERIALS: dict[str, Callable[..., SVBRDF]] = {
    "wood": wood,
    "tiles": tiles,
    "marble": marble,
    "scratched_metal": scratched_metal,
    "leather": leather,
    "fabric": fabric,
}


def make_material(name: str, resolution: int = 128, seed: int = 0, **kw) -> SVBRDF:
    """The procedural material ``name`` (a key of :data:`MATERIALS`) as an :class:`SVBRDF`.

    Example:
        >>> make_material("marble", 32).normal.shape
        torch.Size([3, 32, 32])
    """
    fn = MATERIALS.get(name)
    if fn is None:
        raise InputError(f"unknown material {name!r}", fix=f"choose one of: {', '.join(MATERIALS)}")
    return fn(resolution, seed, **kw)
