"""Per-pixel KDE entropy (Eqs. 19-21): native C kernel vs torch, Silverman's rule, quadrature vs numerical
integration, closed forms, and the unbiasedness of the single-sample Monte Carlo estimator."""
import math

import numpy as np
import pytest
import torch
from scipy.integrate import simpson
from scipy.stats import norm

from bayes_brdf.errors import InputError
from bayes_brdf.guidance import entropy as E
from bayes_brdf.guidance.entropy import kde_entropy, kde_entropy_torch, noise_entropy, silverman

H_STD_NORMAL = 0.5 * math.log(2 * math.pi * math.e)  # 1.4189...


def _columns(n, dtype, seed=0):
    """[n, cols] test matrix: random columns plus the awkward ones (ties, constant, IQR = 0, duplicates)."""
    g = torch.Generator().manual_seed(seed)
    cols = [torch.randn(n, 40, generator=g, dtype=torch.float64),                       # generic
            torch.rand(n, 12, generator=g, dtype=torch.float64) * 0.05 + 0.3,           # narrow, image-like
            (torch.rand(n, 12, generator=g, dtype=torch.float64) * 4).round() / 4,      # many ties in a column
            torch.full((n, 3), 0.25, dtype=torch.float64),                              # constant: bw = min_bw
            torch.zeros(n, 3, dtype=torch.float64)]
    mostly = torch.full((n, 3), 0.5, dtype=torch.float64)                               # IQR = 0, sd > 0
    mostly[0] = torch.linspace(0.6, 1.0, 3, dtype=torch.float64)
    cols.append(mostly)
    x = torch.cat(cols, 1)
    x = torch.cat([x, x[:, :7]], 1)                                                     # identical columns
    return x.to(dtype)   # 80 columns: one full SIMD block of 64 and a partial one


@pytest.mark.parametrize("dtype,tol", [(torch.float64, 1e-8), (torch.float32, 1e-3)])
@pytest.mark.parametrize("estimator", ["mc", "quadrature"])
@pytest.mark.parametrize("noise_var", [0.0, 1e-3])
@pytest.mark.needs_native(kernel="entropy")
def test_native_kernel_equals_torch(dtype, tol, estimator, noise_var):
    for n in (2, 3, 5, 20, 128):
        x = _columns(n, dtype, seed=n)
        g = torch.Generator().manual_seed(100 + n)
        u = torch.rand(x.shape[1], generator=g, dtype=dtype)
        e = torch.randn(x.shape[1], generator=g, dtype=dtype)
        h, sd = kde_entropy(x, estimator, u=u, e=e, noise_var=noise_var, backend="native")
        ht, sdt = kde_entropy_torch(x, estimator, u=u, e=e, noise_var=noise_var)
        assert h.dtype == dtype and h.shape == (x.shape[1],)
        assert torch.isfinite(h).all()
        torch.testing.assert_close(h, ht, atol=tol, rtol=tol, msg=f"n={n}")
        torch.testing.assert_close(sd, sdt, atol=tol, rtol=tol, msg=f"n={n}")
        # identical columns give identical entropies (same u, e by construction only for quadrature)
        if estimator == "quadrature":
            torch.testing.assert_close(h[-7:], h[:7], atol=tol, rtol=0)
        # the std output is the Bessel-corrected column std
        torch.testing.assert_close(sd.double(), torch.tensor(x.double().numpy().std(0, ddof=1)), atol=tol, rtol=tol)


@pytest.mark.needs_native(kernel="entropy")
def test_more_particles_than_native_limit_falls_back_to_torch(monkeypatch):
    nmax = E._lib(torch.float64)[1]
    calls = []
    real = E.kde_entropy_torch
    monkeypatch.setattr(E, "kde_entropy_torch", lambda *a, **k: calls.append(a[0].shape[0]) or real(*a, **k))
    x = torch.randn(nmax + 1, 24, generator=torch.Generator().manual_seed(1), dtype=torch.float64)
    h, sd = kde_entropy(x, "quadrature", backend="native")
    assert calls == [nmax + 1]
    assert torch.isfinite(h).all()
    torch.testing.assert_close(h, real(x, "quadrature")[0], atol=1e-12, rtol=0)
    torch.testing.assert_close(sd, torch.tensor(x.numpy().std(0, ddof=1)))
    # at the limit itself the native kernel runs (no torch call) and agrees
    h2, _ = kde_entropy(x[:nmax], "quadrature", backend="native")
    assert calls == [nmax + 1]
    torch.testing.assert_close(h2, real(x[:nmax], "quadrature")[0], atol=1e-8, rtol=0)
    # 129 particles of N(0, 1): the entropy is still about the true one
    assert abs(float(h.mean()) - H_STD_NORMAL) < 0.15


def _silverman_numpy(x):
    n = x.shape[0]
    sd = x.std(0, ddof=1)
    q25, q75 = np.percentile(x, [25, 75], axis=0)   # numpy's default: linear interpolation
    iqr = (q75 - q25) / 1.34
    a = np.where(iqr > 0, np.minimum(sd, iqr), sd)
    return 0.9 * n ** -0.2 * a, sd


def test_silverman_matches_numpy_reference():
    for n in (2, 3, 4, 7, 20, 33):
        x = _columns(n, torch.float64, seed=7 * n)
        x[:, 0] = torch.tensor([0.0] * (n - 1) + [3.0], dtype=torch.float64)   # IQR 0 for n >= 7
        bw, sd = silverman(x)
        bw_ref, sd_ref = _silverman_numpy(x.numpy())
        np.testing.assert_allclose(bw.numpy(), bw_ref, rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(sd.numpy(), sd_ref, rtol=1e-12, atol=1e-15)
        if n >= 7:  # the IQR-0 column used the std: bw = 0.9 n^-0.2 sd
            assert np.subtract(*np.percentile(x[:, 0].numpy(), [75, 25])) == 0
            assert bw[0] == pytest.approx(0.9 * n ** -0.2 * sd_ref[0], rel=1e-12)
    # a column where IQR/1.34 < sd: the IQR branch is the one taken
    x = torch.tensor([[0.0], [1.0], [1.1], [1.2], [1.3], [10.0]], dtype=torch.float64)
    bw, _ = silverman(x)
    q25, q75 = np.percentile(x.numpy()[:, 0], [25, 75])
    assert float(bw) == pytest.approx(0.9 * 6 ** -0.2 * (q75 - q25) / 1.34, rel=1e-12)


def _kde_entropy_by_integration(values, bw):
    """-int p log p, p the Gaussian mixture of Eq. 19, on a fine grid."""
    y = np.linspace(values.min() - 12 * bw, values.max() + 12 * bw, 60_001)
    p = norm.pdf(y[:, None], values[None], bw).mean(1)
    return -simpson(p * np.log(np.maximum(p, 1e-300)), x=y)


def test_quadrature_equals_numerical_integration():
    backends = ["torch"] + (["native"] if E._lib(torch.float64) is not None else [])
    g = torch.Generator().manual_seed(0)
    cols = [torch.randn(20, generator=g), torch.rand(7, generator=g),
            torch.cat([torch.zeros(10), torch.full((10,), 0.3)]),                        # two tied groups
            torch.cat([torch.randn(12, generator=g) * 0.01, torch.randn(8, generator=g) + 3]),  # bimodal
            torch.tensor([0.0, 0, 0, 0, 0, 0, 1, 2, 5, 9]),                              # IQR 0 -> sd
            torch.tensor([0.2, 0.7])]                                                   # two particles
    for c in cols:
        x = c.double()[:, None]
        for nv in (0.0, 0.05):
            bw = math.sqrt(float(silverman(x)[0]) ** 2 + nv)     # kernel of R + noise
            ref = _kde_entropy_by_integration(c.double().numpy(), bw)
            for backend in backends:
                h8 = float(kde_entropy(x, "quadrature", noise_var=nv, backend=backend)[0])
                h32 = float(kde_entropy(x, "quadrature", nodes=32, noise_var=nv, backend=backend)[0])
                assert h8 == pytest.approx(ref, abs=3e-3), (c, nv, backend)
                assert h32 == pytest.approx(ref, abs=1e-4), (c, nv, backend)


def test_closed_form_for_well_separated_groups():
    """Tied groups far apart (>> bw): p is a mixture of non-overlapping Gaussians of weights w, so
    h = -sum w log w + 0.5 log(2 pi e bw^2) (for k equal groups: log k + ...). Silverman's bandwidth scales
    with the spread, so distinct values can never be that far apart; ties make it possible."""
    n, d = 128, 1.0
    x = torch.zeros(n, 1, dtype=torch.float64)
    x[:4, 0], x[4:8, 0] = d, -d                                    # weights 4/128, 4/128, 120/128
    bw = float(_silverman_numpy(x.numpy())[0][0])
    assert d / bw > 10                                             # well separated
    w = np.array([4, 4, 120]) / n
    closed = -(w * np.log(w)).sum() + 0.5 * math.log(2 * math.pi * math.e * bw * bw)
    for backend in ("native", "torch"):
        if backend == "native" and E._lib(torch.float64) is None:
            continue
        h, _ = kde_entropy(x, "quadrature", backend=backend)
        assert float(h[0]) == pytest.approx(closed, abs=1e-6)
        # MC, one sample: -log p(r) = -log w_group(c) + e^2/2 + log(bw sqrt(2 pi)), exactly, per draw
        xs = x.expand(n, 300).contiguous()
        g = torch.Generator().manual_seed(3)
        u = torch.rand(300, generator=g, dtype=torch.float64)
        e = torch.randn(300, generator=g, dtype=torch.float64)
        hm, _ = kde_entropy(xs, "mc", u=u, e=e, backend=backend)
        c = (u * n).long()
        wc = torch.where(c < 8, 4 / n, 120 / n)
        ref = -wc.log() + 0.5 * e * e + math.log(bw * math.sqrt(2 * math.pi))
        torch.testing.assert_close(hm, ref, atol=1e-6, rtol=0)
    # all particles equal: one Gaussian of width min_bandwidth (or sqrt(noise_var))
    z = torch.full((10, 3), 0.7, dtype=torch.float64)
    assert float(kde_entropy(z, "quadrature")[0][0]) == pytest.approx(
        0.5 * math.log(2 * math.pi * math.e * 1e-12), abs=1e-6)
    assert float(kde_entropy(z, "quadrature", min_bandwidth=1e-3)[0][0]) == pytest.approx(
        0.5 * math.log(2 * math.pi * math.e * 1e-6), abs=1e-6)


def test_standard_normal_samples_average_to_gaussian_entropy():
    x = torch.randn(20, 4000, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    h, sd = kde_entropy(x, "quadrature")
    # KDE smoothing (+0.5 log(1 + bw^2) ~ +0.1) and finite samples (-) nearly cancel at n = 20
    assert float(h.mean()) == pytest.approx(H_STD_NORMAL, abs=0.03)
    assert float(sd.mean()) == pytest.approx(1.0, abs=0.03)
    # entropy is shift invariant and shifts by log(s) under scaling
    h2, _ = kde_entropy(3.0 * x + 5.0, "quadrature")
    torch.testing.assert_close(h2, h + math.log(3.0), atol=1e-8, rtol=0)


def test_mc_estimator_is_unbiased_and_noisy_while_quadrature_is_deterministic():
    """The paper's Eq. 21 vs quadrature: averaged over many independent (u, e) draws the MC estimate
    converges to the quadrature value; a single draw is noisy; quadrature is exactly repeatable."""
    g = torch.Generator().manual_seed(5)
    base = torch.stack([torch.randn(20, generator=g, dtype=torch.float64),
                        torch.rand(20, generator=g, dtype=torch.float64) ** 3,
                        torch.cat([torch.zeros(14), torch.ones(6)]).double() + 0.01 * torch.randn(20, generator=g, dtype=torch.float64),
                        torch.exp(torch.randn(20, generator=g, dtype=torch.float64))], 1)   # [20, 4]
    M = 5000
    xs = base.repeat(1, M)                                           # column j*4 + c is column c
    hq, _ = kde_entropy(base, "quadrature", nodes=32)
    hm, _ = kde_entropy(xs, "mc", generator=torch.Generator().manual_seed(11))
    hm = hm.view(M, 4)
    mean, se = hm.mean(0), hm.std(0) / math.sqrt(M)
    assert ((mean - hq).abs() < 4 * se).all(), (mean, hq, se)
    assert (hm.std(0) > 0.3).all()                                   # single draws really are noisy
    # a different seed gives different single-draw values, the same expectation
    hm2, _ = kde_entropy(xs, "mc", generator=torch.Generator().manual_seed(12))
    assert not torch.equal(hm2.view(M, 4), hm)
    # quadrature: deterministic, whatever the generator
    a, _ = kde_entropy(base, "quadrature", generator=torch.Generator().manual_seed(1))
    b, _ = kde_entropy(base, "quadrature", generator=torch.Generator().manual_seed(2))
    assert torch.equal(a, b)


def test_noise_entropy_and_lower_bound():
    for v in (1e-4, 0.01, 1.0, 3.0):
        assert noise_entropy(v) == pytest.approx(0.5 * math.log(2 * math.pi * math.e * v), rel=1e-12)
    assert noise_entropy(0.0) == 0.0
    v = 1e-3
    x = _columns(20, torch.float64, seed=3)
    h, _ = kde_entropy(x, "quadrature", noise_var=v)
    # a mixture of Gaussians of variance >= v has at least the entropy of one of them
    assert (h >= noise_entropy(v) - 1e-6).all()
    # and constant columns reach the bound exactly (the KDE is N(c, v))
    const = (x.std(0) == 0)
    assert const.any()
    torch.testing.assert_close(h[const], torch.full_like(h[const], noise_entropy(v)), atol=1e-9, rtol=0)
    # without noise the constant columns drop far below it
    h0, _ = kde_entropy(x, "quadrature")
    assert (h0[const] < noise_entropy(v) - 5).all()


def test_bad_input_raises_input_error():
    with pytest.raises(InputError, match="at least 2 particles"):
        kde_entropy(torch.randn(1, 10), "quadrature")
    with pytest.raises(InputError):
        kde_entropy(torch.randn(10), "quadrature")
    with pytest.raises(InputError, match="unknown entropy estimator"):
        kde_entropy(torch.randn(5, 10), "kde")
