"""Signal-dependent noise (pixel_noise = "signal"): the level function, the per-pixel likelihood, the two-phase run."""
import math

import pytest
import torch

import bayes_brdf as bb
from bayes_brdf.models.data import ModelData
from bayes_brdf.models.likelihood import RenderedImages
from bayes_brdf.models.noise import NoiseLevel, fit_noise_level
from bayes_brdf.render import PlanarSample, SVBRDF, collocated_views
from bayes_brdf.render.shade import render

G = lambda s: torch.Generator().manual_seed(s)  # noqa: E731
A, C = 1e-4, 0.05 ** 2          # the true level: s(y)^2 = 1e-4 + (0.05 y)^2 (a floor, then 5 % of the radiance)


def true_scale(y):
    return (A + C * y * y).sqrt()


def noisy_photos(resolution=16, views=5, seed=1, kind="laplace"):
    maps = bb.materials.make_material("wood", resolution, seed=0)
    vs = collocated_views(views, radius=3.0, resolution=resolution, power=20.0)
    y = render(maps, vs, PlanarSample(2.0))[0]
    s = true_scale(y.mean(-1, keepdim=True)).expand_as(y)
    base = torch.distributions.Laplace(0.0, 1.0) if kind == "laplace" else torch.distributions.Normal(0.0, 1.0)
    torch.manual_seed(seed)
    return bb.Observations(vs, y + base.sample(y.shape) * s, PlanarSample(2.0)), y


@pytest.mark.parametrize("kind", ["laplace", "gaussian"])
def test_level_function_recovered_from_residuals(kind):
    y = torch.rand(100_000, generator=G(0)) * 0.8
    base = torch.distributions.Laplace(0.0, 1.0) if kind == "laplace" else torch.distributions.Normal(0.0, 1.0)
    torch.manual_seed(0)
    r = base.sample((100_000, 3)) * true_scale(y)[:, None]
    nl = fit_noise_level(y, r, kind=kind)
    q = torch.tensor([0.02, 0.2, 0.5, 0.8])
    assert torch.allclose(nl.scale(q), true_scale(q), rtol=0.05), (nl, nl.scale(q), true_scale(q))
    assert nl.relative(torch.tensor(nl.y_ref)).item() == pytest.approx(1.0)
    assert NoiseLevel.from_dict(nl.to_dict()) == nl


def test_likelihood_uses_the_per_pixel_scale_exactly():
    obs, _ = noisy_photos(8, 3)
    d = ModelData.from_observations(obs, dtype=torch.float64)
    g = torch.rand(d.weight.shape, generator=G(2), dtype=torch.float64) + 0.5
    d = d.with_noise(g)
    maps = SVBRDF.constant(0.4, 0.5, dtype=torch.float64)
    pred = render(maps, obs.views, obs.surface)[0].double()
    w = d.weight[..., None].expand_as(pred) > 0
    for sigma in (0.02, 0.05):
        scale = (sigma * g)[..., None].expand_as(pred)
        ref = torch.distributions.Laplace(pred[w], scale[w]).log_prob(d.images[w]).sum()
        got = RenderedImages(maps, d, sigma).log_prob(d.images)
        assert float(got) == pytest.approx(float(ref), rel=1e-9)
    # sigma = "auto": the profile over the one overall scale, s = sum |y - R| / g / N
    e = ((d.images - pred).abs() / g[..., None])[w].sum()
    s = float(e / w.sum())
    ref = torch.distributions.Laplace(pred[w], (s * g)[..., None].expand_as(pred)[w]).log_prob(d.images[w]).sum()
    assert float(RenderedImages(maps, d, "auto").log_prob(d.images)) == pytest.approx(float(ref), rel=1e-9)
    # a minibatch of views keeps each pixel's scale
    mb = d.minibatch(G(3), views=2)
    assert mb.noise.shape == mb.weight.shape and any(torch.equal(mb.noise[0], g[i]) for i in range(3))


def test_censored_pixels_use_their_scale():
    obs, _ = noisy_photos(8, 3)
    obs.saturated = obs.images.amax(-1) > obs.images.amax(-1).quantile(0.9)
    d = ModelData.from_observations(obs, dtype=torch.float64)
    K = d.censored.level.shape[0]
    gc = torch.linspace(0.5, 2.0, K, dtype=torch.float64)
    d2 = d.with_noise(torch.ones_like(d.weight), gc)
    maps = SVBRDF.constant(0.4, 0.5, dtype=torch.float64)
    sig = 0.03
    r = bb.render.shade.shade(maps, d.censored.gbuffer)[0, 0, 0]                        # [K, 3]
    t = (d.censored.level - r) / (sig * gc[:, None])
    ref = torch.where(t >= 0, -t - math.log(2), torch.log1p(-0.5 * torch.exp(-t.abs()))).sum()
    got = RenderedImages(maps, d2, sig).censored_log_prob(sig)
    assert float(got) == pytest.approx(float(ref), rel=1e-9)


@pytest.mark.slow
def test_infer_recovers_a_known_signal_dependent_noise_within_ten_percent():
    # nine photos: with 4 parameters per texel and 27 values, the level is identified to a few percent
    # (with 5 photos, 15 values, the inferred overall scale comes out about 11 % high: docs/calibration.md)
    obs, clean = noisy_photos(16, 9)
    post = bb.infer(bb.models.per_texel(16), obs, steps=400, progress=False)
    nl = post.noise_level
    assert nl is not None and post.meta["noise_level"] == nl.to_dict()
    y = clean.mean(-1)[ModelData.from_observations(obs).weight > 0]       # the radiance of the fitted pixels
    q = torch.quantile(y, torch.tensor([0.1, 0.5, 0.9]))
    got = post.noise_sigma * nl.relative(q)
    assert torch.allclose(got, true_scale(q).to(got), rtol=0.10), (got, true_scale(q))
    # the constant model cannot: its one scale is off by more than 10 % at one end or the other
    const = bb.infer(bb.models.per_texel(16, pixel_noise="constant"), obs, steps=200, progress=False)
    off = (const.noise_sigma / true_scale(q) - 1).abs()
    assert float(off.max()) > 0.25


def test_noise_weight_is_made_once_and_follows_its_tensors():
    """The likelihood asks for ``weight / g`` on every step: it is made once per kind (the mesh path keeps its
    compacted copy only while the same tensor comes again), and made again when a tensor changes in place."""
    obs, _ = noisy_photos(8, 3)
    d = ModelData.from_observations(obs, dtype=torch.float64)
    assert d.noise_weight() is d.weight                       # no per-pixel scales: the weights themselves
    g = torch.rand(d.weight.shape, generator=G(2), dtype=torch.float64) + 0.5
    d = d.with_noise(g)
    w1, w2 = d.noise_weight("laplace"), d.noise_weight("gaussian")
    assert d.noise_weight("laplace") is w1 and d.noise_weight("gaussian") is w2
    torch.testing.assert_close(w1, d.weight / d.noise)
    torch.testing.assert_close(w2, d.weight / d.noise ** 2)
    d.noise.mul_(2.0)                                          # a user's in-place change is seen
    w3 = d.noise_weight("laplace")
    assert w3 is not w1
    torch.testing.assert_close(w3, d.weight / d.noise)
