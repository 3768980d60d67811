"""Mesh G-buffers by Mitsuba ray casting: first hits of camera rays and shadow rays towards lights.

:func:`intersect` casts one ray per pixel of every camera in one Mitsuba call (position, shading
normal with a tangent frame along the texture axes, uv, valid mask); :func:`occluded` casts one
shadow ray per valid pixel and light. Mitsuba is single precision: results are float32 values
returned as float64 tensors. The Mitsuba scene of a mesh is built once and kept (:data:`SCENES`,
by the mesh's digest); the variant comes from :mod:`bayes_brdf.mitsuba_env` (``llvm_ad_rgb`` on
CPU, ``cuda_ad_rgb`` with a GPU), switched only for the duration of a call.

Conventions, as for the planar sample (:mod:`.hits`): a mesh is shaded two-sided (a pixel that sees
the back of a face gets the face's normals flipped towards the camera), the side of a face being the
side its vertex normals point to, whatever its winding (the geometric normal is first turned to agree
with the interpolated shading normal: scans and exports often wind faces against their normals, which
would otherwise turn the shading normal away from the camera, black); the tangent follows
``+u``, the bitangent ``+v`` (the direction of texel row 0) even on mirrored atlas charts; uv in
``[0, 1]`` (v up) become ``grid_sample`` coordinates ``(2u - 1, 1 - 2v)``. Shadow rays leave the
surface offset by :data:`SHADOW_EPS` times the mesh's bounding radius along the geometric normal,
on the light's side, and stop that far short of the light.
"""
from __future__ import annotations

import threading
from collections import OrderedDict

import numpy as np
import torch
from torch import Tensor

from ..errors import InputError
from ..mitsuba_env import mitsuba_variant
from .cameras import PerspectiveCamera
from .hits import SurfaceHits

#: shadow-ray offset and shortening, relative to the mesh's bounding radius
SHADOW_EPS = 1e-4

class MeshSceneCache:
    """Mitsuba scenes built from meshes, kept by (mesh digest, variant): ``get(mesh, variant, *args)`` returns the
    kept one or ``build(mesh, variant, *args)``; a few at most, the least recently used out first. Thread-safe.

    Example:
        >>> cache = MeshSceneCache(lambda mesh, variant, tag: (mesh, tag), max_entries=2)
        >>> from bayes_brdf.render.mesh import Mesh
        >>> cache.get(Mesh.plane(), "v", 1) is cache.get(Mesh.plane(), "v", 2)
        True
    """

    def __init__(self, build, max_entries: int = 8):
        self._build, self.max_entries = build, max_entries
        self._store: OrderedDict = OrderedDict()
        self._lock = threading.Lock()

    def get(self, mesh, variant: str, *args):
        key = (mesh.digest, variant)
        with self._lock:
            if key in self._store:
                self._store.move_to_end(key)
                return self._store[key]
            sc = self._build(mesh, variant, *args)
            self._store[key] = sc
            while len(self._store) > self.max_entries:
                self._store.popitem(last=False)
            return sc


def mitsuba_mesh(mesh, mi):
    """The Mitsuba ``Mesh`` of ``mesh`` (positions, vertex normals, uv and faces as they are, float32), in the
    active variant of ``mi``."""
    m = mi.Mesh(mesh.name or "mesh", mesh.num_vertices, mesh.num_faces, has_vertex_normals=True,
                has_vertex_texcoords=True)
    p = mi.traverse(m)
    p["vertex_positions"] = mi.Float(np.ascontiguousarray(mesh.vertices, np.float32).ravel())
    p["vertex_normals"] = mi.Float(np.ascontiguousarray(mesh.normals, np.float32).ravel())
    p["vertex_texcoords"] = mi.Float(np.ascontiguousarray(mesh.uv, np.float32).ravel())
    p["faces"] = mi.UInt(np.ascontiguousarray(mesh.faces, np.uint32).ravel())
    p.update()
    return m


def _build_scene(mesh, variant: str, mi):
    return mi.load_dict({"type": "scene", "mesh": mitsuba_mesh(mesh, mi)})


def _rays(cameras) -> tuple[Tensor, Tensor]:
    """Origins ``[V, 3]`` and unit directions ``[V, 3, H, W]`` (float64) of perspective cameras."""
    os_, ds = [], []
    for c in cameras:
        if not isinstance(c, PerspectiveCamera):
            raise InputError(f"a {type(c).__name__} cannot look at a mesh", fix="use PerspectiveCamera views "
                             "(a rectified camera only images the planar sample)")
        o, d = c.rays(dtype=torch.float64)
        os_.append(o)
        ds.append(d)
    return torch.stack(os_), torch.stack(ds)


#: the Mitsuba scenes of the meshes ray cast so far
SCENES = MeshSceneCache(_build_scene)


def _vec(mi, a: np.ndarray, cls):
    """A Dr.Jit 3-vector from a ``[3, N]`` numpy array."""
    a = np.ascontiguousarray(a, dtype=np.float32)
    return cls(mi.Float(a[0]), mi.Float(a[1]), mi.Float(a[2]))


def _np3(v) -> np.ndarray:
    return np.stack([np.asarray(v.x), np.asarray(v.y), np.asarray(v.z)])


def intersect(mesh, cameras) -> SurfaceHits:
    """First hits of every pixel of ``cameras`` (perspective, one resolution) on ``mesh``.

    Example:
        >>> from bayes_brdf.render.mesh import Mesh                    # doctest: +SKIP
        >>> intersect(Mesh.sphere(), [PerspectiveCamera((0, 0, 4.0), resolution=8)]).mask.sum()  # doctest: +SKIP
        tensor(...)
    """
    cameras = list(cameras)
    res = {tuple(c.resolution) for c in cameras}
    if len(res) != 1:
        raise InputError(f"cameras have different resolutions {sorted(res)}", fix="intersect them in separate calls")
    o, d = _rays(cameras)
    V, _, h, w = d.shape
    n = h * w
    with mitsuba_variant() as mi:
        import drjit as dr
        scene = SCENES.get(mesh, mi.variant(), mi)
        org = o[:, :, None].expand(V, 3, n).permute(1, 0, 2).reshape(3, -1).numpy()
        dirs = d.reshape(V, 3, n).permute(1, 0, 2).reshape(3, -1).numpy()
        ray = mi.Ray3f(_vec(mi, org, mi.Point3f), _vec(mi, dirs, mi.Vector3f))
        si = scene.ray_intersect(ray, ray_flags=mi.RayFlags.All, coherent=True)
        valid = si.is_valid()
        # the frame, in Dr.Jit (one fused kernel): the geometric normal turned to the side of the vertex normals
        # (a face wound against them shades as they say), then both two-sided, facing the camera; tangent along +u
        ng = si.n * dr.select(dr.dot(si.n, si.sh_frame.n) < 0, -1.0, 1.0)
        flip = dr.select(dr.dot(ng, ray.d) > 0, -1.0, 1.0)
        ng, ns = ng * flip, si.sh_frame.n * flip
        ns = dr.select(dr.squared_norm(ns) > 0, ns, ng)
        ns = dr.normalize(ns)
        tu = si.dp_du - ns * dr.dot(ns, si.dp_du)
        fallback, _ = mi.coordinate_system(ns)
        t = dr.normalize(dr.select(dr.squared_norm(tu) > 1e-24, tu, fallback))
        b = dr.cross(ns, t)
        b = b * dr.select(dr.dot(b, si.dp_dv) < 0, -1.0, 1.0)        # mirrored charts: b along +v
        zero = mi.Vector3f(0.0)
        outs = [dr.select(valid, x, zero) for x in (si.p, ns, t, b, ng)]
        uvv = dr.select(valid, mi.Point2f(2 * si.uv.x - 1, 1 - 2 * si.uv.y), mi.Point2f(0.0))
        dr.eval(*outs, uvv, valid)
        p, ns, t, b, ng = (torch.from_numpy(_np3(x)) for x in outs)
        uv = torch.from_numpy(np.stack([np.asarray(uvv.x), np.asarray(uvv.y)]))
        mask = torch.from_numpy(np.asarray(valid)).bool()

    def img(x: Tensor) -> Tensor:      # [C, V * n] float32 -> [V, C, H, W] float64
        return x.reshape(x.shape[0], V, h, w).permute(1, 0, 2, 3).double().contiguous()

    p, ns, t, b, ng = (img(x) for x in (p, ns, t, b, ng))
    return SurfaceHits(position=p, normal=ns, tangent=t, bitangent=b, uv=img(uv).permute(0, 2, 3, 1).contiguous(),
                       mask=mask.reshape(V, h, w), align_corners=False, geometric_normal=ng)


def occluded(mesh, hits: SurfaceHits, light_positions: Tensor) -> Tensor:
    """``[V, L, H, W]`` bool: True where the segment from the hit to light ``l`` of view ``v`` is blocked
    (``light_positions [V, L, 3]``); False off the mesh."""
    V, _, h, w = hits.position.shape
    L = light_positions.shape[1]
    n = h * w
    mask = hits.mask.reshape(-1)
    out = torch.zeros(L, V * n, dtype=torch.bool)
    if not bool(mask.any()):
        return out.reshape(L, V, h, w).transpose(0, 1)
    ng = hits.geometric_normal if hits.geometric_normal is not None else hits.normal
    flat = lambda x: x.permute(1, 0, 2, 3).reshape(3, -1)[:, mask].float().numpy()  # noqa: E731
    view = (torch.arange(V * n) // n)[mask].to(torch.int32).numpy()
    eps = SHADOW_EPS * mesh.radius
    with mitsuba_variant() as mi:
        import drjit as dr
        scene = SCENES.get(mesh, mi.variant(), mi)
        p, nrm = _vec(mi, flat(hits.position), mi.Point3f), _vec(mi, flat(ng), mi.Vector3f)
        vi = mi.UInt32(view.astype(np.uint32))
        blocked = []
        for l in range(L):
            table = mi.Float(np.ascontiguousarray(light_positions[:, l].float().numpy()).ravel())
            lp = dr.gather(mi.Point3f, table, vi)
            to = lp - p
            dist = dr.norm(to)
            d = to / dist
            org = p + nrm * (dr.select(dr.dot(nrm, d) >= 0, eps, -eps))
            ray = mi.Ray3f(org, d)
            ray.maxt = dr.maximum(dist - 2 * eps, 0.0)
            blocked.append(scene.ray_test(ray))
        dr.eval(*blocked)
        for l in range(L):
            out[l, mask] = torch.from_numpy(np.asarray(blocked[l])).bool()
    return out.reshape(L, V, h, w).transpose(0, 1)


def occluded_directions(mesh, points: Tensor, normals: Tensor, directions: Tensor) -> Tensor:
    """``[N]`` bool: True where the ray from ``points [N, 3]`` along ``directions [N, 3]`` (unit, towards a light
    at infinity, e.g. an environment) meets ``mesh``. Each ray leaves its point offset by :data:`SHADOW_EPS` times
    the mesh radius along ``normals [N, 3]`` (the geometric normal), on the direction's side."""
    n = points.shape[0]
    if n == 0:
        return torch.zeros(0, dtype=torch.bool)
    eps = SHADOW_EPS * mesh.radius
    with mitsuba_variant() as mi:
        scene = SCENES.get(mesh, mi.variant(), mi)
        import drjit as dr
        p = _vec(mi, points.T.float().numpy(), mi.Point3f)
        nrm = _vec(mi, normals.T.float().numpy(), mi.Vector3f)
        d = _vec(mi, directions.T.float().numpy(), mi.Vector3f)
        org = p + nrm * dr.select(dr.dot(nrm, d) >= 0, eps, -eps)
        blocked = scene.ray_test(mi.Ray3f(org, d))
        dr.eval(blocked)
        return torch.from_numpy(np.asarray(blocked)).bool()
