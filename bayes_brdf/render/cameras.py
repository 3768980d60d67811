"""Cameras: where each pixel looks.

Two kinds, both giving one ray per pixel so the surface intersects them the same way:

* :class:`PerspectiveCamera` -- a pinhole camera (pose + field of view), for
  synthetic views and novel-view renders.
* :class:`RectifiedCamera` -- a photo already rectified to the sample's texture
  grid (what MaterialGAN-style captures store): pixel ``(i, j)`` sees the texel
  point ``(i, j)`` of the planar sample; only the camera *position* matters, for
  the view direction.

Positions are in the scene's length unit (cm for real captures). Images are
``[H, W]`` with row 0 at the top.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from ..checks import vec3
from ..errors import InputError


def _resolution(res) -> tuple[int, int]:
    if isinstance(res, int):
        res = (res, res)
    res = tuple(int(r) for r in res)
    if len(res) != 2 or min(res) < 1:
        raise InputError(f"resolution must be a positive int or (height, width), got {res!r}")
    return res


@dataclass(frozen=True)
class PerspectiveCamera:
    """Pinhole camera looking from ``position`` at ``target``.

    ``fov`` is the full field of view in degrees along the image width (as
    Mitsuba's default ``fov_axis='x'``); ``resolution`` is ``(height, width)``.

    Example:
        >>> cam = PerspectiveCamera(position=(0, 0, 3), fov=45, resolution=(64, 64))
        >>> origin, dirs = cam.rays()
        >>> dirs.shape
        torch.Size([3, 64, 64])
    """

    position: tuple[float, float, float]
    target: tuple[float, float, float] = (0.0, 0.0, 0.0)
    up: tuple[float, float, float] = (0.0, 1.0, 0.0)
    fov: float = 45.0
    resolution: tuple[int, int] = (128, 128)

    def __post_init__(self):
        object.__setattr__(self, "position", vec3(self.position, "camera position"))
        object.__setattr__(self, "target", vec3(self.target, "camera target"))
        object.__setattr__(self, "up", vec3(self.up, "camera up"))
        object.__setattr__(self, "resolution", _resolution(self.resolution))
        if not 0 < float(self.fov) < 180:
            raise InputError(f"camera fov must be in (0, 180) degrees, got {self.fov}")

    def frame(self, dtype=torch.float64) -> tuple[Tensor, Tensor, Tensor]:
        """Unit ``(right, up, forward)`` world vectors of the image plane."""
        p, t, u = (torch.tensor(v, dtype=dtype) for v in (self.position, self.target, self.up))
        f = t - p
        if f.norm() == 0:
            raise InputError(f"camera at {self.position} looks at itself", fix="give a target away from the position")
        f = f / f.norm()
        r = torch.linalg.cross(f, u)
        if r.norm() < 1e-6:  # looking along `up`: pick any perpendicular
            alt = torch.tensor((1.0, 0.0, 0.0) if abs(float(f[0])) < 0.9 else (0.0, 0.0, 1.0), dtype=dtype)
            r = torch.linalg.cross(f, alt)
        r = r / r.norm()
        return r, torch.linalg.cross(r, f), f

    def rays(self, device=None, dtype=torch.float32) -> tuple[Tensor, Tensor]:
        """Ray origin ``[3]`` and unit directions ``[3, H, W]`` through pixel centres."""
        h, w = self.resolution
        r, u, f = self.frame()
        tx = math.tan(math.radians(self.fov) / 2)
        ty = tx * h / w
        xs = ((torch.arange(w, dtype=torch.float64) + 0.5) / w * 2 - 1) * tx
        ys = (1 - (torch.arange(h, dtype=torch.float64) + 0.5) / h * 2) * ty
        d = f[:, None, None] + xs[None, None, :] * r[:, None, None] + ys[None, :, None] * u[:, None, None]
        d = d / (d * d).sum(0, keepdim=True).sqrt()      # (torch's norm over dim 0 is ~20x slower on CPU)
        o = torch.tensor(self.position, dtype=torch.float64)
        return o.to(device=device, dtype=dtype), d.to(device=device, dtype=dtype)


@dataclass(frozen=True)
class RectifiedCamera:
    """A photo rectified to the sample's texture grid, taken from ``position``.

    Example:
        >>> cam = RectifiedCamera(position=(1.0, 0.3, 16.7), resolution=256)
        >>> cam.resolution
        (256, 256)
    """

    position: tuple[float, float, float]
    resolution: tuple[int, int] = (256, 256)

    def __post_init__(self):
        object.__setattr__(self, "position", vec3(self.position, "camera position"))
        object.__setattr__(self, "resolution", _resolution(self.resolution))
