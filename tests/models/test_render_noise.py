"""Render noise in the likelihood: photos a Monte Carlo renderer made carry its own variance per pixel
(``Observations.variance``), known noise on top of the photo noise. Checked against closed forms: two
independent Gaussian noises add their variances, so the per-pixel likelihood is N(R, s^2 + tau^2) and the
predictive CDF Phi((y - R) / sqrt(s^2 + tau^2)); the noise level fitted around the known part recovers the
photo noise alone; the variance travels through bundles, transforms.json and resampling."""
import dataclasses
import math

import pytest
import torch

import bayes_brdf as bb
from bayes_brdf.errors import InputError
from bayes_brdf.models.data import ModelData
from bayes_brdf.models.likelihood import RenderedImages
from bayes_brdf.models.noise import fit_noise_level, render_noise
from bayes_brdf.noise_estimate import estimate_noise
from bayes_brdf.posterior import Posterior
from bayes_brdf.render import SVBRDF, PlanarSample, collocated_views
from bayes_brdf.render.shade import render
from bayes_brdf.uncertainty import predictive_cdf

S = 0.01            # the photo noise (a Gaussian std)


def _capture(seed=0, resolution=16, views=4):
    """A grey plane whose photos carry Gaussian photo noise S plus render noise of a known, strongly varying
    variance (tau from 0 to 0.05 across the pixels)."""
    vs = collocated_views(views, 3.0, camera="rectified", resolution=resolution, power=20.0)
    clean = render(SVBRDF.constant(0.5, 0.3), vs, PlanarSample(2.0))[0].double()
    g = torch.Generator().manual_seed(seed)
    tau = 0.05 * torch.rand(clean.shape[:3], generator=g, dtype=torch.float64)[..., None].expand_as(clean)
    y = clean + S * torch.randn(clean.shape, generator=g, dtype=torch.float64) \
        + tau * torch.randn(clean.shape, generator=g, dtype=torch.float64)
    obs = bb.Observations(vs, y.float(), PlanarSample(2.0), variance=(tau * tau).float())
    return obs, clean


def test_the_fitted_noise_level_is_the_photo_noise_and_the_likelihood_the_sum_of_two_gaussians():
    obs, clean = _capture()
    model = bb.models.homogeneous(albedo="gray", likelihood="gaussian")
    truth = {"albedo": torch.full((3, 1), 0.5), "roughness": torch.full((3, 1), 0.3)}
    d = ModelData.from_observations(obs, dtype=torch.float64)
    d2, level, _ = estimate_noise(model, d, truth)
    # the photo noise alone, not the render noise (whose variance is 8x the photo noise's on average)
    s_ref = float(level.scale(torch.tensor(level.y_ref, dtype=torch.float64)))
    assert s_ref == pytest.approx(S, rel=0.1)
    without, _, _ = estimate_noise(model, dataclasses.replace(d, observations=dataclasses.replace(obs, variance=None)),
                                   truth)
    assert without.noise is not None
    # per pixel the likelihood's scale is sqrt(s^2 + tau^2) (relative to s_ref: sigma = s_ref below)
    tau2 = obs.variance.double().mean(-1)
    s_y = level.scale(clean.mean(-1))
    assert torch.allclose(d2.noise.double() * s_ref, (s_y * s_y + tau2).sqrt(), rtol=1e-5)
    # the likelihood at sigma = s_ref is the closed form: sum of log N(y; R, s(y)^2 + tau^2)
    maps = model.maps({k: v[:1] for k, v in truth.items()})
    lp = float(RenderedImages(maps, d2, sigma=s_ref, kind="gaussian").log_prob(d2.images))
    var = (s_y * s_y + tau2)[..., None].expand_as(clean)
    want = float((-0.5 * (obs.images.double() - clean) ** 2 / var - 0.5 * torch.log(2 * math.pi * var)).sum())
    assert lp == pytest.approx(want, rel=1e-6)


def test_fit_noise_level_fits_around_a_known_part():
    g = torch.Generator().manual_seed(3)
    y = torch.rand(100_000, generator=g, dtype=torch.float64)
    extra = 4e-4 * torch.rand(100_000, generator=g, dtype=torch.float64)       # known, per value
    r = torch.randn(100_000, generator=g, dtype=torch.float64) * (1e-4 + extra).sqrt()
    nl = fit_noise_level(y, r, kind="gaussian", extra=extra)
    assert nl.a + nl.b * 0.5 + nl.c * 0.25 == pytest.approx(1e-4, rel=0.1)
    assert fit_noise_level(y, r, kind="gaussian").a > 2e-4          # without it: absorbed into the photo noise
    assert float(render_noise(torch.tensor([[2.0, 4.0, 6.0]]), "laplace")[0]) == pytest.approx(2.0)


def test_predictive_adds_the_new_photos_render_noise():
    """One particle, Gaussian noise s, render variance v: F(y) = Phi((y - R) / sqrt(s^2 + v))."""
    model = bb.models.homogeneous(albedo="gray", likelihood="gaussian")
    parts = {"albedo": torch.tensor([[0.5]]), "roughness": torch.tensor([[0.3]])}
    post = Posterior(parts, torch.zeros(1), model=model, surface=PlanarSample(2.0), meta={"noise_sigma": S})
    vs = collocated_views(1, 3.0, camera="rectified", resolution=4, power=20.0)
    R = render(model.maps(parts), vs, PlanarSample(2.0))[0].double()
    y = R + 0.02
    v = torch.full_like(R, 9e-4)
    F, _, _ = predictive_cdf(post, vs, y.float(), PlanarSample(2.0), variance=v.float())
    want = 0.5 * (1 + math.erf(0.02 / math.sqrt(S * S + 9e-4) / math.sqrt(2)))
    assert float(F[0, 1, 2, 0]) == pytest.approx(want, abs=1e-5)
    F0, _, _ = predictive_cdf(post, vs, y.float(), PlanarSample(2.0))
    assert float(F0[0, 1, 2, 0]) == pytest.approx(0.5 * (1 + math.erf(2 / math.sqrt(2))), abs=1e-5)


def test_the_variance_travels_through_bundles_transforms_and_resampling(tmp_path):
    from bayes_brdf.io import load_capture, save_observations, save_transforms
    from bayes_brdf.io.captures import resample_observations
    from bayes_brdf.render.mesh import Mesh

    obs, _ = _capture()
    obs = dataclasses.replace(obs, images=obs.images.clamp_min(0))      # a bundle holds radiance >= 0
    save_observations(obs, tmp_path / "b")
    back = load_capture(tmp_path / "b")
    assert torch.equal(back.variance, obs.variance)
    assert torch.allclose(load_capture(tmp_path / "b", resolution=8).variance.mean(), obs.variance.mean() / 4,
                          rtol=1e-4)       # a mean of four independent pixels
    assert torch.equal(obs.subset([1, 3]).variance, obs.variance[[1, 3]])
    assert obs.append(dataclasses.replace(obs, variance=None)).variance[4:].abs().max() == 0
    small = resample_observations(obs, 8)
    assert small.variance.shape == (4, 8, 8, 3)
    # a mesh capture keeps it per frame
    mesh_obs = bb.Observations(collocated_views(2, 4.0, resolution=8, power=20.0), torch.rand(2, 8, 8, 3),
                               Mesh.sphere(), variance=torch.full((2, 8, 8, 3), 1e-3))
    save_transforms(mesh_obs, tmp_path / "t")
    assert torch.allclose(load_capture(tmp_path / "t").variance, mesh_obs.variance)
    with pytest.raises(InputError, match="variance"):
        bb.Observations(obs.views, obs.images, PlanarSample(2.0), variance=-obs.variance - 1)
    with pytest.raises(InputError, match="variance has shape"):
        bb.Observations(obs.views, obs.images, PlanarSample(2.0), variance=obs.variance[..., :1])


def test_the_posterior_records_the_render_noise_and_guidance_adds_it():
    from bayes_brdf.guidance.scores import observation_noise_var

    obs, _ = _capture(resolution=8, views=3)
    post = bb.infer(bb.models.homogeneous(albedo="gray"), obs, "spos", steps=40, progress=False)
    assert post.render_noise == pytest.approx(float(obs.variance[ModelData.from_observations(obs).weight > 0]
                                                    .double().mean()), rel=1e-6)
    assert observation_noise_var(post) == pytest.approx(2 * post.noise_sigma ** 2 + post.render_noise, rel=1e-9)
    plain = bb.infer(bb.models.homogeneous(albedo="gray"), dataclasses.replace(obs, variance=None), "spos",
                     steps=40, progress=False)
    assert plain.render_noise is None and observation_noise_var(plain) == pytest.approx(2 * plain.noise_sigma ** 2)


def test_a_fixed_sigma_adds_the_render_noise_up_front_and_one_scale_says_it_cannot():
    """A fixed sigma: the pixel's scale is sqrt(sigma^2 + tau^2) from the start (the closed form again); sigma
    'auto' with one noise scale cannot know sigma before sampling: the variance is left out, with a warning."""
    import warnings

    from bayes_brdf.noise_estimate import with_render_noise

    obs, clean = _capture(resolution=8, views=2)
    model = bb.models.homogeneous(albedo="gray", likelihood="gaussian", sigma=S)
    d = with_render_noise(model, ModelData.from_observations(obs, dtype=torch.float64), estimated=False)
    maps = model.maps({"albedo": torch.full((1, 1), 0.5), "roughness": torch.full((1, 1), 0.3)})
    lp = float(RenderedImages(maps, d, sigma=S, kind="gaussian").log_prob(d.images))
    var = S * S + obs.variance.double().mean(-1, keepdim=True).expand_as(clean)
    w = d.weight[..., None].expand_as(clean) > 0
    want = float((-0.5 * (obs.images.double() - clean) ** 2 / var - 0.5 * torch.log(2 * math.pi * var))[w].sum())
    assert lp == pytest.approx(want, rel=1e-6)
    # the run that estimates its noise level after the burn-in puts it there itself
    assert with_render_noise(model, d, estimated=True) is d
    one = bb.models.homogeneous(albedo="gray", pixel_noise="constant")
    with pytest.warns(UserWarning, match="left out"):
        out = with_render_noise(one, ModelData.from_observations(obs), estimated=False)
    assert out.noise is None
    with warnings.catch_warnings():
        warnings.simplefilter("error", UserWarning)
        with_render_noise(one, ModelData.from_observations(dataclasses.replace(obs, variance=None)), estimated=False)
