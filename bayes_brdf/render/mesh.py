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

When a file has no usable uv, an atlas is made with ``xatlas`` (deterministic:
the same mesh and settings give the same atlas); ``meta["atlas"]`` then records
the resolution and padding it was packed for. xatlas charts are not all
orientation-preserving: about half the charts are mirrored in uv (a face that
is counter-clockwise in 3D can be clockwise in uv), which does not matter for
texture lookup but does for tangent frames.

Example:
    >>> m = Mesh.plane(2.0)
    >>> m.num_vertices, m.num_faces, m.bounds[1].tolist()
    (4, 2, [1.0, 1.0, 0.0])
"""
from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np
import torch

from .. import checks
from ..errors import InputError

#: metres per unit of each length unit a file may be in
UNITS = {"mm": 1e-3, "cm": 1e-2, "m": 1.0, "in": 0.0254, "ft": 0.3048}

#: rotation taking a file's up axis to world +z (proper rotations: handedness kept)
UP_AXES = {
    "z": np.eye(3),
    "y": np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]]),   # (x, y, z) -> (x, -z, y)
    "-y": np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]]),  # (x, y, z) -> (x, z, -y)
    "-z": np.array([[1.0, 0, 0], [0, -1, 0], [0, 0, -1]]),  # (x, y, z) -> (x, -y, -z)
}

_UV_MODES = ("auto", "file", "atlas")
_STATE_FORMAT = "bayes-brdf-mesh/1"
_TENSORS = ("vertices", "faces", "uv", "normals")


def _frozen(a, dtype) -> np.ndarray:
    a = np.array(a, dtype=dtype, copy=True, order="C")
    a.setflags(write=False)
    return a


def _area_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals; a vertex without area gets +z."""
    tri = vertices[faces]
    fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])  # length = 2 * area
    vn = np.zeros_like(vertices)
    for k in range(3):
        np.add.at(vn, faces[:, k], fn)
    norm = np.linalg.norm(vn, axis=1, keepdims=True)
    ok = norm[:, 0] > 1e-300
    vn[ok] /= norm[ok]
    vn[~ok] = (0.0, 0.0, 1.0)
    return vn


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
        """A ``trimesh.Trimesh`` view of this mesh (unprocessed: same vertices, faces, normals, uv).

        Example:
            >>> float(Mesh.plane().to_trimesh().area)
            4.0
        """
        import trimesh
        from trimesh.visual import TextureVisuals

        return trimesh.Trimesh(vertices=np.array(self.vertices), faces=np.array(self.faces),
                               vertex_normals=np.array(self.normals),
                               visual=TextureVisuals(uv=np.array(self.uv)), process=False)

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

    # ------------------------------------------------------------------ atlas
    def with_atlas(self, resolution: int = 256, padding: int = 2) -> "Mesh":
        """The same surface with a fresh xatlas uv atlas packed for a ``resolution`` square texture.

        Charts are separated by at least ``padding`` texels at that resolution
        (plus xatlas's bilinear margin). Vertices are split along chart seams;
        faces keep their order and corners. Deterministic.

        Example:
            >>> m = Mesh.sphere(rings=6, segments=12).with_atlas(64, 1)
            >>> m.num_faces, m.meta["atlas"]["resolution"], float(m.uv.max()) <= 1
            (120, 64, True)
        """
        v, f, uv, atlas = _xatlas(self.vertices, self.faces, resolution, padding, where=f"mesh '{self.name}'")
        meta = {**self.meta, "uv_source": "xatlas", "atlas": atlas}
        return Mesh(self.vertices[v], f, uv, self.normals[v], name=self.name, meta=meta)

    # ------------------------------------------------------------------ files
    @classmethod
    def load(cls, path, *, units: str | None = None, scene_units: str = "cm", up: str = "z",
             atlas_resolution: int = 256, atlas_padding: int = 2, uv: str = "auto",
             name: str | None = None) -> "Mesh":
        """Read an OBJ, PLY or GLB/glTF file (anything ``trimesh`` reads) into the world frame.

        * ``units``: the file's length unit (mm, cm, m, in, ft); ``None`` means
          it already is in ``scene_units`` (no scaling).
        * ``up``: the file's up axis: ``"z"`` (unchanged), ``"y"`` (glTF, most
          OBJ exports: ``(x, y, z) -> (x, -z, y)``), ``"-y"`` or ``"-z"``.
        * ``uv``: ``"auto"`` keeps the file's uv when it has usable ones (one
          set of uv in ``[0, 1]``) and makes an xatlas atlas otherwise;
          ``"file"`` requires the file's uv; ``"atlas"`` always makes an atlas.
          A scene of several parts with different materials overlaps in uv,
          so it gets an atlas under ``"auto"``.
        * Normals come from the file when it has finite non-zero ones, else
          area-weighted face normals. Unreferenced vertices are dropped; faces
          keep their order.

        ``meta`` records the source path and its SHA-256, file and scene units,
        up axis, where uv and normals came from, and the atlas settings.

        Example:
            >>> Mesh.load("no/such/file.obj")
            Traceback (most recent call last):
            ...
            bayes_brdf.errors.InputError: no/such/file.obj: mesh file not found; check the path
        """
        where = str(path)
        p = Path(path)
        if units is not None and units not in UNITS:
            raise InputError(f"unknown length unit {units!r}", where=where,
                             fix=f"use one of {', '.join(UNITS)} (or None when the file is in scene units)")
        if scene_units not in UNITS:
            raise InputError(f"unknown scene unit {scene_units!r}", where=where, fix=f"use one of {', '.join(UNITS)}")
        if up not in UP_AXES:
            raise InputError(f"unknown up axis {up!r}", where=where, fix=f"use one of {', '.join(UP_AXES)}")
        if uv not in _UV_MODES:
            raise InputError(f"unknown uv mode {uv!r}", where=where, fix=f"use one of {', '.join(_UV_MODES)}")
        if not p.is_file():
            raise InputError("mesh file not found", where=where, fix="check the path")
        parts = _read_parts(p, where)
        # concatenate the parts (world positions, file normals where every part has them)
        offsets = np.cumsum([0] + [len(q["vertices"]) for q in parts])
        vertices = np.concatenate([q["vertices"] for q in parts])
        faces = np.concatenate([q["faces"] + o for q, o in zip(parts, offsets)])
        file_normals = (np.concatenate([q["normals"] for q in parts])
                        if all(q["normals"] is not None for q in parts) else None)
        file_uv, uv_note = None, None
        if all(q["uv"] is not None for q in parts):
            if len({q["material"] for q in parts}) > 1:
                uv_note = f"{len(parts)} parts with different materials overlap in uv"
            else:
                file_uv = np.concatenate([q["uv"] for q in parts])
                if not np.all(np.isfinite(file_uv)) or file_uv.min() < -1e-6 or file_uv.max() > 1 + 1e-6:
                    uv_note = "uv outside [0, 1] (a tiled texture)"
                    file_uv = None
        else:
            uv_note = "no uv" if not any(q["uv"] is not None for q in parts) else "some parts lack uv"
        if uv == "file" and file_uv is None:
            raise InputError(f"no usable uv in the file ({uv_note})", where=where,
                             fix="use uv='auto' or uv='atlas' to make an atlas")
        # drop unreferenced vertices (keeps face order)
        used = np.zeros(len(vertices), dtype=bool)
        used[faces.ravel()] = True
        if not used.all():
            remap = np.cumsum(used) - 1
            faces = remap[faces]
            vertices = vertices[used]
            file_normals = None if file_normals is None else file_normals[used]
            file_uv = None if file_uv is None else file_uv[used]
        # world frame: scale to scene units, rotate the up axis to +z
        scale = 1.0 if units is None else UNITS[units] / UNITS[scene_units]
        rot = UP_AXES[up]
        vertices = (vertices @ rot.T) * scale
        normals_source = "faces"
        normals = None
        if file_normals is not None:
            nn = np.linalg.norm(file_normals, axis=1)
            if np.all(np.isfinite(file_normals)) and np.all(nn > 1e-8):
                normals = (file_normals / nn[:, None]) @ rot.T
                normals_source = "file"
        if normals is None:
            normals = _area_normals(vertices, faces)
        try:
            digest = hashlib.sha256(p.read_bytes()).hexdigest()
        except OSError:  # pragma: no cover - it was just read by trimesh
            digest = None
        meta = {"source": where, "source_sha256": digest, "format": p.suffix.lower().lstrip("."),
                "parts": len(parts), "file_units": units, "scene_units": scene_units, "scale": scale,
                "up": up, "normals_source": normals_source}
        mesh_name = name if name is not None else p.stem
        if file_uv is not None and uv != "atlas":
            return cls(vertices, faces, file_uv, normals, name=mesh_name, meta={**meta, "uv_source": "file"})
        if uv == "atlas":
            uv_note = "uv='atlas'"
        vmap, faces, atlas_uv, atlas = _xatlas(vertices, faces, atlas_resolution, atlas_padding, where=where)
        meta = {**meta, "uv_source": "xatlas", "uv_note": uv_note, "atlas": atlas}
        return cls(vertices[vmap], faces, atlas_uv, normals[vmap], name=mesh_name, meta=meta)

    # ------------------------------------------------------------------ built-in shapes
    @classmethod
    def plane(cls, size: float = 2.0, grid: str = "centers") -> "Mesh":
        """The flat sample of :class:`~bayes_brdf.render.surface.PlanarSample` as two triangles.

        The square of side ``size`` centred at the origin on ``z = 0``, normal
        ``+z``, ``u = x/size + 0.5``, ``v = y/size + 0.5``: texture row 0 is at
        ``+y``, so :meth:`grid_coords` of the uv equals
        ``PlanarSample(size).texture_coords`` (``align_corners=False``). Only
        the ``"centers"`` texel grid can be represented by uv.

        Example:
            >>> m = Mesh.plane(2.0)
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

    @classmethod
    def sphere(cls, radius: float = 1.0, center=(0.0, 0.0, 0.0), rings: int = 64, segments: int = 128) -> "Mesh":
        """A UV sphere with lat-long uv and radial normals.

        ``u = phi / 2pi`` with ``phi = atan2(y, x)`` in ``[0, 2pi)`` (the seam
        column is duplicated at ``u = 1``), ``v = 1 - theta / pi`` with
        ``theta`` the polar angle from ``+z``. ``rings`` bands in theta,
        ``segments`` in phi; each pole is ``segments`` coincident vertices at
        ``u = (j + 0.5) / segments``, one per fan triangle (no degenerate
        triangles). ``2 * segments * (rings - 1)`` faces.

        Example:
            >>> m = Mesh.sphere(1.0, rings=4, segments=8)
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

    @classmethod
    def bowl(cls, radius: float = 1.0, depth: float = 0.5, thickness: float = 0.05, rings: int = 32,
             segments: int = 96) -> "Mesh":
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
            >>> m = Mesh.bowl(rings=4, segments=8)
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

    @classmethod
    def block_on_plane(cls, size: float = 2.0, block=(0.5, 0.5, 0.5)) -> "Mesh":
        """A ground square of side ``size`` on ``z = 0`` with a box standing at its centre.

        The box spans ``|x| <= bx/2``, ``|y| <= by/2``, ``0 <= z <= bz`` for
        ``block = (bx, by, bz)``; it has five faces (no bottom) and sits on the
        ground quad (which runs under it). All faces point out, each face
        is its own quad (flat normals). A light low on one side shadows the
        ground behind the box. 12 triangles.

        uv, a hand layout on a 3 x 3 grid of cells (each inset by 1/96): the
        ground takes the top-left 2 x 2 cells (``u`` along ``+x``, ``v`` along
        ``+y``, as :meth:`plane`); the box top (+z) is the top-right cell; the
        +x side is the middle-right cell; the -x, +y, -y sides are the bottom
        row left to right. Side faces have ``v`` up (+z) and ``u`` such that
        the uv is not mirrored.

        Example:
            >>> m = Mesh.block_on_plane(2.0, (0.5, 0.5, 1.0))
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


def _read_parts(p: Path, where: str) -> list[dict]:
    """The triangle parts of a mesh file, each in file coordinates with the scene graph's transform applied."""
    import trimesh

    try:
        loaded = trimesh.load(str(p), process=False)
    except NotImplementedError:
        raise InputError(f"unsupported mesh format '{p.suffix}'", where=where,
                         fix="use .obj, .ply, .glb or .gltf") from None
    except Exception as e:  # trimesh raises many types for unreadable files
        msg = " ".join(str(e).split())[:160] or type(e).__name__
        raise InputError(f"cannot read the mesh file ({msg})", where=where,
                         fix="check that it is a valid OBJ, PLY, GLB or glTF file") from None
    items = []  # (geometry, 4x4 transform)
    if isinstance(loaded, trimesh.Scene):
        for node in loaded.graph.nodes_geometry:
            transform, gname = loaded.graph[node]
            items.append((loaded.geometry[gname], np.asarray(transform, float)))
    else:
        items.append((loaded, np.eye(4)))
    parts, kinds = [], set()
    for g, T in items:
        if not isinstance(g, trimesh.Trimesh):
            kinds.add(type(g).__name__)
            continue
        faces = np.asarray(g.faces, dtype=np.int64).reshape(-1, 3)
        if len(faces) == 0:
            kinds.add("Trimesh without faces")
            continue
        vertices = np.asarray(g.vertices, dtype=np.float64)
        # trimesh keeps normals read from the file in its cache ('vertex_normals');
        # Scene.dump / force='mesh' drop them, so read them here.
        normals = None
        try:
            if "vertex_normals" in g._cache:
                normals = np.asarray(g._cache["vertex_normals"], dtype=np.float64)
                if normals.shape != vertices.shape:
                    normals = None
        except Exception:  # pragma: no cover - trimesh internals changed
            normals = None
        uv, material = None, None
        visual = getattr(g, "visual", None)
        if getattr(visual, "kind", None) == "texture" and getattr(visual, "uv", None) is not None:
            uv = np.asarray(visual.uv, dtype=np.float64)
            if uv.shape != (len(vertices), 2):
                uv = None
            material = hash(visual.material) if getattr(visual, "material", None) is not None else None
        lin, t = T[:3, :3], T[:3, 3]
        vertices = vertices @ lin.T + t
        if normals is not None:
            normals = normals @ np.linalg.inv(lin)  # inverse transpose, row vectors
        if np.linalg.det(lin) < 0:
            faces = faces[:, ::-1]
        parts.append({"vertices": vertices, "faces": faces, "normals": normals, "uv": uv, "material": material})
    if not parts:
        what = ", ".join(sorted(kinds)) or "nothing"
        raise InputError(f"not a triangle mesh: no faces (found {what})", where=where,
                         fix="give a mesh with faces (a point cloud needs surface reconstruction first)")
    return parts


def _xatlas(vertices, faces, resolution, padding, *, where):
    """xatlas atlas fitted into a ``resolution`` square: ``(vmapping, faces, uv, atlas_meta)``.

    xatlas's own resolution estimate can overshoot (e.g. 317 x 309 for 256)
    and its exact-resolution mode may spill into several atlases, so when the
    first atlas does not fit, its charts (as a uv mesh: cheap, no new
    charting) are repacked at a lower texel density until one atlas fits.
    uv are texel coordinates over ``resolution`` (row 0 of xatlas's image at
    ``v = 1``), so ``padding`` holds in a ``resolution``-square texture.
    """
    import xatlas

    resolution = _count(resolution, 8, "atlas_resolution")
    padding = checks.count(padding, "atlas_padding", where=where, fix="use e.g. atlas_padding=2")
    pos = np.asarray(vertices, np.float64)
    pos = (pos - 0.5 * (pos.min(0) + pos.max(0))).astype(np.float32)   # centred: float32 keeps precision
    faces = np.asarray(faces, np.int64)

    def pack_options(res, tpu):
        po = xatlas.PackOptions()
        po.resolution, po.texels_per_unit, po.padding = res, tpu, padding
        return po

    def fits(a):
        return a.atlas_count == 1 and max(a.width, a.height) <= resolution

    def texels(a):  # xatlas-python normalises uv by the atlas size
        vm, f, uv = a[0]
        return vm.astype(np.int64), f.astype(np.int64), uv.astype(np.float64) * np.array([a.width, a.height])

    atlas = xatlas.Atlas()
    atlas.add_mesh(pos, np.ascontiguousarray(faces, dtype=np.uint32))
    atlas.generate(xatlas.ChartOptions(), pack_options(resolution, 0.0))
    vmap, new_faces, texel = texels(atlas)
    charts, tpu, passes = int(atlas.chart_count), float(atlas.texels_per_unit), 1
    if not fits(atlas):
        # side(scale) is roughly affine (charts scale, padding does not): secant steps, always shrinking
        last = (1.0, max(atlas.width, atlas.height)) if atlas.atlas_count == 1 else None
        scale = 0.99 * (resolution - 2 * padding - 2) / max(last[1] - 2 * padding - 2, 1) if last else 0.5
        chart_uv, chart_faces = texel.astype(np.float32), np.ascontiguousarray(new_faces, dtype=np.uint32)
        while True:
            repack = xatlas.Atlas()
            repack.add_uv_mesh(chart_uv, chart_faces)
            repack.generate(xatlas.ChartOptions(), pack_options(0, scale))
            passes += 1
            if fits(repack):
                break
            if passes >= 24 or scale < 1e-6:
                raise InputError(f"xatlas could not pack {charts} charts into {resolution}x{resolution} texels "
                                 f"with padding {padding}", where=where,
                                 fix="raise atlas_resolution or lower atlas_padding")
            side = max(repack.width, repack.height)
            step = 0.7 * scale
            if last is not None and side != last[1]:
                step = scale + (resolution - 1 - side) * (scale - last[0]) / (side - last[1])
            last = (scale, side)
            scale = min(max(step, 0.5 * scale), 0.98 * scale)
        vm2, f2, texel = texels(repack)
        if not np.array_equal(vm2[f2], new_faces):
            raise RuntimeError("xatlas repacking changed the faces")  # pragma: no cover
        vmap, new_faces, tpu, atlas = vmap[vm2], f2, tpu * scale, repack
    if new_faces.shape != faces.shape or not np.array_equal(vmap[new_faces], faces):
        raise RuntimeError("xatlas changed the faces")  # pragma: no cover - xatlas keeps face order
    uv = np.stack([texel[:, 0] / resolution, 1 - texel[:, 1] / resolution], axis=1)
    meta = {"generator": "xatlas", "resolution": resolution, "padding": padding, "width": int(atlas.width),
            "height": int(atlas.height), "charts": charts, "texels_per_unit": tpu,
            "utilization": float(atlas.utilization), "passes": passes}
    return vmap, new_faces, uv, meta
