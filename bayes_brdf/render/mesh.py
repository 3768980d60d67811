"""Triangle meshes with texture coordinates: the geometry of captured objects.

Conventions
-----------
* **World**: z is up, right-handed; lengths are in the scene's unit (cm for
  real captures). :meth:`Mesh.load` converts a file's unit (``units=``) and up
  axis (``up=``) into that frame.
* **Faces** are counter-clockwise seen from outside: the geometric normal of
  face ``(a, b, c)`` is ``(b - a) x (c - a)`` (right-hand rule) and points out.
* **Normals** are unit per-vertex shading normals (from the file when it has
  sane ones, else area-weighted face normals, or analytic for built-in shapes).
  They decide a face's side in rendering: a face wound against its vertex
  normals (common in scans and exports) is shaded as the normals say
  (:mod:`.raycast`).
* **Texture** coordinates are per-vertex ``uv`` in ``[0, 1]``, OBJ convention:
  ``u`` runs along texture columns, ``v`` points *up*, so texture image row 0
  is at ``v = 1``. :meth:`Mesh.grid_coords` maps ``uv`` to ``grid_sample``
  coordinates (``x = 2u - 1``, ``y = 1 - 2v``) for use with
  ``align_corners=False``: texel ``(i, j)`` of an ``H x W`` map covers
  ``u in [j/W, (j+1)/W]``, ``v in [1 - (i+1)/H, 1 - i/H]``.
  Vertices are duplicated where uv (or normals) are discontinuous (uv seams,
  the sphere's ``u = 0 / 1`` seam, creases), so a seam is two vertices at the
  same position.
* **Identity**: two meshes are equal (and hash equal) when their vertices,
  faces, uv and normals are bitwise equal (:attr:`Mesh.digest`); ``name`` and
  ``meta`` are provenance only. A mesh is immutable (its arrays are
  read-only), so it can key a G-buffer cache.

This module holds the type: its checks, identity, geometry, state and the
geometry protocol (:meth:`Mesh.intersect`, :meth:`Mesh.occluded`, by
:mod:`.raycast`). Files and uv atlases are :mod:`.mesh_io`'s (:meth:`Mesh.load`,
:meth:`Mesh.with_atlas` and :meth:`Mesh.to_trimesh` call it; :data:`UNITS` and
:data:`UP_AXES` are its tables, importable from here too), the built-in shapes
:mod:`.shapes`' (:meth:`Mesh.plane`, :meth:`Mesh.sphere`, :meth:`Mesh.bowl`,
:meth:`Mesh.block_on_plane`).

Example:
    >>> m = Mesh.plane(2.0)
    >>> m.num_vertices, m.num_faces, m.bounds[1].tolist()
    (4, 2, [1.0, 1.0, 0.0])
"""
from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
import torch

from ..errors import InputError
from . import mesh_io
from .mesh_io import UNITS, UP_AXES

__all__ = ["Mesh", "UNITS", "UP_AXES"]

_STATE_FORMAT = "bayes-brdf-mesh/1"
_TENSORS = ("vertices", "faces", "uv", "normals")


@dataclass(frozen=True, eq=False)
class Mesh:
    """An immutable triangle mesh with per-vertex uv and shading normals (see the module docstring).

    Arrays are stored as read-only copies: ``vertices`` float64 ``[N, 3]``,
    ``faces`` int64 ``[F, 3]`` (counter-clockwise seen from outside), ``uv``
    float64 ``[N, 2]`` in ``[0, 1]``, ``normals`` float64 ``[N, 3]`` (unit;
    renormalised on construction). ``meta`` must be JSON-able (it is stored as
    its JSON form: tuples become lists).

    Example:
        >>> import numpy as np
        >>> m = Mesh(vertices=[[0, 0, 0], [1, 0, 0], [0, 1, 0]], faces=[[0, 1, 2]],
        ...          uv=[[0, 0], [1, 0], [0, 1]], normals=[[0, 0, 1]] * 3, name="tri")
        >>> m.faces.dtype, m.vertices.flags.writeable, m == Mesh.from_state(*m.to_state())
        (dtype('int64'), False, True)
    """

    vertices: np.ndarray
    faces: np.ndarray
    uv: np.ndarray
    normals: np.ndarray
    name: str = "mesh"
    meta: dict = field(default_factory=dict)

    def __post_init__(self):
        where = f"mesh '{self.name}'"
        arrays = {}
        for key, dtype, width in (("vertices", np.float64, 3), ("faces", np.int64, 3),
                                  ("uv", np.float64, 2), ("normals", np.float64, 3)):
            value = getattr(self, key)
            if value is None:
                raise InputError(f"{key} missing", where=where,
                                 fix=f"give {key} as an [N, {width}] array" if key != "uv" else
                                 "give per-vertex uv, or build the mesh with Mesh.load (which makes an atlas)")
            if isinstance(value, torch.Tensor):
                value = value.detach().cpu().numpy()
            try:
                raw = np.asarray(value)
                if key == "faces" and raw.size and not np.issubdtype(raw.dtype, np.integer):
                    if not np.all(np.isfinite(raw)) or np.any(raw != np.round(raw)):
                        raise ValueError("non-integer face indices")
                a = np.array(raw, dtype=dtype, copy=True, order="C")
            except (TypeError, ValueError) as e:
                raise InputError(f"{key} is not a numeric array ({e})", where=where,
                                 fix=f"give {key} as an [N, {width}] array") from None
            if a.ndim != 2 or a.shape[1] != width:
                raise InputError(f"{key} has shape {tuple(a.shape)}, expected [*, {width}]", where=where,
                                 fix=f"give {key} as an [N, {width}] array")
            if not np.all(np.isfinite(a)):
                raise InputError(f"{key} has non-finite values", where=where, fix="remove NaN/inf entries")
            arrays[key] = a
        v, f, uv, n = (arrays[k] for k in _TENSORS)
        if len(v) == 0 or len(f) == 0:
            raise InputError(f"mesh has {len(v)} vertices and {len(f)} faces", where=where,
                             fix="give at least one triangle")
        if f.min() < 0 or f.max() >= len(v):
            raise InputError(f"face indices span [{f.min()}, {f.max()}] but there are {len(v)} vertices",
                             where=where, fix="index vertices from 0 to N-1")
        if len(uv) != len(v) or len(n) != len(v):
            raise InputError(f"{len(v)} vertices but {len(uv)} uv and {len(n)} normals", where=where,
                             fix="give one uv and one normal per vertex")
        if uv.min() < -1e-6 or uv.max() > 1 + 1e-6:
            raise InputError(f"uv spans [{uv.min():.4g}, {uv.max():.4g}], outside [0, 1]", where=where,
                             fix="pack the uv into [0, 1] (Mesh.with_atlas makes a fresh atlas)")
        np.clip(uv, 0.0, 1.0, out=uv)
        norm = np.linalg.norm(n, axis=1)
        if np.any(norm < 1e-12):
            raise InputError(f"{int(np.sum(norm < 1e-12))} zero-length normals", where=where,
                             fix="give unit vertex normals")
        off = np.abs(norm - 1.0) > 1e-12   # renormalise only what is off, so a round trip is exact
        n[off] /= norm[off, None]
        try:
            meta = json.loads(json.dumps(dict(self.meta)))
        except (TypeError, ValueError) as e:
            raise InputError(f"meta is not JSON-able ({e})", where=where,
                             fix="keep meta to str/number/bool/list/dict values") from None
        for key, a in zip(_TENSORS, (v, f, uv, n)):
            a.setflags(write=False)
            object.__setattr__(self, key, a)
        object.__setattr__(self, "name", str(self.name))
        object.__setattr__(self, "meta", meta)

    # ------------------------------------------------------------------ identity
    @cached_property
    def digest(self) -> str:
        """SHA-256 (hex) of vertices, faces, uv and normals (dtypes, shapes and bytes).

        Example:
            >>> Mesh.plane(2.0).digest == Mesh.plane(2.0).digest != Mesh.plane(3.0).digest
            True
        """
        h = hashlib.sha256(_STATE_FORMAT.encode())
        for key in _TENSORS:
            a = getattr(self, key)
            h.update(f"{key}:{a.dtype.str}:{a.shape}".encode())
            h.update(a.tobytes())
        return h.hexdigest()

    def __eq__(self, other):
        if not isinstance(other, Mesh):
            return NotImplemented
        return self is other or self.digest == other.digest

    def __hash__(self):
        return hash(self.digest)

    def __repr__(self):
        return (f"Mesh(name={self.name!r}, vertices={self.num_vertices}, faces={self.num_faces}, "
                f"digest={self.digest[:12]})")

    # ------------------------------------------------------------------ geometry
    @property
    def num_vertices(self) -> int:
        """Number of vertices (seams count twice).

        Example:
            >>> Mesh.plane().num_vertices
            4
        """
        return int(len(self.vertices))

    @property
    def num_faces(self) -> int:
        """Number of triangles.

        Example:
            >>> Mesh.plane(2.0).num_faces
            2
        """
        return int(len(self.faces))

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Axis-aligned bounding box ``(min[3], max[3])`` of the vertices.

        Example:
            >>> [b.tolist() for b in Mesh.sphere(2.0, rings=4, segments=8).bounds]
            [[-2.0, -2.0, -2.0], [2.0, 2.0, 2.0]]
        """
        return self.vertices.min(axis=0), self.vertices.max(axis=0)

    @cached_property
    def face_normals(self) -> np.ndarray:
        """Unit geometric face normals ``[F, 3]`` by the right-hand rule (zero for degenerate faces).

        Example:
            >>> Mesh.plane().face_normals.tolist()
            [[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]]
        """
        tri = self.vertices[self.faces]
        fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        norm = np.linalg.norm(fn, axis=1, keepdims=True)
        fn = np.divide(fn, norm, out=np.zeros_like(fn), where=norm > 0)
        fn.setflags(write=False)
        return fn

    @staticmethod
    def grid_coords(uv):
        """``grid_sample`` coordinates of uv ``[..., 2]``: ``x = 2u - 1``, ``y = 1 - 2v`` (``align_corners=False``).

        A tensor gives a tensor, anything else a numpy array.

        Example:
            >>> Mesh.grid_coords(torch.tensor([[0.0, 1.0], [0.5, 0.25]])).tolist()
            [[-1.0, -1.0], [0.0, 0.5]]
        """
        if isinstance(uv, torch.Tensor):
            return torch.stack([2 * uv[..., 0] - 1, 1 - 2 * uv[..., 1]], dim=-1)
        uv = np.asarray(uv, dtype=np.float64)
        return np.stack([2 * uv[..., 0] - 1, 1 - 2 * uv[..., 1]], axis=-1)

    def to_trimesh(self):
        """A ``trimesh.Trimesh`` view of this mesh (unprocessed: same vertices, faces, normals, uv):
        :func:`.mesh_io.to_trimesh`.

        Example:
            >>> float(Mesh.plane().to_trimesh().area)
            4.0
        """
        return mesh_io.to_trimesh(self)

    # ------------------------------------------------------------------ geometry protocol
    def intersect(self, cameras):
        """Where each pixel of ``cameras`` (perspective, one resolution) meets the mesh: Mitsuba ray casting
        (:func:`bayes_brdf.render.raycast.intersect`), a :class:`~bayes_brdf.render.hits.SurfaceHits`."""
        from .raycast import intersect
        return intersect(self, cameras)

    def occluded(self, hits, light_positions):
        """``[V, L, H, W]`` bool shadow tests of the hits towards ``light_positions [V, L, 3]`` (shadow rays)."""
        from .raycast import occluded
        return occluded(self, hits, light_positions)

    def occluded_directions(self, points, normals, directions):
        """``[N]`` bool: whether rays from ``points [N, 3]`` along ``directions [N, 3]`` meet the mesh (towards an
        environment; :func:`bayes_brdf.render.raycast.occluded_directions`)."""
        from .raycast import occluded_directions
        return occluded_directions(self, points, normals, directions)

    @property
    def center(self) -> tuple[float, float, float]:
        """Centre of the bounding box (the point view directions are measured from).

        Example:
            >>> Mesh.sphere(center=(1, 2, 3)).center
            (1.0, 2.0, 3.0)
        """
        lo, hi = self.bounds
        return tuple(float(x) for x in (lo + hi) / 2)

    @property
    def radius(self) -> float:
        """Radius of the sphere about :attr:`center` that holds every vertex.

        Example:
            >>> round(Mesh.sphere(2.0).radius, 6)
            2.0
        """
        return float(np.linalg.norm(self.vertices - np.asarray(self.center), axis=1).max())

    def state(self) -> tuple[dict, dict[str, torch.Tensor]]:
        """:meth:`to_state` with ``"type": "mesh"``: the geometry protocol's form (see :mod:`bayes_brdf.render.scene`)."""
        meta, tensors = self.to_state()
        return {"type": "mesh", **meta}, tensors

    # ------------------------------------------------------------------ state
    def to_state(self) -> tuple[dict, dict[str, torch.Tensor]]:
        """``(meta, tensors)`` for a safetensors file: JSON-able metadata and four CPU tensors.

        :meth:`from_state` inverts it exactly (same digest, name and meta).

        Example:
            >>> meta, tensors = Mesh.plane().to_state()
            >>> meta["name"], sorted(tensors), tensors["faces"].dtype
            ('plane', ['faces', 'normals', 'uv', 'vertices'], torch.int64)
        """
        meta = {"format": _STATE_FORMAT, "name": self.name, "meta": json.loads(json.dumps(self.meta))}
        tensors = {k: torch.from_numpy(np.array(getattr(self, k))) for k in _TENSORS}
        return meta, tensors

    @classmethod
    def from_state(cls, meta: dict, tensors: dict) -> "Mesh":
        """Rebuild a mesh from :meth:`to_state` output.

        Example:
            >>> m = Mesh.sphere(rings=4, segments=8)
            >>> Mesh.from_state(*m.to_state()).digest == m.digest
            True
        """
        if not isinstance(meta, dict) or meta.get("format") != _STATE_FORMAT:
            got = meta.get("format") if isinstance(meta, dict) else type(meta).__name__
            raise InputError(f"mesh state has format {got!r}, expected {_STATE_FORMAT!r}", where="mesh state",
                             fix="pass the (meta, tensors) pair written by Mesh.to_state")
        missing = [k for k in _TENSORS if k not in tensors]
        if missing:
            raise InputError(f"mesh state lacks tensors {missing}", where="mesh state",
                             fix="pass the (meta, tensors) pair written by Mesh.to_state")
        return cls(**{k: tensors[k] for k in _TENSORS}, name=meta.get("name", "mesh"), meta=meta.get("meta", {}))

    # ------------------------------------------------------------------ atlas and files (mesh_io)
    def with_atlas(self, resolution: int = 256, padding: int = 2) -> "Mesh":
        """The same surface with a fresh xatlas uv atlas packed for a ``resolution`` square texture, at least
        ``padding`` texels between charts: :func:`.mesh_io.with_atlas`.

        Example:
            >>> m = Mesh.sphere(rings=6, segments=12).with_atlas(64, 1)
            >>> m.num_faces, m.meta["atlas"]["resolution"], float(m.uv.max()) <= 1
            (120, 64, True)
        """
        return mesh_io.with_atlas(self, resolution, padding)

    @classmethod
    def load(cls, path, *, units: str | None = None, scene_units: str = "cm", up: str = "z",
             atlas_resolution: int = 256, atlas_padding: int = 2, uv: str = "auto",
             name: str | None = None) -> "Mesh":
        """Read an OBJ, PLY or GLB/glTF file (anything ``trimesh`` reads) into the world frame, converting
        its ``units`` to ``scene_units`` and its ``up`` axis to +z, keeping its uv (``uv="auto"``, ``"file"``
        or ``"atlas"``) and normals: :func:`.mesh_io.load_mesh`, which documents the arguments.

        Example:
            >>> Mesh.load("no/such/file.obj")
            Traceback (most recent call last):
            ...
            bayes_brdf.errors.InputError: no/such/file.obj: mesh file not found; check the path
        """
        return mesh_io.load_mesh(path, units=units, scene_units=scene_units, up=up,
                                 atlas_resolution=atlas_resolution, atlas_padding=atlas_padding, uv=uv,
                                 name=name, cls=cls)

    # ------------------------------------------------------------------ built-in shapes (shapes)
    @classmethod
    def plane(cls, size: float = 2.0, grid: str = "centers") -> "Mesh":
        """The flat sample of :class:`~bayes_brdf.render.surface.PlanarSample` as two triangles (square of side
        ``size`` on ``z = 0``, normal ``+z``): :func:`.shapes.plane`.

        Example:
            >>> Mesh.plane(2.0).num_faces
            2
        """
        from . import shapes
        return shapes.plane(size, grid)

    @classmethod
    def sphere(cls, radius: float = 1.0, center=(0.0, 0.0, 0.0), rings: int = 64, segments: int = 128) -> "Mesh":
        """A UV sphere with lat-long uv and radial normals: :func:`.shapes.sphere`.

        Example:
            >>> Mesh.sphere(1.0, rings=4, segments=8).num_faces
            48
        """
        from . import shapes
        return shapes.sphere(radius, center, rings, segments)

    @classmethod
    def bowl(cls, radius: float = 1.0, depth: float = 0.5, thickness: float = 0.05, rings: int = 32,
             segments: int = 96) -> "Mesh":
        """A closed parabolic bowl of revolution about ``+z``, resting on ``z = 0``, opening upward:
        :func:`.shapes.bowl`.

        Example:
            >>> Mesh.bowl(rings=4, segments=8).num_faces
            128
        """
        from . import shapes
        return shapes.bowl(radius, depth, thickness, rings, segments)

    @classmethod
    def block_on_plane(cls, size: float = 2.0, block=(0.5, 0.5, 0.5)) -> "Mesh":
        """A ground square of side ``size`` on ``z = 0`` with a box of extents ``block`` standing at its centre:
        :func:`.shapes.block_on_plane`.

        Example:
            >>> Mesh.block_on_plane(2.0, (0.5, 0.5, 1.0)).num_faces
            12
        """
        from . import shapes
        return shapes.block_on_plane(size, block)
