"""View scores (Eqs. 13-21): mutual information per candidate vs a slow per-view reference, the footprint rule
(one pixel per texel), chunking, estimator agreement, and the mean image-space std."""
import math

import pytest
import torch

import bayes_brdf as bb
from bayes_brdf.errors import InputError
from bayes_brdf.guidance.entropy import kde_entropy_torch, noise_entropy
from bayes_brdf.guidance.scores import counted_pixels, score_views
from bayes_brdf.posterior import Posterior
from bayes_brdf.render import SVBRDF, PlanarSample
from bayes_brdf.render.cameras import PerspectiveCamera
from bayes_brdf.render.gbuffer import GBuffer
from bayes_brdf.render.shade import render
from bayes_brdf.render.views import View, collocated_views
from bayes_brdf.uncertainty import image_std

S = PlanarSample(2.0)
R = 8
F64 = torch.float64


def _flat(dtype=F64):
    return torch.full((3, 1, 1), 0.04, dtype=dtype), torch.tensor([0.0, 0, 1], dtype=dtype).view(3, 1, 1)


def _random_maps(n=6, seed=0, dtype=F64):
    g = torch.Generator().manual_seed(seed)
    return SVBRDF(torch.rand(n, 3, R, R, generator=g, dtype=dtype) * 0.8 + 0.1,
                  torch.rand(n, 1, R, R, generator=g, dtype=dtype) * 0.5 + 0.2, *_flat(dtype))


def _half_disagreeing_maps(n=8, seed=0):
    """Particles agree (to 0.005) everywhere except on the left half of the sample (columns 0..3, x < 0)."""
    g = torch.Generator().manual_seed(seed)
    alb = 0.5 + 0.005 * torch.randn(n, 3, R, R, generator=g, dtype=F64)
    alb[..., : R // 2] = torch.rand(n, 3, R, R // 2, generator=g, dtype=F64) * 0.8 + 0.1
    return SVBRDF(alb, torch.full((n, 1, R, R), 0.4, dtype=F64), *_flat())


def _zoomed(cx, res=16, fov=12.0):
    """A narrow perspective view looking straight down at (cx, 0): sees a 4 x 4 patch of texels."""
    return View.collocated(PerspectiveCamera((cx, 0.0, 3.0), target=(cx, 0.0, 0.0), fov=fov, resolution=(res, res)),
                           power=10.0, name=f"zoom{cx}")


def _reference_mi(maps, views, footprint=True, noise_var=0.0):
    """Slow Eq. 18: render each candidate alone, per counted pixel and channel the quadrature KDE entropy
    minus the noise entropy, summed."""
    n = maps.num_particles
    out = []
    for v in views:
        img = render(maps, [v], S)[:, 0]                                # [n, H, W, 3]
        g = GBuffer.build([v], S, dtype=F64)
        keep = g.unique_pixel_mask((R, R))[0] if footprint else g.mask[0]
        h, _ = kde_entropy_torch(img[:, keep].reshape(n, -1), "quadrature", noise_var=noise_var)
        out.append(float((h - noise_entropy(noise_var)).sum()))
    return torch.tensor(out, dtype=F64)


@pytest.mark.parametrize("camera,res,footprint,noise_var", [
    ("rectified", R, True, 0.0),          # dense branch
    ("perspective", 32, True, 0.0),       # sparse branch: 1 pixel in 16 counts
    ("perspective", 32, False, 1e-4),     # every valid pixel, with render noise
])
def test_mi_equals_per_view_reference_and_chunking_does_not_matter(camera, res, footprint, noise_var):
    maps = _random_maps()
    views = collocated_views(5, 3.0, camera=camera, resolution=res, power=10.0, max_zenith=60)
    if camera == "perspective":
        views.append(_zoomed(-0.3, res=res))
    s = score_views(maps, views, S, estimator="quadrature", footprint=footprint, noise_var=noise_var)
    ref = _reference_mi(maps, views, footprint, noise_var)
    torch.testing.assert_close(s.mi, ref, rtol=1e-9, atol=1e-7)
    s1 = score_views(maps, views, S, estimator="quadrature", footprint=footprint, noise_var=noise_var,
                     chunk_views=1)
    torch.testing.assert_close(s1.mi, s.mi, rtol=1e-12, atol=1e-9)
    torch.testing.assert_close(s1.mean_std, s.mean_std, rtol=1e-12, atol=1e-12)
    assert len(s) == len(views) and s.to_dict()["estimator"] == "quadrature"
    # the MC estimator does not depend on chunking either (random numbers are tied to pixel positions)
    m_all = score_views(maps, views, S, estimator="mc", footprint=footprint, seed=4)
    m_one = score_views(maps, views, S, estimator="mc", footprint=footprint, seed=4, chunk_views=2)
    torch.testing.assert_close(m_all.mi, m_one.mi, rtol=1e-12, atol=1e-9)


def test_a_candidate_set_over_the_memory_budget_is_scored_in_blocks_with_the_same_result(monkeypatch):
    from bayes_brdf.render.gbuffer import GBUFFERS as _CACHE

    maps = _random_maps()
    views = collocated_views(9, 3.0, camera="perspective", resolution=32, power=10.0, max_zenith=60, seed=3)
    whole = score_views(maps, views, S, estimator="quadrature")
    built = []
    monkeypatch.setattr(GBuffer, "build", classmethod(lambda cls, vs, *a, _b=GBuffer.build, **k:
                                                      built.append(len(vs)) or _b(vs, *a, **k)))
    monkeypatch.setattr(_CACHE, "max_bytes", 8 * GBuffer.bytes_per_view(views[0], F64))   # blocks of 2 views
    blocks = score_views(maps, views, S, estimator="quadrature")
    assert built == [2, 2, 2, 2, 1]                    # never the whole set at once, and nothing cached
    torch.testing.assert_close(blocks.mi, whole.mi, rtol=1e-12, atol=1e-9)
    torch.testing.assert_close(blocks.pixels, whole.pixels)
    torch.testing.assert_close(blocks.mean_std, whole.mean_std, rtol=1e-12, atol=1e-12)


def test_posterior_input_equals_its_particle_maps():
    g = torch.Generator().manual_seed(2)
    n = 5
    post = Posterior({"albedo": torch.rand(n, 1, R, R, generator=g) * 0.8 + 0.1,
                      "roughness": torch.rand(n, 1, R, R, generator=g) * 0.5 + 0.2},
                     torch.zeros(n), model=bb.models.per_texel(R, albedo="gray"),
                     meta={"surface": {"size": 2.0, "grid": "centers"}})
    views = collocated_views(4, 3.0, camera="rectified", resolution=R, power=10.0)
    a = score_views(post, views, estimator="quadrature")            # surface from the posterior's metadata
    b = score_views(post.maps("all"), views, S, estimator="quadrature")
    torch.testing.assert_close(a.mi, b.mi)
    torch.testing.assert_close(a.mi.double(), _reference_mi(post.maps("all"), views).to(a.mi.dtype).double(),
                               rtol=1e-4, atol=1e-3)


def _texel_of_position(g):
    """Independent footprint: the texel (centers grid, size 2) containing each pixel's 3-D hit point."""
    x, y = g.position[:, 0], g.position[:, 1]
    col = ((x + 1) / 2 * R).floor().long().clamp(0, R - 1)
    row = ((1 - y) / 2 * R).floor().long().clamp(0, R - 1)
    return torch.where(g.mask, row * R + col, torch.full_like(col, -1))


def test_footprint_counts_one_pixel_per_texel():
    views = collocated_views(5, 3.0, camera="perspective", resolution=32, power=10.0) + [_zoomed(-0.5, res=32)]
    g = GBuffer.build(views, S, dtype=F64)
    keep = counted_pixels(g, (R, R))
    tex = _texel_of_position(g)
    s = score_views(_random_maps(4), views, S, estimator="quadrature")
    assert torch.equal(s.pixels, keep.reshape(len(views), -1).sum(1))
    for v in range(len(views)):
        seen = set(tex[v][g.mask[v]].tolist())
        counted = tex[v][keep[v]].tolist()
        assert (keep[v] <= g.mask[v]).all()                          # only valid pixels count
        assert len(counted) == len(set(counted)) <= R * R            # each texel at most once ...
        assert set(counted) == seen                                  # ... and every seen texel once
        assert int(s.pixels[v]) == len(seen) < int(g.mask[v].sum())  # far fewer than the valid pixels
    assert int(s.pixels[-1]) == 16                                   # the zoomed view sees a 4 x 4 patch
    # footprint off: every valid pixel counts
    s_all = score_views(_random_maps(4), views, S, estimator="quadrature", footprint=False)
    assert torch.equal(s_all.pixels, g.mask.reshape(len(views), -1).sum(1))
    # rectified views at map resolution: one pixel per texel already, all count
    rect = collocated_views(3, 3.0, camera="rectified", resolution=R, power=10.0)
    s_rect = score_views(_random_maps(4), rect, S, estimator="quadrature")
    assert s_rect.pixels.tolist() == [R * R] * 3
    assert counted_pixels(GBuffer.build(rect, S), (R, R)).all()


def test_views_of_disagreeing_texels_score_higher_and_estimators_agree_on_the_ranking():
    maps = _half_disagreeing_maps()
    views = [_zoomed(-0.5), _zoomed(0.5), _zoomed(0.0)]              # left (disagree), right (agree), straddling
    q = score_views(maps, views, S, estimator="quadrature")
    assert q.pixels.tolist() == [16, 16, 16]
    # per value the KDE entropy is about log(spread ratio) ~ log(60) larger on the disagreeing half
    assert float(q.mi[0] - q.mi[1]) > 16 * 3 * 2.0
    assert q.mi[1] < q.mi[2] < q.mi[0]
    assert q.mean_std[1] < q.mean_std[2] < q.mean_std[0]
    m = score_views(maps, views, S, estimator="mc", seed=0)
    assert torch.equal(torch.argsort(m.mi), torch.argsort(q.mi))
    # MC: same seed -> same numbers; another seed -> slightly different numbers, same expectation
    assert torch.equal(score_views(maps, views, S, estimator="mc", seed=0).mi, m.mi)
    m2 = score_views(maps, views, S, estimator="mc", seed=1)
    assert not torch.equal(m2.mi, m.mi)
    spread = float(q.mi.max() - q.mi.min())
    assert float((m2.mi - m.mi).abs().max()) < 0.1 * spread
    assert float((m.mi - q.mi).abs().max()) < 0.1 * spread
    # the std baseline is not affected by the estimator
    torch.testing.assert_close(m.mean_std, q.mean_std)


@pytest.mark.parametrize("camera,res", [("rectified", R), ("perspective", 32)])
def test_mean_std_is_image_std_over_counted_pixels(camera, res):
    maps = _random_maps(7, seed=3)
    views = collocated_views(4, 3.0, camera=camera, resolution=res, power=10.0)
    s = score_views(maps, views, S, estimator="quadrature")
    std = image_std(maps, views, S)                                  # [V, H, W, 3]
    keep = counted_pixels(GBuffer.build(views, S), (R, R))
    ref = torch.stack([std[v][keep[v]].mean() for v in range(len(views))])
    torch.testing.assert_close(s.mean_std, ref.double(), rtol=1e-9, atol=1e-12)


def test_observation_noise_option_uses_the_models_sigma():
    """noise_var="observation": a Gaussian of the likelihood's variance (2 sigma^2 Laplace, sigma^2 Gaussian);
    then every counted value contributes >= 0, and particles that all agree give MI = 0."""
    views = collocated_views(3, 3.0, camera="rectified", resolution=R, power=10.0)
    g = torch.Generator().manual_seed(5)
    n, sigma = 5, 0.02
    parts = {"albedo": torch.rand(n, 1, R, R, generator=g, dtype=F64) * 0.8 + 0.1,
             "roughness": torch.rand(n, 1, R, R, generator=g, dtype=F64) * 0.5 + 0.2}
    for lik, var in (("laplace", 2 * sigma ** 2), ("gaussian", sigma ** 2)):
        post = Posterior(parts, torch.zeros(n), model=bb.models.per_texel(R, albedo="gray", sigma=sigma, likelihood=lik),
                         meta={"surface": {"size": 2.0, "grid": "centers"}})
        a = score_views(post, views, estimator="quadrature", noise_var="observation")
        torch.testing.assert_close(a.mi, _reference_mi(post.maps("all"), views, noise_var=var), rtol=1e-9, atol=1e-7)
        assert (a.mi > -1e-6).all()
        same = Posterior({k: v[:1].expand(n, *v.shape[1:]) for k, v in parts.items()}, torch.zeros(n),
                         model=post.model, meta=post.meta)
        z = score_views(same, views, estimator="quadrature", noise_var="observation")
        torch.testing.assert_close(z.mi, torch.zeros(3, dtype=F64), atol=1e-8, rtol=0)
    with pytest.raises(InputError, match="model"):
        score_views(_random_maps(3), views, S, noise_var="observation")      # bare maps: no sigma
    with pytest.raises(InputError, match="unknown noise_var"):
        score_views(post, views, noise_var="photo")


def test_bad_input_raises_input_error():
    maps = _random_maps(4)
    with pytest.raises(InputError, match="no candidate"):
        score_views(maps, [], S)
    with pytest.raises(InputError, match="at least 2 particles"):
        score_views(SVBRDF(maps.albedo[:1], maps.roughness[:1], maps.specular, maps.normal),
                    collocated_views(2, 3.0, camera="rectified", resolution=R), S)
    with pytest.raises(InputError, match="particle dimension"):
        score_views(maps.particle(0), collocated_views(2, 3.0, camera="rectified", resolution=R), S)
    with pytest.raises(InputError, match="unknown entropy estimator"):
        score_views(maps, collocated_views(2, 3.0, camera="rectified", resolution=R), S, estimator="kde")
