"""A fitted posterior against photos it was not fitted on (held-out views).

* :func:`predict` -- what the posterior predicts on views with photos: the PIT values of the photos
  under the posterior predictive, the image-space std (Eq. 11), the MAP render and its error.
* :func:`heldout_report` -- the held-out check of ``bayes-brdf fit`` and the demo: per-view std and
  error maps (EXR + PNG), Pearson / Spearman correlation between std and error (the image-space std of
  Eq. 11, and under ``predictive`` the posterior predictive's std, which adds the model's noise), and the
  coverage of the central 50 % and 90 % predictive intervals; saturated (clipped) pixels are left out,
  since they only bound the radiance from below.
* :func:`fitted_noise` -- the noise level the fitted photos show (the Laplace scale of the MAP's
  residuals), to compare with the model's ``sigma``.
"""
from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, NamedTuple

if TYPE_CHECKING:
    from torch import Tensor


class Predicted(NamedTuple):
    """The posterior's prediction of photos ``[V, H, W, 3]`` (``inside``: ``[V, H, W]``)."""

    pit: Tensor         #: the photos' PIT values under the posterior predictive
    std: Tensor         #: image-space std over the particles' renders (Eq. 11)
    mean: Tensor        #: the particles' mean render
    map_render: Tensor  #: the MAP's render
    photos: Tensor      #: the photos, on the renders' device and dtype
    error: Tensor       #: ``|MAP render - photo|``
    inside: Tensor      #: pixels on the sample (bool)


def predict(post, views, images: Tensor, surface, *, sigma: float | None = None,
            variance: Tensor | None = None) -> Predicted:
    """What ``post`` predicts for ``images`` seen from ``views`` of ``surface`` (``sigma``: the noise
    scale of the predictive, by default the posterior's; ``variance``: the images' own render noise; see
    :func:`~bayes_brdf.uncertainty.predictive_cdf`)."""
    from ..render.gbuffer import GBuffer
    from ..render.shade import render
    from ..uncertainty import predictive_cdf

    pit, std, mean = predictive_cdf(post, views, images, surface, sigma=sigma, variance=variance)
    pred = render(post.maps("map"), views, surface)[0]
    y = images.to(pred)
    return Predicted(pit, std, mean, pred, y, (pred - y).abs(), GBuffer.build(views, surface).mask)


def fitted_noise(post, obs) -> float:
    """Laplace scale of the MAP's residuals on the fitted photos (mean |R - y| over usable pixels):
    the noise level the data show, to compare with the model's ``sigma``. Under signal-dependent noise
    (``post.noise_level``) each residual is divided by its pixel's relative scale ``g(R)``, so the
    number is in the units of ``post.noise_sigma`` (the scale at the reference radiance). Where the run
    estimated the photos' gains (``post.view_gains``), the photos are divided by them first, as the fit did."""
    from ..models.data import ModelData
    from ..render.shade import render

    d = ModelData.from_observations(obs)
    gains = post.view_gains
    if gains is not None and len(gains.log_gain) == d.num_views:
        d = d.with_gains(gains.gains())
    pred = render(post.maps("map"), obs.views, obs.surface)[0]
    w = d.weight > 0
    r = (pred - d.images.to(pred)).abs()
    level = post.noise_level
    if level is not None:
        r = r / level.relative(pred.mean(-1, keepdim=True)).to(r)
    return float(r[w].mean())


def heldout_report(post, obs, out: Path, fitted_sigma: float | None = None) -> dict:
    """Image-space std, MAP error maps (under ``out/heldout/``) and calibration numbers on the held-out
    ``obs``; with ``fitted_sigma`` (:func:`fitted_noise`) the coverage is also given with that noise scale."""
    import torch

    from ..io import write_png
    from ..plots import write_map
    from ..uncertainty import correlations, coverage, predictive_cdf, predictive_std

    F, std, mean, pred, y, err, inside = predict(post, obs.views, obs.images, obs.surface, variance=obs.variance)
    valid = inside.clone()
    sat = obs.saturated & inside if obs.saturated is not None else torch.zeros_like(inside)
    n_sat = int(sat.sum())
    if obs.mask is not None:
        valid &= obs.mask
    valid &= ~sat
    # one colour range for a view's error and std maps (and for every held-out view): they are compared by eye
    both = torch.cat([err[valid].flatten()[:1_000_000], std[valid].flatten()[:1_000_000]])
    vmax = float(torch.quantile(both, 0.99)) if both.numel() else 1.0
    per_view = []
    for j, v in enumerate(obs.views):
        tag = f"view_{obs.meta.get('indices', list(range(len(obs))))[j]:02d}"
        masks = {"clipped in the photo (left out)": sat[j], "not the sample": ~inside[j]}
        if obs.mask is not None:
            masks["masked out"] = inside[j] & ~obs.mask[j] & ~sat[j]
        write_map(out / "heldout" / f"{tag}_std", std[j], title=f"{tag}: image-space std (Eq. 11)", vmax=vmax,
                  masks=masks)
        write_map(out / "heldout" / f"{tag}_error", err[j], title=f"{tag}: |MAP render - photo|", vmax=vmax,
                  masks=masks)
        write_png(out / "heldout" / f"{tag}_map_render.png", pred[j].clamp(0, 1).cpu().numpy())
        write_png(out / "heldout" / f"{tag}_photo.png", y[j].clamp(0, 1).cpu().numpy())
        vm = valid[j]
        rec = {"view": tag, "pixels": int(vm.sum()), "mean_abs_error": float(err[j][vm].mean()),
               "mean_std": float(std[j][vm].mean()), **correlations(std[j][vm], err[j][vm]),
               "coverage": coverage(F[j][vm])}
        per_view.append(rec)
    vv = valid[..., None].expand_as(err)
    pstd = predictive_std(post, std, mean, variance=obs.variance)
    extra = {"predictive": {"mean_std": float(pstd[vv].mean()), **correlations(pstd[vv], err[vv])}}
    if fitted_sigma:
        F2, _, _ = predictive_cdf(post, obs.views, obs.images, obs.surface, sigma=fitted_sigma,
                                  variance=obs.variance)
        extra.update(fitted_sigma=fitted_sigma, coverage_with_fitted_sigma=coverage(F2[vv]))
    return {**extra, "pixels": int(valid.sum()), "saturated_left_out": n_sat, "map_range": [0.0, vmax],
            "mean_abs_error": float(err[vv].mean()), "mean_std": float(std[vv].mean()),
            **correlations(std[vv], err[vv]),
            "correlation_posterior_mean": correlations(std[vv], (mean - y).abs()[vv]),
            "coverage": coverage(F[vv]), "views": per_view}
