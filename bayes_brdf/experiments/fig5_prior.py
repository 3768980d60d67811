"""Fig. 5: prior awareness -- a smooth plane inferred without and with a low-roughness prior.

Setup (the paper's Sec. 4, "Prior awareness"): a homogeneous smooth material (albedo ``(0.5, 0.35, 0.25)``,
roughness ``roughness`` = 0.12, specular F0 0.04, flat) observed under ``views`` = 10 collocated flash views
(rectified cameras at the map resolution, Sobol directions within 60 degrees zenith, seeded by ``seed``), with
optional Laplace noise ``noise_sigma``. Albedo (RGB) and roughness are inferred *per texel* (``resolution^2``
texels, ``FIGURE_SAMPLER`` (the former ``spos_maps``)) twice: with the default uniform prior on roughness, and with the low-roughness prior
``Prior.gaussian(prior_mean, prior_std)`` (the paper: a Gaussian around the ground-truth roughness).

Why this is ambiguous without the prior: a roughness-0.12 lobe is a few degrees wide, so a texel only sees
its highlight when one of the 10 views happens to look at it near the mirror direction; for every other texel
the specular term is far below the noise scale of the likelihood (``sigma`` = 0.01) for any roughness (a rough
lobe with F0 = 0.04 is a faint, nearly diffuse glow that a slightly darker albedo absorbs). The experiment
measures this: ``highlight_texels`` is the fraction of texels whose largest true specular radiance over the
observed views exceeds ``sigma``. Those texels have low roughness std even without the prior; all others are
left to the prior. The Gaussian prior removes the ambiguity everywhere (parameter-space std) and with it the
image-space std of a novel view that sees the highlight (collocated, straight above the sample, rendered at
``novel_resolution`` pixels).

Numbers (per prior): posterior mean and std of roughness and albedo (averaged over texels), the error of the
posterior mean and of the MAP estimate (Sec. 3.3.1) against the truth, the fraction of texels whose roughness
std is below 0.05, and the mean / 99th percentile of the novel view's image-space std.
"""
from __future__ import annotations

import time

import numpy as np
import torch

from .common import FIGURE_SAMPLER, PAPER_SIGMA, SURFACE, prepare, write_json
from ..guidance.acquisition import SyntheticCapture
from ..inference import infer
from ..models.data import ModelData
from ..models.material import per_texel
from ..models.priors import gaussian, uniform
from ..plots import fig5_overview, map_panel, panel_grid
from ..potential import Potential
from ..render.cameras import RectifiedCamera
from ..render.maps import SVBRDF
from ..render.shade import render
from ..render.views import View, collocated_views
from ..uncertainty import image_std

DESCRIPTION = "Fig. 5: prior awareness: a smooth plane (roughness 0.12) without / with a low-roughness prior"

PRESETS = {
    "small": {"resolution": 16, "views": 10, "roughness": 0.12, "prior_mean": 0.12, "prior_std": 0.02,
              "particles": 20, "steps": 1500, "refine_steps": 100, "noise_sigma": 0.0, "max_zenith": 60.0,
              "novel_resolution": 64},
    "full": {"resolution": 64, "views": 10, "roughness": 0.12, "prior_mean": 0.12, "prior_std": 0.02,
             "particles": 20, "steps": 4000, "refine_steps": 200, "noise_sigma": 0.0, "max_zenith": 60.0,
             "novel_resolution": 128},
}

ALBEDO = (0.5, 0.35, 0.25)
PRIORS = ("uniform", "gaussian")
LABELS = {"uniform": "no roughness prior", "gaussian": "low-roughness prior"}
INIT_MARGIN = 0.05
#: a texel's roughness counts as "determined" when its posterior std is below this
DETERMINED = 0.05


def _sample(model, obs, cfg, seed, progress):
    """``FIGURE_SAMPLER`` (the former ``spos_maps``) from prior draws kept ``INIT_MARGIN`` away from the bounds (where the logit saturates)."""
    pot = Potential(model, (ModelData.from_observations(obs),))
    x0 = pot.to_constrained(pot.init(int(cfg["particles"]), seed=seed))
    lo, hi = model.roughness_range
    x0["albedo"] = x0["albedo"].clamp(INIT_MARGIN, 1 - INIT_MARGIN)
    x0["roughness"] = x0["roughness"].clamp(lo + INIT_MARGIN * (hi - lo), hi - INIT_MARGIN * (hi - lo))
    return infer(model, obs, FIGURE_SAMPLER, map_steps=0, seed=seed, steps=int(cfg["steps"]), z0=pot.to_unconstrained(x0),
                 progress=progress)


def novel_view(resolution: int, radius: float = 3.0, power: float = 10.0) -> View:
    """Collocated camera and flash straight above the sample: the highlight sits in the middle of the image."""
    return View.collocated(RectifiedCamera((0.0, 0.0, radius), resolution=resolution), power=power, name="top")


def run(out, preset: str = "small", seed: int = 0, progress: bool = False, **overrides) -> dict:
    """Run Fig. 5 (see the module docstring); writes the PNGs and ``fig5.json`` into ``out`` and returns the numbers."""
    cfg, out = prepare(__name__, preset, overrides, out)
    t0 = time.perf_counter()
    R, rough = int(cfg["resolution"]), float(cfg["roughness"])
    truth = SVBRDF.constant(ALBEDO, rough, 0.04, dtype=torch.float32)
    views = collocated_views(int(cfg["views"]), 3.0, method="sobol", camera="rectified", resolution=R, power=10.0,
                             max_zenith=float(cfg["max_zenith"]), seed=seed)
    obs = SyntheticCapture(truth, SURFACE, noise_sigma=float(cfg["noise_sigma"]), seed=seed)(views)
    sigma = PAPER_SIGMA

    # how many texels ever see the highlight: the largest true specular radiance over the observed views
    with torch.no_grad():
        spec = render(SVBRDF.constant(0.0, rough, 0.04, dtype=torch.float32), views, SURFACE)[0].mean(-1).amax(0)
    highlight = (spec > sigma).numpy()

    nv = novel_view(int(cfg["novel_resolution"]))
    with torch.no_grad():
        truth_render = render(truth, [nv], SURFACE)[0, 0].numpy()
    ta = torch.tensor(ALBEDO)[:, None, None]
    res, nums, hist = {}, {}, {}
    for p in PRIORS:
        prior = uniform() if p == "uniform" else gaussian(float(cfg["prior_mean"]), float(cfg["prior_std"]))
        model = per_texel(R, prior={"roughness": prior}, sigma=sigma)
        t1 = time.perf_counter()
        post = _sample(model, obs, cfg, seed, progress)
        secs = time.perf_counter() - t1
        mp = post.map(refine_steps=int(cfg["refine_steps"]), lr=0.01)
        r_std, a_std = post.std("roughness")[0], post.std("albedo").mean(0)
        with torch.no_grad():
            std, _ = image_std(post, [nv], return_mean=True)
            std = std[0].mean(-1).numpy()
            map_render = render(model.maps({k: v[None] for k, v in mp.items()}), [nv], SURFACE)[0, 0].numpy()
        rs = r_std.numpy()
        nums[p] = {
            "roughness_mean": float(post.mean("roughness").mean()), "roughness_std": float(r_std.mean()),
            "roughness_mean_abs_error": float((post.mean("roughness") - rough).abs().mean()),
            "roughness_map_abs_error": float((mp["roughness"] - rough).abs().mean()),
            "albedo_mean": [float(v) for v in post.mean("albedo").mean((1, 2))],
            "albedo_std": float(a_std.mean()),
            "albedo_mean_abs_error": float((post.mean("albedo") - ta).abs().mean()),
            "albedo_map_abs_error": float((mp["albedo"] - ta).abs().mean()),
            "determined_fraction": float((rs < DETERMINED).mean()),
            "roughness_std_highlight_texels": float(rs[highlight].mean()) if highlight.any() else None,
            "roughness_std_other_texels": float(rs[~highlight].mean()) if (~highlight).any() else None,
            "image_std_mean": float(std.mean()), "image_std_p99": float(np.percentile(std, 99)),
            "image_std_max": float(std.max()),
            "map_render_abs_error": float(np.abs(map_render - truth_render).mean()),
            "seconds": secs,
        }
        res[p] = {"render": map_render, "rough_map": mp["roughness"][0].numpy(), "rough_std": rs,
                  "albedo_err": (mp["albedo"] - ta).abs().mean(0).numpy(), "img_std": std}
        hist[p] = post.particles["roughness"].reshape(-1).numpy()

    def vmax(key):
        return float(max(np.percentile(res[p][key], 99) for p in PRIORS)) or 1e-6
    vmaxes = {"rough_map": 1.0, "rough_std": vmax("rough_std"), "albedo_err": vmax("albedo_err"),
              "img_std": vmax("img_std")}
    files = [fig5_overview(out / "fig5.png", {LABELS[p]: res[p] for p in PRIORS}, truth_render,
                           {LABELS[p]: hist[p] for p in PRIORS}, vmaxes, rough,
                           title="Fig. 5: smooth plane, 10 collocated views, without (top) / with (bottom) a "
                                 "low-roughness prior", hist_label="roughness (all particles, all texels)")]
    files.append(_std_grid(out / "fig5_image_std.png", res))

    u, g = nums["uniform"], nums["gaussian"]
    summary = {"roughness_std": {"uniform": round(u["roughness_std"], 4), "gaussian": round(g["roughness_std"], 4)},
               "roughness_mean": {"uniform": round(u["roughness_mean"], 3), "gaussian": round(g["roughness_mean"], 3)},
               "roughness_map_abs_error": {"uniform": round(u["roughness_map_abs_error"], 3),
                                           "gaussian": round(g["roughness_map_abs_error"], 3)},
               "image_std_mean": {"uniform": round(u["image_std_mean"], 4), "gaussian": round(g["image_std_mean"], 4)},
               "highlight_texels": round(float(highlight.mean()), 3),
               "prior_lowers_std": bool(g["roughness_std"] < u["roughness_std"]),
               "seconds": round(time.perf_counter() - t0, 1)}
    out_json = {"experiment": "fig5", "preset": preset, "seed": seed, "config": cfg, "truth": {
        "albedo": list(ALBEDO), "roughness": rough, "specular": 0.04}, "sigma": sigma,
        "highlight_texels": float(highlight.mean()), "results": nums,
        "files": [f.name for f in files] + ["fig5.json"], "summary": summary,
        "seconds": time.perf_counter() - t0}
    write_json(out, "fig5", out_json)
    return out_json


def _std_grid(path, res):
    """The novel-view image-space std side by side (one range)."""
    return panel_grid(path, [map_panel(res[p]["img_std"], LABELS[p]) for p in PRIORS], share=True, style="compact",
                      title="Fig. 5: novel-view image-space std (Eq. 11), one range")
