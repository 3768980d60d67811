"""Where camera pixels meet a surface: :class:`SurfaceHits`, what every geometry's ``intersect`` returns.

For ``V`` cameras of one resolution ``(H, W)``, channel-first and in float64:

=============  ==================  ===========================================================
field          shape               meaning
=============  ==================  ===========================================================
position       ``[V, 3, H, W]``    world position of the first hit (0 where ``mask`` is False)
normal         ``[V, 3, H, W]``    unit shading normal (interpolated vertex normals on a mesh)
tangent        ``[V, 3, H, W]``    unit tangent along texture ``+u`` (orthogonal to ``normal``)
bitangent      ``[V, 3, H, W]``    ``normal x tangent``, along texture ``+v`` (towards texel row 0)
uv             ``[V, H, W, 2]``    ``grid_sample`` coordinates in ``[-1, 1]`` (x: columns, y: rows)
mask           ``[V, H, W]``       True where the pixel sees the surface
=============  ==================  ===========================================================

``align_corners`` is the ``grid_sample`` flag that matches the surface's texel
grid; ``aligned`` is True when every pixel *is* a texel (a rectified photo of the
planar sample). The frame vectors of a flat surface may be expanded views of one
vector (they take no memory per pixel). A tangent-space normal map ``(x, y, z)``
means the world normal ``x * tangent + y * bitangent + z * normal``.

The pixel -> texel footprint (which pixels show the same texel of an ``R x R``
map) is :func:`texel_index`; it is what guidance's redundant-pixel rule counts.
"""
from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor


@dataclass
class SurfaceHits:
    """Per-pixel geometry of ``V`` cameras looking at one surface (see the module docstring for shapes).

    Example:
        >>> from bayes_brdf.render import PlanarSample, RectifiedCamera
        >>> hits = PlanarSample(2.0).intersect([RectifiedCamera((0, 0, 5.0), 4)])
        >>> hits.position.shape, bool(hits.mask.all()), hits.aligned
        (torch.Size([1, 3, 4, 4]), True, True)
    """

    position: Tensor
    normal: Tensor
    tangent: Tensor
    bitangent: Tensor
    uv: Tensor
    mask: Tensor
    align_corners: bool
    aligned: bool = False
    geometric_normal: Tensor | None = None   #: ``[V, 3, H, W]`` face normals facing the camera (meshes; None: = normal)

    @property
    def num_views(self) -> int:
        return self.position.shape[0]

    def select(self, idx) -> "SurfaceHits":
        """The hits of cameras ``idx`` (a list of indices, repeats allowed: views that share a camera).

        Example:
            >>> from bayes_brdf.render import PlanarSample, RectifiedCamera
            >>> h = PlanarSample(2.0).intersect([RectifiedCamera((0, 0, 5.0), 4)]).select([0, 0, 0])
            >>> h.num_views, h.normal.stride(0)      # a flat frame stays one vector
            (3, 0)
        """
        t = torch.as_tensor(idx, dtype=torch.long)

        def pick(x):
            if x is None:
                return None
            if x.dim() == 4 and x.stride(-1) == 0 and x.stride(-2) == 0 and (x.shape[0] == 1 or x.stride(0) == 0):
                return x[:1].expand(len(t), *x.shape[1:])  # an expanded constant (the plane's frame): no copy
            return x[t]
        return SurfaceHits(position=pick(self.position), normal=pick(self.normal), tangent=pick(self.tangent),
                           bitangent=pick(self.bitangent), uv=pick(self.uv), mask=pick(self.mask),
                           align_corners=self.align_corners, aligned=self.aligned,
                           geometric_normal=pick(self.geometric_normal))

    @property
    def resolution(self) -> tuple[int, int]:
        return tuple(self.position.shape[-2:])


def texel_index(uv: Tensor, mask: Tensor, resolution, align_corners: bool) -> Tensor:
    """Footprint: flat index ``[...]`` of the nearest texel of an ``(R_h, R_w)`` map for ``uv [..., 2]`` (-1 where ``mask`` is False).

    Example:
        >>> uv = torch.tensor([[[-0.75, -0.75], [0.75, 0.75]]])    # two pixels, centres of texels 0 and 3
        >>> texel_index(uv, torch.tensor([[True, True]]), 2, align_corners=False).tolist()
        [[0, 3]]
    """
    rh, rw = (resolution, resolution) if isinstance(resolution, int) else resolution
    u, v = uv[..., 0], uv[..., 1]
    if align_corners:
        col, row = (u + 1) / 2 * (rw - 1), (v + 1) / 2 * (rh - 1)
    else:
        col, row = (u + 1) / 2 * rw - 0.5, (v + 1) / 2 * rh - 0.5
    col = col.round().long().clamp(0, rw - 1)
    row = row.round().long().clamp(0, rh - 1)
    return torch.where(mask, row * rw + col, torch.full_like(col, -1))
