"""The samplers' normal draws (``numerics.standard_normal``): the native Philox + Box-Muller generator is a
standard normal in its tails too, and its numbers depend on the generator's state only (not the thread count)."""
from __future__ import annotations

import pytest
import scipy.stats as st
import torch

from bayes_brdf.samplers.numerics import _native_normal, standard_normal

pytestmark = pytest.mark.skipif(_native_normal(torch.float32) is None, reason="native kernels unavailable here")


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_draws_are_standard_normal_with_normal_tails(dtype):
    z = standard_normal((2_000_000,), torch.Generator().manual_seed(0), dtype).double().numpy()
    assert abs(z.mean()) < 0.003 and abs(z.var() - 1) < 0.003
    assert st.kstest(z, "norm").pvalue > 1e-3
    for t in (2.0, 3.0, 4.0):        # two-sided tail frequencies within 5 standard errors of the normal's
        p = 2 * st.norm.sf(t)
        assert abs((abs(z) > t).mean() - p) < 5 * (p * (1 - p) / z.size) ** 0.5
    # consecutive draws (the four of one Philox block, and across blocks) are uncorrelated
    for lag in (1, 2, 3, 4, 5):
        assert abs(float((z[:-lag] * z[lag:]).mean())) < 0.004


def test_draws_depend_on_the_generator_state_only():
    def draw(n, threads, seed=3, dtype=torch.float32):
        old = torch.get_num_threads()
        torch.set_num_threads(threads)
        try:
            return standard_normal((n,), torch.Generator().manual_seed(seed), dtype)
        finally:
            torch.set_num_threads(old)

    a = draw(100_003, 1)
    assert torch.equal(a, draw(100_003, 2))              # any thread count
    assert torch.equal(a[:999], draw(999, 2))             # a prefix is the same draw
    assert not torch.equal(a[:999], draw(999, 1, seed=4))
    torch.testing.assert_close(a.double(), draw(100_003, 1, dtype=torch.float64), rtol=1e-5, atol=1e-5)
    g = torch.Generator().manual_seed(3)
    first, second = standard_normal((64,), g, torch.float32), standard_normal((64,), g, torch.float32)
    assert not torch.equal(first, second)                 # the generator's state advances


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_native_kernel_equals_the_torch_reference(monkeypatch, dtype):
    """The C kernel against ``philox_normal`` (plain torch: the path on CUDA and without a compiler), for seeds
    whose words exercise the 64-bit products' wrap-around; through ``standard_normal`` either way."""
    import bayes_brdf.samplers.numerics as N

    tol = 2e-6 if dtype == torch.float32 else 1e-12
    for seed in (0, 1, 2**32 - 1, 123456789012345, 2**63 - 2):
        out = torch.empty(4099, dtype=dtype)
        N._native_normal(dtype)(seed, out.numel(), 2, out.data_ptr())
        torch.testing.assert_close(out, N.philox_normal(seed, (4099,), dtype), rtol=tol, atol=tol)
    native = standard_normal((3, 5, 7), torch.Generator().manual_seed(9), dtype)
    monkeypatch.setattr(N, "_native_normal", lambda dt: None)
    plain = standard_normal((3, 5, 7), torch.Generator().manual_seed(9), dtype)
    torch.testing.assert_close(native, plain, rtol=tol, atol=tol)
