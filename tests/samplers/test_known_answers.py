"""Every sampler against densities with exact answers (``bayes_brdf.samplers.targets``).

Targets: a correlated 10-D Gaussian (scales 0.5-2, correlations 0.6^|i-j|,
condition number ~70), a 2-D banana (``Var x2 = 3``, heavy-tailed) and a 2-D
two-mode mixture (weights 0.3 / 0.7, modes 5 standard deviations apart).

The bounds are Monte Carlo error bars, not fudge factors. For ``n`` final
particles, ``moment_errors`` measures each coordinate's mean error in units
of ``sd / sqrt(n)`` and each variance ratio's distance from 1 in units of
``sqrt((kurtosis - 1) / n)``: the standard errors of ``n`` independent exact
draws. ``K = 4.5`` of them is what the samplers that should be exact
(SGLD, SPOS with beta = 1, emcee, NUTS) must meet; over 10 coordinates, exact
draws exceed it with probability ~1e-4. Where the particles are correlated
the bars widen by ``1 / sqrt(ess)``: for NUTS (one chain) ``ess`` is the
chain's own measured effective-sample fraction per statistic; for emcee (one
ensemble snapshot, nothing to measure it from) a stated allowance.
Known biases are asserted as what they are: constant-step SGLD is compared
with the exact stationary covariance of unadjusted Langevin
(``CorrelatedGaussian.langevin_cov``); SVGD (no noise) is asserted to
*under*-estimate the 10-D variances; multi-start SGD is asserted to find the
modes, not to sample. ``test_bounds_reject_*`` show the same bounds fail on
wrong answers. Every sampler of the registry (``SAMPLERS``) has cases on every
target and meets one shared check on the Gaussian (mean right, no variance
widened), so a new sampler cannot go untested.

Every case runs once per session (cached) with a fixed seed, one torch thread.
"""
from __future__ import annotations

import functools
import math
import warnings
from dataclasses import dataclass, field

import pytest
import torch
from pyro.ops.stats import effective_sample_size

from bayes_brdf.potential import FunctionPotential
from bayes_brdf.samplers import SAMPLERS, SamplerDiverged, run
from bayes_brdf.samplers.targets import Banana, CorrelatedGaussian, Target, TwoModeMixture, moment_errors

K = 4.5  # standard errors allowed for a sampler that should be exact

TARGETS: dict[str, Target] = {"gaussian10": CorrelatedGaussian(), "banana": Banana(), "mixture": TwoModeMixture()}


@dataclass(frozen=True)
class Case:
    params: dict = field(hash=False)
    particles: int
    steps: int
    seed: int = 0


# Every hyper-parameter that matters is spelled out here: the tests do not depend on presets or defaults.
SGLD = {"preconditioner": "none", "schedule_gamma": 0.0, "schedule_b": 1.0}
SPOS = {"beta": 1.0, "anneal": False, "preconditioner": "adam", "adam_beta2": 0.99, "adam_eps": 1e-8}
SVGD = {"optimizer": "adam", "adam_beta1": 0.9, "adam_beta2": 0.999, "adam_eps": 1e-8, "anneal": False}
MULTI = {"optimizer": "adam", "adam_beta1": 0.9, "adam_beta2": 0.999, "adam_eps": 1e-8}
NUTS = {"thin": 1, "step_size": 0.1, "target_accept": 0.8, "max_tree_depth": 8, "adapt_mass_matrix": True}

CASES: dict[tuple[str, str], Case] = {
    ("sgld", "gaussian10"): Case({**SGLD, "step_size": 0.02}, 1000, 1500),
    ("sgld", "banana"): Case({**SGLD, "step_size": 0.015}, 1000, 2500),
    ("sgld", "mixture"): Case({**SGLD, "step_size": 0.02}, 1000, 1500),
    ("spos", "gaussian10"): Case({**SPOS, "step_size": 0.05}, 200, 600),
    ("spos", "banana"): Case({**SPOS, "step_size": 0.05}, 200, 600),
    ("spos", "mixture"): Case({**SPOS, "step_size": 0.05}, 200, 600),
    ("svgd", "gaussian10"): Case({**SVGD, "step_size": 0.05}, 200, 500),
    ("svgd", "banana"): Case({**SVGD, "step_size": 0.05}, 200, 500),
    ("svgd", "mixture"): Case({**SVGD, "step_size": 0.05}, 200, 500),
    ("emcee", "gaussian10"): Case({"stretch_a": 2.0}, 200, 1500),
    ("emcee", "banana"): Case({"stretch_a": 2.0}, 200, 1500),
    ("emcee", "mixture"): Case({"stretch_a": 2.0}, 200, 1500),
    ("nuts", "gaussian10"): Case({**NUTS, "warmup_steps": 200}, 300, 500),
    ("nuts", "banana"): Case({**NUTS, "warmup_steps": 200}, 300, 500),
    ("nuts", "mixture"): Case({**NUTS, "warmup_steps": 200}, 300, 500),
    ("multistart_sgd", "gaussian10"): Case({**MULTI, "step_size": 0.05}, 20, 500),
    ("multistart_sgd", "banana"): Case({**MULTI, "step_size": 0.05}, 20, 500),
    ("multistart_sgd", "mixture"): Case({**MULTI, "step_size": 0.05}, 20, 500),
}


@pytest.fixture(autouse=True, scope="module")
def _one_thread():
    # small tensors: extra threads cost more than they give (and on a loaded machine far more)
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


def run_case(sampler: str, target: str, seed: int | None = None) -> torch.Tensor:
    """The final particles of one case (``seed`` overrides the case's, for calibration runs)."""
    c = CASES[sampler, target]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = run(SAMPLERS[sampler].from_params(c.params), TARGETS[target].potential(), particles=c.particles,
                  steps=c.steps, seed=c.seed if seed is None else seed, progress=False, checkpoint_every=0)
    return res.z


@functools.lru_cache(maxsize=None)
def samples(sampler: str, target: str) -> torch.Tensor:
    return run_case(sampler, target)


def check_moments(z, target: Target, *, ess=1.0, var_ref=None, k: float = K, narrower_ok: bool = False) -> list[str]:
    """What is wrong with samples ``z`` (empty when nothing): means, variances and, for the mixture, mode weights.

    Each quantity may be off by ``k`` standard errors of ``n * ess`` independent exact draws. ``ess`` is a
    number or, for a chain, :func:`chain_ess`'s per-statistic fractions; ``var_ref`` replaces the exact
    variances (a sampler's known stationary variances); ``narrower_ok`` lets variances fall short of them.
    """
    e = moment_errors(z, target)
    n, D = z.shape
    if not isinstance(ess, dict):
        ess = {"mean": torch.full((D,), float(ess)), "var": torch.full((D,), float(ess)), "weight": float(ess)}
    fails = []
    mean_z = (z.mean(0) - target.mean).abs() / (target.var / n).sqrt() * ess["mean"].sqrt()
    if float(mean_z.max()) > k:
        fails.append(f"mean off by {float(mean_z.max()):.2f} effective standard errors (> {k})")
    ratio = e.var_ratio if var_ref is None else z.var(0) / var_ref
    var_z = ((ratio - 1).clamp_min(0) if narrower_ok else (ratio - 1).abs()) / ((target.kurtosis - 1) / n).sqrt() \
        * ess["var"].sqrt()
    if float(var_z.max()) > k:
        fails.append(f"variance ratios {[round(v, 3) for v in ratio.tolist()]} off by {float(var_z.max()):.2f} "
                     f"effective standard errors (> {k})")
    if isinstance(target, TwoModeMixture):
        p, w = float(target.basin_mass[0]), mode_weight(z, target)
        if abs(w - p) > k * math.sqrt(p * (1 - p) / (n * ess["weight"])):
            fails.append(f"weight of mode 0 is {w:.3f}, exact {p:.3f}")
    return fails


def chain_ess(z, target: Target) -> dict:
    """Effective-sample fractions (at most 1) of the draws ``z [n, D]`` of one chain, in order, for each
    coordinate, each squared deviation and (mixture) the mode indicator: Geyer's initial positive sequence."""
    n, D = z.shape
    cols = [z, (z - z.mean(0)) ** 2]
    if isinstance(target, TwoModeMixture):
        cols.append((target.assign(z) == 0).to(z.dtype)[:, None])
    ess = (effective_sample_size(torch.cat(cols, 1)[None], chain_dim=0, sample_dim=1) / n).clamp(max=1.0)
    ess = torch.nan_to_num(ess, nan=1.0 / n).clamp(min=1.0 / n)
    return {"mean": ess[:D], "var": ess[D:2 * D], "weight": float(ess[2 * D]) if ess.numel() > 2 * D else 1.0}


def mode_weight(z, target: TwoModeMixture) -> float:
    return float((target.assign(z) == 0).double().mean())


# ----------------------------------------------------------------------------- SGLD: exact up to its known bias
def test_sgld_gaussian_matches_unadjusted_langevin():
    t, c = TARGETS["gaussian10"], CASES["sgld", "gaussian10"]
    z = samples("sgld", "gaussian10")
    ula = t.langevin_cov(c.params["step_size"]).diagonal()
    assert not check_moments(z, t, var_ref=ula)
    # against the exact target: the same bars plus the step-size bias (at most +4.3% here)
    e = moment_errors(z, t)
    se = math.sqrt(2 / c.particles)
    assert 1 - K * se < e.var_ratio_min and e.var_ratio_max < float((ula / t.var).max()) + K * se


@pytest.mark.parametrize("target", ["banana", "mixture"])
def test_sgld(target):
    # the banana's step-size bias is small against these bars: with 10,000 chains, h = 0.01-0.015 gave
    # Var x2 0.94-0.96 and Var x1 0.98 of exact, the same after 6,000 steps (so not a lack of convergence)
    fails = check_moments(samples("sgld", target), TARGETS[target])
    assert not fails, fails


# ----------------------------------------------------------------------------- SPOS with beta = 1: calibrated
@pytest.mark.parametrize("target", ["gaussian10", "banana", "mixture"])
def test_spos_beta_1(target):
    fails = check_moments(samples("spos", target), TARGETS[target])
    assert not fails, fails


# ----------------------------------------------------------------------------- SVGD: right means, shrunk spread in 10-D
def test_svgd_gaussian_means_right_variances_too_small():
    t = TARGETS["gaussian10"]
    e = moment_errors(samples("svgd", "gaussian10"), t)
    # the deterministic particle set places the mean better than n exact draws would ...
    assert e.mean_z_max < 1.0
    # ... but, without noise in 10-D, under-estimates every variance (measured 0.51-0.74 with 200 particles)
    assert 0.4 < e.var_ratio_min and e.var_ratio_max < 0.85


def test_svgd_banana():
    t = TARGETS["banana"]
    z = samples("svgd", "banana")
    e = moment_errors(z, t)
    assert e.mean_z_max < K
    # in 2-D SVGD is close, slightly narrow (measured 0.84 for x2, 0.96 for x1) ...
    assert 0.75 < e.var_ratio_min and e.var_ratio_max < 1.05
    # ... and under-covers the curved tails: E[x1^2 x2] = 2 exactly, measured 1.52
    assert 1.2 < float((z[:, 0] ** 2 * z[:, 1]).mean()) < 1.9


def test_svgd_mixture():
    t = TARGETS["mixture"]
    z = samples("svgd", "mixture")
    # both modes populated, each particle close to a mode, but no noise to move mass between the modes:
    # the weight of mode 0 stays between the exact 0.30 and the start's split 0.47 (measured 0.34-0.42)
    w = mode_weight(z, t)
    assert 0.27 < w < 0.47
    assert float(torch.cdist(z, t.modes).min(1).values.max()) < 1.5
    # within-mode spread is right in 2-D: the y variance (all within-mode) within 10%
    assert abs(float(z[:, 1].var() / t.var[1]) - 1) < 0.1


# ----------------------------------------------------------------------------- emcee: exact, correlated walkers
# The walkers of one ensemble are not independent (each moves along a line through another): ess 0.5 (0.3 for
# the banana's heavy tail) is an allowance; measured over seeds 0-5 the errors stayed within 2.3 iid bars.
@pytest.mark.slow
@pytest.mark.parametrize("target, ess", [("gaussian10", 0.5), ("banana", 0.3), ("mixture", 0.5)])
def test_emcee(target, ess):
    fails = check_moments(samples("emcee", target), TARGETS[target], ess=ess)
    assert not fails, fails


# ----------------------------------------------------------------------------- NUTS: exact, one chain
@pytest.mark.slow
@pytest.mark.parametrize("target", ["gaussian10", "banana", "mixture"])
def test_nuts(target):
    # the particles are the chain's last n draws in order (n = steps - warm-up here), so the chain's own
    # autocorrelation gives the error bars: ESS/n measured 0.2-0.5 (Gaussian), 0.04-0.3 (banana), and
    # 0.02-0.04 for the mixture's mode indicator (a handful of mode switches in 300 draws)
    z, t = samples("nuts", target), TARGETS[target]
    ess = chain_ess(z, t)
    fails = check_moments(z, t, ess=ess)
    assert not fails, (fails, ess)
    # the Gaussian is easy for NUTS: an effective sample of at least a fifth of the draws
    if target == "gaussian10":
        assert float(torch.cat([ess["mean"], ess["var"]]).min()) > 0.15


# ----------------------------------------------------------------------------- multi-start SGD: modes, not samples
def test_multistart_finds_the_gaussian_mode():
    t = TARGETS["gaussian10"]
    z = samples("multistart_sgd", "gaussian10")
    assert float((z - t.modes[0]).norm(dim=1).max()) < 1e-2
    assert moment_errors(z, t).var_ratio_max < 1e-3        # no spread at all: a point estimate


def test_multistart_finds_the_banana_mode_not_its_mean():
    t = TARGETS["banana"]
    z = samples("multistart_sgd", "banana")
    assert float((z - t.modes[0]).norm(dim=1).max()) < 1e-2     # (0, -1) ...
    assert float((z.mean(0) - t.mean).norm()) > 0.9             # ... while the mean is (0, 0)


def test_multistart_finds_both_mixture_modes():
    t = TARGETS["mixture"]
    z = samples("multistart_sgd", "mixture")
    d = torch.cdist(z, t.modes)                                 # [n, 2]
    assert float(d.min(1).values.max()) < 1e-2                  # every start ends on a mode
    assert set(d.argmin(1).tolist()) == {0, 1}                  # and both modes are found


# ----------------------------------------------------------------------------- every sampler of the registry
# emcee style: one shared check over SAMPLERS, on the cases above (cached: no extra runs). A sampler added to the
# registry needs cases on every target and then meets this check or fails: none goes untested. Whatever its known
# biases, every sampler must put the 10-D Gaussian's mean within K effective standard errors and widen no variance
# beyond K of them (the exact ones sample it; SGLD's step-size bias is +4.3% at most; SVGD and multi-start shrink it).
ESS = {"emcee": 0.5, "nuts": "chain"}   # correlated particles: the allowances of test_emcee and test_nuts
SLOW = {"emcee", "nuts"}                # experiment-sized cases (as test_emcee and test_nuts)


def test_every_registered_sampler_has_cases():
    assert set(CASES) == {(s, t) for s in SAMPLERS for t in TARGETS}


@pytest.mark.parametrize("sampler", [pytest.param(s, marks=pytest.mark.slow) if s in SLOW else s for s in SAMPLERS])
def test_every_sampler_gets_the_gaussian_mean_without_widening_it(sampler):
    t = TARGETS["gaussian10"]
    z = samples(sampler, "gaussian10")
    ess = chain_ess(z, t) if ESS.get(sampler) == "chain" else ESS.get(sampler, 1.0)
    fails = check_moments(z, t, ess=ess, narrower_ok=True)
    assert not fails, fails


# ----------------------------------------------------------------------------- the bounds can fail
def test_bounds_accept_exact_draws():
    for name, t in TARGETS.items():
        for n in (200, 1000):
            assert not check_moments(t.sample(n, seed=11), t), name


@pytest.mark.parametrize("wrong, right", [
    (CorrelatedGaussian(scale_max=2.4), "gaussian10"),           # last variance 5.8 instead of 4 (+44%)
    (CorrelatedGaussian(scale_min=0.4), "gaussian10"),           # first variance 0.16 instead of 0.25
    (Banana(b=0.5), "banana"),                                   # Var x2 = 1.5 instead of 3
    (TwoModeMixture(weights=(0.4, 0.6)), "mixture"),             # the wrong mode weights
])
def test_bounds_reject_draws_from_a_wrong_target(wrong, right):
    assert check_moments(wrong.sample(1000, seed=11), TARGETS[right])


def test_the_shared_check_rejects_a_widened_variance_not_a_narrower_one():
    t = TARGETS["gaussian10"]
    assert check_moments(CorrelatedGaussian(scale_max=2.4).sample(1000, seed=11), t, narrower_ok=True)
    narrow = CorrelatedGaussian(scale_max=1.6).sample(1000, seed=11)
    assert check_moments(narrow, t) and not check_moments(narrow, t, narrower_ok=True)


def test_bounds_reject_a_sampler_at_the_wrong_temperature():
    # SGLD on 2U is SGLD on U with the noise variance halved (the sqrt(eps)-instead-of-sqrt(2 eps) bug): it
    # samples p^2, whose within-mode variances are halved and mode weights 0.16 / 0.84; the same run on U passes
    t, c = TARGETS["mixture"], CASES["sgld", "mixture"]

    def final(potential):
        return run(SAMPLERS["sgld"].from_params(c.params), potential, particles=500, steps=800, seed=1,
                   progress=False, checkpoint_every=0).z

    assert not check_moments(final(t.potential()), t)
    fails = check_moments(final(FunctionPotential(lambda z: 2 * t.energy(z), 2)), t)
    assert any("variance" in f for f in fails), fails


def test_sgld_above_the_stability_limit_diverges():
    # unadjusted Langevin on the Gaussian is stable for step < 2 / lambda_max(P) ~ 0.2: 1.0 blows up
    t = TARGETS["gaussian10"]
    with pytest.raises(SamplerDiverged, match="sgld diverged at step"):
        run(SAMPLERS["sgld"].from_params({**SGLD, "step_size": 1.0}), t.potential(), particles=10, steps=2000,
            seed=0, progress=False, checkpoint_every=0)
