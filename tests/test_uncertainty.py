"""Uncertainty (Eqs. 9, 11): parameter and image-space std vs per-particle references, the posterior-predictive
CDF vs scipy and its calibration, coverage / correlations (their figures: tests/test_plots.py)."""
import math

import numpy as np
import pytest
import torch
from scipy import stats

import bayes_brdf as bb
from bayes_brdf.errors import InputError
from bayes_brdf.posterior import Posterior
from bayes_brdf.render import SVBRDF, PlanarSample
from bayes_brdf.render.gbuffer import GBuffer
from bayes_brdf.render.shade import render
from bayes_brdf.render.views import collocated_views
from bayes_brdf.uncertainty import correlations, coverage, image_std, parameter_std, predictive_cdf

S = PlanarSample(2.0)
R = 8


def _post(n=6, seed=0, **model_kw):
    g = torch.Generator().manual_seed(seed)
    return Posterior({"albedo": torch.rand(n, 1, R, R, generator=g) * 0.8 + 0.1,
                      "roughness": torch.rand(n, 1, R, R, generator=g) * 0.5 + 0.2},
                     torch.rand(n, generator=g), model=bb.models.per_texel(R, albedo="gray", **model_kw),
                     meta={"surface": {"size": 2.0, "grid": "centers"}})


def _per_particle_renders(post, views):
    n = post.num_particles
    return torch.stack([render(post.maps(i), views, S)[0] for i in range(n)])   # [n, V, H, W, 3]


def test_parameter_std_is_the_bessel_corrected_std():
    post = _post(7)
    sd = parameter_std(post)
    for site, x in post.particles.items():
        np.testing.assert_allclose(sd[site].numpy(), x.numpy().std(0, ddof=1), rtol=1e-5, atol=1e-7)


@pytest.mark.parametrize("camera,res", [("rectified", R), ("perspective", 16)])
def test_image_std_equals_per_particle_loop(camera, res):
    post = _post()
    views = collocated_views(3, 3.0, camera=camera, resolution=res, power=10.0)
    ref = _per_particle_renders(post, views)
    std, mean = image_std(post, views, return_mean=True)                 # surface from the metadata
    assert std.shape == (3, res, res, 3)
    torch.testing.assert_close(std, ref.std(0, unbiased=True), rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(mean, ref.mean(0), rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(image_std(post, views, S, chunk_views=1), std, rtol=1e-6, atol=1e-7)
    # pixels off the sample are 0
    mask = GBuffer.build(views, S).mask
    assert (std[~mask] == 0).all() and (std[mask] > 0).any()
    # particle maps work the same as a posterior
    torch.testing.assert_close(image_std(post.maps("all"), views, S), std)
    with pytest.raises(InputError):
        image_std(post.maps(0), views, S)                                  # no particle dimension


@pytest.mark.parametrize("kind", ["laplace", "gaussian"])
def test_predictive_cdf_equals_scipy_mixture(kind):
    post = _post(5, seed=1)
    views = collocated_views(2, 3.0, camera="rectified", resolution=R, power=10.0)
    ren = _per_particle_renders(post, views).double().numpy()            # [n, V, H, W, 3]
    g = torch.Generator().manual_seed(2)
    y = torch.from_numpy(ren.mean(0)) + 0.05 * torch.randn(ren.shape[1:], generator=g, dtype=torch.float64)
    sigma = 0.03
    F, std, mean = predictive_cdf(post, views, y.float(), S, sigma=sigma, kind=kind)
    dist = stats.laplace if kind == "laplace" else stats.norm
    ref = dist.cdf(y.float().double().numpy()[None], loc=ren, scale=sigma).mean(0)
    np.testing.assert_allclose(F.double().numpy(), ref, atol=2e-5)
    assert 0 < float(F.min()) and float(F.max()) < 1 and float(F.std()) > 0.1   # a real spread of PITs
    np.testing.assert_allclose(std.numpy(), ren.std(0, ddof=1), rtol=1e-4, atol=1e-6)
    np.testing.assert_allclose(mean.numpy(), ren.mean(0), rtol=1e-5, atol=1e-6)


def test_predictive_cdf_defaults_to_the_models_likelihood():
    post = _post(4, seed=2, sigma=0.02, likelihood="gaussian")
    views = collocated_views(2, 3.0, camera="rectified", resolution=R, power=10.0)
    y = render(post.maps(0), views, S)[0] + 0.01
    F, _, _ = predictive_cdf(post, views, y)
    F2, _, _ = predictive_cdf(post, views, y, sigma=0.02, kind="gaussian")
    torch.testing.assert_close(F, F2)
    F3, _, _ = predictive_cdf(post, views, y, sigma=0.02, kind="laplace")
    assert not torch.allclose(F, F3)
    with pytest.raises(InputError, match="noise scale"):
        predictive_cdf(post.maps("all"), views, y, S)                     # maps carry no sigma


def test_predictive_is_calibrated_when_data_come_from_it():
    """Draw each observed pixel from the predictive itself (a random particle's render plus Laplace noise of
    the model's sigma): PIT values are uniform, so 50% / 90% intervals cover 50% / 90% of the pixels."""
    n, sigma = 8, 0.02
    post = _post(n, seed=3, sigma=sigma)
    views = collocated_views(6, 3.0, camera="rectified", resolution=16, power=10.0)
    # 16 x 16 views of the 8 x 8 maps: still all on the sample
    ren = torch.stack([render(post.maps(i), views, S)[0] for i in range(n)]).double()   # [n, V, H, W, 3]
    g = torch.Generator().manual_seed(7)
    pick = torch.randint(n, ren.shape[1:], generator=g)
    base = ren.gather(0, pick[None])[0]
    lap = torch.empty(base.shape, dtype=torch.float64).exponential_(generator=g) - \
        torch.empty(base.shape, dtype=torch.float64).exponential_(generator=g)
    y = base + sigma * lap
    assert float(ren.std(0).mean()) > sigma                                # the particles' spread matters
    F, _, _ = predictive_cdf(post, views, y, S)                          # Laplace, sigma from the model
    cov = coverage(F)
    N = F.numel()                                                        # 4608 values
    assert cov["50"] == pytest.approx(0.5, abs=4 * math.sqrt(0.25 / N))
    assert cov["90"] == pytest.approx(0.9, abs=4 * math.sqrt(0.09 / N))
    assert stats.kstest(F.reshape(-1).double().numpy(), "uniform").pvalue > 1e-3
    # predicting with the noise scale 4x too small is over-confident: clearly lower coverage
    Fs, _, _ = predictive_cdf(post, views, y, S, sigma=sigma / 4)
    assert coverage(Fs)["50"] < 0.45


def test_coverage_against_numpy():
    p = torch.tensor([0.5, 0.3, 0.74, 0.2, 0.94, 0.06, 0.12, 0.99, 0.0])
    # |p - 0.5| = 0, .2, .24, .3, .44, .44, .38, .49, .5
    assert coverage(p) == {"50": pytest.approx(3 / 9), "90": pytest.approx(7 / 9)}
    assert coverage(p, levels=(0.8,)) == {"80": pytest.approx(5 / 9)}
    u = torch.rand(3, 5, 7, generator=torch.Generator().manual_seed(0))
    a = np.abs(u.numpy().reshape(-1) - 0.5)
    got = coverage(u, levels=(0.5, 0.9, 0.2))
    assert got == {"50": pytest.approx((a <= 0.25).mean()), "90": pytest.approx((a <= 0.45).mean()),
                   "20": pytest.approx((a <= 0.1).mean())}
    with pytest.raises(InputError):
        coverage(torch.zeros(0))


def test_correlations_against_numpy():
    g = torch.Generator().manual_seed(0)
    a = torch.rand(4, 10, generator=g)
    b = a ** 3 + 0.05 * torch.rand(4, 10, generator=g)
    c = correlations(a, b)
    x, y = a.reshape(-1).double().numpy(), b.reshape(-1).double().numpy()
    assert c["pearson"] == pytest.approx(np.corrcoef(x, y)[0, 1], abs=1e-10)
    rx, ry = np.argsort(np.argsort(x)), np.argsort(np.argsort(y))      # no ties: ranks
    assert c["spearman"] == pytest.approx(np.corrcoef(rx, ry)[0, 1], abs=1e-10)
    mono = correlations(torch.tensor([1.0, 2, 3, 4]), torch.tensor([1.0, 8, 27, 1000]))
    assert mono["spearman"] == pytest.approx(1.0) and mono["pearson"] < 0.9
    assert correlations(torch.tensor([1.0, 2, 3]), torch.tensor([3.0, 2, 1]))["pearson"] == pytest.approx(-1.0)
    for bad in (correlations(torch.ones(5), torch.rand(5)), correlations(torch.rand(2), torch.rand(2))):
        assert math.isnan(bad["pearson"]) and math.isnan(bad["spearman"])


def test_correlations_match_scipy_with_ties():
    """Pearson and Spearman (ties at their average rank) as scipy computes them."""
    from scipy.stats import pearsonr, spearmanr

    gen = torch.Generator().manual_seed(0)
    a = torch.randint(0, 30, (5000,), generator=gen).double() / 7      # many ties
    b = a * 0.3 + torch.rand(5000, generator=gen, dtype=torch.float64)
    b[::5] = 0.5                                                       # ties in the other too
    c = correlations(a, b)
    assert c["pearson"] == pytest.approx(pearsonr(a.numpy(), b.numpy())[0], abs=1e-12)
    assert c["spearman"] == pytest.approx(spearmanr(a.numpy(), b.numpy())[0], abs=1e-12)
    assert all(math.isnan(v) for v in correlations(torch.ones(10), b[:10]).values())
