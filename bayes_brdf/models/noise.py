"""Signal-dependent noise: a camera-like noise level function ``s(y)^2 = a + b y + c y^2``.

Why: the error between a photo and any forward model is not the same everywhere. A camera adds read
noise (``a``) and shot noise (``b y``); quantising to 8 bits after a gamma curve adds a step that grows
with the radiance; a model that is a little off (the flash's falloff, the BRDF's lobe shape) is off in
proportion to the radiance (``c y^2``). One noise scale for every pixel is then too wide on the dark
pixels and too narrow on the highlights: the held-out intervals are right on average and wrong by
brightness, and so by split and resolution (the share of highlights changes).

:class:`NoiseLevel` is the shape of that function, estimated once from data. The likelihood keeps its one
overall scale ``sigma`` (inferred, integrated out as before) and multiplies it per pixel by
``g(y) = s(y) / s_ref``, the shape normalised to 1 at the mean observed radiance; so every fixed-sigma
and ``sigma = "auto"`` rule of :mod:`bayes_brdf.models.likelihood` holds per pixel. The signal ``y`` of a
pixel is the mean over its channels of a *render* (the pre-fit's render on the fitted photos, a particle's
on held-out views), never the photo itself: a noisy photo would otherwise weigh its own noise.

:func:`fit_noise_level` estimates ``(a, b, c)`` by maximum likelihood from residuals (Laplace or Gaussian),
``a, b, c >= 0``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from ..errors import InputError
from ..optimize import newton

PIXEL_NOISE = ("constant", "signal")


@dataclass(frozen=True)
class NoiseLevel:
    """The shape ``g(y) = sqrt(a + b y + c y^2) / sqrt(a + b y_ref + c y_ref^2)`` of the per-pixel noise scale.

    ``a, b, c`` are the fitted variance coefficients in image units (``s(y)`` is then a Laplace scale,
    or a Gaussian std, at radiance ``y``); ``y_ref`` the radiance where ``g = 1``.

    Example:
        >>> nl = NoiseLevel(a=1e-4, b=0.0, c=0.01, y_ref=0.1)
        >>> round(float(nl.relative(torch.tensor(0.1))), 6), round(float(nl.scale(torch.tensor(1.0))), 4)
        (1.0, 0.1005)
    """

    a: float
    b: float
    c: float
    y_ref: float

    def scale(self, y: Tensor) -> Tensor:
        """``s(y)``: the noise scale the fit found at radiance ``y`` (image units, elementwise)."""
        y = y.clamp_min(0)
        return (self.a + self.b * y + self.c * y * y).clamp_min(1e-20).sqrt()

    def relative(self, y: Tensor) -> Tensor:
        """``g(y) = s(y) / s(y_ref)`` (elementwise)."""
        return self.scale(y) / float(self.scale(torch.tensor(self.y_ref, dtype=torch.float64)))

    def to_dict(self) -> dict:
        return {"a": self.a, "b": self.b, "c": self.c, "y_ref": self.y_ref}

    @classmethod
    def from_dict(cls, d: dict) -> "NoiseLevel":
        try:
            return cls(*(float(d[k]) for k in ("a", "b", "c", "y_ref")))
        except (KeyError, TypeError, ValueError):
            raise InputError(f"not a noise level: {d!r}", fix="a table with a, b, c and y_ref") from None


def check_pixel_noise(kind) -> None:
    if kind not in PIXEL_NOISE:
        raise InputError(f"pixel_noise must be one of {', '.join(PIXEL_NOISE)}, got {kind!r}",
                         fix="\"signal\": a noise scale that grows with the radiance (camera-like); "
                             "\"constant\": one scale for every pixel")


def render_noise(variance: Tensor, kind: str = "laplace", *, per_channel: bool = False) -> Tensor:
    """A renderer's own variance of a value (``[..., 3]``: a Monte Carlo render's, :attr:`Observations.variance`)
    as a squared noise scale per pixel ``[...]`` (the mean over channels; ``per_channel``: ``[..., 3]``), over 2
    for a Laplace scale (a Laplace of scale ``s`` has variance ``2 s^2``), as it is for a Gaussian std. The noise of a photo that a renderer
    made is its photo noise plus this: ``s_total^2 = s(y)^2 + render_noise`` (the Laplace part matched by its
    variance).

    Example:
        >>> [round(x, 6) for x in render_noise(torch.tensor([[2e-4, 4e-4, 6e-4]])).tolist()]
        [0.0002]
    """
    v = variance if per_channel else variance.mean(-1)
    return v / 2.0 if kind == "laplace" else v


def fit_noise_level(signal: Tensor, residual: Tensor, *, kind: str = "laplace", iters: int = 200,
                    extra: Tensor | None = None) -> NoiseLevel:
    """Maximum-likelihood ``a, b, c >= 0`` of ``s(y)^2 = a + b y + c y^2`` from residuals.

    Args:
        signal: the radiance of each value ``[K]`` (a render: what the noise depends on).
        residual: ``photo - render`` ``[K]`` or ``[K, C]`` (every channel of a pixel shares its scale).
        kind: ``"laplace"`` (``s`` is the Laplace scale) or ``"gaussian"`` (the std).
        extra: a known squared scale per value ``[K]`` on top of ``s(y)^2`` (:func:`render_noise`: the photos'
            own Monte Carlo noise), fitted around rather than into ``a, b, c``.

    Example:
        >>> g = torch.Generator().manual_seed(0)
        >>> y = torch.rand(200_000, generator=g)
        >>> s = (4e-4 + 0.01 * y * y).sqrt()
        >>> _ = torch.manual_seed(1)     # the global generator: not seed 0, whose stream is y's
        >>> r = torch.distributions.Laplace(0.0, s).sample()
        >>> nl = fit_noise_level(y, r)
        >>> [round(v, 1) for v in (nl.a * 1e4, nl.c * 1e2)]
        [3.9, 1.0]
    """
    y = signal.detach().to(torch.float64).reshape(-1)
    r = residual.detach().to(torch.float64).reshape(y.shape[0], -1).abs()
    ex = 0.0 if extra is None else extra.detach().to(torch.float64).reshape(-1).clamp_min(0)
    if y.numel() < 10:
        raise InputError(f"too few pixels ({y.numel()}) to estimate a noise level", fix="use pixel_noise = \"constant\"")
    y = y.clamp_min(0)
    ym = float(y.mean())
    # start: a constant scale (the mean residual), split evenly between the three terms at the mean radiance (a
    # term that must grow from nearly nothing is slow to find in log coordinates; one that must vanish is not)
    s0 = float(r.mean()) if kind == "laplace" else float(r.pow(2).mean().sqrt())
    s0 = max(s0, 1e-6)
    ym_ = max(ym, 1e-6)
    theta = torch.tensor([math.log(s0 * s0 / 3), math.log(s0 * s0 / (3 * ym_)), math.log(s0 * s0 / (3 * ym_ ** 2))],
                         dtype=torch.float64)
    y2 = y * y
    # every channel of a value shares its scale: the nll needs the channels' sum of |r| (Laplace) or of r^2 only
    C = r.shape[1]
    R = (r.sum(1) if kind == "laplace" else r.pow(2).sum(1)).div_(C)
    del r
    K = y.numel()

    def nll(theta):
        """The mean nll per channel value, its gradient and Hessian in ``theta = log(a, b, c)``, in closed form (one
        pass over the ``K`` values, a few arrays of ``K``): with ``v = s^2 = a + b y + c y^2``, ``L_v`` and ``L_vv`` the
        nll's derivatives in ``v`` (Laplace: ``1 / (2 v) - R / (2 v s)`` and ``-1 / (2 v^2) + 3 R / (4 v^2 s)``;
        Gaussian: ``1 / (2 v) - R / (2 v^2)`` and ``-1 / (2 v^2) + R / v^3``) and ``u_i = dv / dtheta_i =
        e^theta_i y^i``: ``g_i = mean(L_v u_i)`` and ``H_ij = e^(theta_i + theta_j) mean(L_vv y^(i + j)) +
        delta_ij g_i``."""
        coef = theta.exp()
        a_, b_, c_ = (float(x) for x in coef)
        v = (y2 * c_).add_(y, alpha=b_).add_(a_)
        if extra is not None:
            v.add_(ex)
        if kind == "laplace":
            q = R / v.sqrt()
            loss = float((0.5 * v.log() + q).mean())
            lv = (1 - q).div_(v).mul_(0.5)
            lvv = q.mul_(0.75).sub_(0.5).div_(v).div_(v)
        else:
            q = R / v
            loss = float((0.5 * v.log() + 0.5 * q).mean())
            lv = (1 - q).div_(v).mul_(0.5)
            lvv = q.sub_(0.5).div_(v).div_(v)
        g = torch.stack([lv.sum(), lv @ y, lv @ y2]) / K * coef
        m = []                                  # mean(L_vv y^k), k = 0..4, by one running product in place
        for k in range(5):
            m.append(lvv.sum() / K)
            if k < 4:
                lvv.mul_(y)
        m = torch.stack(m)
        idx = torch.arange(3)
        H = m[idx[:, None] + idx[None, :]] * coef[:, None] * coef[None, :] + torch.diag(g)
        return loss, g, H

    theta = newton(nll, theta, max_iter=iters)
    a, b, c = (float(v) for v in theta.detach().exp())
    if not all(math.isfinite(v) for v in (a, b, c)):
        raise InputError("the noise level fit did not converge", fix="use pixel_noise = \"constant\"")
    # coefficients far below what they could contribute at the data's radiance are zero
    top = a + b * float(y.max()) + c * float(y.max()) ** 2
    a, b, c = (0.0 if v * w < 1e-9 * top else v for v, w in ((a, 1.0), (b, float(y.max())), (c, float(y.max()) ** 2)))
    return NoiseLevel(a, b, c, ym)
