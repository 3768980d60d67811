"""Environment light at the cost of a point light: per-pixel precomputed transfer.

With the geometry, the views and the environment fixed, only the material varies per particle. With
Schlick's Fresnel ``F = ks (1 - w) + w`` (``w`` the Fresnel weight of :func:`~bayes_brdf.render.brdf.fresnel_weight`)
the radiance a pixel sends to its camera under an environment ``L`` with visibility ``V`` is exactly

``R = kd (1 - kf ks) / pi * E  +  ks a(r)  +  b(r)``, with

* ``E    = int L V (n.l) dl``                         (irradiance; RGB),
* ``a(r) = int L V S_r (1 - w) (n.l) dl``,  ``b(r) = int L V S_r w (n.l) dl``   (RGB functions of roughness),

``S_r = D G / (4 (n.l)(n.v))`` the specular lobe of :mod:`.brdf` (the same terms, the same clamped cosines).
``E``, and ``a``, ``b`` at :data:`NODES` roughness nodes, are computed here once per pixel; shading reads them
with a cubic (Catmull-Rom) interpolation in ``t = log(r)`` (:func:`interpolate`), which is smooth in ``r``
and has an exact derivative. Per particle that is one table look-up per pixel: about the cost of one light.

The integrals are estimated with a fixed set of directions per pixel, shared by every roughness node (so
the tables are smooth in ``r``), drawn from a mixture -- the environment's own importance sampling
(luminance x sin theta), a cosine lobe, and GGX lobes at :data:`LOBES` -- and weighted by the balance
heuristic of multiple importance sampling, ``1 / sum_c K_c q_c(l)``. Visibility is one Mitsuba shadow ray
per direction (``surface.occluded_directions``; a plane occludes nothing). A fixed set of samples makes the
Monte Carlo error a fixed, small bias per pixel, the same for every particle (no spurious spread between
particles). Roughness outside ``[ROUGH_MIN, 1]`` reads the end values (zero derivative there).

Normals: the transfer is computed for the surface's own shading normals with the material's normal map
held fixed (a flat map, or a fixed one). Normals inferred per particle cannot be precomputed; such a model
is refused under an environment light (see :func:`check_normals`).
"""
from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import torch
from torch import Tensor

from ..broadcast import broadcast_shapes
from ..errors import InputError
from .brdf import fresnel_weight
from .environment import LUMINANCE as LUMA

#: roughness range of the tables; below ``ROUGH_MIN`` the end value is read
ROUGH_MIN, ROUGH_MAX = 0.02, 1.0
#: roughness nodes of the tables (uniform in log r)
NODES = 16
#: channels of a view's environment terms: E (3), then NODES + 2 slots (a ghost at each end) of a (3), b (3)
CHANNELS = 3 + 6 * (NODES + 2)
#: roughness of the GGX lobes the directions are drawn from


T0 = math.log(ROUGH_MIN)
DT = (math.log(ROUGH_MAX) - T0) / (NODES - 1)


def node_roughness(dtype=torch.float64) -> Tensor:
    """The ``NODES`` roughness values of the tables."""
    return torch.exp(T0 + DT * torch.arange(NODES, dtype=dtype))


@dataclass(frozen=True)
class TransferSamples:
    """Directions per pixel: ``cosine`` for the irradiance, ``lobe`` for each roughness node; ``bias`` shifts the
    filtering level (in octaves of the footprint's side)."""

    cosine: int = 256
    lobe: int = 64
    bias: float = 0.5

    @property
    def total(self) -> int:
        return self.cosine + self.lobe * NODES


def _frame(n: Tensor):
    a = torch.where((n[..., 0].abs() < 0.9)[..., None], torch.tensor([1.0, 0, 0], dtype=n.dtype),
                    torch.tensor([0, 1.0, 0], dtype=n.dtype))
    t = torch.linalg.cross(a, n)
    t = t / t.norm(dim=-1, keepdim=True)
    return t, torch.linalg.cross(n, t)


def lattice(m: int) -> Tensor:
    """``m`` points ``[m, 2]`` of the Fibonacci lattice in the unit square (a rank-1 lattice: well stratified)."""
    i = torch.arange(m, dtype=torch.float64)
    return torch.stack([(i + 0.5) / m, (i * (math.sqrt(5) - 1) / 2) % 1.0], -1)


def _spec(nl, nv, nh, r) -> Tensor:
    """``S = D G / (4 nl nv)`` for clamped cosines and roughness ``r`` (broadcast)."""
    a = r * r
    a2 = a * a
    den = nh * nh * (a2 - 1) + 1
    k = 0.5 * a
    gl = nl * (1 - k) + k
    gv = nv * (1 - k) + k
    return a2 * (0.25 / math.pi) / (den * den * gl * gv)


def _local(u_lat: Tensor, t, b, n, cos_theta: Tensor):
    """World directions ``[P, M, 3]`` at polar cosines ``cos_theta [M]`` (or ``[P, M]``) and azimuths of the lattice."""
    ct = cos_theta
    st = (1 - ct * ct).clamp_min(0).sqrt()
    phi = 2 * math.pi * u_lat[:, 1]
    x, y = st * phi.cos(), st * phi.sin()
    return x[..., None] * t[:, None] + y[..., None] * b[:, None] + ct[..., None] * n[:, None]


def _filtered(light, pyramid, l: Tensor, footprint: Tensor, bias: float) -> Tensor:
    """Radiance ``[..., 3]`` from directions ``l`` averaged over a solid angle ``footprint`` (trilinear in the
    pyramid; the exact look-up where the footprint is below a texel): level ``lev`` (0: the map itself, ``k``:
    ``pyramid[k - 1]``) mixes its two neighbouring levels, ``floor(lev)`` with weight ``1 - frac`` and the next
    with ``frac``, each direction's two levels read in one gather from the packed pyramid."""
    uv = light.to_uv(l)
    h, w, _ = light.radiance.shape
    texel = (2 * math.pi / w) * (math.pi / (h - 1)) * (uv[..., 1] * math.pi).sin().clamp_min(1e-6)
    n = len(pyramid)
    lev = (0.5 * torch.log2(footprint.clamp_min(1e-30) / texel) + bias).clamp(0, n)
    lo = lev.floor().clamp(max=n - 1)
    f = (lev - lo)[..., None]
    k = lo.long()
    packed = _packed(light, pyramid)
    upper, lower = _pyramid_lookup(packed, uv, torch.stack([k + 1, k.clamp_min(1)])) * light.scale
    base = k == 0
    if bool(base.any()):
        lower = torch.where(base[..., None], light.eval_uv(uv), lower)
    return lower * (1 - f) + upper * f


def _pyramid_lookup(packed, uv: Tensor, level: Tensor) -> Tensor:
    """Cell-centred bilinear look-up (periodic in u, clamped in v) of pyramid level ``level [...]`` (1 .. its
    length: each point its own) at ``uv [..., 2]``, from the :func:`_packed` pyramid."""
    flat, off, hs, ws = packed
    lv = level.reshape(-1)
    hk, wk, ok = (t.index_select(0, lv).reshape(level.shape) for t in (hs, ws, off))
    x = uv[..., 0] * wk - 0.5
    y = (uv[..., 1] * hk - 0.5).clamp_min(0).minimum(hk - 1)
    x0 = torch.floor(x)
    fx = (x - x0)[..., None]
    y0 = torch.floor(y).minimum(hk - 2)
    fy = (y - y0)[..., None]
    wi = wk.long()
    x0 = x0.long() % wi
    x1 = (x0 + 1) % wi
    r0 = ok + y0.long() * wi
    r1 = r0 + wi
    # the four corners in one gather (index_select: about 3x torch's advanced indexing here)
    c = flat.index_select(0, torch.stack([r0 + x0, r0 + x1, r1 + x0, r1 + x1]).reshape(-1))
    c = c.reshape(4, *level.shape, flat.shape[-1])
    return c[0] * (1 - fx) * (1 - fy) + c[1] * fx * (1 - fy) + c[2] * (1 - fx) * fy + c[3] * fx * fy


def _packed(light, pyramid):
    """The pyramid's levels as one ``[texels, 3]`` table, with each level's offset, height and width (index
    ``k`` for level ``k``; index 0 unused). Kept on the light, like the pyramid."""
    memo = light.__dict__.setdefault("_pyramid_packed", {})
    if len(pyramid) not in memo:
        sizes = [(img.shape[0], img.shape[1]) for img in pyramid]
        off = torch.tensor([0, 0] + list(itertools.accumulate(hh * ww for hh, ww in sizes))[:-1])
        hs = torch.tensor([2.0] + [float(hh) for hh, _ in sizes], dtype=torch.float64)
        ws = torch.tensor([1.0] + [float(ww) for _, ww in sizes], dtype=torch.float64)
        memo[len(pyramid)] = (torch.cat([img.reshape(-1, 3) for img in pyramid]), off, hs, ws)
    return memo[len(pyramid)]


def pyramid(light, levels: int = 8) -> list[Tensor]:
    """Coarser copies of the map (levels 1, 2, ...: halved each time, solid-angle-weighted means, cell-centred)."""
    memo = light.__dict__.setdefault("_pyramid", {})
    if levels not in memo:
        img = light.radiance64
        h = img.shape[0]
        wt = (torch.arange(h, dtype=torch.float64) / (h - 1) * math.pi).sin().clamp_min(1e-3)[:, None, None]
        out = []
        for _ in range(levels):
            if img.shape[0] < 4 or img.shape[1] < 4:
                break
            hh, ww = img.shape[0] // 2, img.shape[1] // 2
            num = (img * wt)[:2 * hh, :2 * ww].reshape(hh, 2, ww, 2, 3).sum((1, 3))
            den = wt[:2 * hh].reshape(hh, 2, 1, 1).sum(1) * 2
            img, wt = num / den, den[:, None] / 2
            wt = wt.reshape(hh, 1, 1)
            out.append(img)
        memo[levels] = out
    return memo[levels]


def irradiance_map(light, resolution: int = 64, cells: int = 64) -> Tensor:
    """Unoccluded irradiance ``E(n) = int L max(n.l, 0) dl`` ``[resolution, 2 resolution, 3]`` on a lat-long grid
    of normals in the map's own frame (rows at corners in v, columns at centres in u, like the map). Quadrature
    over ``cells x 2 cells`` groups of the map's texels, each group acting from the luminance-weighted mean of
    its texels' directions (exact to first order inside a group, so a bright lamp is not moved to the group's
    centre). Kept on the light."""
    memo = light.__dict__.setdefault("_irradiance", {})
    if resolution not in memo:
        img = light.radiance64
        h, w, _ = img.shape
        u = (torch.arange(w, dtype=torch.float64) + 0.5) / w
        v = torch.arange(h, dtype=torch.float64) / (h - 1)
        th = v * math.pi
        lo = ((v - 0.5 / (h - 1)).clamp(0, 1) * math.pi)
        hi = ((v + 0.5 / (h - 1)).clamp(0, 1) * math.pi)
        omega = (2 * math.pi / w) * (lo.cos() - hi.cos())                                # [h] exact bands
        ph = 2 * math.pi * u
        d = torch.stack([ph.sin()[None] * th.sin()[:, None], th.cos()[:, None].expand(h, w),
                         -ph.cos()[None] * th.sin()[:, None]], -1)                         # [h, w, 3]
        rad = img * omega[:, None, None] * light.scale                                     # [h, w, 3]
        lum = (rad * torch.tensor(LUMA, dtype=torch.float64)).sum(-1, keepdim=True) + 1e-30 * omega[:, None, None]
        rows = (torch.arange(h) * cells // h)
        cols = (torch.arange(w) * 2 * cells // w)
        key = (rows[:, None] * 2 * cells + cols[None]).reshape(-1)
        nc = cells * 2 * cells
        R = torch.zeros(nc, 3, dtype=torch.float64).index_add_(0, key, rad.reshape(-1, 3))
        C = torch.zeros(nc, 3, dtype=torch.float64).index_add_(0, key, (lum * d).reshape(-1, 3))
        C = C / C.norm(dim=-1, keepdim=True).clamp_min(1e-300)
        nu = (torch.arange(2 * resolution, dtype=torch.float64) + 0.5) / (2 * resolution)
        nvv = torch.arange(resolution, dtype=torch.float64) / (resolution - 1)
        nth, nph = nvv * math.pi, 2 * math.pi * nu
        nrm = torch.stack([nph.sin()[None] * nth.sin()[:, None], nth.cos()[:, None].expand(resolution, 2 * resolution),
                           -nph.cos()[None] * nth.sin()[:, None]], -1).reshape(-1, 3)
        E = (nrm @ C.T).clamp_min(0) @ R
        memo[resolution] = E.reshape(resolution, 2 * resolution, 3)
    return memo[resolution]


def irradiance(light, n: Tensor) -> Tensor:
    """Unoccluded irradiance ``[..., 3]`` at world normals ``n [..., 3]`` (bilinear in :func:`irradiance_map`)."""
    emap = irradiance_map(light)
    h, w, _ = emap.shape
    uv = light.to_uv(n)
    x = uv[..., 0] * w - 0.5
    y = uv[..., 1] * (h - 1)
    x0 = torch.floor(x)
    fx = (x - x0)[..., None]
    y0 = torch.floor(y).clamp(max=h - 2)
    fy = (y - y0)[..., None]
    x0 = x0.long() % w
    x1 = (x0 + 1) % w
    y0 = y0.long()
    return (emap[y0, x0] * (1 - fx) * (1 - fy) + emap[y0, x1] * fx * (1 - fy) + emap[y0 + 1, x0] * (1 - fx) * fy
            + emap[y0 + 1, x1] * fx * fy)


def transfer(light, position: Tensor, normal: Tensor, geometric_normal: Tensor, view_dir: Tensor, mask: Tensor,
             occluder, *, samples: TransferSamples = TransferSamples(), eps: float = 1e-8,
             chunk: int = 128) -> Tensor:
    """The environment terms ``[CHANNELS, H, W]`` (float64) of one view: ``E``, then per roughness slot ``a``, ``b``.

    ``position, normal, geometric_normal, view_dir`` ``[3, H, W]`` (world, unit normals and view directions),
    ``mask [H, W]``; ``occluder`` has ``occluded_directions(points, normals, directions)`` (bool ``[N]`` or
    ``None``: nothing occludes). Zero off the mask. ``chunk`` pixels are done at a time (each pixel on its own:
    the result does not depend on it; 128 measured 16 % faster than 64 on the bunny, and 512 twice as slow).

    Example:
        >>> from bayes_brdf.render.environment import EnvironmentLight
        >>> from bayes_brdf.render.surface import PlanarSample
        >>> env = EnvironmentLight(torch.ones(8, 16, 3))          # white: E = pi on an unoccluded plane
        >>> one = lambda *x: torch.tensor(x, dtype=torch.float64)[:, None, None]
        >>> e = transfer(env, one(0, 0, 0), one(0, 0, 1), one(0, 0, 1), one(0, 0, 1), torch.ones(1, 1, dtype=torch.bool),
        ...              PlanarSample())
        >>> abs(float(e[0, 0, 0]) / math.pi - 1) < 5e-3
        True
    """
    h, w = mask.shape
    out = torch.zeros(CHANNELS, h * w, dtype=torch.float64)
    idx = mask.reshape(-1).nonzero()[:, 0]
    if idx.numel() == 0:
        return out.reshape(CHANNELS, h, w)
    flat = lambda x: x.reshape(3, -1)[:, idx].T.to(torch.float64)  # noqa: E731
    P_all, N_all, NG_all, V_all = flat(position), flat(normal), flat(geometric_normal), flat(view_dir)
    pyr = pyramid(light)
    rn = node_roughness()
    uc, ul = lattice(samples.cosine), lattice(samples.lobe)
    a2n = (rn * rn) ** 2                                              # alpha^2 of each node's lobe

    def blocked(p, ng, l, ok):
        """Where directions ``l`` with ``ok`` are occluded (``None``: nothing occludes)."""
        occ = occluder.occluded_directions(p[:, None].expand_as(l)[ok], ng[:, None].expand_as(l)[ok], l[ok])
        if occ is None:
            return None
        out = torch.zeros_like(ok)
        out[ok] = occ
        return out

    for s in range(0, idx.numel(), chunk):
        p, n, ng, v = (x[s:s + chunk] for x in (P_all, N_all, NG_all, V_all))
        P = n.shape[0]
        t, b = _frame(n)
        E = irradiance(light, n)                             # unoccluded, then the occluded part taken away
        mc, m = samples.cosine, samples.lobe
        # one set of directions: a cosine lattice and, per roughness node, a GGX-distributed lattice of half vectors
        lc = _local(uc, t, b, n, (1 - uc[:, 0]).sqrt())
        ct = (1 / (1 + a2n[:, None] * ul[None, :, 0] / (1 - ul[None, :, 0]))).sqrt()    # [J, m]
        hv = _local(ul.repeat(NODES, 1), t, b, n, ct.reshape(-1))                      # [P, J m, 3]
        vh = (v[:, None] * hv).sum(-1)
        l = torch.cat([lc, 2 * vh[..., None] * hv - v[:, None]], 1)                   # [P, K, 3]
        drop = torch.cat([torch.zeros(P, mc, dtype=torch.bool), vh <= 0], 1)
        nl = (n[:, None] * l).sum(-1)
        hp = v[:, None] + l
        hp = hp / hp.norm(dim=-1, keepdim=True).clamp_min(1e-30)
        nh = (n[:, None] * hp).sum(-1)
        vhp = (v[:, None] * hp).sum(-1)
        den = nh[..., None] ** 2 * (a2n - 1) + 1                                        # [P, K, J]
        q = (a2n / (math.pi * den * den)).sum(-1) * m * nh.clamp_min(0) / (4 * vhp.clamp_min(1e-30)) \
            + mc * nl.clamp_min(0) / math.pi                                              # balance heuristic
        ok = (~drop) & (nl > 0) & (nh > 0) & (vhp > 0) & (q > 0)
        occ = blocked(p, ng, l, ok)
        Lf = _filtered(light, pyr, l, 1 / q.clamp_min(1e-30), samples.bias)
        if occ is not None:
            if bool(occ[:, :mc].any()):                      # irradiance lost to occluders (cosine lattice)
                Lc = _filtered(light, pyr, lc, math.pi / (mc * nl[:, :mc].clamp_min(1e-6)), samples.bias)
                E = E - (Lc * occ[:, :mc, None]).sum(1) * (math.pi / mc)
            ok = ok & ~occ
        L = Lf * (ok / q.clamp_min(1e-30))[..., None]
        nv = (n * v).sum(-1).clamp_min(eps)[:, None, None]
        nlc = nl.clamp_min(eps)[..., None]
        S = _spec(nlc, nv, nh.clamp_min(eps)[..., None], rn) * nlc                       # [P, K, J]
        fw = fresnel_weight(vhp.clamp_min(eps))[..., None]
        a = torch.einsum("pkj,pkc->pjc", S * (1 - fw), L)
        bb = torch.einsum("pkj,pkc->pjc", S * fw, L)
        ab = torch.cat([a, bb], -1)                                                        # [P, J, 6]
        ab = torch.cat([2 * ab[:, :1] - ab[:, 1:2], ab, 2 * ab[:, -1:] - ab[:, -2:-1]], 1)   # ghost slots
        out[:, idx[s:s + chunk]] = torch.cat([E, ab.reshape(P, -1)], 1).T
    return out.reshape(CHANNELS, h, w)


def catmull_rom(x: Tensor):
    """The four Catmull-Rom weights at ``x`` in ``[0, 1]`` (taps ``i - 1 .. i + 2``)."""
    x2, x3 = x * x, x * x * x
    return (0.5 * (-x + 2 * x2 - x3), 0.5 * (2 - 5 * x2 + 3 * x3), 0.5 * (x + 4 * x2 - 3 * x3), 0.5 * (x3 - x2))


def interpolate(env: Tensor, r: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """``(E, a(r), b(r))`` from environment terms ``env [..., CHANNELS, H, W]`` at roughness ``r [..., 1, H, W]``
    (broadcast), each ``[..., 3, H, W]``; differentiable in ``r`` (plain torch: the reference)."""
    s = ((torch.log(r.clamp_min(1e-30)) - T0) / DT).clamp(0, NODES - 1)
    i = torch.floor(s).clamp(max=NODES - 2)
    x = s - i
    tab = env[..., 3:, :, :]
    shape = broadcast_shapes(tab.shape[:-3], r.shape[:-3])
    tab = tab.expand(*shape, *tab.shape[-3:]).unflatten(-3, (NODES + 2, 6))        # [..., slots, 6, H, W]
    hw = broadcast_shapes(tab.shape[-2:], r.shape[-2:])
    tab = tab.expand(*tab.shape[:-2], *hw)
    ii = i.long().expand(*shape, 1, *hw)
    acc = 0.0
    for k, wk in enumerate(catmull_rom(x.expand(*shape, 1, *hw))):
        idx = (ii + k)[..., None, :, :].expand(*shape, 1, 6, *hw)
        acc = acc + wk * torch.gather(tab, -4, idx)[..., 0, :, :, :]
    E = env[..., 0:3, :, :]
    return E, acc[..., 0:3, :, :], acc[..., 3:6, :, :]


def check_normals(normal: Tensor) -> None:
    """Refuse normals that vary per particle or are inferred (their transfer cannot be precomputed)."""
    if normal.requires_grad or normal.dim() > 3:
        raise InputError("normals inferred per particle cannot be shaded under an environment light (its transfer "
                         "is precomputed for fixed normals)", fix="use normals='flat' or a fixed normal map with an "
                         "environment light, or point lights only")
