"""A user's own model and priors (examples/custom_model.py, plain Python outside the package) with every sampler."""
import importlib.util
import warnings
from pathlib import Path

import pytest
import torch

import bayes_brdf as bb

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "custom_model.py"


def _example():
    spec = importlib.util.spec_from_file_location("custom_model", EXAMPLE)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


EX = _example()
OBS = EX.synthetic_observations()
SHORT = {"spos": 40, "svgd": 40, "sgld": 40, "emcee": 40, "multistart_sgd": 40, "nuts": 30}


@pytest.mark.parametrize("sampler", list(SHORT))
def test_user_model_runs_with_every_sampler(sampler):
    params = {"warmup_steps": 10, "thin": 1, "max_tree_depth": 4} if sampler == "nuts" else None
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        post = bb.infer(EX.my_model, OBS, sampler, steps=SHORT[sampler], particles=8, params=params, seed=1,
                        progress=False)
    assert set(post.sites) == {"brightness", "tint", "roughness"}
    assert post.particles["tint"].shape == (8, 3)
    torch.testing.assert_close(post.particles["tint"].sum(-1), torch.ones(8), atol=1e-5, rtol=0)  # on the simplex
    assert torch.isfinite(post.energies).all()
    assert post.meta["model"] == "my_model"


def test_user_model_posterior_finds_the_truth():
    post = bb.infer(EX.my_model, OBS, "spos", steps=300, seed=0, progress=False)
    albedo = 3 * post.particles["brightness"][:, None] * post.particles["tint"]
    truth = torch.tensor([0.6, 0.45, 0.3])
    assert (albedo.mean(0) - truth).abs().max() < 0.05
    assert abs(float(post.mean("roughness")) - 0.35) < 0.08
