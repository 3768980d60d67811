"""Texel-local Metropolis moves: each texel's energy checked against the potential and an independent
implementation, the move alone against each texel's exact posterior (quadrature), and the default sampler on
real photos against the quadrature of :mod:`bayes_brdf.experiments.texel_truth`."""
from __future__ import annotations

import pytest
import torch

import bayes_brdf as bb
from bayes_brdf.errors import InputError
from bayes_brdf.experiments import highdim as H
from bayes_brdf.experiments.texel_truth import roughness_marginals
from bayes_brdf.inference import resolve_model
from bayes_brdf.io import load_capture
from bayes_brdf.models import homogeneous
from bayes_brdf.models.data import ModelData
from bayes_brdf.potential import Potential
from bayes_brdf.runs.fingerprint import model_table
from bayes_brdf.samplers.spos import SPOS
from bayes_brdf.samplers import texel_moves as TM
from bayes_brdf.samplers.texel_moves import texel_energy, texel_layout, texel_move


@pytest.fixture(scope="module")
def small():
    prob = H.setup(H.HighDimSetup(noise=True, seed=0, resolution=8))
    return prob, Potential(prob.model, (prob.data64,))


def test_texel_energies_split_the_potential_exactly_with_a_fixed_sigma(small):
    prob, pot = small
    z, z2 = pot.init(6, seed=0), pot.init(6, seed=1)
    L = texel_layout(pot)
    assert L.shape == (64, 2)                                # gray albedo and roughness per texel
    e, _ = texel_energy(pot, z)
    e2, _ = texel_energy(pot, z2)
    dU = pot.energy(z2) - pot.energy(z)
    assert torch.allclose((e2 - e).sum(1), dU, rtol=1e-9, atol=1e-7)           # every texel changed at once
    for t in (0, 27, 63):                                                       # one texel changed
        zt = z.clone()
        zt[:, L[t]] = z2[:, L[t]]
        et, _ = texel_energy(pot, zt)
        assert torch.allclose(et[:, t] - e[:, t], pot.energy(zt) - pot.energy(z), rtol=1e-9, atol=1e-7)
        assert torch.allclose(torch.cat([et[:, :t], et[:, t + 1:]], 1), torch.cat([e[:, :t], e[:, t + 1:]], 1))
    # the likelihood part against the experiment's own implementation (no Jacobian there: compare in x)
    x, x2 = pot.to_constrained(z), pot.to_constrained(z2)
    ref = H.texel_energies(prob, x["albedo"].reshape(6, -1), x["roughness"].reshape(6, -1))
    ref2 = H.texel_energies(prob, x2["albedo"].reshape(6, -1), x2["roughness"].reshape(6, -1))
    from bayes_brdf.models.texel_energy import texel_energies
    mine = texel_energies(prob.model, prob.data64, x)[0]
    mine2 = texel_energies(prob.model, prob.data64, x2)[0]
    assert torch.allclose(mine2 - mine, ref2 - ref, rtol=1e-9, atol=1e-8)


def test_texel_energy_follows_the_profiled_noise_level_on_real_photos(shared_data):
    cap = load_capture(shared_data / "captures" / "card_blue", resolution=16)
    data = ModelData.from_observations(cap)
    assert data.censored is not None                          # the case where kappa is not 1 / sigma
    model = resolve_model(model_table("per_texel", {}, 16))
    pot = Potential(model, (data,))
    z = pot.init(4, seed=0)
    L = texel_layout(pot)
    e, scale = texel_energy(pot, z)
    sigma, kappa = scale
    assert bool(((kappa * sigma - 1).abs() > 0.01).all())    # the saturated pixels pull on the noise level
    for t in (3, 100, 200):
        for c in range(L.shape[1]):
            zt = z.clone()
            zt[:, L[t, c]] += torch.tensor([0.4, -0.8, 1.5, -2.0])
            et, _ = texel_energy(pot, zt, scale)
            dU = (pot.energy(zt) - pot.energy(z)).double()
            assert torch.allclose(et[:, t] - e[:, t], dU, rtol=0.01, atol=0.02), (t, c)


@pytest.mark.parametrize("path", [pytest.param("native", marks=pytest.mark.needs_native), "torch"])
def test_texel_moves_alone_sample_each_texels_exact_posterior_from_a_stranded_start(small, path, monkeypatch):
    """Both implementations of the move (the native kernels, and torch's where they do not run) on their own
    sample each texel's exact posterior (quadrature), starting with every particle in the wrong mode."""
    prob, pot = small
    if path == "torch":
        monkeypatch.setenv("BAYES_BRDF_NO_NATIVE", "1")
    assert TM._native_moves(pot.init(4, seed=0), 20, 2) == (path == "native")
    ex = H.exact_std(prob, check=False, cells=1000)
    z = pot.init(40, seed=0)
    L = texel_layout(pot)
    z[:, L[:, 1]] = 3.0 + 0.3 * torch.randn(40, 64, dtype=z.dtype)   # every particle's roughness near 1
    g = torch.Generator().manual_seed(0)
    rates = []
    for _ in range(300):
        z, rate = texel_move(z, pot, g, bandwidth=2.5)
        rates.append(rate)
    x = pot.to_constrained(z)
    for m in ("albedo", "roughness"):
        v = x[m].reshape(40, -1)
        err = ((v.mean(0) - ex[f"mean_{m}"].flatten()).abs() / ex[f"std_{m}"].flatten()).median()
        ratio = (v.std(0) / ex[f"std_{m}"].flatten()).median()
        assert err < 0.35 and 0.85 < ratio < 1.15, (m, float(err), float(ratio))
    assert 0.05 < sum(rates[-100:]) / 100 < 0.9


def test_models_without_texel_energies_are_left_alone():
    data = H.setup(H.HighDimSetup(resolution=4)).data
    pot = Potential(homogeneous(albedo="gray"), (data,))
    z = pot.init(8)
    assert texel_layout(pot) is None
    z2, rate = texel_move(z, pot, torch.Generator().manual_seed(0))
    assert torch.equal(z2, z) and rate == 0.0


@pytest.mark.parametrize("bad", [-1, 2.5, True])
def test_texel_moves_must_be_a_step_count(bad):
    with pytest.raises(InputError, match="texel_moves"):
        SPOS(texel_moves=bad).validate()


def test_default_fit_on_real_photos_finds_each_texels_exact_roughness(shared_data):
    """The user-visible claim: on card_blue the default's roughness std map is near each texel's exact posterior
    std, where without the moves particles stranded in weak second modes made it several times too wide."""
    cap = load_capture(shared_data / "captures" / "card_blue", resolution=32).subset([0, 3, 4, 6, 7])
    table = model_table("per_texel", {}, 32)
    runs = {k: bb.infer(table, cap, "spos", params=p, progress=False, map_steps=0)
            for k, p in (("default", None), ("no moves", {"texel_moves": 0}))}
    pot = runs["default"].potential
    _, (sig, kap) = texel_energy(pot, runs["default"].z)
    truth = roughness_marginals(pot.model, pot.args[0], float(sig.median()), float(kap.median()), albedo_cells=64,
                                roughness_cells=48)
    narrow = truth["std"] <= truth["std"].median()
    std = {k: p.std("roughness").flatten().double() for k, p in runs.items()}
    exact = float(truth["std"][narrow].mean())
    # measured 1.08x with the preset's sweep on every step (1.7-1.8x with one every 3 steps)
    assert float(std["default"][narrow].mean()) < 1.3 * exact, (std["default"][narrow].mean(), exact)
    assert float(std["no moves"][narrow].mean()) > 4.0 * exact                                       # 6x
    mean = runs["default"].mean("roughness").flatten().double()
    assert float((mean - truth["mean"])[narrow].abs().mean()) < 0.02


def test_a_run_with_texel_moves_resumes_exactly_after_ctrl_c(small, tmp_path):
    from bayes_brdf.samplers import make_sampler, run
    _, pot = small
    smp, _ = make_sampler("spos")
    assert smp.texel_moves == 1
    kw = dict(particles=8, steps=40, seed=2, progress=False, checkpoint_every=10)
    full = run(smp, pot, checkpoint=tmp_path / "full.pt", **kw)

    def stop(t, state, info):
        if t == 22:                                   # after the sweeps of steps 0 to 21, before the next
            raise KeyboardInterrupt
    with pytest.raises(KeyboardInterrupt):
        run(smp, pot, checkpoint=tmp_path / "cut.pt", callbacks=[stop], **kw)
    again = run(smp, pot, checkpoint=tmp_path / "cut.pt", **kw)
    assert again.resumed_from > 0 and torch.equal(again.z, full.z)
    plain = run(make_sampler("spos", params={"texel_moves": 0})[0], pot, **kw)
    assert not torch.equal(plain.z, full.z)           # the sweeps did something


@pytest.mark.needs_native
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_native_proposal_densities_match_the_torch_reference(dtype):
    """The kernel widths and log densities of the C kernel against the torch functions, on bimodal texels with a
    particle alone in a far mode and a texel whose centres coincide (the width floor)."""
    gen = torch.Generator().manual_seed(0)
    G, b, T, k = 2, 10, 300, 4
    xb = torch.randn(G, b, T, k, generator=gen, dtype=dtype) * 0.3
    xb[:, :3, ::2] += 4.0                                   # a second mode on every other texel
    xb[:, 0, 1::3] -= 6.0                                   # one particle alone, far out
    xb[:, :, -1] = 0.7                                      # identical centres: the width floor
    h = TM.widths(xb, 2.5)
    ref = TM._local_scale(xb).mul_(2.5).clamp_min_(TM.H_MIN)
    torch.testing.assert_close(h, ref, rtol=1e-6, atol=0)
    assert float(h[:, -1].max()) == pytest.approx(TM.H_MIN)
    x = torch.cat([xb[:, :7] + 0.05, torch.randn(G, 13, T, k, generator=gen, dtype=dtype) * 3], 1)
    got = TM.log_q(x, xb, h)
    want = TM._log_q(x, xb, h)
    assert got.shape == want.shape == (G, 20, T)
    tol = 2e-4 if dtype == torch.float32 else 1e-10
    torch.testing.assert_close(got, want, rtol=tol, atol=tol)


@pytest.mark.needs_native
@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_native_move_scores_four_coordinates_as_the_torch_reference_does(dtype):
    """``bb_texel_propose`` with four coordinates per texel (rgb albedo and roughness: its own inlined path) and a
    coordinate without a Jacobian: the log ratio of the proposals it drew as the torch reference's, on bimodal
    texels, one particle alone far out and a texel whose centres coincide."""
    from bayes_brdf.render.native import ptr
    gen = torch.Generator().manual_seed(1)
    T, k, n = 96, 4, 20
    L = (torch.arange(k)[None] * T + torch.arange(T)[:, None]).contiguous()          # coordinate-major, as sites
    z = (torch.randn(n, k * T, generator=gen, dtype=torch.float64) * 0.3).to(dtype)
    z[10:13, L[::2]] += 4.0                               # a second mode of the centres on every other texel
    z[10, L[1::3]] -= 6.0                                 # one centre alone, far out
    z[10:, L[-1]] = 0.7                                   # coinciding centres: the width floor
    jac = torch.tensor([1, 1, 1, 0])
    A, B = torch.arange(10), torch.arange(10, 20).reshape(1, 10)
    zp, dlq = z[A], torch.empty(10, T, dtype=torch.float64)
    fn = TM._kde_kernel("bb_texel_propose", z)
    assert fn(1, T, 10, 10, k, z.shape[1], 2, ptr(z), ptr(L), ptr(jac), ptr(A), ptr(B), 99, 2.5, TM.H_MIN,
              TM.DEFENSIVE, ptr(zp), ptr(dlq)) == 0
    cur, prop, xb = z[A][:, L][None], zp[:, L][None], z[B.reshape(-1)][:, L][None]
    h = TM._local_scale(xb).mul_(2.5).clamp_min_(TM.H_MIN)
    cur, prop, xb, h = (t.double() for t in (cur, prop, xb, h))
    J = lambda x: TM._log_logistic(x[..., :3]).sum(-1)                           # noqa: E731
    want = TM._log_q(cur, xb, h) - TM._log_q(prop, xb, h) + J(prop) - J(cur)
    tol = 1e-10 if dtype == torch.float64 else 1e-5
    torch.testing.assert_close(dlq[None], want, rtol=tol, atol=tol)


@pytest.mark.needs_native
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_native_move_is_the_same_whether_a_texels_columns_are_a_run_or_not(dtype):
    """``bb_texel_propose`` copies a stage of texels whose columns are runs (``texel_layout``'s always are) into a
    buffer of its own and works there; with any other layout it reads the rows in place. The same texel values under
    a shuffled layout give the same proposals and log ratios, bit for bit: two groups, 2 stages of 256 texels and
    a last one of 100, whose last block has 4 texels."""
    from bayes_brdf.render.native import ptr
    gen = torch.Generator().manual_seed(5)
    G, a, b, T, k = 2, 5, 6, 612, 4
    N = G * (a + b)
    L = (torch.arange(k)[None] * T + torch.arange(T)[:, None]).contiguous()           # runs
    z = (torch.randn(N, k * T + 3, generator=gen, dtype=torch.float64) * 0.5).to(dtype)   # 3 columns no texel has
    perm = torch.randperm(k * T, generator=gen)
    zs = z.clone()
    zs[:, perm] = z[:, :k * T]                     # column c of z is column perm[c] of zs
    Ls = perm[L].contiguous()                      # texel t's coordinates in zs: no runs
    jac = torch.tensor([1, 1, 1, 0])
    A = torch.cat([torch.arange(a), a + b + torch.arange(a)])
    B = torch.stack([a + torch.arange(b), 2 * a + b + torch.arange(b)])
    fn = TM._kde_kernel("bb_texel_propose", z)
    out = []
    for zz, LL in ((z, L), (zs, Ls)):
        zp, dlq = zz[A], torch.full((G * a, T), float("nan"), dtype=torch.float64)
        assert fn(G, T, a, b, k, zz.shape[1], 2, ptr(zz), ptr(LL), ptr(jac), ptr(A), ptr(B), 4242, 2.5, TM.H_MIN,
                  TM.DEFENSIVE, ptr(zp), ptr(dlq)) == 0
        out.append((zp[:, LL], zp[:, -3:], dlq))
    (p_run, rest_run, d_run), (p_perm, rest_perm, d_perm) = out
    assert not torch.equal(p_run, z[A][:, L])                                   # it proposed
    assert torch.equal(p_run, p_perm) and torch.equal(d_run, d_perm)
    assert torch.equal(rest_run, z[A][:, -3:]) and torch.equal(rest_perm, zs[A][:, -3:])   # the rest untouched
    assert bool(torch.isfinite(d_run).all())


@pytest.mark.needs_native
@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_native_move_scores_its_proposals_as_the_torch_reference_does(small, dtype):
    """``bb_texel_propose``'s log ratio for the proposals it drew: the torch kernel density at the current and
    proposed values (widths from the other half) plus the Jacobian's difference, which its texel energies leave
    out; and ``bb_texel_accept`` moves exactly the texels whose Metropolis test passes. With float32 particles
    the kernel computes in float32: the log ratio within 1e-5 nats of the reference in float64 (measured 1.6e-6), a
    change of the acceptance probability by a relative 1e-5 at most."""
    from bayes_brdf.render.native import ptr
    prob, pot = small
    if dtype == torch.float32:
        pot = Potential(prob.model, (prob.data,))
        assert prob.data.images.dtype == torch.float32
    z = pot.init(12, seed=3)
    assert z.dtype == dtype
    z[:3, texel_layout(pot)[::2, 1]] += 4.0                  # a second mode on every other texel
    L = texel_layout(pot)
    T, k = L.shape
    A, B = torch.arange(6), torch.arange(6, 12).reshape(1, 6)
    jac = TM._interval_coordinates(pot)
    assert jac.tolist() == [1, 1]
    zp, dlq = z[A], torch.empty(6, T, dtype=torch.float64)
    fn = TM._kde_kernel("bb_texel_propose", z)
    assert fn(1, T, 6, 6, k, z.shape[1], 2, ptr(z), ptr(L), ptr(jac), ptr(A), ptr(B), 12345, 2.5, TM.H_MIN,
              TM.DEFENSIVE, ptr(zp), ptr(dlq)) == 0
    cur, prop = z[A][:, L][None], zp[:, L][None]                                  # [1, a, T, k]
    assert not torch.equal(cur, prop)
    xb = z[B.reshape(-1)][:, L][None]
    h = TM._local_scale(xb).mul_(2.5).clamp_min_(TM.H_MIN)                       # the kernel's widths: in dtype
    cur, prop, xb, h = (t.double() for t in (cur, prop, xb, h))                     # the reference: in float64
    J = lambda x: TM._log_logistic(x).sum(-1)                                     # noqa: E731
    want = TM._log_q(cur, xb, h) - TM._log_q(prop, xb, h) + J(prop) - J(cur)
    tol = 1e-10 if dtype == torch.float64 else 1e-5
    torch.testing.assert_close(dlq[None], want, rtol=tol, atol=tol)
    zc = z.clone()
    zc[6:] = 0.3                                   # coinciding centres: the kernel's proposals stay within its floor
    assert fn(1, T, 6, 6, k, z.shape[1], 2, ptr(zc), ptr(L), ptr(jac), ptr(A), ptr(B), 777, 2.5, TM.H_MIN,
              TM.DEFENSIVE, ptr(zp), ptr(dlq)) == 0
    near = (zp[:, L] - 0.3).abs().amax(-1) < 10 * TM.H_MIN
    assert 0.05 < 1 - float(near.double().mean()) < 0.16                          # the defensive share, 0.1
    # the far ones' kernel exponents are about -1e6 (widths 1e-3): clamped in the kernel (glibc's vector exp is
    # slow below -87), their log densities still the reference's
    cur, prop, xb = (t.double() for t in (zc[A][:, L][None], zp[:, L][None], zc[B.reshape(-1)][:, L][None]))
    h = torch.full_like(xb[:, 0], TM.H_MIN)
    want = TM._log_q(cur, xb, h) - TM._log_q(prop, xb, h) + J(prop) - J(cur)
    torch.testing.assert_close(dlq[None], want, rtol=tol, atol=tol)
    zp = z[A]
    assert fn(1, T, 6, 6, k, z.shape[1], 2, ptr(z), ptr(L), ptr(jac), ptr(A), ptr(B), 12345, 2.5, TM.H_MIN,
              TM.DEFENSIVE, ptr(zp), ptr(dlq)) == 0
    e = torch.randn(12, T, dtype=torch.float64)
    ep = e[:6] + torch.randn(6, T, dtype=torch.float64)
    ep[0, :5] = float("inf")                                                      # impossible proposals
    z2 = z.clone()
    n = TM._kde_kernel("bb_texel_accept", z)(6, T, k, z.shape[1], 2, ptr(z2), ptr(L), ptr(A), ptr(zp), ptr(e),
                                              ptr(ep), ptr(dlq), 99)
    moved = (z2[A][:, L] != z[A][:, L]).any(-1)
    assert int(moved.sum()) == n and not bool(moved[0, :5].any())
    log_alpha = e[:6] - ep + dlq
    assert bool(moved[log_alpha > 30].all()) and not bool(moved[log_alpha < -30].any())
    assert torch.equal(z2[A][:, L][moved], zp[:, L][moved])


def test_reference_moves_take_torch_path_on_cpu(small, monkeypatch):
    """Inside ``reference_moves()`` a CPU sweep is torch's (the CUDA path's, with the same draws from the CPU
    generator): the same particles as with the native kernels switched off, and not the native sweep's."""
    _, pot = small
    z = pot.init(12, seed=1)

    def sweep():
        return texel_move(z, pot, torch.Generator().manual_seed(5))[0]

    with TM.reference_moves():
        ref = sweep()
    native, native_ran = sweep(), TM._native_moves(z, 6, 2)
    monkeypatch.setenv("BAYES_BRDF_NO_NATIVE", "1")
    assert torch.equal(ref, sweep())
    assert not torch.equal(ref, native) or not native_ran


@pytest.mark.needs_native
def test_a_sweep_over_all_columns_skips_the_movers_copy_with_the_same_result(small):
    """With the potential's own layout (made once per potential), whose texels hold every column of ``z``, a native
    sweep starts the proposals' rows empty instead of copying the movers' rows: the kernel writes every column.
    The particles and the acceptance rate are those of the same sweep given the layout (which copies), bit for
    bit, and the layout is the same tensor each time."""
    _, pot = small
    z = pot.init(12, seed=2)
    L = texel_layout(pot)
    assert L is texel_layout(pot) and L.numel() == z.shape[1]
    own = texel_move(z, pot, torch.Generator().manual_seed(7))
    given = texel_move(z, pot, torch.Generator().manual_seed(7), layout=L.clone())
    assert torch.equal(own[0], given[0]) and own[1] == given[1]
    assert not torch.equal(own[0], z)
