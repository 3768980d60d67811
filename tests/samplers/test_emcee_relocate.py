"""emcee's walkers left behind in a far local mode: a stretch move never brings them back, the burn-in
relocation does, and what is left after the burn-in is a plain emcee chain on the right posterior."""
import warnings

import pytest
import torch

from bayes_brdf.errors import InputError
from bayes_brdf.potential import FunctionPotential
from bayes_brdf.samplers import make_sampler, run

SD = 0.01


def _two_wells():
    """A narrow 2-D Gaussian (sd 0.01) at 0 and a local one at (3, 3), 40 nats higher."""
    def u(z):
        main = 0.5 * ((z / SD) ** 2).sum(1)
        local = 0.5 * (((z - 3.0) / SD) ** 2).sum(1) + 40.0
        return -torch.logaddexp(-main, -local)
    return FunctionPotential(u, dim=2)


def _start():
    g = torch.Generator().manual_seed(0)
    z = SD * torch.randn(20, 2, generator=g, dtype=torch.float64)
    z[:3] += 3.0                          # three walkers start in the local mode
    return z


def _run(**params):
    smp, cfg = make_sampler("emcee", params=params)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return run(smp, _two_wells(), particles=20, steps=600, seed=1, z0=_start(), progress=False)


def test_walkers_in_a_far_local_mode_stay_there_without_relocation():
    res = _run(relocate=0.0)
    assert int((res.z[:, 0] > 1.5).sum()) == 3
    assert res.state.relocated == 0
    assert "behind" in res.diagnostics.failed


def test_the_burn_in_relocates_them_and_the_rest_is_the_posterior():
    res = _run()
    assert res.state.relocated >= 3
    assert int((res.z[:, 0] > 1.5).sum()) == 0
    assert res.diagnostics.converged, res.diagnostics.failed
    # the walkers are draws of the main well: mean 0 and sd 0.01 per coordinate, within 20 walkers' noise
    assert float(res.z.mean(0).abs().max()) < 4 * SD / 20 ** 0.5
    assert 0.5 * SD < float(res.z.std(0).min()) and float(res.z.std(0).max()) < 1.6 * SD
    # nothing is moved after the burn-in: the second half's energies are an emcee chain's
    assert res.state.relocate_until == 300


def test_bad_relocation_parameters_are_one_line():
    for bad in ({"relocate": 1.0}, {"relocate": -0.1}, {"relocate_every": 0}):
        with pytest.raises(InputError):
            make_sampler("emcee", params=bad)
