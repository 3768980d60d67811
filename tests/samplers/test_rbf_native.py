"""The native RBF kernel matrices (``_native_rbf.c``) against the torch ops of ``rbf_matrix`` they replace."""
from __future__ import annotations

import pytest
import torch

import bayes_brdf.samplers.kernels as K

# (particles, dimension, groups): a large chunked case, two particles, chunk remainders, several groups, 64 particles
SHAPES = ((20, 65536, 1), (2, 7, 1), (12, 1001, 3), (40, 4096, 2), (64, 3000, 1))


def _both(z, groups, monkeypatch):
    fast = K.rbf_matrix(z, groups)
    with monkeypatch.context() as m:
        m.setattr(K, "_native_rbf", lambda z: None)
        ref = K.rbf_matrix(z, groups)
    return fast, ref


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("n,dim,groups", SHAPES)
def test_native_rbf_matrix_equals_the_torch_ops(monkeypatch, dtype, n, dim, groups):
    if K._native_rbf(torch.zeros(1, 1, dtype=dtype)) is None:
        pytest.skip("native kernels unavailable here")
    gen = torch.Generator().manual_seed(n + dim)
    # a shared offset much larger than the spread: the distances come from a Gram matrix with cancellation
    z = torch.randn(n, dim, generator=gen, dtype=dtype) * 0.3 + torch.randn(1, dim, generator=gen, dtype=dtype)
    (k, h), (k0, h0) = _both(z, groups, monkeypatch)
    assert k.shape == k0.shape == (groups, n // groups, n // groups) and h.shape == h0.shape == (groups,)
    assert k.dtype == h.dtype == dtype
    tol = 1e-5 if dtype == torch.float32 else 1e-12
    torch.testing.assert_close(h, h0, rtol=tol, atol=0)
    torch.testing.assert_close(k, k0, rtol=tol, atol=tol)
    assert torch.equal(k, k.transpose(1, 2)) and bool((k.diagonal(dim1=1, dim2=2) == 1).all())


def test_coincident_particles_get_unit_bandwidth(monkeypatch):
    if K._native_rbf(torch.zeros(1, 1)) is None:
        pytest.skip("native kernels unavailable here")
    z = torch.cat([torch.zeros(4, 10), torch.ones(4, 10)])        # group 0 coincident, group 1 too
    (k, h), (k0, h0) = _both(z, 2, monkeypatch)
    assert torch.equal(h, torch.ones(2)) and torch.equal(h, h0) and torch.equal(k, torch.ones(2, 4, 4))


def test_native_rbf_matrix_does_not_depend_on_the_thread_count():
    if K._native_rbf(torch.zeros(1, 1)) is None:
        pytest.skip("native kernels unavailable here")
    z = torch.randn(20, 10000, generator=torch.Generator().manual_seed(3))
    threads = torch.get_num_threads()
    try:
        out = []
        for t in (1, 2, 3):
            torch.set_num_threads(t)
            out.append(K.rbf_matrix(z, 1))
    finally:
        torch.set_num_threads(threads)
    for k, h in out[1:]:
        assert torch.equal(k, out[0][0]) and torch.equal(h, out[0][1])


def test_one_particle_and_differentiated_particles(monkeypatch):
    """One particle per group: a kernel of ones and h = 1 (no pairs to take a median of); particles that require a
    gradient take the torch ops, so that the kernel stays differentiable."""
    if K._native_rbf(torch.zeros(1, 1)) is None:
        pytest.skip("native kernels unavailable here")
    k, h = K.rbf_matrix(torch.randn(3, 5), 3)
    assert torch.equal(k, torch.ones(3, 1, 1)) and torch.equal(h, torch.ones(3))
    z = torch.randn(6, 9, requires_grad=True)
    k, h = K.rbf_matrix(z, 2)
    assert k.requires_grad
    (k0, h0), _ = _both(z.detach(), 2, monkeypatch)
    torch.testing.assert_close(k.detach(), k0, rtol=1e-5, atol=1e-6)
