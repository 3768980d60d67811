"""Posterior: summaries, MAP, files without pickle, ArviZ, and bb.infer's reproducibility."""
import pytest
import torch

import bayes_brdf as bb
from bayes_brdf.errors import InputError
from bayes_brdf.posterior import Posterior
from bayes_brdf.render import PlanarSample, SVBRDF
from bayes_brdf.render.shade import render


def _obs(res=8, views=4):
    vs = bb.render.collocated_views(views, 3.0, camera="rectified", resolution=res, power=10.0)
    return bb.Observations(vs, render(SVBRDF.constant(0.5, 0.3), vs, PlanarSample(2.0))[0], PlanarSample(2.0))


OBS = _obs()


def test_summaries_match_numpy():
    x = torch.rand(7, 3, 2, 2)
    post = Posterior({"albedo": x}, torch.arange(7.0).flip(0))
    torch.testing.assert_close(post.mean("albedo"), x.mean(0))
    torch.testing.assert_close(post.std("albedo"), torch.tensor(x.numpy().std(0, ddof=1)))
    assert post.best() == 6 and torch.equal(post.map()["albedo"], x[6])
    with pytest.raises(InputError, match="no site 'normal'"):
        post.std("normal")


def test_infer_same_seed_same_result_and_save_load(tmp_path):
    model = bb.models.per_texel(8, albedo="gray")
    a = bb.infer(model, OBS, "spos", steps=60, seed=3, progress=False)
    b = bb.infer(model, OBS, "spos", steps=60, seed=3, progress=False)
    c = bb.infer(model, OBS, "spos", steps=60, seed=4, progress=False)
    assert torch.equal(a.particles["albedo"], b.particles["albedo"])
    assert not torch.equal(a.particles["albedo"], c.particles["albedo"])
    p = a.save(tmp_path / "post.safetensors")
    back = Posterior.load(p)
    assert back.sites == a.sites and torch.equal(back.particles["roughness"], a.particles["roughness"])
    assert torch.equal(back.energies, a.energies) and back.meta["sampler"] == "spos"
    assert back.meta["model"]["model"] == "per_texel"
    # a file is not a pickle: arbitrary code cannot run on load, and junk is a one-line error
    (tmp_path / "junk.safetensors").write_bytes(b"not a posterior")
    with pytest.raises(InputError, match="unreadable posterior file"):
        Posterior.load(tmp_path / "junk.safetensors")


def test_checkpoint_resume_through_infer_is_exact(tmp_path):
    model = bb.models.homogeneous(albedo="gray")
    full = bb.infer(model, OBS, "sgld", steps=50, seed=0, progress=False)
    ck = tmp_path / "ck.pt"

    def stop(t, state, info):
        if t == 20:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        bb.infer(model, OBS, "sgld", steps=50, seed=0, progress=False, checkpoint=ck, callbacks=[stop])
    resumed = bb.infer(model, OBS, "sgld", steps=50, seed=0, progress=False, checkpoint=ck)
    assert torch.equal(full.z, resumed.z)


def test_map_refinement_lowers_the_energy_and_maps():
    model = bb.models.per_texel(8, albedo="gray")
    post = bb.infer(model, OBS, "spos", steps=40, seed=0, progress=False, map_steps=0)
    best = post.map()
    assert all(torch.equal(best[k], post.particles[k][post.best()]) for k in best)
    refined = post.map(refine_steps=100, lr=0.02)
    pot = post.potential
    e0 = pot.energy(pot.to_unconstrained({k: v[None] for k, v in best.items()}), jacobian=False)
    e1 = pot.energy(pot.to_unconstrained({k: v[None] for k, v in refined.items()}), jacobian=False)
    assert float(e1) < float(e0)
    m = post.maps("mean")
    assert m.albedo.shape == (3, 8, 8) and m.roughness.shape == (1, 8, 8)
    assert post.maps("all").albedo.shape == (20, 3, 8, 8)
    with pytest.raises(InputError, match="loaded from a file"):
        Posterior(post.particles, post.energies).map(refine_steps=5)


def test_infer_stores_the_refined_map_and_it_travels_in_the_file(tmp_path):
    import warnings
    model = bb.models.per_texel(8, albedo="gray")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        post = bb.infer(model, OBS, "spos", steps=40, seed=0, progress=False)
    pot = post.potential
    energy = lambda vals: float(pot.energy(pot.to_unconstrained({k: v[None] for k, v in vals.items()}),  # noqa: E731
                                           jacobian=False))
    assert energy(post.map()) < energy(post.map(refine_steps=0))      # Eq. 7: refined, better than the best particle
    m = post.meta["map"]
    assert m["refine_steps"] == 40          # min(300, steps)
    # the optimum reached from the posterior mean is kept unless it is over a nat worse than the best particle's
    assert m["start"] == ("mean" if m["energy_from_mean"] <= m["energy_from_best_particle"] + 1 else "best particle")
    assert energy(post.map()) == pytest.approx(m["energy"], abs=1e-2 * abs(m["energy"]) + 1e-3)
    back = Posterior.load(post.save(tmp_path / "p.safetensors"))
    assert all(torch.equal(back.map()[k], post.map()[k]) for k in post.map())
    assert back.diagnostics == post.diagnostics and "converged" in back.diagnostics


def test_arviz_export():
    post = bb.infer(bb.models.homogeneous(albedo="gray"), OBS, "svgd", steps=20, seed=0, progress=False)
    idata = post.to_arviz()
    assert idata.posterior["albedo"].shape == (1, 20, 1)
    assert idata.sample_stats["energy"].shape == (1, 20)


def test_every_sampler_runs_per_texel_and_homogeneous_from_presets():
    import warnings
    for model in (bb.models.homogeneous(), bb.models.per_texel(8)):
        for name in ("spos", "svgd", "sgld", "emcee", "multistart_sgd", "nuts"):
            kw = {"params": {"warmup_steps": 4, "thin": 1, "max_tree_depth": 3}, "steps": 10} if name == "nuts" \
                else {"steps": 10}
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                post = bb.infer(model, OBS, name, particles=6, seed=0, progress=False, **kw)
            assert torch.isfinite(post.energies).all(), (model, name)


@pytest.mark.needs_cuda
def test_device_follows_the_observations():
    post = bb.infer(bb.models.homogeneous(), OBS.to("cuda"), "spos", steps=20, progress=False)
    assert post.particles["albedo"].device.type == "cuda"
