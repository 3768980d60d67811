"""Fig. 4: image-space uncertainty (Eq. 11) against the novel-view errors of four point estimates.

Setup (the paper's Sec. 4, "Image-space uncertainty"): a procedural SVBRDF (``material``, wood by default) at
``resolution^2`` texels is observed under ``views`` collocated flash views (rectified cameras, zenith within
60 degrees, Sobol directions seeded by ``seed``); normals and specular albedo are known (the truth's), albedo (RGB)
and roughness are inferred per texel with ``FIGURE_SAMPLER`` (the former ``spos_maps``; ``sampler = "figure"``; the mesh
presets use ``"spos"``) (``particles`` particles, ``steps`` steps, started from prior
draws kept off the parameter bounds). Four point estimates of the same posterior:

* (b1) Adam on the MAP objective ``-log f(x)`` (the potential's energy without the Jacobian, Eq. 3/7) from high
  initial roughness (``init_high``, albedo 0.5 everywhere);
* (b2) the same from low initial roughness (``init_low``);
* (b3) plain (no momentum) SGD from random initial albedo and roughness (uniform within the central 90% of
  each range), step size decaying linearly to 10%;
* (b4) ours (Sec. 3.3.1): the particle of highest ``f``, refined by ``refine_steps`` of Adam.

(b1)-(b3) run as three rows of one batched potential (:func:`optimize`, ``opt_steps`` steps; Adam step
``adam_lr``, SGD step ``sgd_lr``, both decaying linearly to 10%). Two novel views, not among the observed ones:
``grazing`` (camera and flash together at 75 degrees zenith, beyond every observed view) and ``opposite``
(camera and light at 60 degrees zenith on opposite sides: the mirror configuration, highlight in the middle,
that a collocated capture never sees). For each we render the truth and every estimate, take the per-pixel
absolute error (mean over RGB) and the image-space std of the particles' renders (Eq. 11, mean over RGB), and
report Pearson and Spearman correlations between std and error over the pixels on the sample, per view and
averaged over the two views.

On a mesh (``surface``: ``"bowl"``, ``"sphere"``, ``"block"``, ``"bunny"`` or a mesh file; presets ``mesh_small``
and ``mesh``) the same material covers the object through its uv; the ``views`` observations are collocated
flash photos from perspective cameras around ``mesh.center`` (:func:`~.common.mesh_rig`: 2.6 radii away, zenith
within ``MESH_ZENITH``, Sobol directions by ``seed``, ``image_resolution^2`` pixels; shadows included). Texels no
photo sees keep their prior. The two novel views are ``below`` (camera and flash together at 105 degrees zenith,
under the object's equator, where no observed camera goes: it sees the underside) and ``crossed`` (camera at
50 degrees zenith, the light at 50 degrees zenith 90 degrees of azimuth away: a collocated capture never has the
light off the camera). Every statistic is over the pixels that see the object; ``seen_texels`` repeats the
correlations over the pixels whose texel some photo saw.

Lighting (``lighting``): ``"collocated"`` (the flash photos above) or ``"environment"``, the paper's second
object (its bust "under environmental illuminations"): the same cameras lit by the known environment ``env``
alone, no flash (``"ballroom"``, the psdr-cuda ballroom map of ``../shared/data``, the built-in ``studio()`` with a
warning where that file is missing, ``"studio"``, or a map's path; zenith on ``+z`` turned by ``env_rotate``
degrees, radiance times ``env_scale``). The truth's normal map is made flat (the environment's precomputed
transfer is for the surface's own normals). Its two novel views: the first novel camera (``grazing`` on the plane,
``below`` on a mesh) under the same environment, a novel viewpoint; and ``turned``, the camera of ``opposite``
(plane) or ``crossed`` (mesh) under the environment turned by 180 degrees about ``+z``, a novel lighting. Presets
``mesh_env`` (the bunny, 20 environment-lit photos) and ``mesh_env_small`` (the bowl, what the test runs).
"""
from __future__ import annotations

import math
import time

import numpy as np
import torch

from .common import (PAPER_SIGMA, SURFACE, environment_light, is_mesh, mesh_rig, prepare, sampler_of,
                     scene_surface, synthetic, write_json)
from ..inference import infer
from ..models.data import ModelData
from ..models.material import per_texel
from ..plots import fig4_overview, map_panel, panel_grid
from ..potential import Potential
from ..render.cameras import PerspectiveCamera, RectifiedCamera
from ..render.gbuffer import GBuffer
from ..render.lights import PointLight
from ..render.shade import render
from ..render.views import View, collocated_views
from ..uncertainty import correlations, image_std

DESCRIPTION = "Fig. 4: image-space std (Eq. 11) vs novel-view errors of four point estimates (Adam x2, SGD, ours)"

_COLLOCATED = {"lighting": "collocated", "env": "ballroom", "env_scale": 1.0, "env_rotate": 0.0}
_ENVIRONMENT = {**_COLLOCATED, "lighting": "environment"}
PRESETS = {
    "small": {"material": "wood", "resolution": 32, "views": 20, "particles": 20, "steps": 1500,
              "opt_steps": 600, "adam_lr": 0.05, "sgd_lr": 2e-4, "refine_steps": 100, "init_high": 0.9,
              "init_low": 0.1, "noise_sigma": 0.0, "surface": "plane", "image_resolution": 0,
              "sampler": "figure", **_COLLOCATED},
    "full": {"material": "wood", "resolution": 128, "views": 20, "particles": 20, "steps": 4000,
             "opt_steps": 2000, "adam_lr": 0.05, "sgd_lr": 2e-4, "refine_steps": 200, "init_high": 0.9,
             "init_low": 0.1, "noise_sigma": 0.0, "surface": "plane", "image_resolution": 0,
             "sampler": "figure", **_COLLOCATED},
    # on a mesh (``image_resolution``: pixels per side of its perspective views, 0: twice the map resolution;
    # the plane's rectified views are always at the map resolution). ``mesh_small``: the built-in bowl, what the
    # test runs; ``mesh``: the Stanford bunny of ../shared/data
    "mesh_small": {"material": "wood", "resolution": 16, "views": 10, "particles": 20, "steps": 400,
                   "opt_steps": 300, "adam_lr": 0.05, "sgd_lr": 2e-4, "refine_steps": 50, "init_high": 0.9,
                   "init_low": 0.1, "noise_sigma": 0.0, "surface": "bowl", "image_resolution": 32,
                   "sampler": "spos", **_COLLOCATED},
    "mesh": {"material": "wood", "resolution": 32, "views": 20, "particles": 20, "steps": 1000,
             "opt_steps": 600, "adam_lr": 0.05, "sgd_lr": 2e-4, "refine_steps": 100, "init_high": 0.9,
             "init_low": 0.1, "noise_sigma": 0.0, "surface": "bunny", "image_resolution": 64,
             "sampler": "spos", **_COLLOCATED},
    # the same under the environment alone (the paper's second Fig. 4 object): the bowl (the test) and the bunny
    "mesh_env_small": {"material": "wood", "resolution": 16, "views": 10, "particles": 20, "steps": 400,
                       "opt_steps": 300, "adam_lr": 0.05, "sgd_lr": 2e-4, "refine_steps": 50, "init_high": 0.9,
                       "init_low": 0.1, "noise_sigma": 0.0, "surface": "bowl", "image_resolution": 32,
                       "sampler": "spos", **_ENVIRONMENT},
    "mesh_env": {"material": "wood", "resolution": 32, "views": 20, "particles": 20, "steps": 1000,
                 "opt_steps": 600, "adam_lr": 0.05, "sgd_lr": 2e-4, "refine_steps": 100, "init_high": 0.9,
                 "init_low": 0.1, "noise_sigma": 0.0, "surface": "bunny", "image_resolution": 64,
                 "sampler": "spos", **_ENVIRONMENT},
}
LIGHTINGS = ("collocated", "environment")
#: the observed cameras on a mesh stay within this zenith angle (degrees from +z about ``mesh.center``)
MESH_ZENITH = 80.0

ESTIMATES = ("b1_adam_high", "b2_adam_low", "b3_sgd_random", "b4_ours")
LABELS = {"b1_adam_high": "(b1) Adam, high init", "b2_adam_low": "(b2) Adam, low init",
          "b3_sgd_random": "(b3) SGD, random init", "b4_ours": "(b4) ours (MAP)"}
#: the prior draws that start SPOS and (b3) are kept this fraction of each range away from its bounds
INIT_MARGIN = 0.05


# ------------------------------------------------------------------ point estimates
def optimize(potential, z0: torch.Tensor, methods, *, steps: int, lr, decay: float = 0.1,
             betas=(0.9, 0.999), eps: float = 1e-8) -> tuple[torch.Tensor, torch.Tensor]:
    """Minimise ``-log f(x)`` (``potential.value_and_grad(z, jacobian=False)``) from the rows of ``z0`` ``[n, D]``.

    Every row is an independent optimisation run; all rows share one batched potential evaluation per step.
    ``methods[i]`` is ``"adam"`` or ``"sgd"`` (plain gradient descent) for row ``i``; ``lr`` is one step size or
    one per row; the step size decays linearly to ``decay`` times itself over the run. Returns the final rows
    ``[n, D]`` (unconstrained) and their energies ``[n]``.

    Example:
        >>> from bayes_brdf.potential import FunctionPotential
        >>> pot = FunctionPotential(lambda z: ((z - 1) ** 2).sum(1), dim=2)
        >>> z, u = optimize(pot, torch.zeros(2, 2, dtype=torch.float64), ["adam", "sgd"], steps=300, lr=[0.1, 0.1])
        >>> bool((z - 1).abs().max() < 1e-2)
        True
    """
    z = z0.detach().clone()
    n = z.shape[0]
    methods = [methods] * n if isinstance(methods, str) else list(methods)
    if len(methods) != n or not set(methods) <= {"adam", "sgd"}:
        raise ValueError(f"methods must be 'adam'/'sgd' per row, got {methods}")
    lr = torch.as_tensor(lr, dtype=z.dtype, device=z.device).reshape(-1, 1).expand(n, 1)
    adam = torch.tensor([m == "adam" for m in methods], device=z.device)[:, None]
    m1, m2 = torch.zeros_like(z), torch.zeros_like(z)
    b1, b2 = betas
    for t in range(1, steps + 1):
        _, g = potential.value_and_grad(z, jacobian=False)
        g = torch.nan_to_num(g)
        m1.mul_(b1).add_(g, alpha=1 - b1)
        m2.mul_(b2).addcmul_(g, g, value=1 - b2)
        step_adam = (m1 / (1 - b1 ** t)) / ((m2 / (1 - b2 ** t)).sqrt() + eps)
        frac = 1.0 - (1.0 - decay) * (t - 1) / max(1, steps - 1)
        z = z - frac * lr * torch.where(adam, step_adam, g)
    with torch.no_grad():
        u = potential.energy(z, jacobian=False)
    return z, u


def point_estimates(post, cfg: dict, seed: int) -> tuple[dict, dict]:
    """``({estimate: {site: value}}, {estimate: energy})`` for (b1)-(b4)."""
    pot = post.potential
    like = post.particles
    lo, hi = post.model.roughness_range
    const = lambda site, v: torch.full_like(like[site][:1], float(v))  # noqa: E731
    z_hi = pot.to_unconstrained({"albedo": const("albedo", 0.5), "roughness": const("roughness", cfg["init_high"])})
    z_lo = pot.to_unconstrained({"albedo": const("albedo", 0.5), "roughness": const("roughness", cfg["init_low"])})
    g = torch.Generator().manual_seed(10_000 + seed)
    rnd = {}
    for site, (a, b) in (("albedo", (0.0, 1.0)), ("roughness", (lo, hi))):
        u = torch.rand(like[site][:1].shape, generator=g, dtype=like[site].dtype)
        rnd[site] = a + (b - a) * (INIT_MARGIN + (1 - 2 * INIT_MARGIN) * u)
    z_rnd = pot.to_unconstrained(rnd)
    z0 = torch.cat([z_hi, z_lo, z_rnd])
    z, u = optimize(pot, z0, ["adam", "adam", "sgd"], steps=cfg["opt_steps"],
                    lr=[cfg["adam_lr"], cfg["adam_lr"], cfg["sgd_lr"]])
    x = pot.to_constrained(z)
    est = {name: {k: v[i] for k, v in x.items()} for i, name in enumerate(ESTIMATES[:3])}
    est["b4_ours"] = post.map(refine_steps=cfg["refine_steps"], lr=0.01)
    with torch.no_grad():
        z4 = pot.to_unconstrained({k: v[None] for k, v in est["b4_ours"].items()})
        u4 = pot.energy(z4, jacobian=False)
    energies = {name: float(u[i]) for i, name in enumerate(ESTIMATES[:3])}
    energies["b4_ours"] = float(u4[0])
    return est, energies


# ------------------------------------------------------------------ novel views
def _dir(zenith: float, azimuth: float, r: float):
    t, p = math.radians(zenith), math.radians(azimuth)
    return (r * math.sin(t) * math.cos(p), r * math.sin(t) * math.sin(p), r * math.cos(t))


def novel_views(resolution: int, radius: float = 3.0, power: float = 10.0) -> list[View]:
    """The two novel views (rectified cameras at the map resolution; the observed views are collocated within
    60 degrees zenith): ``grazing``, camera and flash together at 75 degrees zenith, and ``opposite``, camera and
    light at 60 degrees zenith on opposite sides, whose mirror highlight sits in the middle of the sample."""
    graze = _dir(75.0, 30.0, radius)
    cam, light = _dir(60.0, 0.0, radius), _dir(60.0, 180.0, radius)
    return [View.collocated(RectifiedCamera(graze, resolution=resolution), power=power, name="grazing"),
            View(RectifiedCamera(cam, resolution=resolution), (PointLight(light, power),), name="opposite")]


def _mesh_dir(mesh, zenith: float, azimuth: float, r: float):
    c = mesh.center
    return tuple(a + b for a, b in zip(c, _dir(zenith, azimuth, r)))


def mesh_novel_views(mesh, resolution: int) -> list[View]:
    """The two novel views of a mesh (perspective, aimed at ``mesh.center`` from the observed distance; the observed
    views are collocated within ``MESH_ZENITH``): ``below``, camera and flash together at 105 degrees zenith (under
    the object's equator: it sees the underside, which no observed camera does), and ``crossed``, camera at
    50 degrees zenith and the light at 50 degrees zenith 90 degrees of azimuth away."""
    dist, kw = mesh_rig(mesh, resolution)
    cam = lambda pos: PerspectiveCamera(pos, target=kw["target"], fov=kw["fov"], resolution=kw["resolution"])  # noqa: E731
    below = View.collocated(cam(_mesh_dir(mesh, 105.0, 30.0, dist)), power=kw["power"], name="below")
    crossed = View(cam(_mesh_dir(mesh, 50.0, 0.0, dist)), (PointLight(_mesh_dir(mesh, 50.0, 90.0, dist), kw["power"]),),
                   name="crossed")
    return [below, crossed]


def environment_novel_views(views: list[View], env) -> list[View]:
    """The two novel views under the environment ``env`` (from the flash novel views' cameras): the first camera
    under ``env`` itself (a novel viewpoint in the same room), named as it is, and the second camera under ``env``
    turned by 180 degrees about ``+z`` (a novel lighting), named ``turned``."""
    from ..render.environment import EnvironmentLight

    c, s = -1.0, 0.0      # 180 degrees about +z, applied after the map's own to_world
    turn = ((c, -s, 0.0, 0.0), (s, c, 0.0, 0.0), (0.0, 0.0, 1.0, 0.0), (0.0, 0.0, 0.0, 1.0))
    tw = tuple(tuple(sum(turn[i][k] * env.to_world[k][j] for k in range(4)) for j in range(4)) for i in range(4))
    turned = EnvironmentLight(env.radiance, env.scale, tw, name=env.name)
    return [View(views[0].camera, (env,), name=views[0].name), View(views[1].camera, (turned,), name="turned")]


def _lighting(cfg: dict):
    """``(EnvironmentLight or None, description)`` of ``cfg["lighting"]``."""
    from ..errors import InputError

    kind = str(cfg["lighting"])
    if kind not in LIGHTINGS:
        raise InputError(f"unknown lighting {kind!r}", fix=f"lighting: {' or '.join(LIGHTINGS)}")
    if kind == "collocated":
        return None, "collocated flash"
    env, text = environment_light(cfg["env"], cfg["env_scale"], cfg["env_rotate"])
    return env, f"environment alone: {text}"


def _lit(views: list[View], env) -> list[View]:
    """``views`` lit by ``env`` alone (their flashes off); ``views`` as they are for ``env=None``."""
    return list(views) if env is None else [View(v.camera, (env,), name=v.name) for v in views]


def mesh_problem(cfg: dict, mesh, seed: int, env=None):
    """``(truth maps, Observations)`` of Fig. 4 on ``mesh``: ``views`` collocated flash photos around it, or
    the same cameras lit by the environment ``env`` alone (the truth's normal map then flat)."""
    from ..guidance.acquisition import SyntheticCapture
    from ..materials import make_material

    R = int(cfg["resolution"])
    truth = make_material(cfg["material"], R, seed=seed).to(torch.float32)
    if env is not None:
        truth = truth.with_flat_normals()
    dist, kw = mesh_rig(mesh, int(cfg["image_resolution"]) or 2 * R)
    vs = _lit(collocated_views(int(cfg["views"]), dist, method="sobol", max_zenith=MESH_ZENITH, seed=seed, **kw), env)
    obs = SyntheticCapture(truth, mesh, noise_sigma=float(cfg["noise_sigma"]), seed=seed)(vs)
    return truth, obs


def plane_problem(cfg: dict, seed: int, env=None):
    """``(truth maps, Observations)`` of Fig. 4 on the plane: ``views`` collocated rectified flash photos, or the
    same cameras lit by the environment ``env`` alone (the truth's normal map then flat)."""
    from ..guidance.acquisition import SyntheticCapture

    R = int(cfg["resolution"])
    truth, obs = synthetic(cfg["material"], R, views=int(cfg["views"]), seed=seed,
                           noise_sigma=float(cfg["noise_sigma"]))
    if env is None:
        return truth, obs
    truth = truth.with_flat_normals()
    return truth, SyntheticCapture(truth, SURFACE, noise_sigma=float(cfg["noise_sigma"]), seed=seed)(
        _lit(obs.views, env))


def _maps_of(model, values: list[dict]):
    stacked = {k: torch.stack([v[k] for v in values]) for k in values[0]}
    return model.maps(stacked)


def _coverage(obs, mesh, novel_gbuffer, resolution: int) -> dict:
    """Which texels some observed photo sees (``texel_seen [R, R]``) and which novel-view pixels look at one
    (``pixel_seen [V, H, W]``, numpy), by each pixel's nearest texel."""
    from ..render.gbuffer import GBUFFERS

    idx = GBUFFERS.get(tuple(obs.views), mesh).texel_index(resolution)
    seen = torch.zeros(resolution * resolution, dtype=torch.bool)
    seen[idx[idx >= 0]] = True
    nidx = novel_gbuffer.texel_index(resolution)
    pix = torch.where(nidx >= 0, seen[nidx.clamp_min(0)], torch.zeros_like(nidx, dtype=torch.bool))
    return {"texel_seen": seen.reshape(resolution, resolution), "pixel_seen": pix.numpy()}


def _texture_figure(path, truth, est, post, seen, name: str):
    """Texture space on a mesh: true and (b4) roughness, the posterior std of roughness and albedo, with the
    texels no photo sees (atlas gaps and hidden parts: they keep the prior) marked."""
    unseen = {"no photo sees it": ~seen}
    sd = post.std()
    panels = [map_panel(truth.roughness[0], "true roughness", vmax=1.0),
              map_panel(est["roughness"][0], "(b4) roughness", vmax=1.0, masks=unseen),
              map_panel(sd["roughness"][0], "posterior std: roughness", vmax=float(sd["roughness"].max()),
                        masks=unseen),
              map_panel(sd["albedo"].mean(0), "posterior std: albedo (mean RGB)",
                        vmax=float(sd["albedo"].mean(0).max()), masks=unseen)]
    return panel_grid(path, panels, style="compact", panel_size=(2.7, 2.7),
                      title=f"Fig. 4 on the {name}: texture space (the maps the posterior is over)")


def _describe(view: View) -> str:
    """A view's lights in words (:func:`bayes_brdf.report.lighting`), and for an environment the azimuth its
    ``u = 0`` faces: the turned view's environment differs from the photos' by that alone."""
    from ..report import lighting

    env = view.environment
    if env is None:
        return lighting(view)
    r = env.to_world
    az = math.degrees(math.atan2(-r[1][2], -r[0][2]))          # where the map's u = 0 (local -z) points
    return f"{lighting(view)}, u = 0 at azimuth {az % 360:.0f} deg"


# ------------------------------------------------------------------ the experiment
def run(out, preset: str = "small", seed: int = 0, progress: bool = False, **overrides) -> dict:
    """Run Fig. 4 (see the module docstring); writes the PNGs and ``fig4.json`` into ``out`` and returns the numbers."""
    cfg, out = prepare(__name__, preset, overrides, out)
    t0 = time.perf_counter()
    R = int(cfg["resolution"])
    surface = scene_surface(cfg["surface"])
    mesh = is_mesh(surface)
    env, lighting = _lighting(cfg)
    truth, obs = mesh_problem(cfg, surface, seed, env) if mesh else plane_problem(cfg, seed, env)
    model = per_texel(R, specular=truth.specular, normals=truth.normal, sigma=PAPER_SIGMA)

    # SPOS, started from prior draws kept off the bounds (where the logit saturates)
    pot0 = Potential(model, (ModelData.from_observations(obs),))
    x0 = pot0.to_constrained(pot0.init(int(cfg["particles"]), seed=seed))
    lo, hi = model.roughness_range
    x0["albedo"] = x0["albedo"].clamp(INIT_MARGIN, 1 - INIT_MARGIN)
    x0["roughness"] = x0["roughness"].clamp(lo + INIT_MARGIN * (hi - lo), hi - INIT_MARGIN * (hi - lo))
    post = infer(model, obs, sampler_of(cfg["sampler"]), map_steps=0, seed=seed, steps=int(cfg["steps"]), z0=pot0.to_unconstrained(x0),
                 progress=progress)
    t_sample = time.perf_counter() - t0

    t1 = time.perf_counter()
    est, energies = point_estimates(post, cfg, seed)
    t_point = time.perf_counter() - t1

    views = mesh_novel_views(surface, obs.views[0].resolution[0]) if mesh else novel_views(R)
    if env is not None:
        views = environment_novel_views(views, env)
    names = [v.name for v in views]
    with torch.no_grad():
        gb = GBuffer.build(views, surface)
        mask = gb.mask.numpy()                                                  # [V, H, W]
        truth_r = render(truth, views, surface)[0].numpy()                      # [V, H, W, 3]
        est_r_all = render(_maps_of(model, [est[e] for e in ESTIMATES]), views, surface).numpy()
        std = (image_std(post, views, surface) if mesh else image_std(post, views)).mean(-1).numpy()  # [V, H, W]
    est_r = {e: est_r_all[i] for i, e in enumerate(ESTIMATES)}
    errors = {e: np.abs(est_r[e] - truth_r).mean(-1) for e in ESTIMATES}
    coverage = _coverage(obs, surface, gb, R) if mesh else None

    per_view = {}
    for v, name in enumerate(names):
        m = mask[v]
        row = {"std_mean": float(std[v][m].mean()), "truth_mean_radiance": float(truth_r[v][m].mean()),
               "lighting": _describe(views[v])}
        for e in ESTIMATES:
            c = correlations(torch.from_numpy(std[v][m]), torch.from_numpy(errors[e][v][m]))
            row[e] = {"pearson": c["pearson"], "spearman": c["spearman"], "mae": float(errors[e][v][m].mean())}
        if coverage is not None:   # the same over the object's pixels whose texel some photo saw
            ms = m & coverage["pixel_seen"][v]
            row["object_pixels"] = int(m.sum())
            row["unseen_texel_pixels"] = int((m & ~coverage["pixel_seen"][v]).sum())
            row["std_mean_seen_texels"] = float(std[v][ms].mean()) if ms.any() else float("nan")
            row["std_mean_unseen_texels"] = (float(std[v][m & ~ms].mean()) if (m & ~ms).any() else float("nan"))
            row["seen_texels"] = {e: correlations(torch.from_numpy(std[v][ms]), torch.from_numpy(errors[e][v][ms]))
                                  for e in ESTIMATES}
            # and over the lit ones (a pixel in shadow, or facing away from the light, is 0 for every particle:
            # std and error 0 together, which a rank correlation counts as agreement)
            ml = m & (truth_r[v].mean(-1) > 1e-6)
            row["lit_fraction"] = float(ml.sum() / max(int(m.sum()), 1))
            row["lit"] = {e: correlations(torch.from_numpy(std[v][ml]), torch.from_numpy(errors[e][v][ml]))
                          for e in ESTIMATES}
        per_view[name] = row
    avg = {e: {k: float(np.mean([per_view[n][e][k] for n in names])) for k in ("pearson", "spearman", "mae")}
           for e in ESTIMATES}
    param_err = {e: {"albedo_mae": float((est[e]["albedo"] - truth.albedo).abs().mean()),
                     "roughness_mae": float((est[e]["roughness"] - truth.roughness).abs().mean())} for e in ESTIMATES}
    if coverage is not None:   # on a mesh the texels no photo sees keep the prior: the errors over the seen ones
        seen = coverage["texel_seen"]
        for e in ESTIMATES:
            param_err[e]["albedo_mae_seen"] = float((est[e]["albedo"] - truth.albedo).abs().mean(0)[seen].mean())
            param_err[e]["roughness_mae_seen"] = float((est[e]["roughness"] - truth.roughness).abs()[0][seen].mean())

    vmaxes = [float(max(np.percentile(np.concatenate([std[v][mask[v]]] + [errors[e][v][mask[v]] for e in ESTIMATES]),
                                      99), 1e-9)) for v in range(len(names))]
    if mesh:   # off the object: no value (drawn blank), never read as a 0
        std = np.where(mask, std, np.nan)
        errors = {e: np.where(mask, errors[e], np.nan) for e in ESTIMATES}
    files = [fig4_overview(out / "fig4.png", names, truth_r,
                           {LABELS[e]: (e[:2], est_r[e], errors[e]) for e in ESTIMATES}, std, vmaxes)]
    where = (f" on the {surface.name} (blank: off the object)" if mesh else "") + \
        (", environment-lit" if env is not None else "")
    for v, name in enumerate(names):
        panels = [map_panel(std[v], "std (Eq. 11)", vmax=vmaxes[v])] + [
            map_panel(errors[e][v], f"|error| {LABELS[e]}", vmax=vmaxes[v]) for e in ESTIMATES]
        files.append(panel_grid(out / f"fig4_{name}.png", panels, ncols=5, style="compact",
                                title=f"Fig. 4, novel view '{name}'{where}: image-space std and |error| of "
                                      f"(b1)-(b4), one range"))
    if mesh:
        files.append(_texture_figure(out / "fig4_texture.png", truth, est["b4_ours"], post, coverage["texel_seen"],
                                     surface.name))

    summary = {"pearson": {e: round(avg[e]["pearson"], 3) for e in ESTIMATES},
               "spearman": {e: round(avg[e]["spearman"], 3) for e in ESTIMATES},
               "all_positive": bool(all(avg[e]["pearson"] > 0 and avg[e]["spearman"] > 0 for e in ESTIMATES)),
               "seconds": round(time.perf_counter() - t0, 1), "lighting": lighting,
               "std_mean": {n: float(per_view[n]["std_mean"]) for n in names}}
    extra = {}
    if mesh:
        extra = {"surface": {"name": surface.name, "faces": surface.num_faces, "center": list(surface.center),
                             "radius": surface.radius},
                 "texels_seen_fraction": float(coverage["texel_seen"].float().mean()),
                 "average_seen_texels": {e: {k: float(np.mean([per_view[n]["seen_texels"][e][k] for n in names]))
                                             for k in ("pearson", "spearman")} for e in ESTIMATES},
                 "average_lit": {e: {k: float(np.mean([per_view[n]["lit"][e][k] for n in names]))
                                     for k in ("pearson", "spearman")} for e in ESTIMATES}}
        summary["mae"] = {e: float(avg[e]["mae"]) for e in ESTIMATES}
        summary["texels_seen_fraction"] = round(extra["texels_seen_fraction"], 3)
    res = {"experiment": "fig4", "preset": preset, "seed": seed, "config": cfg, "novel_views": names, **extra,
           "lighting": {"observed": lighting, "novel": {n: per_view[n]["lighting"] for n in names}},
           "per_view": per_view, "average": avg, "energies": energies, "parameter_error": param_err,
           "posterior_std": {"albedo": float(post.std("albedo").mean()),
                             "roughness": float(post.std("roughness").mean())},
           "seconds": {"sampling": t_sample, "point_estimates": t_point, "total": time.perf_counter() - t0},
           "files": [p.name for p in files] + ["fig4.json"], "summary": summary}
    write_json(out, "fig4", res)
    return res
