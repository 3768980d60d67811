"""Fig. 6: the posterior over a generator's latent space (``latent_decoder``) beside ``per_texel`` on the same data.

Two data sets, each fitted by both models with the default SPOS (``particles``, ``steps``; the latent model
starts from the projection of the photos, ``project_steps``):

* **synthetic** -- a procedural material the decoder never saw in training (``material`` with seed
  ``material_seed``, from the held-out seed range :data:`~bayes_brdf.materials.augment.HELD_OUT_SEED`), at the
  decoder's ``64²``, observed from ``views`` collocated flash views (rectified cameras within 60 degrees zenith,
  Sobol directions) with Laplace noise ``noise_sigma``, clipped at 1 as a camera's (clipped pixels are censored
  by the likelihood and left out of the scores); scored on Fig. 4's two novel views (``grazing``,
  ``opposite``), rendered from the truth with the same noise and clipping;
* **card_blue** (``capture``; MaterialGAN's real capture in ``../shared/data``) at ``capture_resolution`` pixels,
  fitted on ``capture_views`` and scored on the other photos.

For each: the image-space std (Eq. 11, over the particles' renders) against the MAP render's absolute error
(Pearson, Spearman over pixels and channels), the coverage of the held-out values by the posterior
predictive's central 50 % / 90 % intervals, the MAP's mean absolute error and PSNR, the mean map-space std
(Eq. 9 on albedo and roughness) and the wall time. Both models infer the noise level (``sigma = "auto"``);
``per_texel`` infers RGB albedo and roughness with the truth's normals and specular unknown to it (flat, 0.04),
the latent model all four maps.
"""
from __future__ import annotations

import math
import time

import torch

from .common import SHARED_DATA, camera_clip, prepare, say, synthetic, write_json
from .fig4_image_space import novel_views
from ..errors import InputError
from ..guidance.acquisition import SyntheticCapture
from ..inference import infer
from ..materials.augment import HELD_OUT_SEED
from ..models.latent_decoder import latent_decoder
from ..models.material import per_texel
from ..plots import fig6_overview
from ..runs.heldout import predict
from ..uncertainty import correlations, coverage

DESCRIPTION = "Fig. 6: latent-space (MaterialGAN-style decoder) posterior vs per-texel: std vs error, coverage, time"

PRESETS = {
    "small": {"material": "tiles", "material_seed": HELD_OUT_SEED, "views": 7, "noise_sigma": 0.01,
              "particles": 12, "steps": 300, "per_texel_steps": 1500, "project_steps": 300,
              "capture": "card_blue", "capture_resolution": 64, "capture_views": "0,1,2,4,5,6,8"},
    "full": {"material": "tiles", "material_seed": HELD_OUT_SEED, "views": 7, "noise_sigma": 0.01,
             "particles": 20, "steps": 1000, "per_texel_steps": 2000, "project_steps": 500,
             "capture": "card_blue", "capture_resolution": 64, "capture_views": "0,1,2,4,5,6,8"},
}
SETTING_TYPES = {"capture_views": str, "capture": str, "material": str}
MODELS = ("latent_decoder", "per_texel")


def _psnr(a: torch.Tensor, b: torch.Tensor) -> float:
    mse = float(((a - b) ** 2).mean())
    return 10 * math.log10(1.0 / max(mse, 1e-12))


def score(post, views, images, surface, mask=None) -> dict:
    """``(numbers, std, error, MAP render)`` on ``views`` with observed ``images``: Eq. 11 std vs the MAP's
    error, predictive coverage, MAP error; ``mask [V, H, W]`` selects the pixels scored."""
    F, std, _, pred, y, err, valid = predict(post, views, images, surface)
    if mask is not None:
        valid = valid & mask
    v3 = valid[..., None].expand_as(err)
    return {"pixels": int(valid.sum()), **correlations(std[v3], err[v3]), "coverage": coverage(F[v3]),
            "mean_abs_error": float(err[v3].mean()), "psnr": _psnr(pred[v3], y[v3]),
            "mean_image_std": float(std[v3].mean())}, std, err, pred


def _models(cfg: dict, resolution: int) -> dict:
    return {"latent_decoder": latent_decoder(project_steps=int(cfg["project_steps"])),
            "per_texel": per_texel(resolution)}


def _fit_all(obs, cfg, seed, progress) -> dict:
    out = {}
    for name, model in _models(cfg, 64).items():
        steps = int(cfg["steps"] if name == "latent_decoder" else cfg["per_texel_steps"])
        t = time.perf_counter()
        post = infer(model, obs, "spos", seed=seed, particles=int(cfg["particles"]), steps=steps, progress=progress)
        out[name] = (post, time.perf_counter() - t)
        say("fig6: %s fitted in %.0f s", name, out[name][1])
    return out


def _map_std(post) -> dict:
    sd = post.std()
    return {k: float(sd[k].mean()) for k in ("albedo", "roughness") if k in sd}


def run(out, preset: str = "small", seed: int = 0, progress: bool = False, **overrides) -> dict:
    cfg, out = prepare(__name__, preset, overrides, out)
    results, rows = {"config": cfg, "seed": seed}, []
    # ---- synthetic: a held-out procedural material
    truth, obs = synthetic(cfg["material"], 64, int(cfg["views"]), seed=int(cfg["material_seed"]),
                           noise_sigma=float(cfg["noise_sigma"]), view_seed=seed)
    obs = camera_clip(obs)
    novel = novel_views(64)
    photos = camera_clip(SyntheticCapture(truth, obs.surface, noise_sigma=float(cfg["noise_sigma"]),
                                          seed=20_000 + seed)(novel))
    fits = _fit_all(obs, cfg, seed, progress)
    syn = {}
    for vi, v in enumerate(novel):
        per_model = {}
        for name, (post, secs) in fits.items():
            s, std, err, pred = score(post, [v], photos.images[vi:vi + 1], obs.surface, ~photos.saturated[vi:vi + 1])
            per_model[name] = {**s, "std": std[0].numpy(), "err": err[0].numpy(), "pred": pred[0].numpy()}
        rows.append((f"synthetic, {v.name}", photos.images[vi].numpy(), per_model))
    for name, (post, secs) in fits.items():
        s, *_ = score(post, novel, photos.images, obs.surface, ~photos.saturated)
        syn[name] = {**s, "seconds": round(secs, 1), "map_std": _map_std(post), "noise_sigma": post.noise_sigma,
                     "converged": (post.diagnostics or {}).get("converged")}
    results["synthetic"] = syn
    # ---- card_blue with views held out
    if cfg["capture"]:
        from ..io import load_capture
        path = SHARED_DATA / "captures" / cfg["capture"]
        if not path.is_dir():
            raise InputError(f"no capture '{cfg['capture']}' in ../shared/data/captures",
                             fix="put ../shared/data beside the repository, or --set capture=")
        full = load_capture(path, resolution=int(cfg["capture_resolution"]))
        fit_idx = [int(i) for i in str(cfg["capture_views"]).split(",")]
        held_idx = [i for i in range(len(full)) if i not in fit_idx]
        fobs, hobs = full.subset(fit_idx), full.subset(held_idx)
        cfits = _fit_all(fobs, cfg, seed, progress)
        cap = {}
        mask = torch.ones(hobs.images.shape[:3], dtype=torch.bool)
        if hobs.mask is not None:
            mask &= hobs.mask
        if hobs.saturated is not None:
            mask &= ~hobs.saturated
        for name, (post, secs) in cfits.items():
            s, std, err, pred = score(post, hobs.views, hobs.images, hobs.surface, mask)
            cap[name] = {**s, "seconds": round(secs, 1), "map_std": _map_std(post), "noise_sigma": post.noise_sigma,
                         "converged": (post.diagnostics or {}).get("converged"), "held_out": held_idx}
            cap[name]["_img"] = {"std": std[0].numpy(), "err": err[0].numpy(), "pred": pred[0].numpy(),
                                 "spearman": s["spearman"]}
        rows.append((f"{cfg['capture']}, view {held_idx[0]}", hobs.images[0].numpy(),
                     {k: v.pop("_img") for k, v in cap.items()}))
        results["capture"] = cap
    fig6_overview(out / "fig6.png", rows, title="Fig. 6: latent-space posterior (MaterialGAN-style decoder) vs "
                                                "per-texel maps; one colour range per row")
    results["summary"] = {k: {m: {"spearman": d[m]["spearman"], "coverage_90": d[m]["coverage"]["90"],
                                  "mae": d[m]["mean_abs_error"], "seconds": d[m]["seconds"]} for m in MODELS}
                          for k, d in (("synthetic", results["synthetic"]), ("capture", results.get("capture")))
                          if d}
    write_json(out, "fig6", results)
    return results
