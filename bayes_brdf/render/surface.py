"""Surfaces the cameras look at. For now: the flat square material sample.

:class:`PlanarSample` is a square of side ``size`` centred at the origin on the
plane ``z = 0``, normal ``+z``, texture ``u`` along ``+x`` and texture rows
running from ``+y`` (row 0) to ``-y``. ``grid`` says where texel ``i`` of an
``R``-texel map sits:

* ``"centers"`` (MaterialGAN / svbrdf-diff-renderer):
  ``x_i = ((i + 0.5) / R - 0.5) * size``
* ``"endpoints"`` (DeepInverseRendering): ``x_i = (i / (R - 1) - 0.5) * size``,
  i.e. ``linspace(-size/2, size/2, R)``.

Every geometry (this plane, and :class:`~bayes_brdf.render.mesh.Mesh`) offers the same small protocol,
which is all the G-buffer needs:

* ``intersect(cameras) -> SurfaceHits`` -- where each pixel meets the surface (:mod:`.hits`);
* ``occluded(hits, light_positions [V, L, 3]) -> [V, L, H, W] bool`` or ``None`` -- shadow tests
  (``None``: nothing can shadow, as on a plane);
* ``occluded_directions(points [N, 3], normals [N, 3], directions [N, 3]) -> [N] bool`` or ``None`` -- the
  same towards lights at infinity (an environment);
* ``center`` and ``radius`` -- a bounding sphere, for placing cameras and measuring view directions;
* ``state()`` -- a JSON-able description plus tensors, so a scene can be saved (:mod:`.scene`).
"""
from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from ..errors import InputError
from .cameras import PerspectiveCamera, RectifiedCamera
from .hits import SurfaceHits


@dataclass(frozen=True)
class PlanarSample:
    """Flat square sample of side ``size`` on ``z = 0``.

    Example:
        >>> s = PlanarSample(size=2.0, grid="endpoints")
        >>> s.texel_points((3, 3))[:, 0, 0].tolist()   # row 0, col 0 -> (-1, +1, 0)
        [-1.0, 1.0, 0.0]
    """

    size: float = 2.0
    grid: str = "centers"

    def __post_init__(self):
        if not (float(self.size) > 0):
            raise InputError(f"sample size must be > 0, got {self.size}")
        if self.grid not in ("centers", "endpoints"):
            raise InputError(f"unknown texel grid '{self.grid}'", fix="use 'centers' or 'endpoints'")
        object.__setattr__(self, "size", float(self.size))

    @property
    def align_corners(self) -> bool:
        """The ``grid_sample`` flag that matches this texel grid."""
        return self.grid == "endpoints"

    def _axis(self, n: int, dtype=torch.float64) -> Tensor:
        i = torch.arange(n, dtype=dtype)
        if self.grid == "centers":
            return ((i + 0.5) / n - 0.5) * self.size
        return (i / max(n - 1, 1) - 0.5) * self.size if n > 1 else torch.zeros(1, dtype=dtype)

    def texel_points(self, resolution) -> Tensor:
        """World positions ``[3, H, W]`` (float64) of an ``(H, W)`` texel grid."""
        h, w = resolution
        x = self._axis(w)
        y = -self._axis(h)
        return torch.stack([x[None, :].expand(h, w), y[:, None].expand(h, w), torch.zeros(h, w, dtype=torch.float64)])

    def hit(self, camera) -> tuple[Tensor, Tensor]:
        """Where each pixel of ``camera`` meets the sample: positions ``[3, H, W]`` and valid mask ``[H, W]``.

        Computed in float64. A rectified camera sees the texel grid itself.
        """
        if isinstance(camera, RectifiedCamera):
            pts = self.texel_points(camera.resolution)
            return pts, torch.ones(camera.resolution, dtype=torch.bool)
        if not isinstance(camera, PerspectiveCamera):
            raise InputError(f"unsupported camera type {type(camera).__name__}")
        o, d = camera.rays(dtype=torch.float64)
        dz = d[2]
        t = torch.where(dz < 0, -o[2] / dz.clamp(max=-1e-12), torch.full_like(dz, -1.0))
        pts = o[:, None, None] + t * d
        half = self.size / 2 * (1 + 1e-9)
        mask = (t > 0) & (pts[0].abs() <= half) & (pts[1].abs() <= half)
        if o[2] <= 0:
            mask[:] = False  # the camera is below the sample: it sees its back
        pts = torch.where(mask, pts, torch.zeros_like(pts))
        return pts, mask

    def intersect(self, cameras) -> SurfaceHits:
        """The hits of ``cameras`` (one resolution), in float64; see :class:`~bayes_brdf.render.hits.SurfaceHits`.

        Example:
            >>> from bayes_brdf.render import PerspectiveCamera
            >>> h = PlanarSample(2.0).intersect([PerspectiveCamera((0, 0, 3.0), resolution=8)])
            >>> h.normal[0, :, 0, 0].tolist(), h.aligned
            ([0.0, 0.0, 1.0], False)
        """
        cameras = list(cameras)
        hits = [self.hit(c) for c in cameras]
        pos = torch.stack([p for p, _ in hits])
        V, _, h, w = pos.shape
        t, b, n = (e[None, :, None, None].expand(V, 3, h, w) for e in self.frame())
        return SurfaceHits(position=pos, normal=n, tangent=t, bitangent=b, uv=self.texture_coords(pos.movedim(1, 0)),
                           mask=torch.stack([m for _, m in hits]), align_corners=self.align_corners,
                           aligned=all(isinstance(c, RectifiedCamera) for c in cameras))

    def occluded(self, hits: SurfaceHits, light_positions: Tensor) -> None:
        """A plane cannot shadow itself: ``None`` (a light below it is handled by the clamped ``n.l``)."""
        return None

    def occluded_directions(self, points: Tensor, normals: Tensor, directions: Tensor) -> None:
        """A plane occludes no direction: ``None`` (light from below it is handled by the clamped ``n.l``)."""
        return None

    @property
    def center(self) -> tuple[float, float, float]:
        """Centre of the bounding sphere: the origin."""
        return (0.0, 0.0, 0.0)

    @property
    def radius(self) -> float:
        """Radius of the bounding sphere (half the diagonal)."""
        return self.size * 2 ** -0.5

    def state(self) -> tuple[dict, dict]:
        """``({"type": "plane", "size": ..., "grid": ...}, {})`` for saving (see :func:`bayes_brdf.render.scene.surface_from_state`)."""
        return {"type": "plane", "size": self.size, "grid": self.grid}, {}

    def texture_coords(self, points: Tensor) -> Tensor:
        """``grid_sample`` coordinates ``[..., 2]`` in ``[-1, 1]`` of positions ``[3, ...]``.

        Use with ``align_corners=self.align_corners``; x follows columns,
        y follows rows (row 0 at ``+y``).
        """
        return torch.stack([points[0] * (2 / self.size), -points[1] * (2 / self.size)], dim=-1)

    def frame(self, dtype=torch.float64) -> tuple[Tensor, Tensor, Tensor]:
        """Unit tangent, bitangent and normal (world): ``+x, +y, +z``."""
        e = torch.eye(3, dtype=dtype)
        return e[0], e[1], e[2]
