"""A posterior on a mesh: per-texel maps of a sphere seen from above, sampled, saved and used downstream."""
import warnings

import pytest
import torch

import bayes_brdf as bb
from bayes_brdf.render import SVBRDF, collocated_views
from bayes_brdf.render.gbuffer import GBUFFERS
from bayes_brdf.render.mesh import Mesh
from bayes_brdf.render.shade import render
from bayes_brdf.uncertainty import image_std

pytestmark = pytest.mark.needs_llvm

R = 16


@pytest.fixture(scope="module")
def fitted():
    mesh = Mesh.sphere(1.0, rings=32, segments=64)
    views = collocated_views(8, 3.5, resolution=32, max_zenith=60, power=12.0)     # the upper half only
    g = torch.Generator().manual_seed(0)
    truth = SVBRDF(torch.rand(3, R, R, generator=g) * 0.6 + 0.2, torch.rand(1, R, R, generator=g) * 0.5 + 0.2,
                   torch.full((3, 1, 1), 0.04), torch.tensor([0, 0, 1.0]).view(3, 1, 1))
    obs = bb.Observations(views, render(truth, views, mesh)[0], mesh)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        post = bb.infer(bb.models.per_texel(resolution=R), obs, "spos", steps=200, particles=8, progress=False)
    seen = torch.zeros(R * R, dtype=torch.bool)
    idx = GBUFFERS.get(tuple(views), mesh).texel_index(R)
    seen[idx[idx >= 0]] = True
    return mesh, views, truth, post, seen.reshape(R, R)


def test_texels_no_view_sees_keep_the_prior(fitted):
    mesh, views, truth, post, seen = fitted
    sd = post.std("albedo").mean(0)
    assert 40 < int(seen.sum()) < R * R - 40
    prior_sd = 12 ** -0.5                                     # uniform prior on [0, 1]
    assert float(sd[~seen].mean()) > 0.8 * prior_sd           # unseen: about the prior's spread (8 particles)
    assert float(sd[seen].mean()) < 0.4 * prior_sd            # seen: pinned down by the photos
    err = (post.mean("albedo") - truth.albedo).abs().mean(0)
    assert float(err[seen].median()) < 0.1


def test_mesh_posterior_file_keeps_the_mesh_and_predicts_novel_views(fitted, tmp_path):
    mesh, views, truth, post, seen = fitted
    back = bb.Posterior.load(post.save(tmp_path / "post.safetensors"))
    assert back.surface == mesh and back.surface.num_faces == mesh.num_faces
    novel = collocated_views(2, 3.5, resolution=24, method="sobol", seed=3, power=12.0)
    std = image_std(back, novel)                              # Eq. 11 on novel views, surface from the file
    assert std.shape == (2, 24, 24, 3) and bool((std >= 0).all()) and float(std.max()) > 0


@pytest.fixture(scope="module")
def bowl_obs():
    mesh = Mesh.bowl(rings=12, segments=32)
    views = collocated_views(5, 3.0, resolution=24, target=mesh.center, power=10.0, method="sobol")
    truth = SVBRDF.constant(albedo=0.45, roughness=0.35, specular=0.04)
    return bb.Observations(views, render(truth, views, mesh)[0], mesh)


@pytest.mark.parametrize("sampler", sorted(bb.samplers.SAMPLERS))
def test_every_sampler_runs_on_a_mesh(sampler, bowl_obs):
    """The homogeneous model on a bowl (shadowed inside): every sampler of the registry gives finite
    particles near the truth with the shadows in its likelihood."""
    steps, params = 150, None
    if sampler == "nuts":                      # one chain: warm-up, then one draw per particle
        steps, params = 60, {"warmup_steps": 40, "thin": 1, "max_tree_depth": 4}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        post = bb.infer(bb.models.homogeneous(albedo="gray"), bowl_obs, sampler, steps=steps, particles=8,
                        params=params, progress=False)
    assert post.surface == bowl_obs.surface
    for k, v in post.particles.items():
        assert bool(torch.isfinite(v).all()), k
    assert abs(float(post.map()["roughness"].flatten()[0]) - 0.35) < 0.1
