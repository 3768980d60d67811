"""Every registered sampler runs the per-texel model under a known environment light (through ``bb.infer``,
the precomputed transfer in the potential), and the default recovers a material lit by the environment alone."""
import warnings

import pytest
import torch

import bayes_brdf as bb
from bayes_brdf.render import PlanarSample, SVBRDF
from bayes_brdf.render.environment import studio
from bayes_brdf.render.shade import render
from bayes_brdf.render.views import View
from bayes_brdf.samplers import SAMPLERS


def _obs(flash: bool, res=8, n=5):
    env = studio(azimuth_deg=180.0)
    vs = bb.render.collocated_views(n, 3.0, camera="rectified", resolution=res, power=10.0)
    vs = [View(v.camera, (*v.lights, env) if flash else (env,), v.name) for v in vs]
    truth = SVBRDF.constant(0.5, 0.3)
    return bb.Observations(vs, render(truth, vs, PlanarSample(2.0))[0], PlanarSample(2.0))


ENV, BOTH = _obs(False), _obs(True)


@pytest.mark.parametrize("name", list(SAMPLERS))
def test_every_sampler_runs_the_per_texel_model_under_an_environment(name):
    model = bb.models.per_texel(8, albedo="gray")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")                      # 30 steps do not converge; that is not the point
        params = {"warmup_steps": 10, "thin": 2} if name == "nuts" else None
        post = bb.infer(model, BOTH, name, steps=30, particles=4, seed=1, progress=False, map_steps=0, params=params)
    for site in ("albedo", "roughness"):
        x = post.particles[site]
        assert x.shape[0] == 4 and torch.isfinite(x).all(), (name, site)
    assert torch.isfinite(post.energies).all()


def test_default_spos_recovers_a_material_lit_by_the_environment_alone():
    model = bb.models.per_texel(8, albedo="gray")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        post = bb.infer(model, ENV, "spos", steps=200, seed=0, progress=False)
    albedo, rough = post.mean("albedo"), post.mean("roughness")
    assert float((albedo - 0.5).abs().median()) < 0.05, albedo
    assert float((rough - 0.3).abs().median()) < 0.1, rough
