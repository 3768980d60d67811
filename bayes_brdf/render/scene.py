"""A scene: the geometry the cameras look at, and the views (cameras with their lights) of a capture.

:class:`Scene` is what :class:`~bayes_brdf.observations.Observations` and a
:class:`~bayes_brdf.posterior.Posterior` carry and save. A geometry (a
:class:`~bayes_brdf.render.surface.PlanarSample` or a
:class:`~bayes_brdf.render.mesh.Mesh`) saves itself as ``state() -> (meta,
tensors)``: a JSON-able dict with a ``"type"`` and, for a mesh, its arrays;
:func:`surface_from_state` reads it back. Files written before scenes existed
store a plane as ``{"size", "grid"}`` without a type: still read as a plane.
"""
from __future__ import annotations

import json
from dataclasses import dataclass

from ..errors import InputError
from .surface import PlanarSample
from .views import View

#: prefix of a surface's tensors inside a file that holds other tensors too (posterior, bundle)
TENSOR_PREFIX = "surface/"
#: prefix of the environment maps of a scene's lights (one per map, by digest)
ENVIRONMENT_PREFIX = "environment/"


def surface_state(surface) -> tuple[dict, dict]:
    """``(meta, tensors)`` of a geometry, for saving (tensors keyed with :data:`TENSOR_PREFIX`)."""
    meta, tensors = surface.state()
    return meta, {TENSOR_PREFIX + k: v for k, v in tensors.items()}


def surface_from_state(meta: dict, tensors: dict | None = None, where: str | None = None):
    """The geometry saved by :func:`surface_state` (``tensors`` may hold other keys too).

    Example:
        >>> surface_from_state(*surface_state(PlanarSample(3.0, "endpoints")))
        PlanarSample(size=3.0, grid='endpoints')
    """
    if not isinstance(meta, dict):
        raise InputError("the saved surface is not a JSON object", where=where)
    kind = meta.get("type", "plane")
    try:
        if kind == "plane":
            return PlanarSample(size=float(meta["size"]), grid=meta.get("grid", "centers"))
        if kind == "mesh":
            from .mesh import Mesh
            t = {k[len(TENSOR_PREFIX):]: v for k, v in (tensors or {}).items() if k.startswith(TENSOR_PREFIX)}
            return Mesh.from_state(meta, t)
    except InputError as e:
        raise InputError(e.problem, where=where or e.where, fix=e.fix) from None
    except (KeyError, TypeError, ValueError):
        raise InputError(f"malformed saved surface of type '{kind}'", where=where,
                         fix="re-save the file with this version of bayes_brdf") from None
    raise InputError(f"unknown surface type '{kind}'", where=where, fix="use a plane or a mesh")


def surface_key(surface) -> str:
    """A short text that identifies a geometry (for run digests): a plane by size and grid, a mesh by its content."""
    if isinstance(surface, PlanarSample):   # the form digests had before meshes: plane digests stay the same
        return json.dumps({"size": surface.size, "grid": surface.grid})
    return json.dumps({"type": type(surface).__name__, "digest": surface.digest})   # content, not the file's path


def describe(surface) -> str:
    """A few words for messages and reports: ``plane 6.848 cm`` or ``mesh bunny (4968 faces)``."""
    if isinstance(surface, PlanarSample):
        return f"plane {surface.size:g}"
    return f"mesh {getattr(surface, 'name', 'mesh')} ({surface.num_faces} faces)"


@dataclass(frozen=True)
class Scene:
    """A geometry and the views that observe it.

    Example:
        >>> from bayes_brdf.render.views import collocated_views
        >>> sc = Scene(PlanarSample(2.0), tuple(collocated_views(2, 3.0, resolution=8)))
        >>> meta, tensors = sc.state()
        >>> Scene.from_state(meta, tensors) == sc
        True
    """

    surface: object
    views: tuple = ()

    def __post_init__(self):
        object.__setattr__(self, "views", tuple(self.views))
        for name in ("intersect", "occluded", "state"):
            if not callable(getattr(self.surface, name, None)):
                raise InputError(f"{type(self.surface).__name__} is not a geometry (it has no '{name}')",
                                 fix="use a PlanarSample or a Mesh")

    @property
    def cameras(self) -> list:
        return [v.camera for v in self.views]

    @property
    def lights(self) -> list:
        """Every view's lights, in view order (a light shared by views appears once per view)."""
        return [l for v in self.views for l in v.lights]

    def state(self) -> tuple[dict, dict]:
        """``({"surface": ..., "views": [...]}, tensors)`` for saving."""
        meta, tensors = surface_state(self.surface)
        for v in self.views:
            if v.environment is not None:
                tensors[ENVIRONMENT_PREFIX + v.environment.digest] = v.environment.radiance
        return {"surface": meta, "views": [v.to_dict() for v in self.views]}, tensors

    @classmethod
    def from_state(cls, meta: dict, tensors: dict | None = None, where: str | None = None) -> "Scene":
        envs = {k[len(ENVIRONMENT_PREFIX):]: t for k, t in (tensors or {}).items() if k.startswith(ENVIRONMENT_PREFIX)}
        views = [View.from_dict(v, where=f"{where or 'scene'} views[{i}]", environments=envs)
                 for i, v in enumerate(meta.get("views", []))]
        return cls(surface_from_state(meta.get("surface", {}), tensors, where), tuple(views))
