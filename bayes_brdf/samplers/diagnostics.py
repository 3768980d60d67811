"""Convergence diagnostics from what every run already computes: per-particle energies and positions.

:func:`diagnose` looks at the second half of a run (the driver records each
particle's energy every step and a fixed set of tracked coordinates every few
steps) and at the final particles, and returns :class:`Diagnostics`: named
checks, each with its value, its threshold and whether it passed, plus one
line for the user when a check fails.

Which checks fail a run: only those that say more sampling would change the answer a user reads (the
mean and std of the posterior), by more than rerunning with another seed would. The others describe
the chains and are reported, with what they mean, but do not fail a run: on real photos the energy keeps
creeping down for thousands of steps (a few texels settling) while the maps no longer move, and a
warning that more steps never clears teaches users to ignore warnings (docs/samplers.md, "Diagnostics").

Checks that can fail a run (left out where they do not apply):

``mean_shift``
    The particles' mean per coordinate at the end against three quarters into the run, in units of the
    Monte Carlo error of a mean of ``n`` independent draws, ``sqrt((s_end^2 + s_3/4^2) / n)``: the
    fraction of coordinates that moved by more than 3 of those. Independent ensembles give 0.3 %
    (a t-tail with 20 particles about 0.5 %); consecutive ones of a converged run less. Above 5 % (and
    at least 3 coordinates), the mean map is still moving by more than a rerun with another seed would
    move it.
``std_change``
    The particles' spread per coordinate at the end against three quarters into the run: the mean over
    coordinates of ``log(s_end / s_3/4)`` (the Monte Carlo noise of single coordinates averages out over
    the coordinates; what is left is systematic). Beyond 10 % (``|.| > log 1.1``) plus three standard
    errors of that mean between independent ensembles (what a rerun would give; large for a few coordinates) the
    ensemble is still contracting or spreading: the std map a user reads would change with more steps.
``behind``
    The fraction of particles whose final energy exceeds the median by more than
    ``max(10, 10 * 1.4826 * MAD)``: particles left far behind (prior draws
    stuck where the likelihood is flat), which inflate the std map. Fails above 0.
``stein_ratio``
    With the final gradients: the mean over coordinates of
    ``sum_i dU/dz_d (z_id - mean_d) / (n - 1)``, which is 1 under the target (Stein's
    identity) and, for a Gaussian, the squared ratio of the particles' std to the
    target's: below 0.5 the particles are collapsed, above 2 over-dispersed. Beyond
    :data:`LOW_DIM` dimensions only, where it averages over many coordinates; in a few dimensions
    twenty particles in a skewed posterior (Table 1's, where SPOS is 8x better than i.i.d. draws)
    read 2-10 on one coordinate, so there it is reported.
``energy_spread``
    In a few dimensions (at most :data:`LOW_DIM`): the variance of the final particles' energies over
    ``D / 2``, its value for draws from a Gaussian posterior (0.5-5 for exact draws of the 2-D Table 1
    family). An ensemble that straddles a posterior narrower than its steps sits where the energy is
    far above the posterior's: 17-10^5 on the three such setups of docs/calibration.md. Fails above 10.

Reported, with their meaning (``ok`` is ``None``):

``rhat``, ``rhat_max``, ``rhat_energy``
    Rank-normalised split-R-hat (Vehtari et al. 2021) with every particle as a chain, over a fixed set
    of tracked coordinates (median, largest) and over the particles' energies, for samplers whose
    particles are chains. Near 1 the particles have forgotten where they started; above about 1.2 some
    coordinates have not crossed the posterior within half a run. An ensemble is judged as a whole (its
    mean and std), so slow single coordinates matter through ``mean_shift`` and ``std_change``.
``ess``, ``ess_per_particle``
    Bulk effective sample size of the same draws (smallest over the energy and the tracked
    coordinates): how many independent draws the second half of the run is worth.
``energy_drift``
    The mean energy of the last quarter of the run against the quarter before it, as a z-score over the
    particles (paired): about N(0, 1) when stationary, large while the energy still falls. With tens of
    thousands of pixels a fall far too small to move any map is many standard errors.
``stragglers``
    The fraction of (particle, coordinate) entries more than 10 robust standard
    deviations (1.4826 MAD) from the coordinate's median: single coordinates left
    behind. With 20 particles the MAD of a coordinate is itself noisy:
    20 exact draws from the per-texel posterior of docs/samplers.md give 0.004.

The kernelised Stein discrepancy (:func:`ksd`) is kept as a function for comparing runs of one problem
(benchmarks); it has no scale a reader could interpret, so runs do not report it.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import torch
from torch import Tensor

RHAT_MAX = 1.2            # where R-hat's description turns from "mixed" to "not mixed" (reported)
DRIFT_MAX = 5.0           # where the energy drift's description turns to "still falling" (reported)
STEIN_RANGE = (0.5, 2.0)
MEAN_SHIFT_SDS = 3.0      # a coordinate "moved" when its mean moved by more than this many Monte Carlo errors
MEAN_SHIFT_MAX = 0.05     # the fraction of coordinates that may have moved
MEAN_SHIFT_MIN = 3        # ... and a run fails only when at least this many did (a few coordinates: chance)
ENERGY_SPREAD_MAX = 10.0  # low dimension: var(U) over the particles / (D / 2)
STD_CHANGE_MAX = math.log(1.1)   # systematic change of the spread, as |mean log ratio|


#: at most this many dimensions, a failed Stein check advises an ensemble sampler instead of more steps
LOW_DIM = 16


@dataclass
class Diagnostics:
    """Named checks ``{name: {"value", "threshold", "ok"}}`` (``ok`` is ``None`` for a reported-only value)."""

    checks: dict = field(default_factory=dict)
    steps: int = 0
    dim: int = 0
    sampler: str = ""         # the sampler that ran (the remedy does not advise the sampler that failed)

    @property
    def converged(self) -> bool:
        return all(c["ok"] is not False for c in self.checks.values())

    @property
    def failed(self) -> list[str]:
        return [k for k, c in self.checks.items() if c["ok"] is False]

    @property
    def settled(self) -> bool:
        """No check says the run is still moving (see :meth:`remedy`)."""
        failed = set(self.failed)
        if {"mean_shift", "std_change"} & failed:
            return False
        if "behind" in failed and "energy_spread" not in failed:   # in a few dimensions, one symptom of the spread
            return False
        c = self.checks
        drift = c.get("energy_drift", {}).get("value")
        rhat = c.get("rhat", {}).get("value")
        return not ((drift is not None and drift > DRIFT_MAX) or (rhat is not None and rhat > RHAT_MAX))

    def remedy(self, cli: bool = False) -> str:
        """What to do about the failed checks, in the words of the CLI (``cli``) or of :func:`bayes_brdf.infer`.

        While the run has not settled (the answer still moves: ``mean_shift``, ``std_change``; particles
        left behind; or the reported energy drift and R-hat past their descriptive limits), more steps:
        twice as many. Once it has settled, a low-dimensional posterior whose particles still sit far
        above its energies (``energy_spread``: a posterior narrower than the sampler's steps) gets
        another sampler: more steps of the same one do not change a settled ensemble (measured,
        docs/calibration.md); emcee itself gets more steps (its burn-in, which relocates walkers left
        behind, is half the run).
        """
        if self.settled and "energy_spread" in self.failed and self.sampler != "emcee":
            return ("the particles sit far above the posterior's energies (a posterior narrower than the sampler's "
                    "steps; more steps do not help): use the emcee sampler "
                    + ("(--sampler emcee --overwrite)" if cli else "(sampler=\"emcee\")"))
        n = 2 * self.steps
        return f"rerun with --steps {n} --overwrite (or a new --out)" if cli else f"rerun with steps={n}"

    def message(self, fix: str | None = None, *, cli: bool = False) -> str:
        """``""`` when every check passed, else one line: what failed and the remedy."""
        if self.converged:
            return ""
        parts = []
        for k in self.failed:
            c = self.checks[k]
            parts.append(f"{k} {_fmt(c['value'])} (limit {c['threshold']})")
        return f"not converged: {', '.join(parts)}; {fix or self.remedy(cli)}"

    def to_dict(self) -> dict:
        return {"converged": self.converged, "failed": self.failed, "steps": self.steps, "dim": self.dim,
                **({"sampler": self.sampler} if self.sampler else {}), "checks": {k: dict(v) for k, v in self.checks.items()}}

    @classmethod
    def from_dict(cls, d: dict) -> "Diagnostics":
        return cls(dict(d.get("checks") or {}), int(d.get("steps") or 0), int(d.get("dim") or 0),
                   str(d.get("sampler") or ""))


def _fmt(v) -> str:
    return f"{v:.3g}" if isinstance(v, float) else str(v)


def _check(value, threshold, ok) -> dict:
    return {"value": float(value) if value is not None else None, "threshold": threshold,
            "ok": None if ok is None else bool(ok)}


# ---------------------------------------------------------------- R-hat and ESS (chains x draws)
def _rank_normal(x: Tensor) -> Tensor:
    """Rank-normalise draws ``[chains, draws, K]`` jointly over chains and draws, per column."""
    c, d, k = x.shape
    flat = x.reshape(c * d, k)
    ranks = flat.argsort(0).argsort(0).to(torch.float64) + 1
    p = (ranks - 0.375) / (c * d + 0.25)
    return torch.special.ndtri(p).reshape(c, d, k)


def split_rhat(x: Tensor) -> Tensor:
    """Rank-normalised split-R-hat per column of draws ``[chains, draws, K]`` -> ``[K]``.

    Example:
        >>> g = torch.Generator().manual_seed(0)
        >>> bool(split_rhat(torch.randn(8, 200, 3, generator=g)).max() < 1.05)
        True
        >>> bool(split_rhat(torch.randn(8, 200, 1, generator=g) + torch.arange(8.)[:, None, None]) > 2)
        True
    """
    x = x.to(torch.float64)
    d = x.shape[1] // 2
    xs = torch.cat([x[:, :d], x[:, d:2 * d]], 0)                 # split chains
    z = _rank_normal(xs)
    n = z.shape[1]
    means = z.mean(1)                                            # [2c, K]
    W = z.var(1, unbiased=True).mean(0)
    B = n * means.var(0, unbiased=True)
    var = (n - 1) / n * W + B / n
    return torch.where(W > 0, (var / W).sqrt(), torch.full_like(W, math.inf))


def ess_bulk(x: Tensor) -> Tensor:
    """Bulk effective sample size per column of ``[chains, draws, K]`` (rank-normalised split chains,
    Geyer's initial positive sequence), ``[K]``."""
    x = x.to(torch.float64)
    d = x.shape[1] // 2
    z = _rank_normal(torch.cat([x[:, :d], x[:, d:2 * d]], 0))
    m, n, k = z.shape
    zc = z - z.mean(1, keepdim=True)
    f = torch.fft.rfft(zc, n=2 * n, dim=1)
    acov = torch.fft.irfft(f * f.conj(), n=2 * n, dim=1)[:, :n] / n          # [m, n, K]
    W = z.var(1, unbiased=True).mean(0)
    var = (n - 1) / n * W + z.mean(1).var(0, unbiased=True) if m > 1 else W
    rho = 1 - (W - acov.mean(0)) / var                                      # [n, K]
    rho[0] = 1.0
    out = torch.empty(k, dtype=torch.float64)
    for j in range(k):
        r = rho[:, j]
        pairs = r[: (n // 2) * 2].reshape(-1, 2).sum(1)                     # Geyer: P_t = rho_2t + rho_2t+1
        pos = pairs > 0
        cut = int(pos.to(torch.int64).cumprod(0).sum())
        p = pairs[:cut]
        if cut > 1:
            p = torch.cummin(p, 0).values                                   # initial monotone sequence
        tau = -1 + 2 * float(p.sum()) if cut else 1.0
        out[j] = m * n / max(tau, 1.0 / math.log10(max(m * n, 10)))
    return out


# ---------------------------------------------------------------- particle checks
def stragglers(z: Tensor, sds: float = 10.0) -> float:
    """Fraction of entries of ``z [n, D]`` more than ``sds`` robust standard deviations from their column's median."""
    med = z.median(0).values
    dev = (z - med).abs()
    mad = dev.median(0).values * 1.4826
    scale = torch.where(mad > 0, mad, dev.max(0).values.clamp_min(1e-12))
    return float((dev > sds * scale).to(torch.float64).mean())


def behind_mask(energies: Tensor) -> Tensor:
    """Which particles' energy exceeds the median by ``max(10, 10 * 1.4826 * MAD)`` (``[n]`` booleans)."""
    e = energies.to(torch.float64)
    med = e.median()
    mad = (e - med).abs().median() * 1.4826
    return e - med > max(10.0, 10.0 * float(mad))


def behind(energies: Tensor) -> float:
    """Fraction of particles whose energy exceeds the median by ``max(10, 10 * 1.4826 * MAD)``."""
    return float(behind_mask(energies).to(torch.float64).mean())


def drawn(energies: Tensor | None) -> Tensor | None:
    """Which of a run's final particles stand for posterior draws (``[n]`` booleans), from its per-step
    energies ``[steps, n]``: all but those left behind (:func:`behind_mask`), whose renders are no draw's
    and whose residuals are no noise. ``None`` (all of them) when the energies are missing or not finite,
    or fewer than two particles would remain."""
    if energies is None or not len(energies) or not bool(torch.isfinite(energies[-1]).all()):
        return None
    keep = ~behind_mask(energies[-1])
    return keep if int(keep.sum()) >= 2 else None


def stein_ratio(z: Tensor, grad: Tensor) -> float:
    """Mean over coordinates of ``sum_i grad_id (z_id - mean_d) / (n - 1)`` (1 under the target: Stein's identity)."""
    z, g = z.to(torch.float64), grad.to(torch.float64)
    return float((g * (z - z.mean(0))).sum(0).mean() / (z.shape[0] - 1))


def ksd(z: Tensor, grad: Tensor) -> float:
    """Squared kernelised Stein discrepancy (unbiased U-statistic: about 0 for exact draws, may be slightly
    negative) of particles ``z [n, D]`` with score ``-grad``, IMQ kernel."""
    z, s = z.to(torch.float64), -grad.to(torch.float64)
    n, D = z.shape
    X, SX = z @ z.T, s @ z.T                                 # Gram matrices: no [n, n, D] tensor
    sq = X.diagonal()
    r2 = (sq[:, None] + sq[None, :] - 2 * X).clamp_min(0)
    h = float(r2[r2 > 0].median()) if bool((r2 > 0).any()) else 1.0
    base = 1 + r2 / h
    k = base.pow(-0.5)
    # k = (1 + r2/h)^-1/2; grad_x k = -(1/h) base^-3/2 (x - y); grad_y k = +(1/h) base^-3/2 (x - y)
    gk = base.pow(-1.5) / h                                  # [n, n]
    t1 = (s @ s.T) * k
    sd = SX.diagonal()[:, None] - SX                         # s_i . (x_i - x_j)
    sd2 = SX.T - SX.diagonal()[None, :]                      # s_j . (x_i - x_j)
    t2 = gk * sd - gk * sd2                                  # s_i . grad_y k + s_j . grad_x k
    tr = D * gk - 3 * r2 * base.pow(-2.5) / (h * h)          # trace of grad_x grad_y k
    u = (t1 + t2 + tr).fill_diagonal_(0)
    return float(u.sum() / (n * (n - 1)))


def stability(z: Tensor, earlier: Tensor, groups: int = 1) -> tuple[float, int, float, float]:
    """``(mean_shift, moved, std_change, std_change_se)`` of particles ``z [G * n, D]`` against the same
    particles ``earlier``: the fraction (and number) of coordinates whose mean moved by more than
    :data:`MEAN_SHIFT_SDS` Monte Carlo errors, and the mean over coordinates of ``log(s_z / s_earlier)``
    with the standard error it would have between independent ensembles, ``sqrt(1 / ((n - 1) D))``
    (per group, pooled over the groups).

    Example:
        >>> g = torch.Generator().manual_seed(0)
        >>> a, b = torch.randn(20, 500, generator=g), torch.randn(20, 500, generator=g)
        >>> shift, moved, change, se = stability(a, b)
        >>> shift < 0.02 and abs(change) < 3 * se < 0.05
        True
        >>> shift, moved, change, se = stability(0.5 * a + 2, b)
        >>> shift > 0.9 and round(change, 1)
        -0.7
    """
    n = z.shape[0] // groups
    a = z.to(torch.float64).reshape(groups, n, -1)
    b = earlier.to(torch.float64).reshape(groups, n, -1)
    sa, sb = a.std(1), b.std(1)
    err = ((sa * sa + sb * sb) / n).sqrt()
    moved = (a.mean(1) - b.mean(1)).abs() > MEAN_SHIFT_SDS * err
    moved &= err > 0
    ok = (sa > 0) & (sb > 0)
    ratio = (sa[ok] / sb[ok]).log()
    change = float(ratio.mean()) if ratio.numel() else 0.0
    # two independent ensembles of n draws: log(s_a / s_b) has variance about 1 / (n - 1) per coordinate
    se = math.sqrt(1.0 / ((n - 1) * ratio.numel())) if ratio.numel() and n > 1 else math.inf
    return float(moved.to(torch.float64).mean()), int(moved.sum()), change, se


# ---------------------------------------------------------------- all of them
def diagnose(energies: Tensor, tracked: Tensor | None, z: Tensor, grad: Tensor | None, *, chains: bool,
             steps: int, earlier: Tensor | None = None, groups: int = 1, sampler: str = "") -> Diagnostics:
    """Diagnostics of a run.

    Args:
        energies: per-particle energies of every step ``[T, n]`` (NaN where not recorded).
        tracked: tracked coordinates ``[K, n, C]`` sampled evenly over the second half of the run, or ``None``.
        z: the final particles ``[n, D]``.
        grad: ``dU/dz`` at ``z`` ``[n, D]`` (the Stein checks), or ``None``.
        chains: whether each particle is a Markov chain (R-hat and ESS apply).
        steps: the run's length (for the remedy's step count).
        earlier: the particles three quarters into the run ``[n, D]`` (the stability checks), or ``None``.
        groups: independent ensembles in ``z`` (group by group).
        sampler: the sampler's name (for the remedy).
    """
    checks = {}
    e = energies.to(torch.float64)
    ok_rows = torch.isfinite(e).all(1)
    e = e[ok_rows]
    T, n = e.shape if e.dim() == 2 else (0, 0)
    if chains and T >= 8 and n >= 2:
        half = e[T // 2:].T[:, :, None]                      # [n, draws, 1]
        checks["rhat_energy"] = _check(float(split_rhat(half)[0]), None, None)
        if tracked is not None and tracked.shape[0] >= 8:
            draws = tracked.to(torch.float64).permute(1, 0, 2)
            rh = split_rhat(draws)
            rmed = float(rh.median())
            checks["rhat"] = _check(rmed, RHAT_MAX, None)
            checks["rhat_max"] = _check(float(rh.max()), None, None)
            emin = float(ess_bulk(draws).min())
            checks["ess"] = _check(emin, float(n), None)
    if T >= 8 and n >= 2:
        q = T // 4
        d = e[T - 2 * q:T - q].mean(0) - e[T - q:].mean(0)    # > 0: still falling
        sd = float(d.std(unbiased=True))
        zsc = float(d.mean()) / (sd / math.sqrt(n)) if sd > 0 else 0.0
        checks["energy_drift"] = _check(zsc, DRIFT_MAX, None)
    if earlier is not None and z.shape[0] // groups >= 2 and tuple(earlier.shape) == tuple(z.shape):
        shift, moved, change, se = stability(z, earlier, groups)
        checks["mean_shift"] = _check(shift, MEAN_SHIFT_MAX, shift <= MEAN_SHIFT_MAX or moved < MEAN_SHIFT_MIN)
        limit = STD_CHANGE_MAX + 3 * se
        checks["std_change"] = _check(change, round(limit, 4) if math.isfinite(limit) else None,
                                      abs(change) <= limit)
    if n >= 2 and T:
        b = behind(e[-1])
        checks["behind"] = _check(b, 0.0, b <= 0.0)
    if z.shape[0] >= 5:
        checks["stragglers"] = _check(stragglers(z), None, None)
    low = z.shape[1] <= LOW_DIM
    if grad is not None and z.shape[0] >= 2:
        r = stein_ratio(z, grad)
        checks["stein_ratio"] = _check(r, list(STEIN_RANGE), None if low else STEIN_RANGE[0] <= r <= STEIN_RANGE[1])
    if low and n >= 2 and T:
        spread = float(e[-1].var()) / (z.shape[1] / 2)
        checks["energy_spread"] = _check(spread, ENERGY_SPREAD_MAX, spread <= ENERGY_SPREAD_MAX)
    return Diagnostics(checks, steps, int(z.shape[1]), sampler)
