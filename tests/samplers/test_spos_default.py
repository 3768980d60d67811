"""The one SPOS default (samplers/spos.toml) against exact answers: per-texel maps and 2-D posteriors.

Per texel (the posterior factorises, so quadrature gives every texel's exact std): the median ratio of the
estimated to the exact std within 10 % and at most 2 % of texels off by more than 2x. In 2-D (Table 1-style
problems, dense quadrature): within 2x of the floor that 16 exact i.i.d. draws reach, on a tighter posterior
than Table 1's (two observations), where the previous preset was 5-17x above it.
"""
import pytest
import torch

import bayes_brdf as bb
from bayes_brdf.experiments import highdim as H
from bayes_brdf.experiments.table1 import Table1Setup, compare, problem
from bayes_brdf.potential import Potential
from bayes_brdf.samplers import make_sampler


@pytest.mark.slow
def test_per_texel_std_tails_against_exact_truth():
    prob = H.setup(H.HighDimSetup(noise=True, seed=0, resolution=16))
    ex = H.exact_std(prob, check=False, cells=2000)
    post = bb.infer(prob.model, prob.data.observations, seed=0, progress=False, map_steps=0)
    v = H.summarise(post.particles["albedo"].reshape(20, -1), post.particles["roughness"].reshape(20, -1), ex)
    for m in ("albedo", "roughness"):
        assert 0.9 <= v[f"ratio_{m}"] <= 1.1, v
        assert v[f"off2_{m}"] <= 0.02, v
    assert post.diagnostics["converged"], post.diagnostics


@pytest.mark.slow
@pytest.mark.parametrize("setup, bar", [
    (Table1Setup(observations=[30], grid=600), 2.0),                  # two views: the previous preset was 5-17x above
    # three views, a skewed posterior: 1.81 / 2.30x with beta = 200 in 2-D (nearly SVGD, whose fixed point drops
    # the long roughness tail), 1.71 / 1.68x with the preset's beta = 5 (docs/calibration.md)
    (Table1Setup(observations=[20, 40], sigma=0.02, grid=600), 2.0),
], ids=["two_views", "three_views"])
def test_tighter_2d_posteriors_near_the_floor(setup, bar):
    t = compare(setup, samplers=("spos",), runs=20, particles=16, steps=None)
    for col in ("mse_mean", "mse_var"):
        assert t["spos"][col] <= bar * t["iid"][col], (col, t["spos"][col], t["iid"][col])


@pytest.mark.slow
@pytest.mark.parametrize("setup", [
    Table1Setup(observations=[2.0], albedo=0.4, roughness=0.3, grid=600),   # two nearly equal views: a ridge
    Table1Setup(observations=[40.0], albedo=0.7, roughness=0.15, grid=600),  # a highlight: roughness std 1e-4
], ids=["two_observations", "sharp_highlight"])
def test_narrow_ridges_within_twice_the_floor(setup):
    """The issue's narrow setups: with one Adam scale per group they were 133x and 383x the floor (a particle
    on a flat stretch of the ridge moved at the pace the group's stiffest particles set); with one per particle
    (``precond_scope = "particle"``, the preset) within 2x on both columns, and a single default run passes its checks."""
    t = compare(setup, samplers=("spos",), runs=20, particles=16, steps=None)
    for col in ("mse_mean", "mse_var"):
        assert t["spos"][col] <= 2 * t["iid"][col], (col, t["spos"][col], t["iid"][col])
    model, data = problem(setup)
    post = bb.infer(model, data, seed=0, progress=False)
    assert post.diagnostics["converged"], post.diagnostics


def test_default_is_spread_scaled_with_a_clamped_start():
    s, cfg = make_sampler("spos")
    assert s.step_units == "spread" and cfg.init_margin == 0.05
    assert cfg.steps == 2000
    assert s.adam_eps == "auto" and s.eps_for(2) == 1.0 and s.eps_for(2048) == 2 / 2048
    # one Adam scale per particle in every dimension: a shared one lets narrow texels contract 4x more slowly
    assert s.precond_scope == "particle" and s.per_particle(2) and s.per_particle(16) and s.per_particle(65536)
    # "auto" (the preset before) stays as it was: per particle in at most 16 dimensions, per group beyond
    a, _ = make_sampler("spos", params={"precond_scope": "auto"})
    assert a.per_particle(2) and a.per_particle(16) and not a.per_particle(17)
    with pytest.raises(bb.errors.InputError, match="adam_eps"):
        make_sampler("spos", params={"adam_eps": "big"})


def test_spos_maps_is_a_deprecated_alias(capsys):
    s, cfg = make_sampler("spos_maps")
    assert (s.params(), vars(cfg)) == (make_sampler("spos")[0].params(), vars(make_sampler("spos")[1]))
    err = capsys.readouterr().err
    assert "deprecated" in err and err.count("\n") == 1


def test_init_margin_keeps_prior_draws_off_the_bounds():
    prob = H.setup(H.HighDimSetup(resolution=8))
    pot = Potential(prob.model, (prob.data,))
    x = pot.to_constrained(pot.init(50, seed=0, margin=0.05))
    a, r = x["albedo"], x["roughness"]
    assert float(a.min()) >= 0.05 - 1e-6 and float(a.max()) <= 0.95 + 1e-6
    lo, hi = prob.model.roughness_range
    assert float(r.min()) >= lo + 0.05 * (hi - lo) - 1e-6
    plain = pot.to_constrained(pot.init(50, seed=0))["albedo"]
    assert float(plain.min()) < 0.05 or float(plain.max()) > 0.95     # what the margin removes
    with pytest.raises(bb.errors.InputError, match="init margin"):
        pot.init(2, margin=0.6)


def test_spread_step_is_consistent_on_a_gaussian():
    # an anisotropic Gaussian (scales 0.01 and 1): the dimensionless step serves both coordinates
    from bayes_brdf.potential import FunctionPotential
    from bayes_brdf.samplers import run
    sc = torch.tensor([0.01, 1.0, 0.1, 0.3, 3.0, 0.03, 1.0, 0.5], dtype=torch.float64)
    pot = FunctionPotential(lambda z: 0.5 * ((z / sc) ** 2).sum(1), dim=8)
    s, _ = make_sampler("spos", params={"beta": 1.0})
    res = run(s, pot, particles=200, steps=1500, seed=0, progress=False, groups=1)
    ratio = res.z.std(0) / sc
    assert bool(((ratio > 0.85) & (ratio < 1.15)).all()), ratio
