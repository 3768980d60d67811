"""Side by side with the closest peer, Wiersma et al. 2025 ("Uncertainty for SVBRDF Acquisition using Frequency
Analysis"), on their own scene: ``../shared/data/peer_wiersma`` (MIT).

Their protocol (``plane/dataset.gin``): a UV-mapped plane (``plane.obj``, y up), 64^2 ground-truth textures
(``base_color``, ``roughness``, ``metallic``: Mitsuba ``principled`` parameters), 100 cameras on a Fibonacci upper
hemisphere of radius 3.5 aimed at the origin, FOV 45 degrees, 256^2 renders by Mitsuba at 256 spp under
``matpreview_envmap.exr``. Their method, run on this scene, gives a per-texel Spearman correlation between its
uncertainty and the roughness error of -0.29 (metallic +0.32) (``../shared/data/README.md``).

Here: the same plane (y up turned to our z up), textures and environment (its zenith on +z), the same cameras;
the photos rendered by Mitsuba's own ``principled`` BSDF through its ``path`` integrator
(:func:`~bayes_brdf.render.mitsuba_reference.render_principled`) directly at the fitting resolution
``fit_resolution`` (a pixel of a 64^2 render averages what 16 pixels of theirs at 256^2 do: their 256 spp there
are 4096 per pixel here; ``spp`` says how many we take), then fitted with
:func:`~bayes_brdf.models.metallic.metallic_roughness` (``texels^2`` per map, the default ``sigma = "auto"`` noise
model, the default SPOS) under the same known environment. Fitting with our BRDF what ``principled`` rendered is
part of the test: the two differ in their diffuse term (docs/models.md). For each number of fitted views in
``subsets`` (evenly spread over the 100, so every subset sees the plane from all around):

* per texel, Spearman(posterior std, |MAP - truth|) of roughness and metallic (their -0.29 / +0.32), and the
  MAP's mean absolute error of base colour, roughness and metallic against the truth (at ``texels^2``, the
  truth area-averaged where ``texels`` is below 64);
* on ``novel_views`` other cameras (a second Fibonacci set, turned by half a step), rendered the same way: the
  image-space std (Eq. 11) against the MAP render's |error| (Pearson, Spearman) and the 50 % / 90 % coverage of
  the posterior predictive;
* the times (rendering, the environment's transfer and sampling).

``run`` writes ``wiersma.json`` and the same numbers as ``summary.json`` (``per_texel_spearman.roughness`` and
``.metallic`` for the largest subset), and ``wiersma_maps.png`` (truth, MAP, std and error of roughness and
metallic with the most views).
"""
from __future__ import annotations

import math
import time

import numpy as np
import torch

from .common import SHARED_DATA, prepare, say, write_json
from ..errors import InputError

DESCRIPTION = "Wiersma et al. 2025 side by side on their plane: per-texel Spearman(std, |error|) of roughness, metallic"

SCENE = SHARED_DATA / "peer_wiersma" / "experiments" / "scenes"
#: their numbers on this scene (../shared/data/README.md): per-texel Spearman of entropy and error
PEER = {"roughness": -0.29, "metallic": 0.32}
RADIUS, FOV = 3.5, 45.0

#: what ``bayes-brdf experiment wiersma`` runs without ``--preset``: the peer's whole protocol (about 6 minutes)
DEFAULT_PRESET = "full"

PRESETS = {
    # what the test runs: 8 views of 24^2, 16^2 texels, a short run
    "small": {"views": 8, "subsets": "3,8", "fit_resolution": 24, "texels": 16, "spp": 16, "novel_views": 2,
              "particles": 12, "steps": 300, "seed_render": 0},
    # their protocol (100 views, their textures at 64^2), rendered and fitted at 64^2 pixels with their samples
    # per area (256 spp at 256^2 = 4096 per pixel at 64^2)
    "full": {"views": 100, "subsets": "3,10,30,100", "fit_resolution": 64, "texels": 64, "spp": 4096,
             "novel_views": 8, "particles": 20, "steps": 2000, "seed_render": 0},
}


def scene():
    """``(mesh, textures {base_color [3, 64, 64], metallic [1, ...], roughness [1, ...]}, EnvironmentLight)`` of
    their scene, in our conventions (z up; texel row 0 at ``v = 1``); one line if ``../shared/data`` is missing."""
    from ..io import read_image
    from ..render.environment import EnvironmentLight, z_up
    from ..render.mesh import Mesh

    obj = SCENE / "plane" / "plane.obj"
    if not obj.is_file():
        raise InputError("Wiersma et al.'s scene is not there", where=str(obj),
                         fix="put ../shared/data beside the repository")
    mesh = Mesh.load(obj, up="y")
    tex = {}
    for name, c in (("base_color", 3), ("metallic", 1), ("roughness", 1)):
        a = read_image(SCENE / "plane" / "textures" / f"{name}.exr")[..., :c]
        # Mitsuba reads a bitmap's row j at v = (j + 1/2) / H, ours texel row 0 at v = 1: rows flipped
        tex[name] = torch.from_numpy(np.ascontiguousarray(a[::-1].transpose(2, 0, 1))).float().clamp(0, 1)
    env = EnvironmentLight.from_file(SCENE / "envmaps" / "matpreview_envmap.exr", 1.0, z_up(0.0))
    return mesh, tex, env


def cameras(count: int, resolution: int, env, offset: float = 0.0):
    """``count`` views on the Fibonacci upper hemisphere of radius 3.5 about the origin
    (:func:`~bayes_brdf.render.views.hemisphere_directions`, its spiral turned the other way round, as theirs
    turns), FOV 45 degrees, lit by ``env`` alone; ``offset`` turns the spiral by that fraction of its azimuth
    step (a second, novel set)."""
    from ..render.cameras import PerspectiveCamera
    from ..render.views import View, hemisphere_directions

    d = hemisphere_directions(count, "fibonacci")
    a = math.pi * (3 - math.sqrt(5)) * offset                  # the golden angle times offset
    c, s = math.cos(a), math.sin(a)
    x, y = d[:, 0], -d[:, 1]                                    # mirrored: azimuths + i * golden angle
    pos = RADIUS * torch.stack([c * x - s * y, s * x + c * y, d[:, 2]], 1)
    return [View(PerspectiveCamera(tuple(p.tolist()), target=(0.0, 0.0, 0.0), up=(0.0, 0.0, 1.0), fov=FOV,
                                   resolution=(resolution, resolution)), (env,),
                 name=f"cam{i:03d}" if not offset else f"novel{i:02d}") for i, p in enumerate(pos)]


def subset_indices(total: int, k: int) -> list[int]:
    """``k`` of ``total`` views spread evenly over the spiral (first and last included).

    Example:
        >>> subset_indices(100, 3), subset_indices(8, 8)
        ([0, 50, 99], [0, 1, 2, 3, 4, 5, 6, 7])
    """
    return sorted({int(round(x)) for x in np.linspace(0, total - 1, k)})


def _area(t: torch.Tensor, res: int) -> torch.Tensor:
    """A map ``[C, R, R]`` area-averaged to ``res^2`` (itself where ``res`` is ``R``)."""
    return t if t.shape[-1] == res else torch.nn.functional.adaptive_avg_pool2d(t[None], res)[0]


def _spearman(a: torch.Tensor, b: torch.Tensor) -> float:
    from ..uncertainty import correlations
    return correlations(a, b)["spearman"]


def run(out, preset: str = DEFAULT_PRESET, seed: int = 0, progress: bool = False, **overrides) -> dict:
    """Run the side-by-side (see the module docstring; by default the full protocol); returns and writes the
    numbers."""
    from ..inference import infer
    from ..models.metallic import SITES, metallic_roughness
    from ..observations import Observations
    from ..plots import map_panel, panel_grid
    from ..render.mitsuba_reference import render_principled
    from ..runs.heldout import predict
    from ..uncertainty import correlations, coverage

    cfg, out = prepare(__name__, preset, overrides, out)
    V, R, T = int(cfg["views"]), int(cfg["fit_resolution"]), int(cfg["texels"])
    subsets = sorted({int(k) for k in str(cfg["subsets"]).split(",") if k.strip()})
    if not subsets or subsets[0] < 1 or subsets[-1] > V:
        raise InputError(f"subsets {cfg['subsets']!r} must be view counts from 1 to views ({V})")
    t_all = time.perf_counter()
    mesh, tex, env = scene()
    truth = {k: _area(v, T) for k, v in tex.items()}

    t0 = time.perf_counter()
    views = cameras(V, R, env)
    novel = cameras(int(cfg["novel_views"]), R, env, offset=0.5)
    spp, sr = int(cfg["spp"]), int(cfg["seed_render"])
    images = render_principled(tex, views, mesh, spp=spp, seed=sr).float()
    novel_images = render_principled(tex, novel, mesh, spp=spp, seed=sr + 1).float()
    t_render = time.perf_counter() - t0
    say("wiersma: rendered %d + %d views of %d^2 at %d spp in %.0f s", V, len(novel), R, spp, t_render)

    rows, best = {}, None
    for k in subsets:
        idx = subset_indices(V, k)
        obs = Observations([views[i] for i in idx], images[idx], mesh, meta={"indices": idx})
        model = metallic_roughness(T, roughness_range=(0.02, 1.0))
        t1 = time.perf_counter()
        post = infer(model, obs, "spos", seed=seed, particles=int(cfg["particles"]), steps=int(cfg["steps"]),
                     progress=progress)
        t_fit = time.perf_counter() - t1
        mp = post.map()
        std = post.std()
        err = {s: (mp[s] - truth[s].to(mp[s])).abs() for s in SITES}
        row = {"views": k, "indices": idx, "seconds": round(t_fit, 1),
               "sampling_seconds": round(float(post.log.get("seconds") or 0.0), 1),
               "per_texel_spearman": {s: round(_spearman(std[s].mean(0), err[s].mean(0)), 3)
                                      for s in ("roughness", "metallic")},
               "map_mae": {s: round(float(err[s].mean()), 4) for s in SITES},
               "mean_std": {s: round(float(std[s].mean()), 4) for s in SITES},
               "noise_sigma": post.noise_sigma,
               "converged": bool(post.diagnostics and post.diagnostics.get("converged")),
               "failed_checks": list((post.diagnostics or {}).get("failed", []))}
        F, istd, _, _, _, ierr, inside = predict(post, novel, novel_images, mesh)
        m = inside[..., None].expand_as(ierr)
        row["novel_views"] = {**{k2: round(v, 3) for k2, v in correlations(istd[m], ierr[m]).items()},
                              "coverage": {q: round(v, 3) for q, v in coverage(F[m]).items()},
                              "mean_abs_error": round(float(ierr[m].mean()), 5),
                              "mean_std": round(float(istd[m].mean()), 5)}
        rows[str(k)] = row
        best = (k, mp, std, err)
        say("wiersma: %d views: per-texel Spearman roughness %.2f, metallic %.2f (%.0f s)", k,
            row["per_texel_spearman"]["roughness"], row["per_texel_spearman"]["metallic"], t_fit)

    k, mp, std, err = best
    panels = []
    for s in ("roughness", "metallic"):
        panels += [map_panel(truth[s], f"{s}: truth", vmax=1.0), map_panel(mp[s], f"{s}: MAP ({k} views)", vmax=1.0),
                   map_panel(std[s], f"{s}: posterior std"), map_panel(err[s], f"{s}: |MAP - truth|")]
    files = [panel_grid(out / "wiersma_maps.png", panels, ncols=4, style="compact",
                        title=f"Wiersma et al.'s plane: {k} views of {R}^2 under matpreview_envmap, "
                              f"metallic_roughness at {T}^2")]
    top = rows[str(subsets[-1])]
    res = {"experiment": "wiersma", "preset": preset, "seed": seed, "config": cfg,
           "per_texel_spearman": top["per_texel_spearman"], "peer_per_texel_spearman": PEER,
           "map_mae": top["map_mae"], "novel_views": top["novel_views"], "rows": rows,
           "seconds": {"render": round(t_render, 1), "render_per_view": round(t_render / (V + len(novel)), 3),
                       "total": round(time.perf_counter() - t_all, 1)},
           "protocol": f"{V} cameras on a Fibonacci upper hemisphere of radius {RADIUS}, FOV {FOV:g}, rendered at "
                       f"{R}^2 with {spp} spp by Mitsuba's principled BSDF and path integrator under "
                       "matpreview_envmap.exr; fitted with metallic_roughness at "
                       f"{T}^2 texels (their renders: 256^2 at 256 spp)",
           "files": [f.name for f in files]}
    write_json(out, "wiersma", res)
    write_json(out, "summary", res)
    return res
