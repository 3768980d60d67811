"""Guidance under a known environment light: candidate views lit by the environment (alone, or with a flash
that is added or moved) are scored by mutual information, placed in configuration space, and recommended.

The posterior is synthetic: a homogeneous material whose particles agree on the albedo (up to a small
jitter) and disagree on the roughness, under the built-in ``studio()`` map (a dim sky and one bright softbox
20 degrees from the zenith, towards +x)."""
import math

import pytest
import torch

from bayes_brdf.errors import InputError
from bayes_brdf.guidance import recommend, score_views
from bayes_brdf.guidance import scores as scores_module
from bayes_brdf.guidance.recommend import configuration, distances, top_k
from bayes_brdf.render import SVBRDF, PlanarSample, collocated_views
from bayes_brdf.render import gbuffer as gbuffer_module
from bayes_brdf.render.cameras import RectifiedCamera
from bayes_brdf.render.environment import studio
from bayes_brdf.render.gbuffer import GBufferCache
from bayes_brdf.render.lights import PointLight
from bayes_brdf.render.views import View

RES = 12
SURFACE = PlanarSample(2.0)


@pytest.fixture(scope="module")
def env():
    return studio(16)


def _camera(zenith, azimuth, dist=3.0):
    z, a = math.radians(zenith), math.radians(azimuth)
    return RectifiedCamera((dist * math.sin(z) * math.cos(a), dist * math.sin(z) * math.sin(a), dist * math.cos(z)),
                           resolution=(RES, RES))


def _posterior(n=16, rough=(0.08, 0.5), seed=0):
    """``n`` particles of a 1x1 material: albedo 0.3 (+-1 %), specular 0.3, roughness spread over ``rough``."""
    g = torch.Generator().manual_seed(seed)
    albedo = 0.3 * (1 + 0.01 * torch.randn(n, 3, 1, 1, generator=g))
    r = torch.linspace(*rough, n).view(n, 1, 1, 1)
    return SVBRDF(albedo, r, torch.full((3, 1, 1), 0.3), torch.tensor([0.0, 0.0, 1.0]).view(3, 1, 1))


def test_an_environment_only_view_is_placed_by_its_camera(env):
    cams = [_camera(z, a) for z, a in ((0, 0), (30, 0), (30, 90), (45, 200))]
    alone = [View(c, (env,)) for c in cams]
    flash = [View.collocated(c, 20.0) for c in cams]
    conf = configuration(alone)
    assert torch.allclose(conf[:, :3], conf[:, 3:])                        # light part = camera direction
    assert torch.allclose(conf, configuration(flash))                      # as a collocated flash view
    assert torch.allclose(distances(alone, alone), distances(flash, flash))
    # with a flash, the flash places the light part: moving it (the environment fixed) moves the view
    c = cams[1]
    moved = View(c, (PointLight((0.0, 3.0, 0.5), 20.0), env))
    assert torch.allclose(configuration([View(c, (PointLight(c.position, 20.0), env))]), configuration([flash[1]]))
    assert float(distances([moved], [View(c, (env,))])[0, 0]) > 0.3
    # the exclusion radius acts between environment-only views as between flash views
    vals = torch.tensor([4.0, 3.0, 2.0, 1.0])
    assert top_k(vals, alone, 4, radius=40) == top_k(vals, flash, 4, radius=40) == [0, 3]


def test_the_view_of_the_softbox_highlight_is_worth_most_when_the_roughness_is_uncertain(env):
    """The softbox sits 20 degrees from the zenith towards +x: a camera 20 degrees off towards -x sees its
    mirror reflection (a highlight whose size and height are the roughness); one 20 degrees towards +x sees
    the reflection of the dim sky. With the roughness uncertain the highlight view carries the most
    information, and the recommendation picks it."""
    views = [View(_camera(20, az), (env,)) for az in (180, 0, 90, 270)] + [View(_camera(50, 0), (env,))]
    post = _posterior()
    s = score_views(post, views, SURFACE)
    assert bool(torch.isfinite(s.mi).all()) and bool(torch.isfinite(s.mean_std).all())
    assert s.pixels.tolist() == [RES * RES] * len(views)
    assert int(s.mi.argmax()) == 0 and float(s.mi[0] - s.mi[1]) > 100       # highlight >> dim sky, nats
    assert int(s.mean_std.argmax()) == 0
    assert recommend(post, views, k=1, surface=SURFACE).indices == [0]
    # with a noisy photo's score too: the highlight's spread is far above the noise, the sky's is not
    noisy = score_views(post, views, SURFACE, noise_var=1e-4)
    assert int(noisy.mi.argmax()) == 0 and bool((noisy.mi > s.mi).all())
    # a posterior sure of its roughness has nothing to learn from the highlight: the margin collapses
    sure = score_views(_posterior(rough=(0.2, 0.2)), views[:2], SURFACE, noise_var=1e-4)
    assert float(sure.mi[0] - sure.mi[1]) < 0.2 * float(noisy.mi[0] - noisy.mi[1])


def test_candidates_under_the_environment_with_a_flash_added_or_moved_score_as_they_would_alone(env):
    """One call over a mixed set (environment alone, environment + flash at the camera, environment + a
    moved flash, a flash alone) gives each candidate the score it gets on its own: a candidate's lighting
    does not leak into another's score."""
    cams = [_camera(20, 180), _camera(35, 60)]
    mixed = []
    for c in cams:
        mixed += [View(c, (env,)), View(c, (PointLight(c.position, 20.0), env)),
                  View(c, (PointLight((2.0, 0.0, 2.0), 20.0), env)), View.collocated(c, 20.0)]
    post = _posterior(8)
    together = score_views(post, mixed, SURFACE, seed=3)
    assert bool(torch.isfinite(together.mi).all())
    for i, v in enumerate(mixed):
        alone = score_views(post, [v], SURFACE, seed=3)
        assert math.isclose(float(together.mi[i]), float(alone.mi[0]), rel_tol=1e-6, abs_tol=1e-6), i
    # adding or moving the flash changes what the candidate shows: the scores differ from the environment's alone
    mi = together.mi.view(2, 4)
    assert bool((mi[:, 1] != mi[:, 0]).all()) and bool((mi[:, 2] != mi[:, 1]).all())


def test_the_environment_transfer_is_computed_once_per_candidate_not_per_particle(env, monkeypatch):
    calls = []
    real = gbuffer_module.env_transfer.transfer

    def counting(light, *args, **kw):
        calls.append(light)
        return real(light, *args, **kw)

    monkeypatch.setattr(gbuffer_module.env_transfer, "transfer", counting)
    views = [View(c.camera, c.lights + (env,)) for c in
             collocated_views(3, 3.0, camera="rectified", resolution=RES, power=20.0)] + \
        [View.collocated(_camera(40, 10), 20.0)]                          # one candidate without the environment
    counts = []
    for n in (2, 12):
        monkeypatch.setattr(scores_module, "GBUFFERS", GBufferCache())  # a cold cache each time
        calls.clear()
        s = score_views(_posterior(n), views, SURFACE)
        assert bool(torch.isfinite(s.mi).all())
        counts.append(len(calls))
    assert counts == [3, 3]                                               # one per environment-lit candidate
    calls.clear()
    score_views(_posterior(12), views, SURFACE)                           # the same set again: cached, none
    score_views(_posterior(12), views, SURFACE)
    assert len(calls) <= 3


def test_particles_with_their_own_normals_are_refused_in_one_line(env):
    post = _posterior(4)
    tilted = torch.nn.functional.normalize(torch.tensor([0.2, 0.0, 1.0]), dim=0).view(1, 3, 1, 1).expand(4, 3, 1, 1)
    post = SVBRDF(post.albedo, post.roughness, post.specular, tilted.contiguous())
    with pytest.raises(InputError) as e:
        score_views(post, [View(_camera(20, 180), (env,))], SURFACE)
    assert "\n" not in str(e.value) and "environment" in str(e.value)
