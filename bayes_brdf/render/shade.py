"""Batched deferred shading: SVBRDF maps (per particle) x views -> linear radiance.

One call shades ``n`` particles' maps under ``V`` views and returns
``[n, V, H, W, 3]``. Geometry comes from a :class:`GBuffer` computed once per
view; the per-pixel work is a fused BRDF evaluation (:mod:`.fused`) that
broadcasts over particles, views and lights, with memory bounded by chunking
over views. The device and dtype follow the maps.

Example:
    >>> import torch
    >>> from bayes_brdf.render import SVBRDF, PlanarSample, collocated_views
    >>> views = collocated_views(3, radius=3.0, resolution=16)
    >>> maps = SVBRDF.constant(albedo=0.5, roughness=0.3).to(torch.float32)
    >>> render(maps, views, PlanarSample(2.0)).shape     # no particle dim -> n = 1
    torch.Size([1, 3, 16, 16, 3])
"""
from __future__ import annotations

import numbers
from dataclasses import replace

import torch
import torch.nn.functional as F
from torch import Tensor

from ..errors import InputError
from . import fused, native, texels
from .gbuffer import GBUFFERS, GBuffer
from .maps import SVBRDF, unit_vectors
from .surface import PlanarSample
from .tensor_memo import TensorMemo

#: default cap on the elements of one chunk's output (particles x views x pixels x 3)
CHUNK_ELEMENTS = 64 * 2**20


def lookup(tex: Tensor, g: GBuffer) -> Tensor:
    """Bilinear texture lookup of ``tex`` ``[n, C, Ht, Wt]`` (or ``[C, Ht, Wt]``) for every pixel of ``g``.

    Returns ``[n, V', C, H', W']`` where ``V' = 1`` and ``(H', W')`` is the map's
    own size when no lookup is needed (a ``1 x 1`` constant, or a rectified view
    whose pixels are the texels), and ``[n, V, C, H, W]`` otherwise.
    """
    t = tex[None] if tex.dim() == 3 else tex
    n, c, ht, wt = t.shape
    if (ht, wt) == (1, 1) or (g.aligned and (ht, wt) == g.resolution):
        return t[:, None]
    if g.texel is not None and (ht, wt) == tuple(g.texel_grid):       # gathered pixels of aligned views
        V, (h, w) = g.num_views, g.resolution
        idx = g.texel.reshape(-1).to(t.device).expand(n, c, -1)      # gather: 1.5-2.5x index_select on the last dim
        return torch.gather(t.flatten(-2), -1, idx).reshape(n, c, V, h, w).transpose(1, 2)
    if g.gathered:                        # gathered pixels (a mesh's valid pixels): bilinear taps, sparse product
        tp = taps_of(g, (ht, wt), t.dtype, t.device)
        return texels.gather(t, tp.S, tp.St).reshape(n, c, *g.resolution)[:, None]
    V, (h, w) = g.num_views, g.resolution
    grid = g.uv.to(t.dtype).reshape(1, V * h, w, 2).expand(n, -1, -1, -1)
    s = F.grid_sample(t, grid, mode="bilinear", padding_mode="border", align_corners=g.align_corners)
    return s.reshape(n, c, V, h, w).transpose(1, 2)


def taps_of(g: GBuffer, grid, dtype, device) -> "texels.Taps":
    """The bilinear taps of the pixels of a gathered G-buffer in an ``(Ht, Wt)`` map, built once and kept on ``g``."""
    memo = g.__dict__.setdefault("_taps", {})
    key = (tuple(grid), dtype, str(device))
    if key not in memo:
        memo[key] = texels.taps(g.uv.reshape(-1, 2), tuple(grid), g.align_corners, dtype=dtype, device=device)
    return memo[key]


def _texel_grid(maps: SVBRDF, g: GBuffer):
    """The one ``(Ht, Wt)`` of the material maps that the fused kernel can read through taps (pixels of a
    gathered G-buffer that are not texels), or ``None``."""
    if not g.gathered or g.texel is not None:
        return None
    sizes = {tuple(t.shape[-2:]) for t in (maps.albedo, maps.roughness, maps.specular)} - {(1, 1)}
    return sizes.pop() if len(sizes) == 1 else None


def _normalize(x: Tensor, dim: int) -> Tensor:
    return unit_vectors(x, dim, floor=1e-15)


def geometry_terms(normal: Tensor, g: GBuffer, eps: float = 1e-8):
    """Clamped cosines for every (particle, view, light, pixel).

    ``normal`` is a looked-up tangent-space normal map ``[P, V', 3, H', W']``
    (``P = 1`` when the normals are shared by all particles: then these terms
    are computed once, not per particle). Returns ``n.l, n.v, n.h, v.h`` with
    shapes ``[P, V, L, 1, H, W]`` (``n.v``: ``L = 1``), each clamped to
    ``>= eps``.
    """
    nt = normal.unsqueeze(2)  # [P, V', 1, 3, H', W']
    frame = [x[None, :, None] for x in (g.tangent, g.bitangent, g.normal)]  # [1, V, 1, 3, H, W]
    nw = _normalize(frame[0] * nt[:, :, :, 0:1] + frame[1] * nt[:, :, :, 1:2] + frame[2] * nt[:, :, :, 2:3], 3)
    v = g.view_dir[None, :, None]  # [1, V, 1, 3, H, W]
    l = g.light_dir[None]  # [1, V, L, 3, H, W]
    hv = _normalize(l + v, 3)
    dot = lambda a, b: (a * b).sum(3, keepdim=True).clamp_min(eps)  # noqa: E731
    return dot(nw, l), dot(nw, v), dot(nw, hv), dot(v, hv)


def _chunks(maps: SVBRDF, g: GBuffer, eps: float, chunk_views: int | None, texel_space: bool = False):
    """Shared set-up of :func:`shade` and :func:`shade_loss`.

    Returns ``(n, g, iterator)``; the iterator yields, per chunk of views
    ``start:stop``, the kernel inputs ``(kd, r, ks, n.l, n.v, n.h, v.h, scale)`` and the taps: ``None``, or
    with ``texel_space`` on a gathered G-buffer, the :class:`~bayes_brdf.render.texels.Taps` through which the
    kernel reads the maps, which are then passed as texel maps (not looked up here).
    With normals held fixed (no particle dimension, no gradient) the cosines
    are computed once and kept on the G-buffer until the normal map changes.
    """
    n = maps.num_particles or 1
    dev, dt = maps.albedo.device, maps.albedo.dtype
    if g.position.device != dev or g.position.dtype != dt:
        g = g.to(dtype=dt, device=dev)
    V, (h, w) = g.num_views, g.resolution
    if chunk_views is None:
        chunk_views = max(1, CHUNK_ELEMENTS // max(1, n * h * w * 3 * g.light_dir.shape[1]))
    if chunk_views < 1:
        raise InputError(f"chunk_views must be >= 1, got {chunk_views}")

    nrm = maps.normal
    fixed_normals = nrm.dim() == 3 and not nrm.requires_grad
    memo = g.__dict__.setdefault("_cosines", {})  # {(start, stop, eps): (normal map, its version, cosines)}
    if g.env is not None:
        _check_env_normals(nrm, memo)

    def cosines(s, e, gc):
        if not fixed_normals:  # per-particle or differentiated normals: recomputed every call
            return geometry_terms(lookup(nrm, gc), gc, eps)
        hit = memo.get((s, e, eps))
        if hit is None or hit[0] is not nrm or hit[1] != nrm._version:
            hit = memo[(s, e, eps)] = (nrm, nrm._version, geometry_terms(lookup(nrm, gc), gc, eps))
        return hit[2]

    grid = _texel_grid(maps, g) if texel_space else None
    tp = taps_of(g, grid, dt, dev) if grid is not None else None

    def it():
        for s in range(0, V, chunk_views):
            e = min(V, s + chunk_views)
            gc = g.views_slice(s, e) if V > chunk_views else g
            if tp is not None:
                kd, rough, ks = (native.texel_maps(t) for t in (maps.albedo, maps.roughness, maps.specular))
            else:
                kd, rough, ks = (lookup(t, gc) for t in (maps.albedo, maps.roughness, maps.specular))
            sc = memo.get((s, e, "scale"))
            if sc is None or sc[0] is not g.light_scale:    # one view object, so the native geometry cache hits
                sc = memo[(s, e, "scale")] = (g.light_scale, gc.light_scale[None])
            env = None
            if g.env is not None:                           # one tensor object: the kernel's layout copy is kept
                ev = memo.get((s, e, "env"))
                if ev is None or ev[0] is not g.env:
                    ev = memo[(s, e, "env")] = (g.env, gc.env[None])
                env = ev[1]
            yield s, e, (kd, rough, ks, *cosines(s, e, gc), sc[1]), tp, env

    return n, g, it()


def _check_env_normals(nrm: Tensor, memo: dict) -> None:
    """An environment's transfer is precomputed for the surface's own normals: the normal map must be flat."""
    hit = memo.get("env_normals")
    if hit is not None and hit[0] is nrm and hit[1] == nrm._version:
        return
    flat = torch.tensor([0.0, 0.0, 1.0], dtype=nrm.dtype, device=nrm.device)
    ok = not nrm.requires_grad and nrm.dim() == 3 and bool(
        ((nrm - flat[:, None, None]).abs() <= 1e-6).all())
    if not ok:
        raise InputError("under an environment light the normal map must be flat (the light's transfer is "
                         "precomputed for the surface's own normals)",
                         fix="use normals='flat' with an environment light, or point lights only")
    memo["env_normals"] = (nrm, nrm._version)


def shade(maps: SVBRDF, g: GBuffer, *, ks_factor: bool = True, eps: float = 1e-8,
          chunk_views: int | None = None, backend: str = "auto", channels_last: bool = True) -> Tensor:
    """Radiance ``[n, V, H, W, 3]`` of ``maps`` under the views of ``g`` (channel-first ``[n, V, 3, H, W]`` with ``channels_last=False``).

    ``ks_factor`` keeps the ``(1 - ks)`` factor on the diffuse term (the
    MaterialGAN convention); ``eps`` is the clamp on every cosine; ``backend``
    picks the per-pixel kernel: ``"eager"`` (plain torch, the reference),
    ``"compiled"`` (fused with analytic gradients, via ``torch.compile``) or
    ``"auto"`` (compiled when ``torch.compile`` works and the call has at least
    ``fused.AUTO_COMPILE_MIN_WORK`` pixel evaluations, else eager). Pixels outside the
    sample are 0.
    """
    parts = [img for _, _, img in shade_chunks(maps, g, ks_factor=ks_factor, eps=eps, chunk_views=chunk_views,
                                                backend=backend)]
    img = parts[0] if len(parts) == 1 else torch.cat(parts, dim=1)
    return img.permute(0, 1, 3, 4, 2) if channels_last else img


def shade_chunks(maps: SVBRDF, g: GBuffer, *, ks_factor: bool = True, eps: float = 1e-8,
                 chunk_views: int | None = None, backend: str = "auto"):
    """Yield ``(start, stop, radiance [n, stop - start, 3, H, W])`` over chunks of the views of ``g``.

    For consumers that reduce each chunk (image-space std, view scoring) so the full
    ``[n, V, ...]`` stack never exists; the geometry cached on ``g`` is reused across calls.
    """
    if _sparse_images(maps, g, backend):
        yield from _compact_chunks(maps, g, ks_factor, eps, chunk_views, backend)
        return
    n, g, chunks = _chunks(maps, g, eps, chunk_views, texel_space=backend != "eager")
    V, (h, w) = g.num_views, g.resolution
    kernel = fused.get_kernel(backend, n * V * h * w)
    for s, e, args, tp, env in chunks:
        extra = {} if env is None else {"env": env}
        out = kernel(*args, ks_factor, **extra) if tp is None else kernel(*args, ks_factor, taps=tp, **extra)
        yield s, e, out.expand(n, e - s, 3, h, w)


def _sparse_images(maps: SVBRDF, g: GBuffer, backend: str) -> bool:
    """Whether images of ``g`` are shaded on its valid pixels only (compacted, through the native texel gather):
    views whose pixels are not texels (a mesh, perspective views of the plane), on the CPU kernel's terms."""
    if backend == "eager" or g.aligned or g.gathered or g.light_dir.shape[1] > native.MAX_LIGHTS:
        return False
    nrm = maps.normal
    return nrm.dim() == 3 and not nrm.requires_grad and native.available(maps.albedo, texels=True) and \
        _texel_grid(maps, compacted(g)[0]) is not None


def _compact_chunks(maps: SVBRDF, g: GBuffer, ks_factor: bool, eps: float, chunk_views: int | None, backend: str):
    """:func:`shade_chunks` on the valid pixels of ``g`` (compacted), put back into images (0 off the surface)."""
    n = maps.num_particles or 1
    c, index = compacted(g)
    V, (h, w) = g.num_views, g.resolution
    if chunk_views is None:
        chunk_views = max(1, CHUNK_ELEMENTS // max(1, n * h * w * 3 * g.light_dir.shape[1]))
    memo = c.__dict__.setdefault("_views", {})
    for s in range(0, V, chunk_views):
        e = min(V, s + chunk_views)
        hit = memo.get((s, e))
        if hit is None:                        # the chunk's pixels, in texture order, and where they go
            if (s, e) == (0, V):
                hit = (c, index)
            else:
                pick = ((index >= s * h * w) & (index < e * h * w)).nonzero()[:, 0]
                hit = (c.pixels(pick), index[pick] - s * h * w)
            memo[(s, e)] = hit
        cc, where = hit
        img = torch.zeros(n, (e - s) * h * w, 3, dtype=maps.albedo.dtype, device=maps.albedo.device)
        if where.numel():
            (_, _, out), = shade_chunks(maps, cc, ks_factor=ks_factor, eps=eps, backend=backend)
            img[:, where] = out[:, 0, :, 0, :].transpose(1, 2)
        yield s, e, img.reshape(n, e - s, h, w, 3).permute(0, 1, 4, 2, 3)


class Renderer:
    """The forward model ``R(x; theta)`` for fixed views: G-buffers built once, then ``renderer(maps)``.

    Example:
        >>> import torch
        >>> from bayes_brdf.render import SVBRDF, PlanarSample, collocated_views
        >>> r = Renderer(collocated_views(4, 3.0, resolution=8), PlanarSample(2.0))
        >>> maps = SVBRDF.constant(roughness=0.4)
        >>> r(maps).shape
        torch.Size([1, 4, 8, 8, 3])
    """

    def __init__(self, views, surface: PlanarSample | None = None, *, ks_factor: bool = True, eps: float = 1e-8,
                 dtype=torch.float32, device=None, chunk_views: int | None = None, backend: str = "auto"):
        self.views = list(views)
        self.surface = surface or PlanarSample()
        self.gbuffer = GBuffer.build(self.views, self.surface, dtype=dtype, device=device)
        self.kw = dict(ks_factor=ks_factor, eps=eps, chunk_views=chunk_views, backend=backend)

    def __call__(self, maps: SVBRDF, channels_last: bool = True) -> Tensor:
        return shade(maps, self.gbuffer, channels_last=channels_last, **self.kw)


def render(maps: SVBRDF, views, surface: PlanarSample | None = None, **kw) -> Tensor:
    """Shade ``maps`` under ``views`` (G-buffers cached across calls); see :func:`shade` for options."""
    dev, dt = maps.albedo.device, maps.albedo.dtype
    g = GBUFFERS.get(tuple(views), surface or PlanarSample(), dtype=dt, device=dev)
    return shade(maps, g, **kw)


def compacted(g: GBuffer) -> tuple[GBuffer, Tensor]:
    """``(G-buffer of the valid pixels of g as one 1 x K view, their flat indices into [V * H * W])``, kept on ``g``.

    The pixels are in texture order (:func:`~bayes_brdf.render.texels.texture_order`): consecutive pixels read
    nearby texels, which keeps the native texel kernel's reads and gradient rows in cache (on the bunny, 20
    views of 128^2, its loss and gradient took 1.2-1.4x as long in raster order with 20 particles, 1.5-1.7x
    with 64).

    Example:
        >>> from bayes_brdf.render import collocated_views
        >>> g = GBuffer.build(collocated_views(2, 3.0, resolution=8), PlanarSample(2.0))
        >>> c, index = compacted(g)
        >>> c.resolution == (1, int(g.mask.sum())) and bool(g.mask.reshape(-1)[index].all())
        True
    """
    hit = g.__dict__.get("_compacted")
    if hit is None:
        v, r, col = g.mask.nonzero(as_tuple=True)
        order = texels.texture_order(g.uv[v, r, col])
        h, w = g.resolution
        hit = g.__dict__["_compacted"] = (g.gather(g.mask, order), ((v * h + r) * w + col)[order])
    return hit


def compacted_taps(g: GBuffer) -> tuple[GBuffer, Tensor]:
    """:func:`compacted` of rectified (``aligned``) views with each pixel read through bilinear taps at its ``uv``
    (at a texel's centre when the map has the views' resolution: one tap of weight 1) rather than by texel index,
    so that the native texel kernel applies; kept on ``g``.

    Example:
        >>> from bayes_brdf.render import collocated_views
        >>> g = GBuffer.build(collocated_views(2, 3.0, camera="rectified", resolution=4), PlanarSample(2.0))
        >>> c, index = compacted_taps(g)
        >>> c.gathered, c.texel is None, c.resolution, index.shape
        (True, True, (1, 32), torch.Size([32]))
    """
    hit = g.__dict__.get("_compacted_taps")
    if hit is None:
        c, index = compacted(g)
        hit = g.__dict__["_compacted_taps"] = (replace(c, texel=None, texel_grid=None), index)
    return hit


def _compact_data(g: GBuffer, index: Tensor, target: Tensor, weight, kind: str):
    """Target and weight at the compacted pixels ``[1, 1, K, ...]`` and the loss of the pixels off the surface
    (they render 0, so it does not depend on the maps); kept on ``g`` while the same tensors come again
    (a sampler's every step)."""
    scalar = isinstance(weight, numbers.Real)        # a number: the same weight whenever the value is
    wt = torch.as_tensor(weight, device=target.device, dtype=target.dtype)
    key = (id(target), target._version, ("value", float(weight)) if scalar else (id(wt), wt._version), kind)
    hit = g.__dict__.get("_compact_data")
    if hit is not None and hit[0] == key and hit[1][0] is target and (scalar or hit[1][1] is wt):
        return hit[2]
    V, (h, w) = g.num_views, g.resolution
    we = (wt.expand(V, h, w) if wt.dim() < 3 else wt).reshape(-1)
    y = target.reshape(-1, 3)
    off = ~g.mask.reshape(-1)
    const = None
    if bool(off.any()):
        const = (we[off][:, None] * (y[off].abs() if kind == "l1" else y[off] * y[off])).sum()
    out = (y[index][None, None].contiguous(), we[index][None, None].contiguous(), const)
    g.__dict__["_compact_data"] = (key, (target, wt), out)
    return out


_CHANNELS_FIRST = TensorMemo(4)


def _normal_maps_native(maps: SVBRDF, g: GBuffer, target: Tensor, weight: Tensor, backend: str,
                        chunk_views) -> bool:
    """Whether :func:`shade_loss` runs :class:`~bayes_brdf.render.native.NativeNormalMapLoss`: normals per particle
    or differentiated, on rectified views whose pixels are the texels (maps of the views' resolution or ``1 x 1``,
    the normals full), point lights only (at most ``MAX_LIGHTS`` per view), no gradient w.r.t. the data, CPU."""
    nrm = maps.normal
    if backend == "eager" or chunk_views is not None or g.env is not None or (nrm.dim() == 3 and not nrm.requires_grad):
        return False
    hw = tuple(g.resolution)
    if not g.aligned or g.texel is not None or tuple(nrm.shape[-2:]) != hw or \
            any(tuple(t.shape[-2:]) not in (hw, (1, 1)) for t in (maps.albedo, maps.roughness, maps.specular)):
        return False
    if not 1 <= g.light_dir.shape[1] <= native.MAX_LIGHTS or target.requires_grad or weight.requires_grad:
        return False
    ts = (maps.albedo, maps.roughness, maps.specular, nrm)
    return all(t.dtype == nrm.dtype and t.device == nrm.device for t in ts) and native.available(nrm, normal_maps=True)


def channels_first(target: Tensor, device, dtype) -> Tensor:
    """Images ``[V, H, W, 3]`` as contiguous ``[V, 3, H, W]`` of ``dtype`` on ``device``: the kernels' layout.

    Made once and kept while the same, unmodified tensor comes again (a sampler passes its observed images on
    every step; the copy used to be made each time). ``target`` in a graph is converted each call.
    """
    if target.requires_grad:
        return target.to(device=device, dtype=dtype).permute(0, 3, 1, 2)
    return _CHANNELS_FIRST.get((target,), (dtype, str(device)),
                               lambda: target.to(device=device, dtype=dtype).permute(0, 3, 1, 2).contiguous())


def shade_pixel_loss(maps: SVBRDF, g: GBuffer, target: Tensor, weight: Tensor | float = 1.0, *, kind: str = "l1",
                     ks_factor: bool = True, eps: float = 1e-8, backend: str = "auto") -> Tensor:
    """``[n, H, W, 3]``: the loss of :func:`shade_loss` per pixel and channel, summed over the views only (no
    gradient). On rectified views (``g.aligned``: every pixel is a texel) this is each texel's share of the loss,
    what a texel-local move scores (:mod:`bayes_brdf.models.texel_energy`).

    On rectified views without an environment light the native kernel computes it without materialising the
    images (``fused.pixel_loss``); otherwise, and with ``backend="eager"``, the images are shaded and reduced
    here (the reference the kernel is checked against).

    Example:
        >>> import torch
        >>> from bayes_brdf.render import SVBRDF, PlanarSample, collocated_views
        >>> g = GBuffer.build(collocated_views(2, 3.0, camera="rectified", resolution=4), PlanarSample(2.0))
        >>> x = SVBRDF.constant(roughness=0.3)
        >>> y = shade(x, g)[0]
        >>> tuple(shade_pixel_loss(x, g, y + 0.01).shape), round(float(shade_pixel_loss(x, g, y + 0.01).max()), 4)
        ((1, 4, 4, 3), 0.02)
    """
    if kind not in ("l1", "l2"):
        raise InputError(f"unknown loss kind '{kind}'", fix="use l1 (Laplace) or l2 (Gaussian)")
    V, (h, w) = g.num_views, g.resolution
    if tuple(target.shape) != (V, h, w, 3):
        raise InputError(f"target images have shape {tuple(target.shape)}, expected {(V, h, w, 3)}")
    dev, dt = maps.albedo.device, maps.albedo.dtype
    wt = torch.as_tensor(weight, device=dev, dtype=dt)
    wt = wt.expand(V, h, w) if wt.dim() < 3 else wt
    with torch.no_grad():
        if backend == "eager" or not g.aligned or g.env is not None:
            d = shade(maps, g, ks_factor=ks_factor, eps=eps, backend=backend).sub_(target.to(dev, dt)[None])
            d = d.abs_() if kind == "l1" else d.square_()
            return torch.einsum("nvhwc,vhw->nhwc", d, wt)
        n, g, chunks = _chunks(maps, g, eps, None)
        y = channels_first(target, dev, dt)
        wt = wt[:, None]
        total = None
        for s, e, args, _, _ in chunks:
            part = fused.pixel_loss(*args, y[s:e], wt[s:e], ks_factor, kind == "l1")
            total = part if total is None else total.add_(part)
        return total.expand(n, 3, h, w).permute(0, 2, 3, 1)


def shade_loss(maps: SVBRDF, g: GBuffer, target: Tensor, weight: Tensor | float = 1.0, *, kind: str = "l1",
               ks_factor: bool = True, eps: float = 1e-8, chunk_views: int | None = None,
               backend: str = "auto") -> Tensor:
    """Per-particle pixel loss ``[n]`` between the shaded views and ``target``, never materialising the images.

    ``loss[i] = sum_{v, pixel, c} weight * |R(x_i; theta_v) - target|`` (``kind="l1"``,
    the paper's Eq. 2 energy times ``sigma``) or ``* (R - target)^2`` (``kind="l2"``).
    ``target`` is ``[V, H, W, 3]`` linear radiance; ``weight`` is a scalar or
    ``[V, H, W]`` (e.g. ``mask / sigma``), non-negative (a negative weight makes no loss: the native kernels take
    the L1 gradient ``weight * sign`` as ``weight`` with the residual's sign). With the compiled backend the
    shading and the loss are fused and differentiated analytically (w.r.t.
    albedo, roughness and specular; normals held fixed), which is the hot path
    of posterior sampling.

    Example:
        >>> import torch
        >>> from bayes_brdf.render import SVBRDF, PlanarSample, collocated_views
        >>> views = collocated_views(2, 3.0, camera="rectified", resolution=8)
        >>> g = GBuffer.build(views, PlanarSample(2.0))
        >>> x = SVBRDF.constant(roughness=0.3)
        >>> y = shade(x, g)[0]
        >>> float(shade_loss(x, g, y)[0])
        0.0
    """
    if kind not in ("l1", "l2"):
        raise InputError(f"unknown loss kind '{kind}'", fix="use l1 (Laplace) or l2 (Gaussian)")
    V, (h, w) = g.num_views, g.resolution
    if tuple(target.shape) != (V, h, w, 3):
        raise InputError(f"target images have shape {tuple(target.shape)}, expected {(V, h, w, 3)}")
    env_aligned = g.aligned and g.env is not None and backend != "eager"
    if (not (g.aligned or g.gathered) or env_aligned) and chunk_views is None:
        # views whose pixels are not the texels (a mesh, perspective views of the plane): only the pixels that
        # see the surface, as one 1 x K view, so masked pixels cost nothing and the fused kernel applies.
        # Rectified views under an environment go the same way, their pixels read through taps, because only the
        # texel kernel shades an environment natively (the pixel kernel would fall back to eager torch)
        c, index = compacted_taps(g) if env_aligned else compacted(g)
        yc, wc, const = _compact_data(g, index, target, weight, kind)
        loss = shade_loss(maps, c, yc, wc, kind=kind, ks_factor=ks_factor, eps=eps, backend=backend)
        return loss + const if const is not None else loss
    dev, dt = maps.albedo.device, maps.albedo.dtype
    wt = torch.as_tensor(weight, device=dev, dtype=dt)
    wt = (wt.expand(V, h, w) if wt.dim() < 3 else wt)[:, None]
    y = channels_first(target, dev, dt)
    if _normal_maps_native(maps, g, target, wt, backend, chunk_views):
        # each particle its own normal map (decoded, or sampled): the native kernel makes the cosines per particle
        gg = g if g.position.dtype == dt else g.to(dtype=dt)
        geo = native.normal_map_geometry(gg.tangent, gg.bitangent, gg.normal, gg.view_dir, gg.light_dir,
                                         gg.light_scale, eps)
        return native.NativeNormalMapLoss.apply(maps.albedo, maps.roughness, maps.specular, maps.normal, geo, y, wt,
                                                ks_factor, kind == "l1", eps)
    n, g, chunks = _chunks(maps, g, eps, chunk_views, texel_space=backend != "eager")
    kernel = fused.get_loss_kernel(backend, n * V * h * w)
    total = 0.0
    for s, e, args, tp, env in chunks:
        extra = {} if tp is None else {"taps": tp}
        if env is not None:
            extra["env"] = env
        total = total + kernel(*args, y[s:e].contiguous(), wt[s:e].contiguous(), ks_factor, kind == "l1", **extra)
    return total.expand(n) if total.dim() == 1 else total
