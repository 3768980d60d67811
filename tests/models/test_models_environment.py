"""Every built-in model under a known environment light (issue 24, part 5): homogeneous, per_texel and
latent_decoder build, have a finite potential and gradient and fit on environment-lit photos (the environment
alone, and with the flash), on the plane and on a mesh; the likelihood renders through the precomputed transfer;
a homogeneous material under studio() is recovered inside its 90 % interval; Eq. 9 and Eq. 11 are finite under an
environment, Eq. 11 equals the per-particle loop and its closed form under a white sky, and the predictive is
calibrated when the photos come from it."""
import math
import warnings

import pytest
import torch

import bayes_brdf as bb
from bayes_brdf.errors import InputError
from bayes_brdf.models import ModelData
from bayes_brdf.posterior import Posterior
from bayes_brdf.potential import Potential
from bayes_brdf.render import SVBRDF, PlanarSample, collocated_views
from bayes_brdf.render.gbuffer import GBuffer
from bayes_brdf.render.environment import EnvironmentLight, studio
from bayes_brdf.render.mesh import Mesh
from bayes_brdf.render.shade import render
from bayes_brdf.render.views import View
from bayes_brdf.uncertainty import coverage, image_std, predictive_cdf

PLANE = PlanarSample(2.0)
ENV = studio(16)
TRUTH = SVBRDF.constant(albedo=(0.6, 0.4, 0.25), roughness=0.3, specular=0.04)
LIGHTING = ["environment", "environment+flash"]
SURFACES = ["plane", pytest.param("mesh", marks=pytest.mark.needs_llvm)]


def _surface(name):
    return PLANE if name == "plane" else Mesh.sphere(1.0, rings=16, segments=32)


def _views(surface, lighting, n=4, res=16, env=ENV, camera=None, seed=1):
    kw = {"camera": camera} if camera else {}
    vs = collocated_views(n, 3.0, resolution=res, power=10.0, max_zenith=50, method="sobol", seed=seed, **kw)
    return [View(v.camera, (v.lights if lighting == "environment+flash" else ()) + (env,)) for v in vs]


def _obs(surface, lighting, truth=TRUTH, noise=0.005, **kw):
    vs = _views(surface, lighting, **kw)
    img = render(truth, vs, surface)[0]
    img = img + noise * torch.randn(img.shape, generator=torch.Generator().manual_seed(0))
    return bb.Observations(vs, img, surface)


def _models():
    return {"homogeneous": bb.models.homogeneous(),
            "per_texel": bb.models.per_texel(8),
            "latent_decoder": bb.models.latent_decoder(project_steps=5, noise="zero", normals="flat")}


def _fit(model, obs, steps, particles, seed=0):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return bb.infer(model, obs, "spos", steps=steps, particles=particles, progress=False, seed=seed)


@pytest.mark.parametrize("surface", SURFACES)
@pytest.mark.parametrize("lighting", LIGHTING)
def test_every_model_builds_with_a_finite_potential_and_gradient(surface, lighting):
    surf = _surface(surface)
    obs = _obs(surf, lighting)
    data = ModelData.from_observations(obs)
    assert data.gbuffer.env is not None                                    # the transfer was precomputed
    for name, m in _models().items():
        pot = Potential(m, (data,))
        e, g = pot.value_and_grad(pot.init(3, seed=0))
        assert e.shape == (3,) and bool(torch.isfinite(e).all()), name
        assert bool(torch.isfinite(g).all()) and float(g.abs().max()) > 0, name


@pytest.mark.parametrize("surface", SURFACES)
def test_the_likelihood_renders_the_environment_through_the_transfer(surface):
    """The photos are the latent decoder's own render of one particle under the environment: its energy there is
    the Laplace likelihood at zero residual, N log(2 sigma), exactly; the same photos seen without the environment
    are far from it."""
    surf = _surface(surface)
    m = bb.models.latent_decoder(project_steps=5, noise="zero", normals="flat", sigma=0.01)
    vs = _views(surf, "environment+flash", n=3)
    start = m.starts(torch.zeros(1))
    maps = m.maps(start)
    assert torch.equal(maps.normal, torch.tensor([0.0, 0.0, 1.0]).view(3, 1, 1))     # flat, fixed: no particle dim
    img = render(SVBRDF(maps.albedo[0], maps.roughness[0], maps.specular[0], maps.normal), vs, surf)[0]
    data = ModelData.from_observations(bb.Observations(vs, img, surf))
    pot = Potential(m, (data,))
    z = pot.to_unconstrained(start)
    e = float(pot.energy(z, jacobian=False)[0])
    n = 3 * float(data.weight.sum())
    assert e == pytest.approx(n * math.log(2 * 0.01), abs=2e-3 * n)
    flash_only = [View(v.camera, v.point_lights) for v in vs]
    other = Potential(m, (ModelData.from_observations(bb.Observations(flash_only, img, surf)),))
    assert float(other.energy(z, jacobian=False)[0]) > e + 10 * n        # residuals of order 0.1 per value
    # decoded normals vary per particle: refused under the environment in one line that says what to do
    decoded = bb.models.latent_decoder(project_steps=5, noise="zero", sigma=0.01)
    with pytest.raises(InputError, match="normals='flat'"):
        Potential(decoded, (data,)).energy(z)
    with pytest.raises(InputError, match="normals must be one of decoded, flat"):
        bb.models.latent_decoder(normals="infer")
    assert "normals" not in decoded.to_dict() and m.to_dict()["normals"] == "flat"


@pytest.mark.parametrize("surface", SURFACES)
@pytest.mark.parametrize("lighting", LIGHTING)
def test_every_model_fits_under_the_environment(surface, lighting):
    """A short SPOS run of each model lowers its energy well below the start and Eq. 9 (map-space std) is finite;
    per_texel's mean albedo is close to the truth where the views see the sample."""
    surf = _surface(surface)
    obs = _obs(surf, lighting)
    for name, m in _models().items():
        post = _fit(m, obs, 60, 4)
        data = ModelData.from_observations(obs)
        pot = Potential(m, (data,))
        e0 = float(pot.energy(pot.init(4, seed=0) if name != "latent_decoder"
                              else pot.to_unconstrained(m.starts(data.images, 4))).min())
        assert float(post.energies.min()) < e0 - 0.1 * abs(e0), (name, float(post.energies.min()), e0)
        sd = post.std()
        assert sd and all(bool(torch.isfinite(v).all()) for v in sd.values()), name
        assert ("normal" in sd) is False, name                             # flat normals carry no uncertainty
        mean = post.maps("mean")
        assert bool(torch.isfinite(mean.albedo).all()) and bool(torch.isfinite(mean.roughness).all())
        if name == "per_texel" and surface == "plane":
            err = (mean.albedo - TRUTH.albedo).abs()
            assert float(err.median()) < 0.1, float(err.median())


@pytest.mark.parametrize("lighting", LIGHTING)
def test_a_homogeneous_material_under_studio_is_recovered_inside_its_90_percent_interval(lighting):
    """Known answer: a constant material photographed under studio() (alone, or with the flash), 5 views of 16²,
    Gaussian noise 0.01; the homogeneous model's 90 % interval holds every true parameter and is narrow."""
    obs = _obs(PLANE, lighting, noise=0.01, n=5, env=studio())
    post = _fit(bb.models.homogeneous(), obs, 300, 16)
    truth = {"albedo": torch.tensor([0.6, 0.4, 0.25]), "roughness": torch.tensor([0.3])}
    for k, t in truth.items():
        p = post.particles[k].double()
        lo, hi = torch.quantile(p, 0.05, 0), torch.quantile(p, 0.95, 0)
        assert bool(((t >= lo) & (t <= hi)).all()), (k, lo.tolist(), hi.tolist())
        assert float((hi - lo).max()) < 0.05, (k, lo.tolist(), hi.tolist())


# ------------------------------------------------------------------ Eq. 9 and Eq. 11 under an environment
def _homogeneous_post(n=8, seed=0, rough=None, sigma=0.02):
    g = torch.Generator().manual_seed(seed)
    r = torch.full((n, 1), 0.3) if rough is None else torch.rand(n, 1, generator=g) * 0.5 + 0.2
    return Posterior({"albedo": torch.rand(n, 3, generator=g) * 0.6 + 0.2, "roughness": r}, torch.zeros(n),
                     model=bb.models.homogeneous(sigma=sigma), meta={"surface": {"size": 2.0, "grid": "centers"}})


def test_eq11_under_a_white_sky_is_its_closed_form():
    """Under a white sky of radiance 1 a plane receives E = pi, so a pixel's radiance is kd (1 - ks) + (a lobe term
    that is the same for every particle at a fixed roughness): Eq. 11 is std(kd) (1 - ks), the same at every pixel."""
    sky = EnvironmentLight(torch.ones(16, 32, 3))
    post = _homogeneous_post()
    views = _views(PLANE, "environment", n=2, res=8, env=sky)
    std = image_std(post, views, PLANE)
    want = post.particles["albedo"].double().std(0) * (1 - 0.04)
    on = GBuffer.build(views, PLANE).mask
    assert std.shape == (2, 8, 8, 3) and bool(torch.isfinite(std).all()) and int(on.sum()) > 60
    torch.testing.assert_close(std[on].double(), want.expand(int(on.sum()), 3), rtol=5e-3, atol=0)
    assert bool((std[~on] == 0).all())
    assert float(post.std()["albedo"].sub(post.particles["albedo"].std(0)).abs().max()) == 0     # Eq. 9


@pytest.mark.parametrize("surface,camera", [("plane", "rectified"), ("plane", "perspective"),
                                            pytest.param("mesh", "perspective", marks=pytest.mark.needs_llvm)])
def test_eq11_under_an_environment_equals_the_per_particle_loop(surface, camera):
    surf = _surface(surface)
    post = _homogeneous_post(6, seed=1, rough=True)
    views = _views(surf, "environment+flash", n=2, res=12, camera=camera)
    ref = torch.stack([render(post.maps(i), views, surf)[0] for i in range(6)])
    std, mean = image_std(post, views, surf, return_mean=True)
    assert bool(torch.isfinite(std).all()) and float(std.max()) > 0
    torch.testing.assert_close(std, ref.std(0), rtol=1e-4, atol=1e-6)
    torch.testing.assert_close(mean, ref.mean(0), rtol=1e-4, atol=1e-6)


def test_the_predictive_under_an_environment_is_calibrated_when_the_photos_come_from_it():
    n, sigma = 8, 0.02
    post = _homogeneous_post(n, seed=3, rough=True, sigma=sigma)
    post.meta["noise_sigma"] = sigma
    views = _views(PLANE, "environment", n=4, res=16, camera="rectified")
    ren = torch.stack([render(post.maps(i), views, PLANE)[0] for i in range(n)]).double()
    g = torch.Generator().manual_seed(7)
    base = ren.gather(0, torch.randint(n, ren.shape[1:], generator=g)[None])[0]
    lap = (torch.empty(base.shape, dtype=torch.float64).exponential_(generator=g)
           - torch.empty(base.shape, dtype=torch.float64).exponential_(generator=g))
    y = base + sigma * lap
    F, std, _ = predictive_cdf(post, views, y, PLANE, sigma=sigma)
    assert bool(torch.isfinite(F).all()) and float(std.mean()) > sigma           # the particles' spread matters
    N = F.numel()
    cov = coverage(F)
    assert cov["50"] == pytest.approx(0.5, abs=4 * math.sqrt(0.25 / N))
    assert cov["90"] == pytest.approx(0.9, abs=4 * math.sqrt(0.09 / N))
