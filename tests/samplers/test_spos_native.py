"""The fused native SPOS update (``_native_spos.c``) against the plain torch update it replaces.

Both run from the same noise draw, so the particles and Adam's moments must agree to rounding, for every
combination of options the update has: float32/float64, one or several groups, 2 or 20 particles, the
ensemble-scaled or the parameter step, Adam (per group in high dimension, per particle in low) or no
preconditioner, and through the annealing (the noise's own preconditioner) into the plain steps.
"""
from __future__ import annotations

import itertools

import pytest
import torch

import bayes_brdf.samplers.spos as S
from bayes_brdf.potential import FunctionPotential
from bayes_brdf.samplers import make_sampler

SHAPES = ((2, 1, 20), (37, 3, 2), (37, 1, 20), (2, 3, 2))          # (dimension, groups, particles per group)
CASES = [(dt, *SHAPES[k % 4], units, precond) for k, (dt, units, precond) in enumerate(itertools.product(
    (torch.float64, torch.float32), ("spread", "parameter"), ("adam", "none")))] + \
    [(torch.float32, *shape, "spread", "adam") for shape in SHAPES]


def _run(native: bool, dtype, dim, groups, n, units, precond, steps, monkeypatch):
    scale = torch.linspace(1.0, 3.0, dim, dtype=dtype)
    pot = FunctionPotential(lambda z: 0.5 * (z * z * scale).sum(1), dim=dim, dtype=dtype)
    s, _ = make_sampler("spos")
    s.step_units, s.preconditioner = units, precond
    if precond == "none":
        s.step_size = 0.01
    with monkeypatch.context() as m:
        if not native:
            m.setattr(S, "_native_update", lambda dt: None)
        rng = torch.Generator().manual_seed(0)
        st = s.init(pot.init(groups * n, seed=1), pot, rng, steps=steps, groups=groups)
        for t in range(steps):
            st, info = s.step(st, t, pot, rng)
    return st


@pytest.mark.parametrize("dtype,dim,groups,n,units,precond", CASES)
def test_native_update_equals_the_torch_update(monkeypatch, dtype, dim, groups, n, units, precond):
    if S._native_update(dtype) is None:
        pytest.skip("native kernels unavailable here")
    steps = 12   # anneal_fraction 0.2 of 12: the first steps anneal (gamma < 0.99), the later ones do not
    a = _run(True, dtype, dim, groups, n, units, precond, steps, monkeypatch)
    b = _run(False, dtype, dim, groups, n, units, precond, steps, monkeypatch)
    tol = 2e-5 if dtype == torch.float32 else 1e-12
    torch.testing.assert_close(a.z, b.z, rtol=tol, atol=tol * float(b.z.abs().max()))
    for pa, pb in ((a.precond, b.precond), (a.precond_noise, b.precond_noise)):
        assert pa.count == pb.count
        torch.testing.assert_close(pa.v, pb.v, rtol=tol, atol=tol * float(pb.v.abs().max()) + 1e-30)


def test_the_native_update_leaves_its_input_state_alone():
    """A sampler state is a value: stepping twice from one state gives the same result (the benchmarks and
    the driver's checkpoints rely on it)."""
    pot = FunctionPotential(lambda z: 0.5 * (z * z).sum(1), dim=64, dtype=torch.float32)
    s, _ = make_sampler("spos")
    st0 = s.init(pot.init(20, seed=0), pot, torch.Generator().manual_seed(0), steps=100)
    z0, v0 = st0.z.clone(), st0.precond.v.clone()
    one = s.step(st0, 3, pot, torch.Generator().manual_seed(5))[0]
    two = s.step(st0, 3, pot, torch.Generator().manual_seed(5))[0]
    assert torch.equal(st0.z, z0) and torch.equal(st0.precond.v, v0)
    assert torch.equal(one.z, two.z) and torch.equal(one.precond.v, two.precond.v)
