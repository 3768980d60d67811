"""G-buffers: everything about a view that does not depend on the material.

For each pixel of each view: the texture coordinate it sees, its 3-D position,
the surface frame (tangent, bitangent, normal), the unit direction to the camera,
the unit direction and squared distance to each light, the light's RGB power
(with its falloff and shadowing) and whether the pixel sees the surface at all.
Computed once per view from the surface's hits (:mod:`.hits`: analytic for the
planar sample, ray cast for a mesh) and each light's incident terms, in float64,
then stored in the requested dtype/device; :class:`GBufferCache` keeps them so that shading never
repeats geometry work.

The pixel -> texel *footprint* (which pixels fall in the same texel of an
``R x R`` map) is :meth:`GBuffer.texel_index`.
"""
from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass, fields, replace

import torch
from torch import Tensor

from ..errors import InputError
from . import transfer as env_transfer
from .hits import texel_index
from .surface import PlanarSample
from .views import View


@dataclass
class GBuffer:
    """Per-pixel geometry of ``V`` views of equal resolution ``(H, W)`` with up to ``L`` lights.

    Shapes (channel-first): ``position, normal, tangent, bitangent, view_dir``
    ``[V, 3, H, W]``; ``light_dir [V, L, 3, H, W]``; ``light_dist2 [V, L, 1, H, W]``;
    ``light_scale [V, L, 3, H, W]`` (RGB power / distance^2, or power alone
    without falloff, zero outside the mask or for padding lights); ``env``
    ``[V, C, H, W]`` the environment light's precomputed transfer (:mod:`.transfer`: irradiance and the
    roughness tables; zero for views without one; ``None`` when no view has one); ``mask
    [V, H, W]`` bool; ``uv [V, H, W, 2]`` ``grid_sample`` coordinates in
    ``[-1, 1]``. ``aligned`` is True when every view is a rectified photo whose
    pixels sit exactly on the texel grid of a map of resolution ``(H, W)``.

    Example:
        >>> from bayes_brdf.render.views import collocated_views
        >>> g = GBuffer.build(collocated_views(2, 3.0, resolution=16), PlanarSample(2.0))
        >>> g.light_dir.shape
        torch.Size([2, 1, 3, 16, 16])
    """

    position: Tensor
    normal: Tensor
    tangent: Tensor
    bitangent: Tensor
    view_dir: Tensor
    light_dir: Tensor
    light_dist2: Tensor
    light_scale: Tensor
    mask: Tensor
    uv: Tensor
    align_corners: bool
    aligned: bool
    texel: Tensor | None = None          # gathered pixels of aligned views: flat texel index [V, H, W] ...
    texel_grid: tuple | None = None      # ... into a map of this (H, W) (see :meth:`gather`)
    gathered: bool = False               # True for the 1 x K view of selected pixels :meth:`gather` returns
    env: Tensor | None = None            # [V, transfer.CHANNELS, H, W] environment terms (zero for views without)

    @classmethod
    def build(cls, views: list[View], surface, *, dtype=torch.float32, device=None) -> "GBuffer":
        """Compute the G-buffer of ``views`` (all of one resolution) looking at ``surface``.

        The surface gives the hits (:meth:`intersect`) and the shadow tests (:meth:`occluded`), each
        light what it delivers: a point light its incident terms (:meth:`PointLight.incident`), an environment
        its transfer (:func:`~bayes_brdf.render.transfer.transfer`, shadowed by
        ``surface.occluded_directions``); all in float64, then cast.
        """
        views = list(views)
        if not views:
            raise InputError("no views given", fix="pass at least one View")
        res = {tuple(v.resolution) for v in views}
        if len(res) != 1:
            raise InputError(f"views have different resolutions {sorted(res)}",
                             fix="shade views of different resolutions in separate calls")
        h, w = res.pop()
        L = max(len(v.point_lights) for v in views)
        cams = [v.camera for v in views]
        uniq = list(dict.fromkeys(cams))               # a light stage: many views share a camera, cast its rays once
        hits = surface.intersect(uniq)
        if len(uniq) < len(cams):
            where = {c: i for i, c in enumerate(uniq)}
            hits = hits.select([where[c] for c in cams])
        lpos = torch.zeros(len(views), L, 3, dtype=torch.float64)
        for k, v in enumerate(views):
            if v.point_lights:
                lpos[k, :len(v.point_lights)] = torch.tensor([l.position for l in v.point_lights], dtype=torch.float64)
        blocked = surface.occluded(hits, lpos) if L else None   # [V, L, H, W] bool, or None: nothing casts shadows
        per_view = []
        for k, v in enumerate(views):
            pos, mask = hits.position[k], hits.mask[k]
            cam = torch.tensor(v.camera.position, dtype=torch.float64)[:, None, None]
            vd = cam - pos
            vd = vd / (vd * vd).sum(0, keepdim=True).sqrt().clamp_min(1e-30)
            ld = torch.zeros(L, 3, h, w, dtype=torch.float64)
            d2 = torch.ones(L, 1, h, w, dtype=torch.float64)
            scale = torch.zeros(L, 3, h, w, dtype=torch.float64)
            for i, light in enumerate(v.point_lights):
                inc = light.incident(pos, mask, None if blocked is None else ~blocked[k, i],
                                     where=f"{i} of view '{v.name}' ")
                ld[i], d2[i], scale[i] = inc.direction, inc.dist2, inc.scale
            per_view.append((vd, ld, d2, scale))
        stack = lambda k: torch.stack([pv[k] for pv in per_view])  # noqa: E731
        env = None
        if any(v.environment is not None for v in views):
            env = torch.zeros(len(views), env_transfer.CHANNELS, h, w, dtype=torch.float64)
            ng = hits.geometric_normal if hits.geometric_normal is not None else hits.normal
            for k, v in enumerate(views):
                if v.environment is not None:
                    env[k] = env_transfer.transfer(v.environment, hits.position[k], hits.normal[k], ng[k],
                                                   per_view[k][0], hits.mask[k], surface)
        g = cls(position=hits.position, normal=hits.normal, tangent=hits.tangent, bitangent=hits.bitangent,
                view_dir=stack(0), light_dir=stack(1), light_dist2=stack(2), light_scale=stack(3), mask=hits.mask,
                uv=hits.uv, align_corners=hits.align_corners, aligned=hits.aligned, env=env)
        return g.to(dtype=dtype, device=device)

    @property
    def num_views(self) -> int:
        return self.position.shape[0]

    @property
    def nbytes(self) -> int:
        """Memory held by the G-buffer's tensors (the expanded frame vectors count once)."""
        return sum(t.untyped_storage().nbytes() for f in fields(self)
                   if isinstance(t := getattr(self, f.name), Tensor))

    @staticmethod
    def bytes_per_view(view: View, dtype=torch.float32, flat: bool = True) -> int:
        """Memory one view adds to a G-buffer (``dtype`` values; for planning chunks before building); ``flat``:
        the surface's frame is one vector (the plane), else three per pixel (a mesh) and its compacted copy."""
        h, w = view.resolution
        nl = len(view.point_lights)
        floats = 8 + 7 * nl + (0 if flat else 9 + 17 + 7 * nl)
        if view.environment is not None:
            floats += env_transfer.CHANNELS * (1 if flat else 2)
        return h * w * (floats * torch.finfo(dtype).bits // 8 + 1)

    @property
    def resolution(self) -> tuple[int, int]:
        return tuple(self.position.shape[-2:])

    def to(self, dtype=None, device=None) -> "GBuffer":
        """Move floating tensors to ``dtype``/``device`` (the mask stays bool)."""
        out = {}
        for f in fields(self):
            t = getattr(self, f.name)
            if isinstance(t, Tensor):
                t = t.to(device=device, dtype=dtype if t.is_floating_point() and dtype else None)
                out[f.name] = t.contiguous() if f.name not in ("normal", "tangent", "bitangent") else t
        return replace(self, **out)

    def views_slice(self, start: int, stop: int) -> "GBuffer":
        """The G-buffer of views ``start:stop`` (for chunked shading)."""
        return replace(self, **{f.name: getattr(self, f.name)[start:stop] for f in fields(self)
                                if isinstance(getattr(self, f.name), Tensor)})

    def views_index(self, idx) -> "GBuffer":
        """The G-buffer of the views ``idx`` (a list or tensor of indices), e.g. a minibatch of views."""
        t = torch.as_tensor(idx, dtype=torch.long, device=self.position.device)
        return replace(self, **{f.name: getattr(self, f.name)[t] for f in fields(self)
                                if isinstance(getattr(self, f.name), Tensor)})

    def gather(self, pixels: Tensor, order: Tensor | None = None) -> "GBuffer":
        """The pixels where ``pixels [V, H, W]`` is True, as one view of ``1 x K`` pixels: in raster order, or
        in ``order`` (a permutation of the ``K`` pixels, e.g. :func:`~bayes_brdf.render.texels.texture_order`).

        For shading a sparse set of pixels (e.g. the saturated ones) without
        shading whole views. Pixels of aligned views keep their texel's flat
        index (``texel``), so a map of the views' resolution is read by index,
        not interpolated; otherwise textures are looked up at each pixel's ``uv``.
        """
        pixels = torch.as_tensor(pixels, dtype=torch.bool, device=self.position.device)
        if tuple(pixels.shape) != (self.num_views, *self.resolution):
            raise InputError(f"pixel selection has shape {tuple(pixels.shape)}, expected "
                             f"{(self.num_views, *self.resolution)}")
        v, r, c = pixels.nonzero(as_tuple=True)
        if order is not None:
            v, r, c = v[order], r[order], c[order]

        def pick(t: Tensor) -> Tensor:
            if t.dim() >= 4 and tuple(t.shape[-2:]) == self.resolution:      # [V, ..., H, W]
                out = t[v, ..., r, c] if t.dim() > 3 else t[v, r, c]
                return out.movedim(0, -1)[None, ..., None, :]              # [1, ..., 1, K]
            if t.dim() == 4 and t.shape[-1] == 2:                          # uv [V, H, W, 2]
                return t[v, r, c][None, None]                              # [1, 1, K, 2]
            return t[v, r, c][None, None]                                  # mask [V, H, W] -> [1, 1, K]
        src = self
        if self.aligned and self.texel is None:          # a rectified view: pixel (r, c) shows texel r * W + c
            h, w = self.resolution
            idx = torch.arange(h * w, device=self.position.device).reshape(1, h, w).expand(self.num_views, h, w)
            src = replace(self, texel=idx, texel_grid=(h, w))
        out = {f.name: pick(getattr(src, f.name)).contiguous() for f in fields(src)
               if isinstance(getattr(src, f.name), Tensor)}
        return replace(src, aligned=False, gathered=True, **out)

    def pixels(self, index: Tensor | slice) -> "GBuffer":
        """Pixels ``index`` (a slice or indices) of a gathered ``1 x K`` G-buffer (:meth:`gather`), e.g. those of
        some of its views."""
        if not self.gathered:
            raise InputError("pixels needs a gathered G-buffer", fix="call gather() first")
        out = {}
        for f in fields(self):
            t = getattr(self, f.name)
            if isinstance(t, Tensor):
                out[f.name] = t[:, :, index] if f.name == "uv" else t[..., index]
        return replace(self, **out)

    def texel_index(self, resolution) -> Tensor:
        """Footprint: flat index ``[V, H, W]`` of the nearest texel of an ``(R_h, R_w)`` map (-1 if invalid).

        Pixels of one view with equal index see the same texel.
        """
        return texel_index(self.uv, self.mask, resolution, self.align_corners)

    def unique_pixel_mask(self, resolution) -> Tensor:
        """``[V, H, W]`` bool: one valid pixel per (view, texel), the first in raster order.

        The paper's handling of redundant pixels (Sec. 3.4.1): pixels that
        share a texel are counted once.
        """
        idx = self.texel_index(resolution)
        V = idx.shape[0]
        flat = idx.reshape(V, -1)
        n_tex = (resolution if isinstance(resolution, int) else resolution[0]) * \
                (resolution if isinstance(resolution, int) else resolution[1])
        key = torch.where(flat >= 0, flat + torch.arange(V, device=flat.device)[:, None] * n_tex, -1)
        order = torch.arange(flat.shape[1], device=flat.device).expand(V, -1)
        first = torch.full((V * n_tex + 1,), flat.shape[1], dtype=torch.long, device=flat.device)
        k = torch.where(key >= 0, key, V * n_tex)
        first.scatter_reduce_(0, k.reshape(-1), order.reshape(-1), reduce="amin")
        keep = (first[k] == order) & (key >= 0)
        return keep.reshape(idx.shape)


class GBufferCache:
    """Keeps G-buffers by (views, surface, dtype, device) so each view's geometry is computed once.

    The library shares one, :data:`GBUFFERS` (rendering, model data, uncertainty, guidance): one
    memory budget, and a view set used by two of them is built once.

    Example:
        >>> from bayes_brdf.render.views import collocated_views
        >>> cache = GBufferCache()
        >>> vs = collocated_views(2, 3.0, resolution=8)
        >>> cache.get(vs, PlanarSample()) is cache.get(vs, PlanarSample())
        True
    """

    def __init__(self, max_entries: int = 64, max_bytes: int = 1 << 30):
        self._store: OrderedDict = OrderedDict()
        self.max_entries = max_entries
        self.max_bytes = max_bytes

    @property
    def nbytes(self) -> int:
        return sum(g.nbytes for g in self._store.values())

    def get(self, views, surface, dtype=torch.float32, device=None) -> GBuffer:
        """The G-buffer of ``views``; built on a miss and kept unless it alone exceeds ``max_bytes``
        (least recently used entries go first when there are over ``max_entries`` or ``max_bytes``)."""
        key = (tuple(views), surface, dtype, str(torch.device(device) if device is not None else "cpu"))
        if key in self._store:
            self._store.move_to_end(key)
            return self._store[key]
        g = GBuffer.build(list(views), surface, dtype=dtype, device=device)
        if g.nbytes > self.max_bytes:
            return g
        self._store[key] = g
        while len(self._store) > self.max_entries or self.nbytes > self.max_bytes:
            self._store.popitem(last=False)
        return g

    def blocks(self, views, surface, dtype=torch.float32, device=None):
        """``(first index, G-buffer)`` covering ``views``: the whole set through the cache when it fits
        ``max_bytes`` (a set used again, e.g. candidates scored every round, is built once), else blocks built
        one at a time and not kept, so a set of several GB never sits in memory whole. A block holds a quarter
        of the budget: :meth:`GBuffer.build` works in float64 and stacks, about 4x the result at its peak."""
        views = list(views)
        flat = isinstance(surface, PlanarSample)
        per_view = max(GBuffer.bytes_per_view(v, dtype, flat) for v in views)
        if per_view * len(views) <= self.max_bytes:
            yield 0, self.get(views, surface, dtype=dtype, device=device)
            return
        step = max(1, self.max_bytes // (4 * per_view))
        for b0 in range(0, len(views), step):
            yield b0, GBuffer.build(views[b0:b0 + step], surface, dtype=dtype, device=device)


#: the one G-buffer cache of the library (1 GiB, 64 view sets, least recently used first out)
GBUFFERS = GBufferCache()
