"""A known environment light: an equirectangular HDR map at infinity, read exactly as Mitsuba 3's ``envmap``.

:class:`EnvironmentLight` holds the map's linear RGB radiance ``[H, W, 3]``, a ``scale`` and a rigid
``to_world`` (4 x 4; only its rotation acts on directions). For a unit direction ``d`` from the scene
towards the environment (world frame), Mitsuba's convention (checked against Mitsuba itself by
``tests/render/test_environment.py``) is:

* ``v_loc = R^T d`` (``R`` the rotation of ``to_world``); ``u = atan2(v_loc.x, -v_loc.z) / 2 pi`` wrapped to
  ``[0, 1)``, ``v = acos(v_loc.y) / pi``: the local ``+y`` is the zenith (row 0), ``u = 0`` looks along ``-z``;
* bilinear look-up with the columns at texel *centres* and periodic in ``u`` (``x = u W - 1/2`` modulo ``W``)
  and the rows at texel *corners* (``y = v (H - 1)``: row 0 is exactly the zenith, the last row the nadir);
* radiance times ``scale``.

So a user's Mitsuba scene (``{"type": "envmap", "filename": ..., "scale": s, "to_world": T}``) and this
light agree. Our scenes are z-up (the sample on ``z = 0``, normal ``+z``) while Mitsuba's envmap has its
zenith on local ``+y``: :func:`z_up` gives the ``to_world`` that puts the map's zenith on world ``+z``
(optionally turned about it), which the CLI uses; ``to_world`` defaults to the identity, as Mitsuba's.

Sampling (:meth:`EnvironmentLight.sample`, :meth:`EnvironmentLight.pdf`): a piecewise-constant density over
the ``W x (H - 1)`` cells of the ``(u, v)`` square, proportional to the cell's luminance times
``sin(theta)`` (as Mitsuba's own warp), uniform inside a cell; the solid-angle density is
``p_cell W (H - 1) / (2 pi^2 sin theta)``.
"""
from __future__ import annotations

import hashlib
import math
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from ..errors import InputError

#: Rec. 709 luminance weights (Mitsuba's ``luminance`` for RGB)
LUMINANCE = (0.212671, 0.715160, 0.072169)


def z_up(rotate_deg: float = 0.0) -> tuple:
    """``to_world`` (4 x 4, nested tuples) that puts an envmap's zenith (local ``+y``) on world ``+z`` and its
    ``u = 0`` direction (local ``-z``) on world ``+x``, turned by ``rotate_deg`` about ``+z``.

    Example:
        >>> T = z_up()
        >>> [round(T[i][1], 6) for i in range(3)]        # local +y -> world +z
        [0.0, 0.0, 1.0]
    """
    c, s = math.cos(math.radians(rotate_deg)), math.sin(math.radians(rotate_deg))
    base = np.array([[0.0, 0.0, -1.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])   # columns: images of x, y, z
    turn = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    r = turn @ base
    m = np.eye(4)
    m[:3, :3] = r
    return tuple(tuple(float(x) for x in row) for row in m)


def studio(height: int = 32, softbox: float = 6.0, zenith_deg: float = 20.0, size_deg: float = 30.0,
           sky: float = 0.3, floor: float = 0.05, azimuth_deg: float = 0.0) -> "EnvironmentLight":
    """A small built-in studio: a dim sky (``sky`` at the zenith falling to half at the horizon), a dark floor
    (``floor``) and one bright square softbox (radiance ``softbox``, ``size_deg`` across) centred ``zenith_deg``
    from the zenith at azimuth ``azimuth_deg`` (0: towards world ``+x``, 90: ``+y``), as a ``height x 2 height`` map z-up (:func:`z_up`).
    Deterministic and file-free: for tests, the Table 1 problem under an environment and quick looks; a
    softbox beside the zenith gives a flat sample a highlight whose size tells its roughness.

    Example:
        >>> env = studio(16)
        >>> tuple(env.radiance.shape), float(env.radiance.max())
        ((16, 32, 3), 6.0)
    """
    h, w = int(height), 2 * int(height)
    v = torch.arange(h, dtype=torch.float64) / (h - 1)                     # rows at corners: 0 the zenith
    u = (torch.arange(w, dtype=torch.float64) + 0.5) / w                    # columns at centres
    theta = (v * 180.0)[:, None].expand(h, w)
    img = torch.where(theta < 90, sky * (1 - 0.5 * theta / 90), torch.full_like(theta, floor))
    # the softbox, in the map's own frame: z_up puts u = 0 (local -z) on world +x, so azimuth 0 is u = 0
    d = torch.stack([torch.sin(torch.deg2rad(theta)) * torch.sin(2 * math.pi * u)[None],
                     torch.cos(torch.deg2rad(theta)),
                     -torch.sin(torch.deg2rad(theta)) * torch.cos(2 * math.pi * u)[None]], -1)
    z = math.radians(zenith_deg)
    c = torch.tensor([0.0, math.cos(z), -math.sin(z)], dtype=torch.float64)
    e1 = torch.tensor([1.0, 0.0, 0.0], dtype=torch.float64)                 # across the box
    e2 = torch.linalg.cross(c, e1)
    half = math.tan(math.radians(size_deg) / 2)
    front = (d * c).sum(-1)
    x, y = (d * e1).sum(-1) / front.clamp_min(1e-9), (d * e2).sum(-1) / front.clamp_min(1e-9)
    box = (front > 0) & (x.abs() <= half) & (y.abs() <= half)
    img = torch.where(box, torch.full_like(img, softbox), img)
    return EnvironmentLight(img[..., None].expand(h, w, 3).float(), 1.0, z_up(azimuth_deg), name="studio")


def _rigid(to_world, where) -> tuple:
    if to_world is None:
        return tuple(tuple(float(i == j) for j in range(4)) for i in range(4))
    try:
        m = np.asarray(to_world, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError("the environment's to_world is not a 4x4 matrix of numbers", where=where,
                         fix="give to_world as [[4 numbers] x 4]") from None
    if m.shape != (4, 4) or not np.isfinite(m).all():
        raise InputError(f"the environment's to_world must be a finite 4x4 matrix, got shape {m.shape}",
                         where=where, fix="give to_world as [[4 numbers] x 4]")
    r = m[:3, :3]
    if np.abs(m[3] - (0, 0, 0, 1)).max() > 1e-6 or np.abs(r.T @ r - np.eye(3)).max() > 1e-4:
        raise InputError("the environment's to_world is not rigid (its 3x3 part must be a rotation, its last "
                         "row 0 0 0 1)", where=where, fix="remove scaling and shear from to_world")
    return tuple(tuple(float(x) for x in row) for row in m)


class EnvironmentLight:
    """An environment map at infinity (linear RGB ``radiance [H, W, 3]``, ``H >= 3``, ``W >= 2``).

    Equal (and hashed) by content: map, scale and ``to_world``.

    Example:
        >>> env = EnvironmentLight(torch.ones(4, 8, 3), scale=2.0)
        >>> env.eval(torch.tensor([[0.0, 0.0, 1.0]], dtype=torch.float64)).tolist()
        [[2.0, 2.0, 2.0]]
    """

    kind = "environment"

    def __init__(self, radiance, scale: float = 1.0, to_world=None, name: str = "", where: str | None = None):
        t = torch.as_tensor(np.ascontiguousarray(radiance.detach().cpu() if isinstance(radiance, Tensor) else radiance),
                            dtype=torch.float32)
        if t.dim() != 3 or t.shape[-1] != 3:
            raise InputError(f"an environment map must be RGB [H, W, 3], got shape {tuple(t.shape)}", where=where)
        if t.shape[0] < 3 or t.shape[1] < 2:
            raise InputError(f"an environment map needs at least 3 rows and 2 columns, got {tuple(t.shape[:2])}",
                             where=where, fix="use an equirectangular map (width = 2 x height)")
        if not bool(torch.isfinite(t).all()):
            raise InputError("the environment map holds NaN or infinite radiance", where=where,
                             fix="repair the map (every pixel finite and >= 0)")
        if bool((t < 0).any()):
            raise InputError(f"the environment map holds negative radiance (min {float(t.min()):.3g})",
                             where=where, fix="clamp the map to >= 0")
        s = float(scale)
        if not (math.isfinite(s) and s >= 0):
            raise InputError(f"the environment's scale must be finite and >= 0, got {scale!r}", where=where)
        self.radiance = t.contiguous()
        self.scale = s
        self.to_world = _rigid(to_world, where)
        self.name = str(name)
        h = hashlib.sha256(self.radiance.numpy().tobytes())
        h.update(repr((tuple(t.shape), self.scale, self.to_world)).encode())
        self.digest = h.hexdigest()[:16]
        self._cdf = None

    # ---------------------------------------------------------------- identity
    def __eq__(self, other):
        return isinstance(other, EnvironmentLight) and other.digest == self.digest

    def __hash__(self):
        return hash(("environment", self.digest))

    def __repr__(self):
        h, w, _ = self.radiance.shape
        return f"EnvironmentLight({self.name or 'map'} {w}x{h}, scale={self.scale:g})"

    @classmethod
    def from_file(cls, path, scale: float = 1.0, to_world=None) -> "EnvironmentLight":
        """Read an equirectangular HDR map (OpenEXR, or Radiance ``.hdr``) as linear RGB."""
        p = Path(path)
        if not p.is_file():
            raise InputError("environment map not found", where=str(p), fix="give the path of an .exr or .hdr file")
        head = p.read_bytes()[:16]
        if head.startswith(b"#?"):                          # Radiance RGBE
            import cv2
            a = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
            if a is None or a.ndim != 3:
                raise InputError("could not read the Radiance HDR environment map", where=str(p))
            a = np.ascontiguousarray(a[..., 2::-1], dtype=np.float32)
        elif head[:4] == b"\x76\x2f\x31\x01":                # OpenEXR magic
            from ..io import read_image
            a = read_image(p)
        else:
            raise InputError("the environment map is not an HDR image (OpenEXR or Radiance .hdr)", where=str(p),
                             fix="convert the map to linear OpenEXR")
        return cls(a, scale, to_world, name=p.name, where=str(p))

    # ---------------------------------------------------------------- directions and look-up
    def _rotation(self, dtype=torch.float64) -> Tensor:
        return torch.tensor(self.to_world, dtype=dtype)[:3, :3]

    def to_uv(self, d: Tensor) -> Tensor:
        """``(u, v)`` in ``[0, 1)^2`` of world directions ``d [..., 3]`` (unit)."""
        loc = d.to(torch.float64) @ self._rotation()          # R^T d, row-vector form
        u = torch.atan2(loc[..., 0], -loc[..., 2]) / (2 * math.pi)
        u = u - torch.floor(u)
        v = torch.acos(loc[..., 1].clamp(-1.0, 1.0)) / math.pi
        return torch.stack([u, v], -1)

    def from_uv(self, uv: Tensor) -> Tensor:
        """World directions ``[..., 3]`` of ``(u, v)``; the inverse of :meth:`to_uv`."""
        th, ph = uv[..., 1] * math.pi, uv[..., 0] * 2 * math.pi
        loc = torch.stack([ph.sin() * th.sin(), th.cos(), -ph.cos() * th.sin()], -1)
        return loc @ self._rotation().T

    @property
    def radiance64(self) -> Tensor:
        """The map in float64 (made once per light; the look-ups and the precomputations read it)."""
        m = self.__dict__.get("_radiance64")
        if m is None:
            m = self.__dict__["_radiance64"] = self.radiance.to(torch.float64)
        return m

    def eval(self, d: Tensor) -> Tensor:
        """Radiance ``[..., 3]`` (float64) arriving from world directions ``d [..., 3]`` (Mitsuba's look-up)."""
        return self.eval_uv(self.to_uv(d))

    def eval_uv(self, uv: Tensor) -> Tensor:
        """:meth:`eval` at map coordinates ``uv [..., 2]`` (those of :meth:`to_uv`)."""
        h, w, _ = self.radiance.shape
        x = uv[..., 0] * w - 0.5
        y = uv[..., 1] * (h - 1)
        x0 = torch.floor(x)
        fx = x - x0
        y0 = torch.floor(y).clamp(max=h - 2)
        fy = y - y0
        x0 = x0.long() % w
        x1 = (x0 + 1) % w
        y0 = y0.long()
        r0, r1 = y0 * w, (y0 + 1) * w
        # the four texels in one gather from the flattened map (index_select: about 3x advanced indexing)
        c = self.radiance64.reshape(h * w, 3).index_select(0, torch.stack([r0 + x0, r0 + x1, r1 + x0, r1 + x1]).reshape(-1))
        c = c.reshape(4, *uv.shape[:-1], 3)
        out = (c[0] * ((1 - fx) * (1 - fy))[..., None] + c[1] * (fx * (1 - fy))[..., None]
               + c[2] * ((1 - fx) * fy)[..., None] + c[3] * (fx * fy)[..., None])
        return out * self.scale

    # ---------------------------------------------------------------- sampling
    def _distribution(self):
        if self._cdf is None:
            h, w, _ = self.radiance.shape
            lum = (self.radiance64 * torch.tensor(LUMINANCE, dtype=torch.float64)).sum(-1)
            cell = 0.25 * (lum[:-1] + lum[1:]).unsqueeze(-1)            # rows j, j+1 -> cell row j
            cell = torch.cat([cell[..., 0], cell[..., 0][:, :1]], 1)      # columns periodic
            cell = (cell[:, :-1] + cell[:, 1:])                            # [H-1, W] average of 4 corners (x2)
            theta = (torch.arange(h - 1, dtype=torch.float64) + 0.5) / (h - 1) * math.pi
            wgt = cell * theta.sin()[:, None]
            wgt = wgt + 1e-3 * float(wgt.mean()) + 1e-30                  # never zero: every direction samplable
            p = (wgt / wgt.sum()).reshape(-1)
            self._cdf = (p, torch.cumsum(p, 0))
        return self._cdf

    def sample(self, n: int, generator: torch.Generator | None = None, u: Tensor | None = None):
        """``n`` world directions ``[n, 3]`` and their solid-angle densities ``[n]`` (float64); ``u [n, 3]`` in
        ``[0, 1)`` instead of fresh uniforms (column 0 picks the cell, 1-2 the point inside it)."""
        h, w, _ = self.radiance.shape
        p, cdf = self._distribution()
        if u is None:
            u = torch.rand(n, 3, generator=generator, dtype=torch.float64)
        idx = torch.searchsorted(cdf, u[:, 0].contiguous() * cdf[-1]).clamp(max=p.numel() - 1)
        row, col = idx // w, idx % w
        uv = torch.stack([(col + u[:, 1]) / w, (row + u[:, 2]) / (h - 1)], -1)
        d = self.from_uv(uv)
        return d, self._pdf_uv(uv, p)

    def _pdf_uv(self, uv: Tensor, p: Tensor) -> Tensor:
        h, w, _ = self.radiance.shape
        col = (uv[..., 0] * w).long().clamp(0, w - 1)
        row = (uv[..., 1] * (h - 1)).long().clamp(0, h - 2)
        sin_t = (uv[..., 1] * math.pi).sin().clamp_min(1e-12)
        return p[row * w + col] * (w * (h - 1)) / (2 * math.pi ** 2 * sin_t)

    def pdf(self, d: Tensor) -> Tensor:
        """Solid-angle density ``[...]`` of :meth:`sample` at world directions ``d [..., 3]``."""
        p, _ = self._distribution()
        return self._pdf_uv(self.to_uv(d), p)

    # ---------------------------------------------------------------- saving
    def to_dict(self) -> dict:
        """A JSON-able description (the map itself is saved as a tensor under :attr:`digest`)."""
        return {"type": "environment", "digest": self.digest, "scale": self.scale,
                "to_world": [list(r) for r in self.to_world], "name": self.name}
