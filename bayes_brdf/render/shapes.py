"""The built-in shapes, all with uv and analytic (or flat) normals: test scenes and synthetic captures.

Each is also a :class:`~bayes_brdf.render.mesh.Mesh` classmethod (``Mesh.sphere()`` is
:func:`sphere`): :func:`plane` (the planar sample as two triangles), :func:`sphere` (lat-long uv),
:func:`bowl` (a closed shell of revolution that shadows its inside) and :func:`block_on_plane` (a box
on a ground square). They are built from quads and surfaces of revolution, faces counter-clockwise seen
from outside, as every mesh's.

Example:
    >>> sphere(rings=4, segments=8) == Mesh.sphere(rings=4, segments=8)
    True
"""
from __future__ import annotations

import math

import numpy as np

from .. import checks
from ..errors import InputError
from .mesh import Mesh


def plane(size: float = 2.0, grid: str = "centers") -> Mesh:
    """The flat sample of :class:`~bayes_brdf.render.surface.PlanarSample` as two triangles.

    The square of side ``size`` centred at the origin on ``z = 0``, normal
    ``+z``, ``u = x/size + 0.5``, ``v = y/size + 0.5``: texture row 0 is at
    ``+y``, so :meth:`Mesh.grid_coords` of the uv equals
    ``PlanarSample(size).texture_coords`` (``align_corners=False``). Only
    the ``"centers"`` texel grid can be represented by uv.

    Example:
        >>> m = plane(2.0)
        >>> m.num_faces, m.uv[m.vertices[:, 0].argmax()].tolist()
        (2, [1.0, 0.0])
    """
    if grid != "centers":
        raise InputError(f"a mesh cannot represent the {grid!r} texel grid", where="Mesh.plane(grid=...)",
                         fix="use grid='centers' (uv sample with align_corners=False), "
                             "or PlanarSample for 'endpoints'")
    size = checks.positive(size, "size", where="Mesh.plane(size=...)")
    h = size / 2
    b = _Builder()
    b.quad((0, 0, 0), (h, 0, 0), (0, h, 0), (0.0, 0.0, 1.0, 1.0))
    return b.mesh("plane", {"shape": "plane", "size": size, "grid": grid})


def sphere(radius: float = 1.0, center=(0.0, 0.0, 0.0), rings: int = 64, segments: int = 128) -> Mesh:
    """A UV sphere with lat-long uv and radial normals.

    ``u = phi / 2pi`` with ``phi = atan2(y, x)`` in ``[0, 2pi)`` (the seam
    column is duplicated at ``u = 1``), ``v = 1 - theta / pi`` with
    ``theta`` the polar angle from ``+z``. ``rings`` bands in theta,
    ``segments`` in phi; each pole is ``segments`` coincident vertices at
    ``u = (j + 0.5) / segments``, one per fan triangle (no degenerate
    triangles). ``2 * segments * (rings - 1)`` faces.

    Example:
        >>> m = sphere(1.0, rings=4, segments=8)
        >>> m.num_faces, bool(np.allclose(np.linalg.norm(m.vertices, axis=1), 1))
        (48, True)
    """
    radius = checks.positive(radius, "radius", where="Mesh.sphere(radius=...)")
    rings, segments = _count(rings, 2, "rings"), _count(segments, 3, "segments")
    c = np.array(checks.vec3(center, "center", where="Mesh.sphere(center=...)", fix="e.g. (0, 0, 0)"))
    theta = np.pi * np.arange(rings + 1) / rings
    r, z = np.sin(theta), np.cos(theta)
    r[[0, -1]] = 0.0
    b = _Builder()
    b.revolve(radius * r, radius * z, r, z, 1 - theta / np.pi, segments)
    b.offset(c)
    return b.mesh("sphere", {"shape": "sphere", "radius": radius, "center": c.tolist(),
                             "rings": rings, "segments": segments})


def bowl(radius: float = 1.0, depth: float = 0.5, thickness: float = 0.05, rings: int = 32,
         segments: int = 96) -> Mesh:
    """A closed parabolic bowl of revolution about ``+z``, resting on ``z = 0``, opening upward.

    Outer surface ``z = (depth + thickness) (r / radius)^2`` (lowest point at
    the origin), inner surface ``z = thickness + depth (r / (radius - thickness))^2``
    (the cavity is ``depth`` deep), joined by a flat rim annulus at
    ``z = depth + thickness`` between ``radius - thickness`` and ``radius``.
    Normals are analytic and point out of the shell (into the cavity on the
    inner surface). uv: ``u = phi / 2pi``; ``v`` runs by arc length along
    the profile from the inner centre (``v = 1``) over the rim to the outer
    bottom (``v = 0``), so the inner surface takes the top of the texture.
    The inside shadows itself at grazing light (non-convex). Vertices are
    duplicated at the rim creases (same uv, different normals).

    Example:
        >>> m = bowl(rings=4, segments=8)
        >>> m.num_faces, [round(float(x), 6) for x in m.bounds[1]]
        (128, [1.0, 1.0, 0.55])
    """
    radius = checks.positive(radius, "radius", where="Mesh.bowl(radius=...)")
    depth = checks.positive(depth, "depth", where="Mesh.bowl(depth=...)")
    t = checks.positive(thickness, "thickness", where="Mesh.bowl(thickness=...)")
    if t >= radius:
        raise InputError(f"thickness {t} must be below radius {radius}", where="Mesh.bowl(thickness=...)",
                         fix="use a thinner wall")
    rings, segments = _count(rings, 1, "rings"), _count(segments, 3, "segments")
    s = np.arange(rings + 1) / rings
    a_out, ri = (depth + t) / radius**2, radius - t
    a_in = depth / ri**2
    # inner: centre -> rim (normals up and toward the axis)
    r1, z1 = ri * s, t + a_in * (ri * s) ** 2
    n1 = np.stack([-2 * a_in * r1, np.ones_like(r1)])
    # rim annulus (normal +z)
    r2, z2 = np.array([ri, radius]), np.full(2, depth + t)
    n2 = np.array([[0.0, 0.0], [1.0, 1.0]])
    # outer: rim -> bottom (normals outward and down)
    r3 = radius * s[::-1]
    z3 = a_out * r3**2
    n3 = np.stack([2 * a_out * r3, -np.ones_like(r3)])
    rs, zs = np.concatenate([r1, r2, r3]), np.concatenate([z1, z2, z3])
    arc = np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(rs), np.diff(zs)))])
    v = 1 - arc / arc[-1]
    b = _Builder()
    k = 0
    for r_, z_, n_ in ((r1, z1, n1), (r2, z2, n2), (r3, z3, n3)):
        nrm = n_ / np.linalg.norm(n_, axis=0)
        b.revolve(r_, z_, nrm[0], nrm[1], v[k:k + len(r_)], segments)
        k += len(r_)
    return b.mesh("bowl", {"shape": "bowl", "radius": radius, "depth": depth, "thickness": t,
                           "rings": rings, "segments": segments, "rests_on": "z=0"})


def block_on_plane(size: float = 2.0, block=(0.5, 0.5, 0.5)) -> Mesh:
    """A ground square of side ``size`` on ``z = 0`` with a box standing at its centre.

    The box spans ``|x| <= bx/2``, ``|y| <= by/2``, ``0 <= z <= bz`` for
    ``block = (bx, by, bz)``; it has five faces (no bottom) and sits on the
    ground quad (which runs under it). All faces point out, each face
    is its own quad (flat normals). A light low on one side shadows the
    ground behind the box. 12 triangles.

    uv, a hand layout on a 3 x 3 grid of cells (each inset by 1/96): the
    ground takes the top-left 2 x 2 cells (``u`` along ``+x``, ``v`` along
    ``+y``, as :func:`plane`); the box top (+z) is the top-right cell; the
    +x side is the middle-right cell; the -x, +y, -y sides are the bottom
    row left to right. Side faces have ``v`` up (+z) and ``u`` such that
    the uv is not mirrored.

    Example:
        >>> m = block_on_plane(2.0, (0.5, 0.5, 1.0))
        >>> m.num_faces, m.bounds[1].tolist()
        (12, [1.0, 1.0, 1.0])
    """
    size = checks.positive(size, "size", where="Mesh.block_on_plane(size=...)")
    try:
        bx, by, bz = (float(x) for x in block)
    except (TypeError, ValueError):
        raise InputError(f"block must be three extents (x, y, z), got {block!r}",
                         where="Mesh.block_on_plane(block=...)", fix="e.g. block=(0.5, 0.5, 0.5)") from None
    if not all(math.isfinite(x) and x > 0 for x in (bx, by, bz)) or bx >= size or by >= size:
        raise InputError(f"block {block!r} must be positive and fit on the ground of side {size}",
                         where="Mesh.block_on_plane(block=...)", fix="use extents > 0 and below size")
    c, m = 1.0 / 3.0, 1.0 / 96.0

    def cell(col, row, w=1, h=1):  # row 0 is the top row (v near 1)
        return (col * c + m, 1 - (row + h) * c + m, (col + w) * c - m, 1 - row * c - m)

    hx, hy, hz = bx / 2, by / 2, bz / 2
    b = _Builder()
    b.quad((0, 0, 0), (size / 2, 0, 0), (0, size / 2, 0), cell(0, 0, 2, 2))   # ground
    b.quad((0, 0, bz), (hx, 0, 0), (0, hy, 0), cell(2, 0))                    # top, +z
    b.quad((hx, 0, hz), (0, hy, 0), (0, 0, hz), cell(2, 1))                   # +x
    b.quad((-hx, 0, hz), (0, -hy, 0), (0, 0, hz), cell(0, 2))                 # -x
    b.quad((0, hy, hz), (-hx, 0, 0), (0, 0, hz), cell(1, 2))                  # +y
    b.quad((0, -hy, hz), (hx, 0, 0), (0, 0, hz), cell(2, 2))                  # -y
    return b.mesh("block_on_plane", {"shape": "block_on_plane", "size": size, "block": [bx, by, bz]})


# ---------------------------------------------------------------------- helpers
def _count(n, least: int, what: str) -> int:
    return checks.count(n, what, least=least, where=f"{what}=", fix=f"use {what} >= {least}")


class _Builder:
    """Accumulates vertices/uv/normals/faces for the built-in shapes."""

    def __init__(self):
        self.v, self.uv, self.n, self.f, self.count = [], [], [], [], 0

    def add(self, v, uv, n, f):
        self.v.append(np.asarray(v, float))
        self.uv.append(np.asarray(uv, float))
        self.n.append(np.asarray(n, float))
        self.f.append(np.asarray(f, np.int64) + self.count)
        self.count += len(self.v[-1])

    def quad(self, center, right, up, rect):
        """Quad ``center -+ right -+ up`` (outward normal ``right x up``), uv rect ``(u0, v0, u1, v1)``."""
        c, r, u = (np.asarray(x, float) for x in (center, right, up))
        v = np.stack([c - r - u, c + r - u, c + r + u, c - r + u])
        u0, v0, u1, v1 = rect
        uv = [(u0, v0), (u1, v0), (u1, v1), (u0, v1)]
        n = np.cross(r, u)
        n = np.tile(n / np.linalg.norm(n), (4, 1))
        self.add(v, uv, n, [[0, 1, 2], [0, 2, 3]])

    def revolve(self, r, z, nr, nz, v, segments):
        """Surface of revolution of a profile ``(r_k, z_k)`` about +z; normals ``(nr, nz)`` in the r-z plane.

        The outward side is to the right of the direction of travel (normal
        ``(-dz, dr)``). Profile ends on the axis (``r = 0``) become fans with one
        pole vertex per segment.
        """
        r, z, nr, nz, v = (np.asarray(x, float) for x in (r, z, nr, nz, v))
        K = len(r) - 1
        j = np.arange(segments + 1)
        phi = 2 * np.pi * j / segments
        cos, sin = np.cos(phi), np.sin(phi)
        cos[-1], sin[-1] = 1.0, 0.0  # exact seam
        verts, uvs, nrms, index = [], [], [], []
        count = 0
        for k in range(K + 1):
            if r[k] == 0:
                uc = (np.arange(segments) + 0.5) / segments
                pos = np.tile([0.0, 0.0, z[k]], (segments, 1))
                nn = np.tile([0.0, 0.0, np.sign(nz[k]) or 1.0], (segments, 1))
                uv = np.stack([uc, np.full(segments, v[k])], axis=1)
            else:
                pos = np.stack([r[k] * cos, r[k] * sin, np.full(segments + 1, z[k])], axis=1)
                nn = np.stack([nr[k] * cos, nr[k] * sin, np.full(segments + 1, nz[k])], axis=1)
                uv = np.stack([j / segments, np.full(segments + 1, v[k])], axis=1)
            index.append(count)
            count += len(pos)
            verts.append(pos)
            uvs.append(uv)
            nrms.append(nn)
        faces = []
        s = np.arange(segments)
        for k in range(K):
            a, b = index[k], index[k + 1]
            if r[k] == 0 and r[k + 1] == 0:
                continue
            if r[k] == 0:          # fan from the pole at k
                faces.append(np.stack([a + s, b + s, b + s + 1], axis=1))
            elif r[k + 1] == 0:    # fan into the pole at k + 1
                faces.append(np.stack([a + s, b + s, a + s + 1], axis=1))
            else:
                faces.append(np.stack([a + s, b + s, b + s + 1], axis=1))
                faces.append(np.stack([a + s, b + s + 1, a + s + 1], axis=1))
        self.add(np.concatenate(verts), np.concatenate(uvs), np.concatenate(nrms), np.concatenate(faces))

    def offset(self, c):
        self.v = [x + c for x in self.v]

    def mesh(self, name, meta) -> Mesh:
        return Mesh(np.concatenate(self.v), np.concatenate(self.f), np.concatenate(self.uv),
                    np.concatenate(self.n), name=name, meta=meta)
