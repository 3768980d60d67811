"""The sampler contract (samplers/base.py): protocols, a run's numbers in its state, nothing written on a sampler."""
from __future__ import annotations

import inspect
import warnings
from dataclasses import dataclass
from typing import NamedTuple

import pytest
import torch
from torch import Tensor

from bayes_brdf.potential import FunctionPotential
from bayes_brdf.samplers import SAMPLERS, Info, Sampler, run
from bayes_brdf.samplers.base import Potential
from bayes_brdf.samplers.targets import Banana

from .test_driver import N, PARAMS, STEPS, _one_thread  # noqa: F401  (its autouse fixture: one torch thread)

NAMES = list(SAMPLERS)


def _run(sampler, potential=None, **kw):
    kw = {"particles": N, "steps": STEPS, "seed": 3, "progress": False, **kw}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return run(sampler, potential or Banana().potential(), **kw)


@pytest.mark.parametrize("name", NAMES)
def test_registered_samplers_follow_the_protocol(name):
    s = SAMPLERS[name].from_params(PARAMS[name])
    assert isinstance(s, Sampler) and s.name == name
    init = inspect.signature(s.init).parameters
    assert init["steps"].kind is init["groups"].kind is inspect.Parameter.KEYWORD_ONLY
    assert isinstance(Banana().potential(), Potential)


@pytest.mark.parametrize("name", NAMES)
def test_a_run_writes_nothing_onto_the_sampler(name):
    """Two runs of one sampler object, the second inside the first (other particles, horizon, groups): each ends
    where it ends alone, and the sampler's attributes are its hyper-parameters before and after."""
    s = SAMPLERS[name].from_params(PARAMS[name])
    before = dict(vars(s))
    groups = 2 if s.supports_groups else 1
    inner = {"particles": 2 * N, "steps": STEPS + 10, "seed": 5, "groups": groups}
    alone = _run(s, **inner).z
    box = {}

    def nested(t, state, info):
        if t == 10:
            box["z"] = _run(s, **inner).z

    assert torch.equal(_run(s, callbacks=[nested]).z, _run(s).z)
    assert torch.equal(box["z"], alone)
    assert vars(s) == before


def test_the_state_keeps_the_first_horizon_under_max_steps():
    # steps="auto": the run goes on past `steps`, its annealing horizon stays `steps`
    s = SAMPLERS["spos"].from_params(PARAMS["spos"])
    res = _run(s, max_steps=3 * STEPS)
    assert (res.state.num_steps, res.state.groups) == (STEPS, 1)
    if res.steps > STEPS:
        assert not torch.equal(res.z, _run(s, steps=res.steps).z)      # a longer horizon anneals otherwise


# ----------------------------------------------------------------------------- a sampler of one's own
class WalkState(NamedTuple):
    z: Tensor
    energy: Tensor
    accepted: Tensor


@dataclass
class RandomWalk(Sampler):
    """Random-walk Metropolis, one chain per particle: the example of docs/samplers.md."""

    scale: float = 0.5
    name = "random_walk"
    uses_gradients = False

    def params(self) -> dict:
        return {"scale": self.scale}

    def init(self, z0, potential, rng, *, steps, groups=1):
        return WalkState(z0.clone(), potential.energy(z0), torch.zeros(z0.shape[0], dtype=z0.dtype))

    def step(self, state, t, potential, rng):
        z = state.z + self.scale * torch.randn(state.z.shape, generator=rng, dtype=state.z.dtype)
        e = potential.energy(z)
        accept = torch.rand(e.shape, generator=rng, dtype=e.dtype).log() < state.energy - e
        z = torch.where(accept[:, None], z, state.z)
        e = torch.where(accept, e, state.energy)
        return WalkState(z, e, state.accepted + accept), Info(e, {"accepted": float(accept.double().mean())})


def test_a_sampler_of_ones_own_runs_checkpoints_and_resumes(tmp_path):
    s = RandomWalk(scale=0.8)
    assert isinstance(s, Sampler)
    full = _run(s, particles=400, steps=300)
    assert float(full.state.accepted.mean()) > 50
    assert abs(float(full.z[:, 0].var()) - 1) < 0.3                      # the banana's Var x1 = 1

    def stop(t, state, info):
        assert 0 <= info["accepted"] <= 1 and info.energy.shape == (400,)
        if t == 120:
            raise KeyboardInterrupt

    ck = tmp_path / "walk.pt"
    with pytest.raises(KeyboardInterrupt):
        _run(s, particles=400, steps=300, checkpoint=ck, checkpoint_every=50, callbacks=[stop])
    res = _run(s, particles=400, steps=300, checkpoint=ck, checkpoint_every=50)
    assert res.resumed_from == 121 and torch.equal(res.z, full.z)


def test_transient_state_fields_stay_out_of_checkpoints(tmp_path):
    # emcee's EnsembleSampler and NUTS's Pyro kernel ride in the state, not in the checkpoint
    for name, field in (("emcee", "ensemble"), ("nuts", "kernel")):
        s = SAMPLERS[name].from_params(PARAMS[name])
        ck = tmp_path / f"{name}.pt"
        res = _run(s, checkpoint=ck)
        assert field in res.state._fields and field in type(res.state).transient
        saved = torch.load(ck, weights_only=True)["state"]
        assert set(saved) == set(res.state._fields) - {field}


def test_info_reads_as_the_mapping_it_was():
    info = Info(torch.ones(2), {"gamma": 0.3})
    assert info["energy"] is info.energy and info["gamma"] == 0.3 and info.get("step_size", 1) == 1
    assert "gamma" in info and "accepted" not in info and info.keys() == ("energy", "gamma")
    energy, extras = info
    assert extras == {"gamma": 0.3} and Info(None).get("energy") is None
    assert isinstance(FunctionPotential(lambda z: z.sum(1), 2), Potential)
