"""The sampler driver: exact checkpoint/resume, seeds, divergence, stale checkpoints, parameter errors."""
from __future__ import annotations

import re
import warnings

import pytest
import torch

from bayes_brdf.errors import InputError
from bayes_brdf.potential import FunctionPotential
from bayes_brdf.samplers import SAMPLERS, Info, Sampler, SamplerDiverged, make_sampler, run
from bayes_brdf.samplers.targets import Banana

# Small explicit settings: every sampler takes a few real steps on the banana in well under a second. One row per
# sampler of the registry (test_every_registered_sampler_has_settings): the tests below run over SAMPLERS.
PARAMS = {
    "spos": {"step_size": 0.05, "beta": 1.0, "anneal": True, "anneal_fraction": 0.5, "preconditioner": "adam"},
    "svgd": {"step_size": 0.05, "optimizer": "adam"},
    "sgld": {"step_size": 0.01, "preconditioner": "rmsprop", "schedule_gamma": 0.3},
    "emcee": {"stretch_a": 2.0},
    "multistart_sgd": {"step_size": 0.05, "optimizer": "adam"},
    "nuts": {"warmup_steps": 10, "thin": 1, "step_size": 0.1, "max_tree_depth": 4},
}
NAMES = list(SAMPLERS)
RESUMABLE = [k for k in NAMES if SAMPLERS[k].exact_resume]
N, STEPS = 8, 40


@pytest.fixture(autouse=True)
def _one_thread():
    # tiny tensors: thread start-up costs more than it saves (and a loaded machine makes it far worse)
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


def _sampler(name):
    return SAMPLERS[name].from_params(PARAMS[name])


def _run(name, potential=None, **kw):
    kw = {"particles": N, "steps": STEPS, "seed": 3, "progress": False, **kw}
    return run(_sampler(name), potential or Banana().potential(), **kw)


def _interrupt_at(step):
    def cb(t, state, info):
        if t == step:
            raise KeyboardInterrupt
    return cb


def test_resumable_list():
    assert RESUMABLE == ["spos", "svgd", "sgld", "emcee", "multistart_sgd"]


def test_every_registered_sampler_has_settings():
    assert list(PARAMS) == NAMES      # a sampler added to SAMPLERS needs a row here (and cases in test_known_answers)


# ----------------------------------------------------------------------------- checkpoint + resume
@pytest.mark.parametrize("name", RESUMABLE)
def test_resume_after_interrupt_inside_a_step_is_exact(name, tmp_path):
    """Ctrl-C while the potential is being evaluated (where a real Ctrl-C lands) resumes bitwise exactly."""
    full = _run(name, checkpoint=tmp_path / "full.pt", checkpoint_every=10)
    banana = Banana()
    armed = {"on": False}

    def energy(z):
        if armed["on"]:
            raise KeyboardInterrupt
        return banana.energy(z)

    def arm(t, state, info):
        if t == 24:          # the next evaluation is inside step 25
            armed["on"] = True

    ck = tmp_path / "cut.pt"
    with pytest.raises(KeyboardInterrupt):
        _run(name, FunctionPotential(energy, 2), checkpoint=ck, checkpoint_every=10, callbacks=[arm])
    assert torch.load(ck, weights_only=True)["t"] == 25
    res = _run(name, checkpoint=ck, checkpoint_every=10)
    assert res.resumed_from == 25
    assert torch.equal(res.z, full.z)
    assert not torch.equal(res.z, _run(name, seed=4).z)      # the comparison can fail


class _CountingBanana(FunctionPotential):
    """The banana, whose evaluation counter raises KeyboardInterrupt when read after step ``cut`` (a Ctrl-C landing
    in the driver's bookkeeping between steps, after the step's particles exist)."""

    def __init__(self, cut=None):
        super().__init__(Banana().energy, 2)
        self.cut, self.t = cut, -1

    def energy(self, z, *, jacobian=True):
        self._n += z.shape[0]
        return self.fn(z)

    @property
    def evaluations(self):
        if self.t == self.cut:
            self.cut = None
            raise KeyboardInterrupt
        return self._n

    @evaluations.setter
    def evaluations(self, n):
        self._n = n


@pytest.mark.parametrize("name", RESUMABLE)
def test_a_ctrl_c_between_steps_keeps_the_evaluation_count(name, tmp_path):
    """Ctrl-C while the driver records step 25 (after its particles were made): the resumed run reports the same
    particles and the same number of evaluations as an uninterrupted one (CI once saw one step's worth missing)."""
    full = _run(name, _CountingBanana(), checkpoint=tmp_path / "full.pt", checkpoint_every=10)
    pot = _CountingBanana(cut=25)

    def clock(t, state, info):
        pot.t = t + 1            # the counter is read after step t + 1's particles are made

    ck = tmp_path / "cut.pt"
    with pytest.raises(KeyboardInterrupt):
        _run(name, pot, checkpoint=ck, checkpoint_every=10, callbacks=[clock])
    assert torch.load(ck, weights_only=True)["t"] == 25       # step 25 not committed: it is redone
    res = _run(name, _CountingBanana(), checkpoint=ck, checkpoint_every=10)
    assert res.resumed_from == 25 and torch.equal(res.z, full.z)
    assert res.evaluations == full.evaluations > 0


@pytest.mark.parametrize("name", RESUMABLE)
def test_resume_after_interrupt_in_callback_is_exact(name, tmp_path):
    """Ctrl-C after step 25 was taken (in a callback) resumes after it, bitwise exactly."""
    full = _run(name, checkpoint=tmp_path / "full.pt", checkpoint_every=10)
    ck = tmp_path / "cut.pt"
    with pytest.raises(KeyboardInterrupt):
        _run(name, checkpoint=ck, checkpoint_every=10, callbacks=[_interrupt_at(25)])
    res = _run(name, checkpoint=ck, checkpoint_every=10)
    assert res.resumed_from == 26           # step 25 was committed before the callbacks ran
    assert torch.equal(res.z, full.z)
    assert torch.equal(res.energy_trace, full.energy_trace)


@pytest.mark.parametrize("name", RESUMABLE)
def test_resume_from_periodic_checkpoint_is_exact(name, tmp_path):
    """A run killed hard (no Ctrl-C handler: only the checkpoint of step 20 exists) resumes exactly."""
    full = _run(name)
    ck = tmp_path / "ck.pt"
    saved = {}

    def kill(t, state, info):
        if t == 25:
            saved["ck"] = ck.read_bytes()     # what a SIGKILL at step 25 would leave behind
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        _run(name, checkpoint=ck, checkpoint_every=10, callbacks=[kill])
    ck.write_bytes(saved["ck"])
    assert torch.load(ck, weights_only=True)["t"] == 20
    res = _run(name, checkpoint=ck, checkpoint_every=10)
    assert res.resumed_from == 20
    assert torch.equal(res.z, full.z)


def test_finished_checkpoint_returns_the_result(tmp_path):
    ck = tmp_path / "ck.pt"
    a = _run("sgld", checkpoint=ck, checkpoint_every=0)
    b = _run("sgld", checkpoint=ck, checkpoint_every=0)
    assert b.resumed_from == STEPS and torch.equal(a.z, b.z)
    assert torch.equal(a.energy_trace, b.energy_trace)


def test_nuts_replays_instead_of_resuming(tmp_path):
    full = _run("nuts")
    ck = tmp_path / "ck.pt"
    with pytest.raises(KeyboardInterrupt):
        _run("nuts", checkpoint=ck, checkpoint_every=10, callbacks=[_interrupt_at(25)])
    res = _run("nuts", checkpoint=ck, checkpoint_every=10)
    assert res.resumed_from == 0
    assert torch.equal(res.z, full.z)


# ----------------------------------------------------------------------------- seeds
@pytest.mark.parametrize("name", NAMES)
def test_same_seed_same_result(name):
    a, b, c = _run(name, seed=7), _run(name, seed=7), _run(name, seed=8)
    assert torch.equal(a.z, b.z)
    assert torch.equal(a.energy_trace, b.energy_trace)
    assert not torch.equal(a.z, c.z)


# ----------------------------------------------------------------------------- divergence
def _nan_everywhere(z):
    return (z * float("nan")).sum(1)


def _nan_outside(z):
    return torch.where(z.abs().amax(1) > 3.0, torch.full_like(z[:, 0], float("nan")), 0.5 * (z * z).sum(1))


@pytest.mark.parametrize("name", NAMES)
def test_nan_potential_raises_sampler_diverged(name):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with pytest.raises(SamplerDiverged) as e:
            _run(name, FunctionPotential(_nan_everywhere, 2))
    assert isinstance(e.value, InputError)
    assert "\n" not in str(e.value)
    assert re.search(r"diverged at step 0|energy is NaN at \d+ of \d+ starting points", str(e.value))


@pytest.mark.parametrize("name, params", [
    ("spos", {"step_size": 3.0, "beta": 1.0, "anneal": False, "preconditioner": "none"}),
    ("sgld", {"step_size": 3.0, "preconditioner": "none"}),
    ("multistart_sgd", {"step_size": 3.0, "optimizer": "sgd"}),
])
def test_nan_met_later_raises_sampler_diverged(name, params):
    # a standard normal that is NaN beyond |z| = 3, with a step (z <- z - 3 z + ...) that throws particles out there
    pot = FunctionPotential(_nan_outside, 2, init_std=0.1)
    with pytest.raises(SamplerDiverged) as e:
        run(SAMPLERS[name].from_params(params), pot, particles=N, steps=STEPS, seed=3, progress=False)
    assert "\n" not in str(e.value) and "step_size" in str(e.value)


def test_huge_step_raises_sampler_diverged():
    # plain Langevin on the banana with a step 500 times too large: the particles overflow
    with pytest.raises(SamplerDiverged, match=r"sgld diverged at step \d+: \d+ of 8 particles are not finite"):
        run(SAMPLERS["sgld"].from_params({"step_size": 5.0, "preconditioner": "none"}), Banana().potential(),
            particles=N, steps=STEPS, seed=0, progress=False, checkpoint_every=0)


# ----------------------------------------------------------------------------- stale / bad checkpoints
@pytest.mark.parametrize("change", [{"seed": 4}, {"steps": 30}, {"particles": 6}])
def test_checkpoint_from_other_run_is_rejected(change, tmp_path):
    ck = tmp_path / "ck.pt"
    _run("sgld", checkpoint=ck, steps=20)
    kw = {"steps": 20, **change}
    with pytest.raises(InputError, match="written by another run") as e:
        _run("sgld", checkpoint=ck, **kw)
    assert "\n" not in str(e.value) and str(ck) in str(e.value) and f"differs in {next(iter(change))}" in str(e.value)


def test_checkpoint_from_other_params_is_rejected(tmp_path):
    ck = tmp_path / "ck.pt"
    _run("sgld", checkpoint=ck, steps=20)
    s = SAMPLERS["sgld"].from_params({**PARAMS["sgld"], "step_size": 0.02})
    with pytest.raises(InputError, match="written by another run"):
        run(s, Banana().potential(), particles=N, steps=20, seed=3, progress=False, checkpoint=ck)
    with pytest.raises(InputError, match="written by another run"):   # another sampler on the same path
        _run("spos", checkpoint=ck, steps=20)


def test_garbage_checkpoint_is_rejected(tmp_path):
    ck = tmp_path / "ck.pt"
    ck.write_bytes(b"not a checkpoint")
    with pytest.raises(InputError, match="unreadable checkpoint") as e:
        _run("sgld", checkpoint=ck)
    assert "\n" not in str(e.value)
    torch.save({"format": "something else"}, ck)
    with pytest.raises(InputError, match="not a bayes-brdf checkpoint"):
        _run("sgld", checkpoint=ck)


# ----------------------------------------------------------------------------- make_sampler errors
@pytest.mark.parametrize("name, params, match", [
    ("spos", {"stepsize": 0.1}, "unknown spos parameter"),
    ("svgd", {"step_size": 0.1, "temperature": 2}, r"unknown svgd parameter\(s\) \['temperature'\]"),
    ("spos", {"step_size": -0.1}, "step_size must be a positive number"),
    ("spos", {"step_size": float("nan")}, "step_size must be a positive number"),
    ("spos", {"step_size": "0.1"}, "step_size must be a number"),
    ("spos", {"step_size": True}, "step_size must be a number"),
    ("spos", {"beta": 0}, "beta must be a positive number"),
    ("spos", {"beta": "hot"}, "beta must be a positive number"),
    ("spos", {"preconditioner": "lbfgs"}, "preconditioner must be one of"),
    ("spos", {"anneal": 1}, "anneal must be true or false"),
    ("spos", {"adam_beta2": 1.0}, "adam_beta2 must be in"),
    ("sgld", {"schedule_gamma": 2.0}, "schedule_gamma must be in"),
    ("sgld", {"preconditioner": "adam"}, "preconditioner must be one of"),
    ("svgd", {"optimizer": "lbfgs"}, "optimizer must be one of"),
    ("emcee", {"stretch_a": 1.0}, "stretch_a must be > 1"),
    ("multistart_sgd", {"step_size": 0}, "step_size must be a positive number"),
    ("nuts", {"target_accept": 1.5}, "target_accept must be in"),
    ("nuts", {"warmup_steps": -1}, "warmup_steps must be >= 0"),
    ("nuts", {"warmup_steps": 10.5}, "warmup_steps must be an integer"),
    ("nuts", {"thin": 0}, "thin must be a positive number"),
])
def test_make_sampler_rejects_bad_params(name, params, match):
    with pytest.raises(InputError, match=match) as e:
        make_sampler(name, params=params)
    assert "\n" not in str(e.value)


@pytest.mark.parametrize("name, params", [
    ("sgld", {"rms_beta2": 1.5}),
    ("sgld", {"rms_beta2": 1.0}),
    ("svgd", {"adam_beta1": 1.0}),
    ("svgd", {"adam_beta2": 1.0}),
    ("svgd", {"anneal_fraction": 2.0}),
    ("multistart_sgd", {"adam_beta2": 2.0}),
])
def test_make_sampler_rejects_out_of_range_rates(name, params):
    with pytest.raises(InputError):
        make_sampler(name, params=params)


@pytest.mark.parametrize("spec, run_cfg, match", [
    ("no_such_sampler", None, "no sampler preset 'no_such_sampler'"),
    ({"sampler": "gibbs"}, None, "unknown sampler 'gibbs'"),
    ({"sampler": "sgld", "parms": {}}, None, r"unknown key\(s\) \['parms'\]"),
    ("sgld", {"particle": 10}, r"unknown key\(s\) \['particle'\] in \[run\]"),
    ("sgld", {"particles": 0}, "run.particles must be a positive integer"),
    ("sgld", {"steps": 2.5}, "run.steps must be a positive integer"),
    ("sgld", {"minibatch_pixels": 1.5}, r"run.minibatch_pixels must be in \(0, 1\]"),
])
def test_make_sampler_rejects_bad_specs(spec, run_cfg, match):
    with pytest.raises(InputError, match=match) as e:
        make_sampler(spec, run=run_cfg)
    assert "\n" not in str(e.value)


def test_make_sampler_accepts_good_params():
    s, cfg = make_sampler("spos", params={"step_size": 1, "beta": 1}, run={"particles": 50})
    assert s.step_size == 1.0 and isinstance(s.step_size, float) and s.beta == 1 and cfg.particles == 50
    assert make_sampler("nuts", params={"warmup_steps": 5})[0].warmup_steps == 5


@pytest.mark.parametrize("kw, match", [
    ({"steps": 0}, "steps must be a positive integer"),
    ({"particles": 0}, "particles must be a positive integer"),
    ({"z0": torch.zeros(3, 2, dtype=torch.float64)}, r"initial particles have shape \(3, 2\), expected \(8, 2\)"),
])
def test_run_rejects_bad_arguments(kw, match):
    with pytest.raises(InputError, match=match):
        _run("sgld", **kw)


def test_emcee_rejects_odd_walkers():
    with pytest.raises(InputError, match="even number of walkers"):
        _run("emcee", particles=7)


def test_divergence_check_reads_each_element_not_only_the_sum():
    # the driver's per-step check sums the particles first; finite particles whose sum overflows are still finite
    from bayes_brdf.samplers.driver import _all_finite
    z = torch.ones(4, 3)
    assert _all_finite(z)
    for bad in (float("nan"), float("inf"), float("-inf")):
        zb = z.clone()
        zb[2, 1] = bad
        assert not _all_finite(zb)
    assert _all_finite(torch.full((4, 3), 3e38))
    assert not bool(torch.isfinite(torch.full((4, 3), 3e38).sum()))
