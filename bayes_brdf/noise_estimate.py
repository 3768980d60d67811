"""Estimating the signal-dependent noise level of a capture before sampling (``pixel_noise = "signal"``).

The shape of the noise level function ``s(y)^2 = a + b y + c y^2`` (:mod:`bayes_brdf.models.noise`)
comes from the photos themselves, in two phases of one run (:func:`bayes_brdf.infer`): the burn-in
samples with one noise scale for every pixel; its particles' residuals on the fitted photos give
``a, b, c`` (:func:`estimate_noise`); the rest of the run samples with the scale ``sigma * g(y)`` per
pixel, ``g = s(y) / s(y_ref)`` at the particles' mean render ``y``. Sampling still infers (integrates
out) the one overall scale ``sigma``, so only the shape is fixed here. The estimate is deterministic
given the data, the model and the seed, and is recorded in the posterior (``meta["noise_level"]``).

Photos that a Monte Carlo renderer made carry its own variance per pixel (``Observations.variance``): that
is known noise on top of the photo noise, so the noise level is fitted around it (``s_total^2 = s(y)^2 +
tau^2``, :func:`~bayes_brdf.models.noise.render_noise`) and the per-pixel scale is ``sigma`` times
``s_total / s(y_ref)``.

Under ``view_gain = "estimated"`` (:mod:`bayes_brdf.models.gains`) the same particles first give each
photo's overall gain; the photos are divided by their gains before the noise level is fitted to their
residuals, and the rest of the run samples the corrected photos (``meta["view_gains"]``).
"""
from __future__ import annotations

import torch

from typing import NamedTuple

from .models.data import ModelData
from .models.gains import ViewGains, estimate_gains
from .models.noise import NoiseLevel, fit_noise_level, render_noise
from .render.shade import shade


def with_render_noise(model, data: ModelData, *, estimated: bool) -> ModelData:
    """``data`` with its photos' own render variance (``Observations.variance``) in the per-pixel noise scales,
    where the run will not put it there itself: ``estimated`` (a run that fits the noise level after its burn-in,
    :func:`estimate_noise`) does. With a fixed ``sigma`` the scale of a pixel is exactly
    ``sqrt(sigma^2 + tau^2)`` (:func:`~bayes_brdf.models.noise.render_noise`): relative scales
    ``sqrt(1 + tau^2 / sigma^2)``. With ``sigma = "auto"`` and one noise scale (``pixel_noise = "constant"``)
    the scale is not known before sampling: the variance is left out, with a warning that says so.

    Example:
        >>> import bayes_brdf as bb
        >>> from bayes_brdf.render import PlanarSample, collocated_views
        >>> vs = collocated_views(1, 3.0, camera="rectified", resolution=2)
        >>> obs = bb.Observations(vs, torch.full((1, 2, 2, 3), 0.5), PlanarSample(2.0),
        ...                       variance=torch.full((1, 2, 2, 3), 3e-4))
        >>> d = with_render_noise(bb.models.homogeneous(sigma=0.01, likelihood="gaussian"),
        ...                       ModelData.from_observations(obs), estimated=False)
        >>> round(float(d.noise[0, 0, 0]), 4)            # sqrt(1 + 3e-4 / 1e-4)
        2.0
    """
    import warnings

    var = getattr(data.observations, "variance", None)
    if var is None or estimated or tuple(var.shape) != tuple(data.images.shape):
        return data
    sigma = getattr(model, "sigma", None)
    if not isinstance(sigma, (int, float)) or isinstance(sigma, bool):
        warnings.warn("the photos carry their renderer's own variance, which sigma='auto' with one noise scale "
                      "(pixel_noise='constant') cannot use: it is left out; use pixel_noise='signal' (the default) "
                      "or a fixed sigma", stacklevel=3)
        return data
    tau2 = render_noise(var.to(device=data.device, dtype=torch.float64), getattr(model, "likelihood", "laplace"))
    rel = (1 + tau2 / float(sigma) ** 2).sqrt().to(data.dtype)
    return data.with_noise(torch.where(data.weight > 0, rel, torch.ones_like(rel)))


class NoiseEstimate(NamedTuple):
    """What :func:`estimate_noise` found: the data to sample on, the noise level, the views' gains (or ``None``)."""

    data: ModelData
    level: NoiseLevel
    gains: ViewGains | None


def estimate_noise(model, data: ModelData, values: dict) -> NoiseEstimate:
    """The data with per-pixel relative noise scales (and photos divided by their gains), the fitted noise
    level and the views' gains, from posterior draws.

    ``values`` are site values ``{site: [n, ...]}`` of ``n`` particles that sample the posterior under one
    noise scale (the end of the burn-in). Every particle's residuals ``photo - R(x_i)`` on every usable
    pixel are samples of the noise at the radiance ``R(x_i)``, pooled over the particles. Residuals of
    *posterior draws*, not of a point estimate: a per-texel fit has nearly as many parameters per texel as
    values, and its optimum passes close to the pixels of most leverage (the bright ones), so its residuals
    shrink exactly where the noise is largest; at a draw from the posterior, the part of the noise the
    fit absorbed comes back as the draw's own deviation (for a linear-Gaussian model, exactly).

    Example:
        >>> import bayes_brdf as bb
        >>> from bayes_brdf.render import SVBRDF, PlanarSample, collocated_views
        >>> from bayes_brdf.render.shade import render
        >>> views = collocated_views(3, 3.0, camera="rectified", resolution=16)
        >>> y = render(SVBRDF.constant(0.5, 0.3), views, PlanarSample(2.0))[0]
        >>> y = y + 0.01 * torch.randn(y.shape, generator=torch.Generator().manual_seed(0))
        >>> d = ModelData.from_observations(bb.Observations(views, y, PlanarSample(2.0)))
        >>> m = bb.models.homogeneous(albedo="gray")
        >>> d2, nl, gains = estimate_noise(m, d, {"albedo": torch.full((4, 1), 0.5),
        ...                                       "roughness": torch.full((4, 1), 0.3)})
        >>> d2.noise.shape == d.weight.shape and nl.y_ref > 0, gains is None   # view_gain = "none"
        (True, True)
    """
    with torch.no_grad():
        r = shade(model.maps(values), data.gbuffer, backend=getattr(model, "backend", "auto"))   # [n, V, H, W, 3]
        w = data.weight > 0
        signal = r.mean(-1)                                                                     # [n, V, H, W]
        gains = None
        if getattr(model, "view_gain", "none") == "estimated":
            gains = estimate_gains(signal.mean(0), data.images, data.weight)
            if gains is not None:
                data = data.with_gains(gains.gains())
        kind = getattr(model, "likelihood", "laplace")
        var = getattr(data.observations, "variance", None)
        tau2 = None
        if var is not None and tuple(var.shape) == tuple(data.images.shape):    # the photos' own render noise
            tau2 = render_noise(var.to(device=data.device, dtype=torch.float64), kind)   # [V, H, W]
        n = signal.shape[0]
        level = fit_noise_level(signal[:, w].reshape(-1), (data.images[None] - r)[:, w].reshape(-1, 3), kind=kind,
                                extra=None if tau2 is None else tau2[w][None].expand(n, -1).reshape(-1))
        if tau2 is None:
            rel = level.relative(signal.mean(0)).to(data.dtype)
        else:                                   # s_total = sqrt(s(y)^2 + tau^2), relative to s(y_ref)
            ref = float(level.scale(torch.tensor(level.y_ref, dtype=torch.float64)))
            s = level.scale(signal.mean(0).to(torch.float64))
            rel = ((s * s + tau2).sqrt() / ref).to(data.dtype)
        rel = torch.where(w, rel, torch.ones_like(rel))
        cens = None
        if data.censored is not None:
            cens = level.relative(data.censored.level.mean(-1)).to(data.dtype)
    return NoiseEstimate(data.with_noise(rel, cens), level, gains)
