"""Each texel's share of a per-texel model's energy: what a texel-local Metropolis move needs.

On rectified photos (every pixel *is* a texel, ``GBuffer.aligned``) a :class:`~bayes_brdf.models.material.PerTexel`
model without a smoothness prior makes the texels conditionally independent given the noise scale: its negative
log-density is a sum over texels of the texel's prior and the likelihood of the pixels that show it (in every
view, with the saturated ones' censored term). :func:`texel_energies` returns those terms per particle and texel,
at a given noise scale per particle; :func:`offers_texel_energy` says whether a model and data have that form.

This is the one small protocol :mod:`bayes_brdf.samplers.texel_moves` reads: a model that offers it gets
texel-local jumps between the modes of a texel's posterior (docs/calibration.md, "Stranded particles").
"""
from __future__ import annotations

import math

import torch
from torch import Tensor

from ..render.shade import shade, shade_pixel_loss
from ..render.tensor_memo import TensorMemo
from .censored_kernel import censored_laplace
from .data import ModelData
from .likelihood import SIGMA_FLOOR, censored_log_survival


_WEIGHT_SUMS = TensorMemo(4)     # 3 * the pixel weights' sum, by the weights' identity: the same every sweep


def offers_texel_energy(model, data) -> bool:
    """Whether ``model`` on ``data`` is a sum of independent per-texel terms (given the noise scale)."""
    from .material import PerTexel
    if type(model) is not PerTexel or not isinstance(data, ModelData):
        return False
    g = data.gbuffer
    R = model.resolution
    return (model.smoothness is None and bool(getattr(g, "aligned", False)) and g.texel is None
            and tuple(g.resolution) == (R, R) and isinstance(model.normals, str))


def _scale(model, data: ModelData, resid: Tensor, r: Tensor | None) -> tuple[Tensor, Tensor, Tensor | None]:
    """``(sigma [n], kappa [n], censored)``: the noise scale at which :func:`texel_energies` splits the likelihood,
    the weight of a texel's residual sum in the particle's energy there, and the saturated pixels' censored terms
    at that scale, summed over channels (:func:`_censored_terms`, from the same pass as their slope; ``None``
    without them).

    With a fixed ``sigma``, ``kappa`` is ``1 / sigma`` (Laplace) or ``1 / (2 sigma^2)`` (Gaussian). Under
    ``sigma = "auto"`` the energy is the profile over the noise level, ``N log e - log P_censored(s(e))`` with
    ``s = e / N`` (Laplace); one texel changes ``e`` by about ``1 / N`` of itself, so its share is the energy's
    derivative in ``e`` times its residual: ``kappa = 1 / s - (d log P_censored / d s) (d s / d e)``. The
    second term is not small on real photos: the saturated pixels' bound favours a larger noise level, and on
    card_blue ``kappa`` is 0.86 to 0.93 of ``1 / s``.
    """
    n = resid.shape[0]
    lap = model.likelihood == "laplace"
    if model.sigma != "auto":
        s = torch.full((n,), float(model.sigma), dtype=torch.float64, device=resid.device)
        return s, (1 / s if lap else 1 / (2 * s * s)), None if r is None else _censored_terms(model, data, r, s,
                                                                                                  channels=False)
    e = resid.sum(tuple(range(1, resid.dim()))).double()     # [n, H, W, 3] in its own layout: a reshape copied it
    N = _WEIGHT_SUMS.get((data.weight,), (), lambda: 3 * data.weight.sum().double())
    if lap:
        s = (e / N).clamp_min(SIGMA_FLOOR)
        kappa, ds_de = 1 / s, (e / N >= SIGMA_FLOOR).double() / N
    else:
        s = (e / N).clamp_min(SIGMA_FLOOR ** 2).sqrt()
        kappa, ds_de = 1 / (2 * s * s), (e / N >= SIGMA_FLOOR ** 2).double() / (2 * s * N)
    if r is None:
        return s, kappa, None
    cens, slope = _censored_terms(model, data, r, s, slope=True, channels=False)
    return s, kappa - slope * ds_de, cens


def _censored_renders(model, data: ModelData, values: dict) -> Tensor | None:
    c = data.censored
    if c is None or model.saturated != "censored":
        return None
    with torch.no_grad():       # [n, K, 3] in the maps' dtype: the native terms read them so (and compute in double)
        return shade(model.maps(values), c.gbuffer, backend=model.backend)[:, 0, 0]


def _censored_terms(model, data: ModelData, r: Tensor, sigma: Tensor, slope: bool = False, channels: bool = True):
    """``[n, K, 3]``: each saturated pixel's ``w log P(R + noise >= level)`` at noise scale ``sigma [n]`` (with
    ``channels=False``, ``[n, K]`` summed over its channels: the native kernel's, for Laplace noise); with
    ``slope``, also their sum's derivative in ``sigma`` (``(terms, [n])``; ``t = (level - R) / (sigma g)``, so
    ``d log S / d sigma = (d log S / d t) (-t / sigma)``)."""
    c = data.censored
    if not channels and model.likelihood == "laplace":       # the native kernel, in double from r as it is
        got = censored_laplace(r, c.level, sigma, c.noise, c.weight, terms=True)
        if got is not None:
            _, dsig, per_pixel, _ = got
            return (per_pixel, dsig.to(sigma.dtype)) if slope else per_pixel
    if not channels:
        out = _censored_terms(model, data, r, sigma, slope)
        return (out[0].sum(-1), out[1]) if slope else out.sum(-1)
    n, r = r.shape[0], r.double()                            # the torch terms: in float64
    sc = sigma.reshape(n, 1, 1).to(r) * (1 if c.noise is None else c.noise.to(r)[None, :, None])
    t = (c.level.to(r)[None] - r) / sc
    val = censored_log_survival(t, model.likelihood)
    w = c.weight.to(r)[None, :, None]
    if not slope:
        return val * w
    terms = val * w
    if model.likelihood == "laplace":
        dlog = torch.where(t >= 0, torch.full_like(t, -1.0), 1 - val.neg().exp())
    else:
        dlog = (-0.5 * t * t - 0.5 * math.log(2 * math.pi) - val).exp().neg()
    return terms, (dlog * (-t) * w).sum((1, 2)) / sigma.to(r)


def _pixel_residuals(model, data: ModelData, values: dict) -> Tensor:
    """``w |y - R|`` (Laplace) or ``w (y - R)^2`` (Gaussian) summed over views: ``[n, H, W, 3]``."""
    return shade_pixel_loss(model.maps(values), data.gbuffer, data.images, data.noise_weight(model.likelihood),
                            kind="l1" if model.likelihood == "laplace" else "l2", backend=model.backend)


def _likelihood(model, data: ModelData, resid: Tensor, cens: Tensor | None, kappa: Tensor,
                channels: bool = True) -> Tensor:
    """``[n, T, 3]`` per channel, or with ``channels=False`` ``[n, T]`` summed over them (summed first: a third of
    the work on the sampler's path); ``cens`` the saturated pixels' terms (:func:`_censored_terms`, ``[n, K, 3]``, or
    ``[n, K]`` with ``channels=False``) or ``None``."""
    n, T = kappa.shape[0], model.resolution ** 2
    resid = resid.reshape(n, T, 3) if channels else resid.sum(-1).reshape(n, T)   # summed first: no [n, T, 3] copy
    out = resid.double().mul_(kappa.reshape(n, *[1] * (1 + channels)).double())
    if cens is not None:
        idx = data.censored.gbuffer.texel.reshape(-1).to(out.device)
        out.index_add_(1, idx, cens.to(out.dtype).neg())
    return out.mul_(data.scale)


def texel_channel_energies(model, data: ModelData, values: dict, sigma: Tensor, kappa: Tensor) -> Tensor:
    """``[n, R * R, 3]`` float64: each texel's pixels' share of the negative log-likelihood, channel by channel
    (``kappa`` times their residual sum, less their censored terms at noise scale ``sigma``; both ``[n]``): what
    :func:`texel_energies` sums, for a quadrature that integrates each channel's albedo apart
    (:mod:`bayes_brdf.experiments.texel_truth`)."""
    r = _censored_renders(model, data, values)
    cens = None if r is None else _censored_terms(model, data, r, sigma)
    return _likelihood(model, data, _pixel_residuals(model, data, values), cens, kappa)


def texel_energies(model, data: ModelData, values: dict, sigma: Tensor | None = None,
                   kappa: Tensor | None = None) -> tuple[Tensor, tuple[Tensor, Tensor]]:
    """``([n, R * R] float64, (sigma, kappa))``: each texel's negative log prior plus its pixels' share of the
    negative log-likelihood (:func:`texel_channel_energies`), up to one constant per texel, at ``sigma`` and
    ``kappa`` (by default the particles' own, :func:`_scale`, from the same renders).

    A texel-local move compares two states of one texel, so only differences matter; they agree with the
    full potential's to first order in ``1 / N`` (exactly with a fixed ``sigma``; tests/samplers/test_texel_moves.py).
    """
    resid = _pixel_residuals(model, data, values)
    r = _censored_renders(model, data, values)
    if sigma is None:
        sigma, kappa, cens = _scale(model, data, resid, r)
    else:
        cens = None if r is None else _censored_terms(model, data, r, sigma, channels=False)
    out = _likelihood(model, data, resid, cens, kappa, channels=False)
    n, T = out.shape
    for name, x in values.items():
        lp = _prior_log_density(model, name, x)
        if lp is not None:
            out = out.sub_(lp.double().reshape(n, -1, T).sum(1))
    return out, (sigma, kappa)


def _prior_log_density(model, name: str, x: Tensor) -> Tensor | None:
    """Elementwise log prior density of site ``name`` (``None`` for a uniform prior: a constant per texel)."""
    if name == "normal_slope":
        return torch.distributions.Normal(0.0, model.slope_std).log_prob(x)
    p = model._prior(name)
    if p.kind == "uniform":
        return None
    lo, hi = model._range(name)
    d = p.distribution(tuple(x.shape[1:]), lo, hi, dtype=x.dtype, device=x.device).base_dist
    return d.log_prob(x)
