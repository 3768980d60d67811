"""Test densities with known answers: a correlated Gaussian, a banana and a two-mode mixture.

Each target gives a batched energy ``U(z) = -log p(z)`` (``[n, D] -> [n]``,
float64, up to a constant), a :class:`~bayes_brdf.potential.FunctionPotential`
for the samplers, its exact mean and covariance, its mode(s), and exact
independent draws (``sample``), so a sampler's output can be compared with
the truth and with what ``n`` perfect samples would give (:func:`moment_errors`).

=============================  ===  =========================================================
:class:`CorrelatedGaussian`    10   scales 0.5 to 2, correlations 0.6 down to 0.01
:class:`Banana`                2    ``x1 ~ N(0, a^2)``, ``x2 | x1 ~ N(b (x1^2 - a^2), s^2)``
:class:`TwoModeMixture`        2    ``w1 N(mu1, s^2 I) + w2 N(mu2, s^2 I)``, modes 5 s apart
=============================  ===  =========================================================

Example:
    >>> from bayes_brdf.samplers import SGLD, run
    >>> t = CorrelatedGaussian(dim=2)
    >>> res = run(SGLD(step_size=0.02, preconditioner="none"), t.potential(), particles=400, steps=800,
    ...           progress=False, checkpoint_every=0)
    >>> err = moment_errors(res.z, t)
    >>> err.mean_z_max < 4.5, err.var_z_max < 4.5
    (True, True)
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from ..errors import InputError
from ..potential import FunctionPotential

_F64 = torch.float64


class Target:
    """A density with exact moments: ``energy``, ``potential()``, ``mean``, ``cov``, ``var``, ``modes``, ``sample``."""

    name = "target"
    dim: int
    mean: Tensor       # [D]
    cov: Tensor        # [D, D]
    modes: Tensor      # [k, D] the local maxima of the density
    kurtosis: Tensor   # [D] exact E[(x - mean)^4] / var^2 per coordinate (3 for a Gaussian)

    @property
    def var(self) -> Tensor:
        """The exact marginal variances ``[D]``."""
        return self.cov.diagonal().clone()

    def energy(self, z: Tensor) -> Tensor:
        """``-log p(z)`` up to a constant, ``[n, D] -> [n]``."""
        raise NotImplementedError

    def potential(self, init_std: float = 1.0) -> FunctionPotential:
        """The potential the samplers see; its ``init`` draws ``N(0, init_std^2 I)``."""
        return FunctionPotential(self.energy, self.dim, init_std=init_std, dtype=_F64)

    def sample(self, n: int, seed: int = 0) -> Tensor:
        """``n`` exact independent draws ``[n, D]`` (the yardstick for Monte Carlo error)."""
        raise NotImplementedError

    def __repr__(self) -> str:
        return f"{type(self).__name__}(dim={self.dim})"


class CorrelatedGaussian(Target):
    """``N(mean, cov)`` in ``dim`` dimensions with a range of scales and correlations.

    ``cov = diag(s) R diag(s)`` with standard deviations ``s`` log-spaced from
    ``scale_min`` to ``scale_max`` and ``R_ij = rho^|i - j|`` (correlations from
    ``rho`` between neighbours down to ``rho^(dim-1)``), mean evenly spaced
    from -1 to 1. The defaults give condition number ~ 70.

    Example:
        >>> t = CorrelatedGaussian()
        >>> corr = t.cov / (t.var[:, None] * t.var[None, :]).sqrt()
        >>> t.dim, [round(float(v), 3) for v in t.var[[0, -1]]], [round(float(c), 2) for c in corr[0, 1:4]]
        (10, [0.25, 4.0], [0.6, 0.36, 0.22])
        >>> x = t.sample(20000, seed=1)
        >>> bool((x.mean(0) - t.mean).abs().max() < 0.05), bool(((x.var(0) / t.var) - 1).abs().max() < 0.05)
        (True, True)
        >>> u = t.energy(torch.stack([t.mean, t.mean + 1]))
        >>> float(u[0]), bool(u[1] > 0)
        (0.0, True)
    """

    name = "gaussian"

    def __init__(self, dim: int = 10, scale_min: float = 0.5, scale_max: float = 2.0, rho: float = 0.6):
        if not (isinstance(dim, int) and dim >= 1):
            raise InputError(f"CorrelatedGaussian dim must be a positive integer, got {dim!r}")
        if not (0 < scale_min <= scale_max):
            raise InputError(f"CorrelatedGaussian needs 0 < scale_min <= scale_max, got {scale_min}, {scale_max}")
        if not -1 < rho < 1:
            raise InputError(f"CorrelatedGaussian rho must be in (-1, 1), got {rho!r}")
        self.dim = dim
        s = torch.logspace(math.log10(scale_min), math.log10(scale_max), dim, dtype=_F64)
        i = torch.arange(dim, dtype=_F64)
        R = rho ** (i[:, None] - i[None, :]).abs()
        self.cov = s[:, None] * R * s[None, :]
        self.mean = torch.linspace(-1.0, 1.0, dim, dtype=_F64) if dim > 1 else torch.zeros(1, dtype=_F64)
        self.precision = torch.linalg.inv(self.cov)
        self.precision = 0.5 * (self.precision + self.precision.T)
        self._chol = torch.linalg.cholesky(self.cov)
        self.modes = self.mean[None].clone()
        self.kurtosis = torch.full((dim,), 3.0, dtype=_F64)

    def langevin_cov(self, step_size: float) -> Tensor:
        """The exact stationary covariance of unadjusted Langevin with a constant step ``h`` (SGLD, ``G = 1``).

        ``x <- x - h P (x - mean) + sqrt(2 h) xi`` with precision ``P`` leaves
        ``N(mean, (P - h P^2 / 2)^-1)`` invariant: the discretisation bias a
        constant-step SGLD run should show (none as ``h -> 0``; unstable for
        ``h >= 2 / lambda_max(P)``).

        Example:
            >>> t = CorrelatedGaussian()
            >>> r = t.langevin_cov(0.02).diagonal() / t.var
            >>> bool((r > 1).all()), round(float(r.max()), 3), bool(torch.allclose(t.langevin_cov(1e-12), t.cov))
            (True, 1.043, True)
        """
        P = self.precision
        lam = float(torch.linalg.eigvalsh(P).max())
        if not 0 <= step_size < 2 / lam:
            raise InputError(f"unadjusted Langevin with step {step_size} is unstable here (needs < {2 / lam:.4g})")
        S = torch.linalg.inv(P - 0.5 * step_size * P @ P)
        return 0.5 * (S + S.T)

    def energy(self, z: Tensor) -> Tensor:
        d = z - self.mean.to(z)
        return 0.5 * ((d @ self.precision.to(z)) * d).sum(1)

    def sample(self, n: int, seed: int = 0) -> Tensor:
        g = torch.Generator().manual_seed(seed)
        return self.mean + torch.randn(n, self.dim, generator=g, dtype=_F64) @ self._chol.T


class Banana(Target):
    """A twisted Gaussian: ``x1 ~ N(0, a^2)``, ``x2 | x1 ~ N(b (x1^2 - a^2), s^2)``.

    Exact moments: ``E x = 0``, ``Var x1 = a^2``, ``Var x2 = s^2 + 2 b^2 a^4``,
    ``Cov(x1, x2) = 0`` (yet strongly dependent: ``E[x1^2 x2] = 2 b a^4``,
    see :attr:`third_moment`); the single mode is ``(0, -b a^2)``, not the mean.

    Example:
        >>> t = Banana()
        >>> t.mean.tolist(), t.var.tolist(), t.modes.tolist(), t.third_moment
        ([0.0, 0.0], [1.0, 3.0], [[0.0, -1.0]], 2.0)
        >>> x = t.sample(200000, seed=0)
        >>> [round(float(v), 1) for v in x.var(0)], round(float((x[:, 0] ** 2 * x[:, 1]).mean()), 1)
        ([1.0, 3.0], 2.0)
        >>> float(t.energy(t.modes)[0])
        0.0
    """

    name = "banana"

    def __init__(self, a: float = 1.0, b: float = 1.0, s: float = 1.0):
        if not (a > 0 and s > 0):
            raise InputError(f"Banana needs a > 0 and s > 0, got a={a!r}, s={s!r}")
        self.a, self.b, self.s = float(a), float(b), float(s)
        self.dim = 2
        self.mean = torch.zeros(2, dtype=_F64)
        self.cov = torch.diag(torch.tensor([a ** 2, s ** 2 + 2 * b ** 2 * a ** 4], dtype=_F64))
        self.modes = torch.tensor([[0.0, -b * a ** 2]], dtype=_F64)
        #: ``E[x1^2 x2] = 2 b a^4``: what a Gaussian fit with the right covariance gets wrong (0)
        self.third_moment = 2 * b * a ** 4
        # x2 = b a^2 (chi2_1 - 1) + s e: E(chi2_1 - 1)^2 = 2, E(chi2_1 - 1)^4 = 60
        v2 = s ** 2 + 2 * b ** 2 * a ** 4
        m4 = 60 * b ** 4 * a ** 8 + 12 * b ** 2 * a ** 4 * s ** 2 + 3 * s ** 4
        self.kurtosis = torch.tensor([3.0, m4 / v2 ** 2], dtype=_F64)

    def energy(self, z: Tensor) -> Tensor:
        x1, x2 = z[:, 0], z[:, 1]
        return 0.5 * (x1 / self.a) ** 2 + 0.5 * ((x2 - self.b * (x1 ** 2 - self.a ** 2)) / self.s) ** 2

    def sample(self, n: int, seed: int = 0) -> Tensor:
        g = torch.Generator().manual_seed(seed)
        e = torch.randn(n, 2, generator=g, dtype=_F64)
        x1 = self.a * e[:, 0]
        return torch.stack([x1, self.b * (x1 ** 2 - self.a ** 2) + self.s * e[:, 1]], 1)


class TwoModeMixture(Target):
    """``w1 N(mu1, s^2 I) + w2 N(mu2, s^2 I)`` in 2-D (``s = scale``): exact moments, modes and basin masses.

    The two components share the isotropic scale ``s``, so the set where
    component 1 is the more responsible one is a half-plane, and the exact
    probability mass on each side (:attr:`basin_mass`, close to the weights
    when the modes are well separated) is what the fraction of samples
    :meth:`assign`\\ ed to each mode should estimate. :attr:`modes` are the
    density's true local maxima (Newton on the line through the means; they
    sit slightly inside ``mu1``, ``mu2``).

    Example:
        >>> t = TwoModeMixture()
        >>> t.weights.tolist(), [round(v, 4) for v in t.mean.tolist()], [round(v, 4) for v in t.var.tolist()]
        ([0.3, 0.7], [0.5, 0.0], [1.5625, 0.25])
        >>> [round(v, 4) for v in t.basin_mass.tolist()], [[round(v, 4) for v in m] for m in t.modes.tolist()]
        ([0.2997, 0.7003], [[-1.25, 0.0], [1.25, 0.0]])
        >>> x = t.sample(100000, seed=0)
        >>> round(float((t.assign(x) == 0).double().mean()), 2), bool((x.mean(0) - t.mean).abs().max() < 0.02)
        (0.3, True)
    """

    name = "mixture"

    def __init__(self, weights=(0.3, 0.7), locs=((-1.25, 0.0), (1.25, 0.0)), scale: float = 0.5):
        w = torch.as_tensor(weights, dtype=_F64)
        mu = torch.as_tensor(locs, dtype=_F64)
        if w.shape != (2,) or not bool((w > 0).all()) or abs(float(w.sum()) - 1) > 1e-12:
            raise InputError(f"TwoModeMixture weights must be two positive numbers summing to 1, got {weights!r}")
        if mu.shape != (2, 2) or not scale > 0:
            raise InputError("TwoModeMixture needs locs of shape (2, 2) and scale > 0")
        self.dim, self.weights, self.locs, self.scale = 2, w, mu, float(scale)
        self.mean = w @ mu
        dm = mu - self.mean
        self.cov = scale ** 2 * torch.eye(2, dtype=_F64) + (w[:, None, None] * dm[:, :, None] * dm[:, None, :]).sum(0)
        m4 = (w[:, None] * (dm ** 4 + 6 * dm ** 2 * scale ** 2 + 3 * scale ** 4)).sum(0)
        self.kurtosis = m4 / self.cov.diagonal() ** 2
        # the responsibility boundary: t = (x - mu1).u < c, with u the unit vector from mu1 to mu2
        d = float((mu[1] - mu[0]).norm())
        if d == 0:
            raise InputError("TwoModeMixture needs two different locs")
        self._u, self._d = (mu[1] - mu[0]) / d, d
        c = d / 2 + scale ** 2 * math.log(float(w[0] / w[1])) / d
        self._c = c
        phi = lambda v: 0.5 * (1 + math.erf(v / math.sqrt(2)))  # noqa: E731
        m1 = float(w[0]) * phi(c / scale) + float(w[1]) * phi((c - d) / scale)
        #: exact probability of each component's side of the responsibility boundary ``[2]``
        self.basin_mass = torch.tensor([m1, 1 - m1], dtype=_F64)
        self.modes = self._find_modes()

    def _log_comp(self, z: Tensor) -> Tensor:
        d2 = ((z[:, None, :] - self.locs.to(z)[None]) ** 2).sum(-1)              # [n, 2]
        return self.weights.to(z).log()[None] - 0.5 * d2 / self.scale ** 2

    def energy(self, z: Tensor) -> Tensor:
        # the normalising constant is the same for both components: leave it out
        return -torch.logsumexp(self._log_comp(z), dim=1)

    def assign(self, z: Tensor) -> Tensor:
        """The index ``[n]`` (0 or 1) of the more responsible component of each row of ``z``."""
        t = (z - self.locs[0].to(z)) @ self._u.to(z)
        return (t >= self._c).long()

    def _find_modes(self) -> Tensor:
        # stationary points on the line mu1 + t u solve t = d r2(t); Newton from both means
        d, s2 = self._d, self.scale ** 2
        t = torch.tensor([0.0, d], dtype=_F64)
        lw = self.weights.log()
        for _ in range(100):
            logit = (lw[1] - lw[0]) + (2 * t * d - d * d) / (2 * s2)
            r2 = torch.sigmoid(logit)
            g = t - d * r2
            dg = 1 - d * d * r2 * (1 - r2) / s2
            t = t - g / dg
        r2 = torch.sigmoid((lw[1] - lw[0]) + (2 * t * d - d * d) / (2 * s2))
        if not bool(((t - d * r2).abs() < 1e-10).all()) or float(t[1] - t[0]) < 0.5 * d \
                or not bool((1 - d * d * r2 * (1 - r2) / s2 > 0).all()):
            raise InputError("TwoModeMixture components overlap too much to have two modes",
                             fix="move the locs apart or lower scale")
        return self.locs[0][None] + t[:, None] * self._u[None]

    def sample(self, n: int, seed: int = 0) -> Tensor:
        g = torch.Generator().manual_seed(seed)
        k = (torch.rand(n, generator=g, dtype=_F64) >= self.weights[0]).long()
        return self.locs[k] + self.scale * torch.randn(n, 2, generator=g, dtype=_F64)


@dataclass
class MomentErrors:
    """How far samples ``z [n, D]`` are from a target's exact first two moments.

    ``mean_abs_error``: mean over coordinates of ``|mean_hat - mean|``;
    ``mean_z_max``: the largest ``|mean_hat - mean| / (sd / sqrt(n))``, the
    error in units of the standard error ``n`` independent exact draws would
    have (for 10 coordinates of exact draws: median 1.7, rarely above 3.5);
    ``var_ratio``: ``var_hat / var`` per coordinate, and ``var_z_max`` the
    largest ``|var_ratio - 1|`` in units of its standard error for ``n``
    independent exact draws, ``sqrt((kurtosis - 1) / n)`` (``sqrt(2 / n)`` for
    a Gaussian; larger for the banana's heavy-tailed ``x2``).
    """

    mean_abs_error: float
    mean_z_max: float
    var_ratio: Tensor
    var_z_max: float
    n: int

    @property
    def var_ratio_min(self) -> float:
        return float(self.var_ratio.min())

    @property
    def var_ratio_max(self) -> float:
        return float(self.var_ratio.max())

    @property
    def var_ratio_mean(self) -> float:
        return float(self.var_ratio.mean())


def moment_errors(z: Tensor, target: Target) -> MomentErrors:
    """:class:`MomentErrors` of samples ``z [n, D]`` against ``target``'s exact mean and variances.

    Example:
        >>> t = Banana()
        >>> e = moment_errors(t.sample(4000, seed=3), t)
        >>> e.mean_z_max < 4, e.var_z_max < 4, abs(e.var_ratio_mean - 1) < 0.1
        (True, True, True)
    """
    z = z.detach().to(_F64)
    n = z.shape[0]
    err = (z.mean(0) - target.mean).abs()
    sd = target.var.sqrt()
    ratio = z.var(0) / target.var
    var_se = ((target.kurtosis - 1) / n).sqrt()
    return MomentErrors(float(err.mean()), float((err / (sd / math.sqrt(n))).max()), ratio,
                        float(((ratio - 1).abs() / var_se).max()), n)


__all__ = ["Target", "CorrelatedGaussian", "Banana", "TwoModeMixture", "MomentErrors", "moment_errors"]
