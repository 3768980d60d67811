"""sigma = "auto": the noise level integrated out under a Jeffreys prior, against closed forms and known noise."""
import math
import warnings

import pytest
import torch

import bayes_brdf as bb
from bayes_brdf.errors import InputError
from bayes_brdf.experiments import highdim as H
from bayes_brdf.models.likelihood import RenderedImages
from bayes_brdf.render.maps import SVBRDF


def _problem(sigma, R=16, views=10):
    prob = H.setup(H.HighDimSetup(noise=True, sigma=sigma, resolution=R, views=views, seed=3))
    return prob, prob.data.observations


@pytest.mark.parametrize("kind", ["laplace", "gaussian"])
def test_auto_likelihood_is_the_jeffreys_marginal_up_to_a_constant(kind):
    prob, _ = _problem(0.02, R=8, views=3)
    d = prob.data
    lps, es = [], []
    for a in (0.3, 0.5, 0.7):
        maps = SVBRDF.constant(a, 0.4, dtype=torch.float32)
        lik = RenderedImages(maps, d, "auto", kind)
        e, N = lik.residual(d.images)
        lps.append(float(lik.log_prob(d.images)))
        es.append(float(e[0]))
    N = float(N)
    # exact marginal: Laplace  lgamma(N) - N log(2 e);  Gaussian  lgamma(N/2) - (N/2) log(pi e) - log 2 (+ const)
    exact = [-(N if kind == "laplace" else N / 2) * math.log(e) for e in es]
    diffs = [lp - ex for lp, ex in zip(lps, exact)]
    assert max(diffs) - min(diffs) < 1e-3 * abs(lps[0]), (lps, exact)


@pytest.mark.slow
@pytest.mark.parametrize("sigma", [0.005, 0.02])
def test_auto_sigma_recovers_the_known_noise(sigma):
    prob, obs = _problem(sigma)
    model = bb.models.per_texel(16, albedo="gray", specular=0.04, sigma="auto")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        post = bb.infer(model, obs, seed=0, progress=False, map_steps=0)
    assert post.noise_sigma == pytest.approx(sigma, rel=0.10)
    # and it is what the predictive uses
    from bayes_brdf.uncertainty import predictive_cdf
    F, _, _ = predictive_cdf(post, obs.views[:2], obs.images[:2], obs.surface)
    assert F.shape == obs.images[:2].shape


def test_sigma_option_checks():
    assert bb.models.per_texel(8, sigma="auto").sigma == "auto"
    for bad in (0, -1, "big", True):
        with pytest.raises(InputError, match="sigma must be a positive number or \"auto\""):
            bb.models.per_texel(8, sigma=bad)
