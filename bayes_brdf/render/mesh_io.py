"""Mesh files: reading OBJ, PLY and glTF through ``trimesh``, uv atlases by ``xatlas``, writing OBJ.

:class:`~bayes_brdf.render.mesh.Mesh` is the type; this module moves meshes in and out of files.
:func:`load_mesh` (what :meth:`Mesh.load` calls) reads a file into the world frame (z up, scene
units: :data:`UNITS`, :data:`UP_AXES`), keeping the file's normals and uv where they are usable;
:func:`make_atlas` packs a uv atlas with xatlas (what :func:`load_mesh` does for a file without
usable uv, and :func:`with_atlas` for any mesh); :func:`to_trimesh` and :func:`obj_text` write a
mesh out (an OBJ from :func:`obj_text` reads back exactly).

When a file has no usable uv, an atlas is made with ``xatlas`` (deterministic:
the same mesh and settings give the same atlas); ``meta["atlas"]`` then records
the resolution and padding it was packed for. xatlas charts are not all
orientation-preserving: about half the charts are mirrored in uv (a face that
is counter-clockwise in 3D can be clockwise in uv), which does not matter for
texture lookup but does for tangent frames.

Example:
    >>> from bayes_brdf.render.mesh import Mesh
    >>> obj_text(Mesh.plane()).splitlines()[1]
    'v -1.0 -1.0 0.0'
"""
from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np

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

#: the ``uv=`` modes of :func:`load_mesh`
UV_MODES = ("auto", "file", "atlas")


def area_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
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


def load_mesh(path, *, units: str | None = None, scene_units: str = "cm", up: str = "z",
              atlas_resolution: int = 256, atlas_padding: int = 2, uv: str = "auto",
              name: str | None = None, cls=None):
    """Read an OBJ, PLY or GLB/glTF file (anything ``trimesh`` reads) into the world frame: a
    :class:`~bayes_brdf.render.mesh.Mesh` (or a ``cls``: what :meth:`Mesh.load` passes).

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
      area-weighted face normals. The file's normals and winding are kept as
      they are (``trimesh`` reads unprocessed) even where faces wind against
      the normals: the ray caster shades such faces by the normals.
      Unreferenced vertices are dropped; faces keep their order.

    ``meta`` records the source path and its SHA-256, file and scene units,
    up axis, where uv and normals came from, and the atlas settings.

    Example:
        >>> load_mesh("no/such/file.obj")
        Traceback (most recent call last):
        ...
        bayes_brdf.errors.InputError: no/such/file.obj: mesh file not found; check the path
    """
    if cls is None:
        from .mesh import Mesh
        cls = Mesh
    where = str(path)
    p = Path(path)
    if units is not None and units not in UNITS:
        raise InputError(f"unknown length unit {units!r}", where=where,
                         fix=f"use one of {', '.join(UNITS)} (or None when the file is in scene units)")
    if scene_units not in UNITS:
        raise InputError(f"unknown scene unit {scene_units!r}", where=where, fix=f"use one of {', '.join(UNITS)}")
    if up not in UP_AXES:
        raise InputError(f"unknown up axis {up!r}", where=where, fix=f"use one of {', '.join(UP_AXES)}")
    if uv not in UV_MODES:
        raise InputError(f"unknown uv mode {uv!r}", where=where, fix=f"use one of {', '.join(UV_MODES)}")
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
        normals = area_normals(vertices, faces)
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
    vmap, faces, atlas_uv, atlas = make_atlas(vertices, faces, atlas_resolution, atlas_padding, where=where)
    meta = {**meta, "uv_source": "xatlas", "uv_note": uv_note, "atlas": atlas}
    return cls(vertices[vmap], faces, atlas_uv, normals[vmap], name=mesh_name, meta=meta)


def with_atlas(mesh, resolution: int = 256, padding: int = 2):
    """``mesh`` with a fresh xatlas uv atlas packed for a ``resolution`` square texture.

    Charts are separated by at least ``padding`` texels at that resolution
    (plus xatlas's bilinear margin). Vertices are split along chart seams;
    faces keep their order and corners. Deterministic.

    Example:
        >>> from bayes_brdf.render.mesh import Mesh
        >>> m = with_atlas(Mesh.sphere(rings=6, segments=12), 64, 1)
        >>> m.num_faces, m.meta["atlas"]["resolution"], float(m.uv.max()) <= 1
        (120, 64, True)
    """
    from .mesh import Mesh

    v, f, uv, atlas = make_atlas(mesh.vertices, mesh.faces, resolution, padding, where=f"mesh '{mesh.name}'")
    meta = {**mesh.meta, "uv_source": "xatlas", "atlas": atlas}
    return Mesh(mesh.vertices[v], f, uv, mesh.normals[v], name=mesh.name, meta=meta)


def to_trimesh(mesh):
    """A ``trimesh.Trimesh`` view of ``mesh`` (unprocessed: same vertices, faces, normals, uv).

    Example:
        >>> from bayes_brdf.render.mesh import Mesh
        >>> float(to_trimesh(Mesh.plane()).area)
        4.0
    """
    import trimesh
    from trimesh.visual import TextureVisuals

    return trimesh.Trimesh(vertices=np.array(mesh.vertices), faces=np.array(mesh.faces),
                           vertex_normals=np.array(mesh.normals),
                           visual=TextureVisuals(uv=np.array(mesh.uv)), process=False)


def obj_text(mesh) -> str:
    """The mesh as OBJ text, full float64 precision, one v/vt/vn index per vertex (read back exactly by
    :func:`load_mesh`)."""
    lines = [f"# {mesh.name}: written by bayes_brdf (units: cm, up: z)"]
    lines += [f"v {x!r} {y!r} {z!r}" for x, y, z in mesh.vertices.tolist()]
    lines += [f"vt {u!r} {v!r}" for u, v in mesh.uv.tolist()]
    lines += [f"vn {x!r} {y!r} {z!r}" for x, y, z in mesh.normals.tolist()]
    lines += ["f " + " ".join(f"{k}/{k}/{k}" for k in (a + 1, b + 1, c + 1)) for a, b, c in mesh.faces.tolist()]
    return "\n".join(lines) + "\n"


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


def make_atlas(vertices, faces, resolution, padding, *, where):
    """xatlas atlas fitted into a ``resolution`` square: ``(vmapping, faces, uv, atlas_meta)``.

    xatlas's own resolution estimate can overshoot (e.g. 317 x 309 for 256)
    and its exact-resolution mode may spill into several atlases, so when the
    first atlas does not fit, its charts (as a uv mesh: cheap, no new
    charting) are repacked at a lower texel density until one atlas fits.
    uv are texel coordinates over ``resolution`` (row 0 of xatlas's image at
    ``v = 1``), so ``padding`` holds in a ``resolution``-square texture.
    """
    import xatlas

    resolution = checks.count(resolution, "atlas_resolution", least=8, where="atlas_resolution=",
                              fix="use atlas_resolution >= 8")
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
