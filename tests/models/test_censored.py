"""Saturated pixels as censored data: log P(R + noise >= level), against closed forms and a plain reference."""
import math
from dataclasses import replace

import pytest
import torch

import bayes_brdf as bb
from bayes_brdf.errors import InputError
from bayes_brdf.models.data import ModelData
from bayes_brdf.models.censored_kernel import censored_laplace
from bayes_brdf.models.likelihood import RenderedImages, _CensoredSum, censored_log_survival
from bayes_brdf.observations import Observations
from bayes_brdf.render import PlanarSample, collocated_views
from bayes_brdf.render.gbuffer import GBuffer
from bayes_brdf.render.maps import SVBRDF
from bayes_brdf.render.shade import render


def _laplace_sf(t):   # P(X >= t), X ~ Laplace(0, 1)
    return 0.5 * math.exp(-t) if t >= 0 else 1 - 0.5 * math.exp(t)


def _normal_sf(t):
    return 0.5 * math.erfc(t / math.sqrt(2))


@pytest.mark.parametrize("kind,sf", [("laplace", _laplace_sf), ("gaussian", _normal_sf)])
def test_log_survival_matches_the_closed_form(kind, sf):
    ts = [-8.0, -2.5, -0.3, 0.0, 0.2, 1.0, 4.0, 12.0, 25.0]
    got = censored_log_survival(torch.tensor(ts, dtype=torch.float64), kind)
    for t, g in zip(ts, got.tolist()):
        assert g == pytest.approx(math.log(sf(t)), rel=1e-9, abs=1e-12), t
    # far in the tails it stays finite and follows the asymptote
    far = censored_log_survival(torch.tensor([60.0, -60.0], dtype=torch.float64), kind)
    assert torch.isfinite(far).all() and abs(float(far[1])) < 1e-12
    if kind == "laplace":
        assert float(far[0]) == pytest.approx(-60 - math.log(2))
    else:
        assert float(far[0]) == pytest.approx(-60 ** 2 / 2 - math.log(60 * math.sqrt(2 * math.pi)), rel=1e-3)


@pytest.mark.needs_native
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("noise", [False, True])
def test_native_censored_terms_match_the_torch_expressions(dtype, noise):
    """The native pass (censored_kernel.py) against the torch expressions and their autograd derivatives: the
    sum per particle, each pixel's channel sum, and the derivatives in the renders and in the noise scale, on
    renders far below, at and far above the clip (both branches, and t = 0)."""
    gen = torch.Generator().manual_seed(3)
    n, K = 5, 400
    r = torch.rand(n, K, 3, generator=gen, dtype=torch.float64) * 2
    level = torch.full((K, 3), 0.9, dtype=torch.float64)
    r[0, :3] = level[:3]                                                      # t = 0 exactly
    sigma = torch.rand(n, generator=gen, dtype=torch.float64) * 0.05 + 0.01
    w = torch.rand(K, generator=gen, dtype=torch.float64) + 0.5
    g = torch.rand(K, generator=gen, dtype=torch.float64) + 0.5 if noise else None
    rr, ss = r.clone().requires_grad_(True), sigma.clone().requires_grad_(True)
    scale = ss.reshape(-1, 1, 1) * (1 if g is None else g[None, :, None])
    val = censored_log_survival((level[None] - rr) / scale, "laplace") * w[None, :, None]
    d_r, d_s = torch.autograd.grad(val.sum(), (rr, ss))
    d_r[0, :3] = w[:3, None] / scale[0, :3].detach()      # at t = 0 autograd takes the kink of |t| as 0: d log S / dt is -1
    total, dsig, per_pixel, dr = censored_laplace(r.to(dtype), level.to(dtype), sigma, g, w, terms=True, grad=True)
    tol = 1e-5 if dtype == torch.float32 else 1e-10
    torch.testing.assert_close(total, val.sum((1, 2)).detach(), rtol=tol, atol=tol)
    torch.testing.assert_close(per_pixel.double(), val.sum(2).detach(), rtol=tol, atol=tol)
    torch.testing.assert_close(dr.double(), d_r, rtol=tol, atol=tol * 100)
    torch.testing.assert_close(dsig, d_s, rtol=tol, atol=tol)
    # and through the likelihood's autograd function, as a step calls it
    rr2, ss2 = r.to(dtype).requires_grad_(True), sigma.to(dtype).requires_grad_(True)
    out = _CensoredSum.apply(rr2, level.to(dtype), ss2, w.to(dtype), "laplace", None if g is None else g.to(dtype))
    gr2, gs2 = torch.autograd.grad((out * torch.arange(1.0, n + 1, dtype=dtype)).sum(), (rr2, ss2))
    weights = torch.arange(1.0, n + 1, dtype=torch.float64)
    torch.testing.assert_close(gr2.double(), d_r * weights[:, None, None], rtol=tol, atol=tol * 100)
    torch.testing.assert_close(gs2.double(), d_s * weights, rtol=tol * 10, atol=tol * 10)


def _clipped_capture(camera="perspective", clip=None, R=12, seed=0):
    """A textured sample under collocated flashes, clipped at ``clip`` (default: its 97th percentile)."""
    g = torch.Generator().manual_seed(seed)
    views = collocated_views(3, 2.5, camera=camera, resolution=R)
    surface = PlanarSample(2.0)
    truth = SVBRDF(torch.rand(3, R, R, generator=g, dtype=torch.float64) * 0.6 + 0.2,
                   torch.rand(1, R, R, generator=g, dtype=torch.float64) * 0.4 + 0.1,
                   torch.full((3, R, R), 0.04, dtype=torch.float64),
                   torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64).reshape(3, 1, 1).expand(3, R, R))
    img = render(truth, views, surface)[0]
    clip = float(img.quantile(0.97)) if clip is None else clip
    sat = (img >= clip).any(-1)
    obs = Observations(views, img.clamp(max=clip).float(), surface, saturated=sat)
    return obs, truth, clip


def _check_gradient(f, x, idx, rel, h=1e-6):
    """Autograd's derivative of the scalar ``f`` at ``x`` against central differences at flat indices ``idx``."""
    (g,) = torch.autograd.grad(f(x), x)
    for i in idx(g):
        e = torch.zeros_like(x).flatten()
        e[i] = h
        e = e.reshape(x.shape)
        with torch.no_grad():
            fd = (f(x + e) - f(x - e)) / (2 * h)
        assert float(g.flatten()[i]) == pytest.approx(float(fd), rel=rel), i
    return g


def _reference(maps, obs, sigma, kind, censored=True):
    """Plain reference: render every pixel, then sum the density on unclipped pixels and the survival on clipped."""
    img = render(maps, obs.views, obs.surface, backend="eager")          # [n, V, H, W, 3]
    y = obs.images.to(img)
    valid = GBuffer.build(obs.views, obs.surface).mask                  # pixels that see the sample
    sat = obs.saturated & valid
    out = []
    for i in range(img.shape[0]):
        s = float(sigma[i]) if torch.is_tensor(sigma) else sigma
        r = (y - img[i])[valid & ~sat]
        if kind == "laplace":
            lp = float((-r.abs() / s - math.log(2 * s)).sum())
            sf = _laplace_sf
        else:
            lp = float((-(r ** 2) / (2 * s * s) - 0.5 * math.log(2 * math.pi * s * s)).sum())
            sf = _normal_sf
        if censored:
            t = ((y - img[i])[sat] / s).reshape(-1).tolist()
            lp += sum(math.log(sf(v)) for v in t)
        out.append(lp)
    return out


@pytest.mark.parametrize("kind", ["laplace", "gaussian"])
@pytest.mark.parametrize("camera", ["perspective", "rectified"])
def test_log_prob_with_clipped_pixels_matches_a_plain_reference(kind, camera):
    obs, truth, clip = _clipped_capture(camera)
    d = ModelData.from_observations(obs, dtype=torch.float64)
    assert d.censored is not None
    seen = GBuffer.build(obs.views, obs.surface).mask
    assert d.censored.count == int((seen & obs.saturated).sum()) > 0
    assert float(d.weight.sum()) == float((seen & ~obs.saturated).sum())
    # particles: the truth, a dimmer and a brighter material
    maps = SVBRDF(torch.stack([truth.albedo, 0.7 * truth.albedo, (1.3 * truth.albedo).clamp(max=1)]),
                  truth.roughness.expand(3, -1, -1, -1), truth.specular, truth.normal)
    for sigma in (0.02, 0.1):
        got = RenderedImages(maps, d, sigma, kind, "eager").log_prob(d.images)
        assert got.tolist() == pytest.approx(_reference(maps, obs, sigma, kind), rel=1e-6)
        dropped = RenderedImages(maps, d, sigma, kind, "eager", saturated="drop").log_prob(d.images)
        assert dropped.tolist() == pytest.approx(_reference(maps, obs, sigma, kind, censored=False), rel=1e-6)
    # sigma = "auto": the unclipped pixels' profile sigma, the censored term at that sigma
    lik = RenderedImages(maps, d, "auto", kind, "eager")
    s = lik.sigma_hat(d.images)
    ref = _reference(maps, obs, s, kind)
    got = lik.log_prob(d.images)
    # the auto form drops the constant N log 2 (Laplace) / (N/2) log(2 pi) (Gaussian) the same way for all particles
    assert (got - torch.tensor(ref, dtype=got.dtype)).std() < 1e-6 * abs(ref[0])


def test_censoring_pulls_a_too_dim_rendering_up_and_ignores_a_brighter_one():
    obs, truth, clip = _clipped_capture("rectified", R=8)
    d = ModelData.from_observations(obs, dtype=torch.float64)
    bright = SVBRDF(truth.albedo * 1.5, truth.roughness, truth.specular, truth.normal)
    dim = SVBRDF(truth.albedo * 0.5, truth.roughness, truth.specular, truth.normal)
    cl = lambda m: float(RenderedImages(m, d, 0.01, "laplace", "eager").censored_log_prob(0.01)[0])  # noqa: E731
    assert cl(bright) > -3 * d.censored.count * math.log(1.0 / 0.9)      # nearly P = 1 on every clipped value
    assert cl(dim) < cl(truth) < cl(bright)


def test_censored_gradient_matches_finite_differences():
    obs, truth, _ = _clipped_capture("perspective", R=8)
    d = ModelData.from_observations(obs, dtype=torch.float64)
    a = truth.albedo.clone()[None].mul(0.9).requires_grad_(True)
    lik = lambda x: RenderedImages(SVBRDF(x, truth.roughness[None], truth.specular, truth.normal),  # noqa: E731
                                   d, 0.05, "gaussian", "eager").censored_log_prob(0.05)[0]
    g = _check_gradient(lik, a, lambda g: [int(g.abs().flatten().argmax())], rel=1e-5)
    assert float(g.abs().max()) > 0


@pytest.mark.parametrize("kind", ["laplace", "gaussian"])
def test_full_log_prob_gradient_with_auto_sigma_matches_finite_differences(kind):
    """The censored term's closed-form derivative (w.r.t. the renders and the profile sigma) inside the whole
    likelihood, against central differences; far-off renders (t of hundreds) stay finite in float32."""
    obs, truth, _ = _clipped_capture("rectified", R=8)
    d = ModelData.from_observations(obs, dtype=torch.float64)
    r0 = truth.roughness[None].clone().requires_grad_(True)
    lp = lambda r: RenderedImages(SVBRDF(truth.albedo[None] * 0.8, r, truth.specular, truth.normal),  # noqa: E731
                                  d, "auto", kind, "eager").log_prob(d.images)[0]
    _check_gradient(lp, r0, lambda g: g.abs().flatten().topk(3).indices.tolist(), rel=1e-4)
    d32 = ModelData.from_observations(obs)
    dark = SVBRDF.constant(0.0, 0.9, dtype=torch.float32)
    v = RenderedImages(dark, d32, 1e-3, kind).censored_log_prob(1e-3)
    assert torch.isfinite(v).all() and float(v[0]) < -100


def test_minibatch_of_views_keeps_their_clipped_pixels():
    obs, truth, _ = _clipped_capture("perspective")
    d = ModelData.from_observations(obs, dtype=torch.float64)
    assert d.minibatch(torch.Generator().manual_seed(0), views=3).censored.count == d.censored.count
    mb = d.minibatch(torch.Generator().manual_seed(1), views=2)
    assert set(mb.censored.view.tolist()) <= {0, 1}
    # the censored term of views ``sub`` taken from the full data = that of the same views loaded alone
    for sub in ([0, 1], [0, 2], [1, 2]):
        alone = ModelData.from_observations(obs.subset(sub), dtype=torch.float64)
        picked = replace(d, censored=d.censored.views_index(torch.tensor(sub)))
        lp = lambda dd: float(RenderedImages(truth, dd, 0.02, "laplace", "eager").censored_log_prob(0.02))  # noqa: E731
        assert lp(picked) == pytest.approx(lp(alone), rel=1e-9)
    # a pixel subsample thins the clipped pixels too
    half = d.minibatch(torch.Generator().manual_seed(2), pixels=0.5)
    assert 0 < half.censored.count < d.censored.count


def test_saturated_option_is_checked_and_in_the_preset():
    assert bb.models.per_texel(8).saturated == "censored"
    assert bb.models.homogeneous(saturated="drop").to_dict()["saturated"] == "drop"
    with pytest.raises(InputError, match="saturated must be one of censored, drop"):
        bb.models.per_texel(8, saturated="exact")
