"""Shared pieces of the experiments: synthetic problems, fitting and JSON (figures: :mod:`bayes_brdf.plots`)."""
from __future__ import annotations

import functools
import json
import logging
import sys
from pathlib import Path

import torch

from ..inference import infer
from ..models.material import per_texel
from ..observations import Observations
from ..errors import InputError
from ..render.shade import render
from ..render.surface import PlanarSample
from ..render.views import collocated_views

SURFACE = PlanarSample(2.0)
#: the noise scale sigma_err of Eq. 2 the paper's figures use, pinned for the (noiseless) figure problems:
#: the model default ``sigma = "auto"`` would infer the noise level, which on noiseless renders is its floor
PAPER_SIGMA = 0.01


#: ``../shared/data`` beside the repository (the Stanford bunny of ``surface="bunny"`` lives there)
SHARED_DATA = Path(__file__).resolve().parents[2].parent / "shared" / "data"
#: the ``surface`` settings of the experiments that have one: the planar sample or a mesh
SURFACES = ("plane", "bowl", "sphere", "block", "bunny")
#: cameras on a mesh: at this many times ``mesh.radius`` from ``mesh.center`` (with ``MESH_FOV`` the
#: bounding sphere just fills the image), flash power ``MESH_POWER * distance^2`` (a radiance like the plane's)
MESH_DISTANCE, MESH_FOV, MESH_POWER = 2.6, 45.0, 1.2


def scene_surface(spec: str = "plane"):
    """The scene an experiment photographs: ``"plane"`` (:data:`SURFACE`, the planar sample), a built-in mesh
    (``"bowl"``, ``"sphere"``, ``"block"``), ``"bunny"`` (the Stanford bunny of ``../shared/data``, y up, with
    its xatlas atlas) or the path of a mesh file (OBJ/PLY/GLB, z up, its own unit).

    Example:
        >>> scene_surface("plane") is SURFACE
        True
        >>> scene_surface("bowl").name
        'bowl'
    """
    spec = str(spec)
    if spec == "plane":
        return SURFACE
    return _mesh(spec)


@functools.lru_cache(maxsize=4)
def _mesh(spec: str):
    from ..render.mesh import Mesh

    if spec in ("bowl", "sphere", "block"):
        return {"bowl": Mesh.bowl, "sphere": Mesh.sphere, "block": Mesh.block_on_plane}[spec]()
    if spec == "bunny":
        path = SHARED_DATA / "psdr_assets" / "bunny_low.obj"
        if not path.is_file():
            raise InputError("the bunny mesh (surface=bunny) is not there", where=str(path),
                             fix="put ../shared/data beside the repository, or use surface=bowl (built in)")
        return Mesh.load(path, up="y")
    if Path(spec).suffix.lower() in (".obj", ".ply", ".glb", ".gltf") and Path(spec).is_file():
        return Mesh.load(spec)
    raise InputError(f"unknown surface {spec!r}", fix=f"use one of {', '.join(SURFACES)} or a mesh file path")


def is_mesh(surface) -> bool:
    """Whether ``surface`` is a mesh (not the planar sample)."""
    return not isinstance(surface, PlanarSample)


def mesh_rig(mesh, resolution: int) -> tuple[float, dict]:
    """``(distance, view keywords)`` of the flash cameras around ``mesh``: perspective, aimed at its centre from
    :data:`MESH_DISTANCE` times its radius, ``resolution^2`` pixels, power by the square of the distance."""
    dist = MESH_DISTANCE * float(mesh.radius)
    return dist, dict(camera="perspective", target=tuple(mesh.center), resolution=int(resolution), fov=MESH_FOV,
                      power=MESH_POWER * dist ** 2)


def say(msg: str, *args) -> None:
    """A progress line of long work (an experiment's rounds, a comparison's samplers) on the
    ``bayes_brdf`` logger: the CLI shows it on stderr; a Python caller sees it once logging is set up."""
    logging.getLogger("bayes_brdf").info(msg, *args)


def synthetic(material: str = "wood", resolution: int = 32, views: int = 10, *, seed: int = 0,
              method: str = "sobol", radius: float = 3.0, power: float = 10.0, max_zenith: float = 60.0,
              noise_sigma: float = 0.0, view_seed: int | None = None):
    """``(truth maps, Observations)``: a procedural material under collocated rectified views at map resolution."""
    from ..guidance.acquisition import SyntheticCapture
    from ..materials import make_material

    truth = make_material(material, resolution, seed=seed).to(torch.float32)
    vs = collocated_views(views, radius, method=method, camera="rectified", resolution=resolution, power=power,
                          max_zenith=max_zenith, seed=seed if view_seed is None else view_seed)
    obs = SyntheticCapture(truth, SURFACE, noise_sigma=noise_sigma, seed=seed)(vs)
    return truth, obs


def camera_clip(obs: Observations, level: float = 1.0) -> Observations:
    """``obs`` as a camera records it: values clipped at ``level``, a pixel with a channel there marked saturated."""
    from dataclasses import replace
    sat = (obs.images >= level).any(-1)
    if obs.saturated is not None:
        sat = sat | obs.saturated
    return replace(obs, images=obs.images.clamp(max=level), saturated=sat)


#: The sampler the figures (Figs. 2-5, 7) were measured with, kept so that their published numbers reproduce:
#: SPOS with the step in unconstrained parameter units (0.005) and 4000 steps, the former ``spos_maps``
#: preset. The package default (``samplers/spos.toml``) is calibrated as well and twice as fast on these
#: problems (docs/samplers.md); the figures move to it when they are re-measured.
FIGURE_SAMPLER = {"sampler": "spos",
                  "params": {"step_size": 0.005, "step_units": "parameter", "beta": "auto", "beta_low_dim": 200.0,
                             "anneal": True, "anneal_delta": 1.0, "anneal_fraction": 0.2, "preconditioner": "adam",
                             "adam_beta2": 0.99, "adam_eps": 1e-8},
                  "run": {"particles": 20, "steps": 4000, "checkpoint_every": 100}}


def sampler_of(name: str):
    """A ``sampler`` setting of an experiment: ``"figure"`` is :data:`FIGURE_SAMPLER` (what the plane figures were
    measured with), anything else a sampler name or preset of :func:`bayes_brdf.infer` (the mesh presets use
    ``"spos"``, the package default: on the bunny it reaches at 300 steps the novel-view error that
    ``FIGURE_SAMPLER`` reaches at 1600)."""
    return FIGURE_SAMPLER if str(name) == "figure" else str(name)


def fit(obs: Observations, resolution: int, *, steps: int, particles: int = 20, seed: int = 0,
        sampler=FIGURE_SAMPLER, model=None, params=None, progress: bool = False):
    """Sample the per-texel posterior (RGB albedo, roughness) of ``obs``."""
    model = model if model is not None else per_texel(resolution, sigma=PAPER_SIGMA)
    return infer(model, obs, sampler, seed=seed, particles=particles, steps=steps, params=params, progress=progress,
                 map_steps=0)


def prepare(module_name: str, preset: str, overrides: dict, out):
    """``(config, out folder)`` of an experiment run: the module's preset with ``overrides``, ``out`` created."""
    from . import preset as _preset

    cfg = _preset(sys.modules[module_name], preset, overrides)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    return cfg, out


def write_json(out, name: str, data: dict) -> Path:
    """``out/name.json`` (atomically, numbers that are not JSON floats as floats)."""
    from ..io.outputs import write_text

    return write_text(Path(out) / f"{name}.json", json.dumps(data, indent=2, default=float))


def views_at(obs: Observations):
    return list(obs.views)


#: the environment map of the environment-lit experiments (``env = "ballroom"``): the psdr-cuda ballroom of
#: ``../shared/data`` (1024 x 512, lamps of radiance up to 141 on a mean of 0.45)
BALLROOM = SHARED_DATA / "psdr_assets" / "ballroom_1k.exr"


def environment_light(spec: str = "ballroom", scale: float = 1.0, rotate: float = 0.0):
    """``(EnvironmentLight, description)`` of an experiment's ``env`` setting: ``"ballroom"`` (:data:`BALLROOM`;
    where the file is missing, the built-in :func:`~bayes_brdf.render.environment.studio` instead, with a warning
    and the description saying so), ``"studio"`` (file-free) or the path of an EXR / Radiance HDR map. The map's
    zenith is put on ``+z`` and turned by ``rotate`` degrees about it (:func:`~bayes_brdf.render.environment.z_up`),
    its radiance times ``scale``.

    Example:
        >>> env, text = environment_light("studio", 2.0, 90)
        >>> env.scale, text
        (2.0, 'studio() 64x32, scale 2, rotate 90 deg')
    """
    import warnings

    from ..render.environment import EnvironmentLight, studio, z_up

    spec, scale, rotate = str(spec), float(scale), float(rotate)
    note = ""
    if spec == "ballroom" and not BALLROOM.is_file():
        note = f" (fallback: the ballroom map is not at {BALLROOM})"
        warnings.warn(f"env=ballroom: {BALLROOM} is missing; using the built-in studio() map instead "
                      "(put ../shared/data beside the repository for the paper's lighting)", stacklevel=2)
        say("env=ballroom: %s is missing; using studio() instead", BALLROOM)
        spec = "studio"
    if spec == "studio":
        base = studio()
        env = EnvironmentLight(base.radiance, scale, z_up(rotate), name="studio()")
    else:
        path = BALLROOM if spec == "ballroom" else Path(spec)
        env = EnvironmentLight.from_file(path, scale, z_up(rotate))
    h, w = env.radiance.shape[:2]
    return env, f"{env.name} {w}x{h}, scale {scale:g}, rotate {rotate:g} deg{note}"


__all__ = ["SURFACE", "synthetic", "fit", "write_json", "render"]
