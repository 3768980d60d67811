"""The likelihood of Eq. (2): observed pixels ~ Laplace(rendered, sigma) (or Gaussian), as a Pyro distribution.

:class:`RenderedImages` is a distribution over the ``[V, H, W, 3]`` images
whose ``log_prob`` calls the fused ``shade_loss`` (shading and the L1/L2 loss
in one pass, analytic gradients), so a model's likelihood never materialises
the ``[n, V, H, W, 3]`` renders. Its batch shape is the particle dimension of
the maps. :func:`observe` is the one line a material model ends with.

``sigma = "auto"``: the noise level is part of the model and integrated out.
With ``N`` observed values, residual sum ``e(x) = sum w |y - R(x)|`` and the
scale-invariant (Jeffreys) prior ``p(sigma) ∝ 1 / sigma``, the Laplace
likelihood marginalised over sigma is ``∫ (2 sigma)^-N exp(-e / sigma) dsigma / sigma
= Γ(N) (2 e)^-N``, which equals, up to a constant, the likelihood at the
profile value ``sigma_hat(x) = e(x) / N``; the Gaussian case likewise with
``sigma_hat^2 = sum w (y - R)^2 / N``. So every sampler sees the exact marginal
posterior of the maps (no extra dimension to mix: with ``N`` in the tens of
thousands, sigma's own posterior is 0.5 % wide), and sigma given the maps is
``InvGamma(N, e(x))`` (Laplace), mean ``e / (N - 1)``. ``sigma_floor`` bounds
the prior below (noiseless synthetic renders would otherwise drive sigma to 0).

``saturated = "censored"`` (the default): a pixel the photo clipped at
``level`` (:class:`~bayes_brdf.models.data.Censored`) says only that the
radiance plus noise reached the clip, so it contributes
``log P(R + noise >= level)`` per channel: for Laplace noise
``log(1/2) - t`` for ``t = (level - R) / sigma >= 0`` and ``log(1 - exp(t) / 2)``
below; for Gaussian noise ``log Phi(-t)``. A clipped highlight then pulls a
rendering that is too dim upwards and says nothing against one that is
brighter. Under ``sigma = "auto"`` it is evaluated at the profile sigma of
the unclipped pixels (the censored pixels are a few percent of the data).
``saturated = "drop"`` leaves them out.
"""
from __future__ import annotations

import math

import pyro
import torch
from pyro.distributions import TorchDistribution
from torch.distributions import constraints

from ..errors import InputError
from ..render.maps import SVBRDF
from ..render.shade import shade, shade_loss
from .censored_kernel import censored_laplace
from .data import ModelData

KINDS = ("laplace", "gaussian")
SATURATED = ("censored", "drop")
#: the lower bound of the noise prior under ``sigma = "auto"`` (image units: a quarter of an 8-bit step)
SIGMA_FLOOR = 1e-3


def censored_log_survival(t: torch.Tensor, kind: str) -> torch.Tensor:
    """``log P(noise / sigma >= t)`` for standardised Laplace or Gaussian noise, elementwise and stable."""
    if kind == "laplace":
        a = -t.abs()
        return torch.where(t >= 0, a - math.log(2.0), torch.log1p(-0.5 * torch.exp(a)))
    return torch.special.log_ndtr(-t)


class _CensoredSum(torch.autograd.Function):
    """``sum_{k, c} w_k log P(noise >= level - R)`` per particle, with the derivative in closed form.

    ``r [n, K, 3]`` renders, ``level [K, 3]``, ``sigma [n]``, ``w [K]`` -> ``[n]``; ``g [K]`` (optional) the
    pixels' relative noise scales (signal-dependent noise: the scale is ``sigma * g``). One pass for the value
    and the derivative (``d log S / dt``, kept for backward) instead of a chain of autograd nodes: these
    pixels are shaded apart from the fused loss, so their elementwise cost is what censoring adds per step.
    """

    @staticmethod
    def forward(ctx, r, level, sigma, w, kind, g=None):
        got = censored_laplace(r, level, sigma, g, w, grad=ctx.needs_input_grad[0]) if kind == "laplace" else None
        ctx.native = got is not None
        if got is not None:           # the native pass (censored_kernel.py): value and derivatives at once
            total, dsig, _, dr = got
            ctx.save_for_backward(dr, dsig.to(sigma.dtype))
            return total.to(r.dtype)
        s = sigma.reshape(-1, 1, 1)
        t = (level[None] - r).div_(s if g is None else s * g[None, :, None])
        val = censored_log_survival(t, kind)
        if kind == "laplace":       # d/dt: -1 above 0; below, -(e^t / 2) / (1 - e^t / 2) = 1 - 1 / S
            dlog = torch.where(t >= 0, torch.full_like(t, -1.0), 1 - val.neg().exp_())
        else:
            dlog = (-0.5 * t * t - 0.5 * math.log(2 * math.pi) - val).exp_().neg_()   # -phi(t) / Phi(-t)
        ww = w[None, :, None]
        ctx.save_for_backward(t, dlog, s if g is None else s * g[None, :, None], s, ww)
        return (val * ww).sum((1, 2))

    @staticmethod
    def backward(ctx, grad):
        if ctx.native:
            dr, dsig = ctx.saved_tensors
            gr = dr * grad.reshape(-1, 1, 1) if ctx.needs_input_grad[0] else None
            gs = dsig * grad if ctx.needs_input_grad[2] else None
            return gr, None, gs, None, None, None
        t, dlog, sp, s, ww = ctx.saved_tensors
        gt = dlog.mul_(ww).mul_(grad.reshape(-1, 1, 1))                   # d out / d t
        gr = gt.div(sp).neg_() if ctx.needs_input_grad[0] else None     # t = (level - r) / (s g)
        gs = (gt * t).sum((1, 2)).div_(s.reshape(-1)).neg_() if ctx.needs_input_grad[2] else None
        return gr, None, gs, None, None, None


def check_saturated(saturated):
    if saturated not in SATURATED:
        raise InputError(f"saturated must be one of {', '.join(SATURATED)}, got {saturated!r}",
                         fix="\"censored\" uses clipped pixels as lower bounds, \"drop\" leaves them out")


def check_sigma(sigma):
    """One-line error unless ``sigma`` is a positive number or ``"auto"``."""
    if sigma == "auto":
        return
    if isinstance(sigma, bool) or not isinstance(sigma, (int, float)) or not sigma > 0:
        raise InputError(f"sigma must be a positive number or \"auto\", got {sigma!r}",
                         fix="sigma_err is the noise scale in image units, e.g. 0.01; \"auto\" infers it")


class RenderedImages(TorchDistribution):
    """``y ~ Laplace(R(x; theta), sigma)`` per observed pixel and channel (``kind="gaussian"``: Normal).

    Args:
        maps: the material; a leading particle dimension ``n`` becomes the batch shape ``[n]``.
        data: the :class:`ModelData` (G-buffer, pixel weights, likelihood scale).
        sigma: the noise scale ``sigma_err`` in the images' units (Eq. 2).
        kind: ``"laplace"`` (the paper's L1 likelihood) or ``"gaussian"``.
        backend: shading backend (see :func:`bayes_brdf.render.shade.shade`).
        saturated: ``"censored"`` (clipped pixels as lower bounds) or ``"drop"``.

    ``log_prob(y)`` is the exact normalised log-density summed over weighted
    pixels: ``-sum w |y - R| / sigma - sum w log(2 sigma)`` for Laplace, plus
    the censored term of the saturated pixels.
    """

    arg_constraints = {}
    support = constraints.real

    def __init__(self, maps: SVBRDF, data: ModelData, sigma: "float | str" = 0.01, kind: str = "laplace",
                 backend: str = "auto", validate_args=None, sigma_floor: float = SIGMA_FLOOR,
                 saturated: str = "censored"):
        if kind not in KINDS:
            raise InputError(f"unknown likelihood '{kind}'", fix=f"use one of {', '.join(KINDS)}")
        check_sigma(sigma)
        check_saturated(saturated)
        self.maps, self.data, self.kind, self.backend = maps, data, kind, backend
        self.censored = data.censored if saturated == "censored" else None
        self.sigma = sigma if sigma == "auto" else float(sigma)
        self.sigma_floor = float(sigma_floor)
        n = maps.num_particles
        super().__init__(torch.Size([] if n is None else [n]), data.images.shape, validate_args=False)

    def expand(self, batch_shape, _instance=None):
        batch_shape = torch.Size(batch_shape)
        if batch_shape == self.batch_shape:
            return self
        n = self.maps.num_particles
        if n is None and len(batch_shape) >= 1 and all(s == 1 for s in batch_shape[1:]):
            return _Expanded(self, batch_shape)
        raise InputError(f"the likelihood's particle dimension {tuple(self.batch_shape)} does not match the "
                         f"plates {tuple(batch_shape)}", fix="keep the particle dimension of the sampled maps")

    def _norm_const(self) -> torch.Tensor:
        per = math.log(2 * self.sigma) if self.kind == "laplace" else 0.5 * math.log(2 * math.pi * self.sigma ** 2)
        return 3 * self.data.weight.sum() * per + self.data.noise_log_norm()

    def residual(self, value) -> tuple[torch.Tensor, torch.Tensor]:
        """``(e [n], N)``: the weighted residual sum (``|y - R|``, or ``(y - R)^2`` for Gaussian) and the count
        of observed values it sums over."""
        d = self.data
        e = shade_loss(self.maps, d.gbuffer, value, d.noise_weight(self.kind),
                       kind="l1" if self.kind == "laplace" else "l2", backend=self.backend)
        return e, 3 * d.weight.sum()

    def sigma_hat(self, value) -> torch.Tensor:
        """The noise level the residuals show, per particle ``[n]`` (the profile value, floored)."""
        e, N = self.residual(value)
        return (e / N).clamp_min(self.sigma_floor) if self.kind == "laplace" else \
            (e / N).clamp_min(self.sigma_floor ** 2).sqrt()

    def censored_log_prob(self, sigma) -> torch.Tensor:
        """``[n]``: the sum over saturated pixels and channels of ``log P(R + noise >= level)`` at noise
        scale ``sigma`` (a number or ``[n]``); 0 without saturated pixels."""
        c = self.censored
        n = self.maps.num_particles or 1
        if c is None:
            return torch.zeros(n, dtype=self.data.dtype, device=self.data.device)
        r = shade(self.maps, c.gbuffer, backend=self.backend)[:, 0, 0]              # [n, K, 3]
        s = torch.as_tensor(sigma, dtype=r.dtype, device=r.device).reshape(-1).expand(r.shape[0])
        g = None if c.noise is None else c.noise.to(r)
        return _CensoredSum.apply(r, c.level.to(r), s, c.weight.to(r), self.kind, g)

    def log_prob(self, value):
        d = self.data
        if self.sigma == "auto":
            e, N = self.residual(value)
            if self.kind == "laplace":
                s = (e / N).clamp_min(self.sigma_floor)
                lp = -(N * torch.log(2 * s) + e / s)
            else:
                s2 = (e / N).clamp_min(self.sigma_floor ** 2)
                s = s2.sqrt()
                lp = -(0.5 * N * torch.log(2 * math.pi * s2) + e / (2 * s2))
            lp = (lp - d.noise_log_norm() + self.censored_log_prob(s)) * d.scale
            return lp if self.maps.num_particles is not None else lp[0]
        w = d.noise_weight(self.kind)
        if self.kind == "laplace":
            e = shade_loss(self.maps, d.gbuffer, value, w / self.sigma, kind="l1", backend=self.backend)
        else:
            e = shade_loss(self.maps, d.gbuffer, value, w / (2 * self.sigma ** 2), kind="l2", backend=self.backend)
        lp = (self.censored_log_prob(self.sigma) - e - self._norm_const()) * d.scale
        return lp if self.maps.num_particles is not None else lp[0]

    def mean_images(self):
        """The noiseless renders ``[*batch, V, H, W, 3]``."""
        img = shade(self.maps, self.data.gbuffer, backend=self.backend)
        return img if self.maps.num_particles is not None else img[0]

    def sample(self, sample_shape=torch.Size()):
        with torch.no_grad():
            mu = self.mean_images().expand(torch.Size(sample_shape) + self.batch_shape + self.event_shape)
            sig = self.sigma if self.sigma != "auto" else float(self.sigma_hat(self.data.images).mean())
            scale = torch.full_like(mu, sig)
            if self.data.noise is not None:
                scale = scale * self.data.noise[..., None].to(mu)
            noise = (torch.distributions.Laplace if self.kind == "laplace" else torch.distributions.Normal)(
                torch.zeros_like(mu), scale).sample()
            w = self.data.weight[..., None] > 0
            return torch.where(w, mu + noise, mu)


class _Expanded(TorchDistribution):
    """A particle-free likelihood broadcast over a particle plate (the same value for every particle)."""

    arg_constraints = {}
    support = constraints.real

    def __init__(self, base: RenderedImages, batch_shape):
        self.base = base
        super().__init__(batch_shape, base.event_shape, validate_args=False)

    def log_prob(self, value):
        return self.base.log_prob(value).expand(self.batch_shape)

    def sample(self, sample_shape=torch.Size()):
        return self.base.sample().expand(torch.Size(sample_shape) + self.batch_shape + self.event_shape)


def observe(data: ModelData, maps: SVBRDF, *, sigma: "float | str" = 0.01, kind: str = "laplace",
            name: str = "images", backend: str = "auto", saturated: str = "censored"):
    """Condition ``maps`` on the observed images of ``data`` (Eq. 2): the last line of a material model.

    Example:
        >>> import pyro, pyro.distributions as dist
        >>> from bayes_brdf.render import SVBRDF
        >>> def my_model(data):
        ...     rho = pyro.sample("albedo", dist.Uniform(0.0, 1.0))
        ...     maps = SVBRDF.constant(albedo=0.0, roughness=0.3)
        ...     maps.albedo = rho[..., None, None, None].expand(*rho.shape, 3, 1, 1)
        ...     observe(data, maps)
    """
    if not isinstance(data, ModelData):
        raise InputError(f"observe() needs the ModelData the model was called with, got {type(data).__name__}")
    return pyro.sample(name, RenderedImages(maps, data, sigma, kind, backend, saturated=saturated),
                       obs=data.images)
