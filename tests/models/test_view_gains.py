"""Per-view gains (view_gain = "estimated", an option): the estimate, the corrected photos, the predictive of a new view."""
import math
import warnings

import pytest
import torch
from scipy import integrate, stats

import bayes_brdf as bb
from bayes_brdf.models.data import ModelData
from bayes_brdf.models.gains import ViewGains, estimate_gains
from bayes_brdf.posterior import Posterior
from bayes_brdf.render import PlanarSample, SVBRDF, collocated_views
from bayes_brdf.render.shade import render
from bayes_brdf.uncertainty import predictive_cdf

TRUE_LOG_GAIN = torch.tensor([-0.12, 0.0, 0.15, -0.05, 0.02])


def photos_with_gains(log_gain, resolution=16, sigma=0.005, seed=1):
    vs = collocated_views(len(log_gain), radius=3.0, camera="rectified", resolution=resolution, power=20.0)
    clean = render(SVBRDF.constant(0.5, 0.3), vs, PlanarSample(2.0))[0]
    torch.manual_seed(seed)
    y = clean * log_gain.exp().view(-1, 1, 1, 1)
    if sigma:
        y = y + torch.distributions.Laplace(0.0, sigma).sample(clean.shape)
    return bb.Observations(vs, y, PlanarSample(2.0)), clean


def test_estimate_finds_the_gains_and_needs_enough_views_and_pixels():
    obs, clean = photos_with_gains(TRUE_LOG_GAIN, sigma=0.0)
    d = ModelData.from_observations(obs)
    g = estimate_gains(clean.mean(-1), d.images, d.weight)
    want = TRUE_LOG_GAIN - TRUE_LOG_GAIN.mean()
    assert torch.allclose(torch.tensor(g.log_gain, dtype=torch.float32), want, atol=1e-5)
    assert g.spread == pytest.approx(float(want.std()), rel=1e-5)
    assert ViewGains.from_dict(g.to_dict()) == g
    # the corrected photos are the clean renders up to the common gain
    c = d.with_gains(g.gains())
    assert torch.allclose(c.images, clean * math.exp(float(TRUE_LOG_GAIN.mean())), rtol=1e-4)
    # two views, or views of a few pixels: no estimate (a gain would take the BRDF's change with angle)
    assert estimate_gains(clean.mean(-1)[:2], d.images[:2], d.weight[:2]) is None
    assert estimate_gains(clean.mean(-1)[:, :4, :4], d.images[:, :4, :4], d.weight[:, :4, :4]) is None


def test_predictive_of_a_new_view_integrates_its_gain():
    """F(y) = E_u[ mean_i LaplaceCDF((y - e^u R_i) / (sigma g(e^u R_i))) ], u ~ t_(V-1)(0, s sqrt(1 + 1/V)):
    the nodes against adaptive quadrature of the t density."""
    gains = ViewGains(tuple(float(v) for v in TRUE_LOG_GAIN - TRUE_LOG_GAIN.mean()))
    model = bb.models.homogeneous(albedo="gray")
    parts = {"albedo": torch.tensor([[0.45], [0.55]]), "roughness": torch.tensor([[0.3], [0.35]])}
    sigma = 0.01
    post = Posterior(parts, torch.zeros(2), model=model, surface=PlanarSample(2.0),
                     meta={"noise_sigma": sigma, "view_gains": gains.to_dict()})
    vs = collocated_views(1, radius=3.0, camera="rectified", resolution=4, power=20.0)
    R = render(model.maps(parts), vs, PlanarSample(2.0))[:, 0, 1, 2, 0].double()       # [2] one pixel
    ys = torch.linspace(float(R.min()) * 0.7, float(R.max()) * 1.3, 7)
    scale = gains.spread * math.sqrt(1 + 1 / 5)
    for y in ys.tolist():
        def f(u):
            t = (y - math.exp(u) * R) / sigma
            cdf = torch.where(t < 0, 0.5 * torch.exp(t.clamp_max(0)), 1 - 0.5 * torch.exp(-t.clamp_min(0)))
            return float(cdf.mean()) * stats.t.pdf(u / scale, 4) / scale
        ref = integrate.quad(f, -2, 2, limit=200, points=[0.0])[0]
        img = torch.full((1, 4, 4, 3), y)
        got = float(predictive_cdf(post, vs, img)[0][0, 1, 2, 0])
        assert got == pytest.approx(ref, abs=0.01), (y, got, ref)
    # without gains: the plain mixture of Laplace CDFs
    plain = Posterior(parts, torch.zeros(2), model=model, surface=PlanarSample(2.0), meta={"noise_sigma": sigma})
    y = float(R.mean() * 1.05)
    t = (y - R) / sigma
    ref = float(torch.where(t < 0, 0.5 * torch.exp(t.clamp_max(0)), 1 - 0.5 * torch.exp(-t.clamp_min(0))).mean())
    assert float(predictive_cdf(plain, vs, torch.full((1, 4, 4, 3), y))[0][0, 1, 2, 0]) == pytest.approx(ref, abs=1e-5)


@pytest.mark.slow
def test_infer_estimates_the_gains_and_fits_the_corrected_photos():
    obs, _ = photos_with_gains(TRUE_LOG_GAIN)
    model = bb.models.homogeneous(albedo="gray", view_gain="estimated")
    # one BRDF from 1280 pixels: a posterior far narrower than SPOS's steps, with local modes in the roughness
    # (0.07, 0.77) where SPOS leaves particles, which its checks say; emcee, the sampler for a few dimensions,
    # finds the gains (from the renders of the burn-in's particles, less those left behind) and fits the
    # corrected photos
    with pytest.warns(bb.errors.ConvergenceWarning, match="energy_spread"):
        bb.infer(model, obs, steps=300, progress=False)
    post = bb.infer(model, obs, "emcee", progress=False, seed=0)
    assert post.diagnostics["converged"], post.diagnostics["failed"]
    g = post.view_gains
    assert g is not None and post.meta["view_gains"] == g.to_dict()
    want = TRUE_LOG_GAIN - TRUE_LOG_GAIN.mean()
    assert torch.allclose(torch.tensor(g.log_gain, dtype=torch.float32), want, atol=0.02), (g, want)   # 10 seeds: <= 0.012
    # the albedo is the truth times the photos' geometric-mean gain, the roughness the truth
    assert float(post.mean("albedo")) == pytest.approx(0.5 * math.exp(float(TRUE_LOG_GAIN.mean())), rel=0.02)
    assert float(post.mean("roughness")) == pytest.approx(0.3, abs=0.02)
    # off (the default), the same photos are fitted as they are and nothing is recorded
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", bb.errors.ConvergenceWarning)
        off = bb.infer(bb.models.homogeneous(albedo="gray"), obs, "emcee", progress=False, seed=0)
    assert off.view_gains is None and "view_gains" not in off.meta
    # and their noise absorbs the offsets: a noise scale several times the photos' own
    assert off.noise_sigma > 3 * post.noise_sigma
