"""The potential bridge: energies equal the closed-form posterior, gradients are right, particles stay apart."""
import math

import numpy as np
import pyro
import pyro.distributions as dist
import pytest
import torch

import bayes_brdf as bb
from bayes_brdf.errors import InputError
from bayes_brdf.models import ModelData
from bayes_brdf.potential import Potential
from bayes_brdf.render import PlanarSample, SVBRDF, View, PerspectiveCamera
from bayes_brdf.render.shade import render
from tests.render import numpy_reference as ref


def _one_pixel_data(albedo=0.5, rough=0.4, angle=20.0):
    """One pixel at the sample centre under a collocated flash, with its radiance from the numpy reference."""
    a = math.radians(angle)
    pos = np.array([2 * math.sin(a), 0.0, 2 * math.cos(a)])
    cam = PerspectiveCamera(position=tuple(pos), fov=1.0, resolution=(1, 1))
    view = View.collocated(cam, power=3.0)
    n = np.array([0.0, 0.0, 1.0])
    ldir = pos / np.linalg.norm(pos)
    f, nl = ref.brdf(np.full(3, albedo), rough, np.full(3, 0.04), n, ldir, ldir)
    y = f * nl * 3.0 / float(pos @ pos)
    obs = bb.Observations([view], torch.tensor(y, dtype=torch.float64).reshape(1, 1, 1, 3), PlanarSample(1.0))
    return ModelData.from_observations(obs, dtype=torch.float64), y


def _closed_form_energy(x_albedo, x_rough, y, sigma, angle=20.0):
    """-log p(x, y) by hand: uniform priors, Laplace likelihood on 3 channels (numpy reference renderer)."""
    a = math.radians(angle)
    pos = np.array([2 * math.sin(a), 0.0, 2 * math.cos(a)])
    ldir = pos / np.linalg.norm(pos)
    f, nl = ref.brdf(np.full(3, x_albedo), x_rough, np.full(3, 0.04), np.array([0.0, 0, 1]), ldir, ldir)
    r = f * nl * 3.0 / float(pos @ pos)
    loglik = -np.abs(y - r).sum() / sigma - 3 * math.log(2 * sigma)
    logprior = -math.log(1.0) - math.log(0.95)
    return -(loglik + logprior)


def test_energy_matches_closed_form_and_jacobian():
    data, y = _one_pixel_data()
    pot = Potential(bb.models.homogeneous(albedo="gray", sigma=0.02), (data,))
    vals = {"albedo": torch.tensor([[0.3], [0.7]], dtype=torch.float64),
            "roughness": torch.tensor([[0.2], [0.8]], dtype=torch.float64)}
    z = pot.to_unconstrained(vals)
    u = pot.energy(z, jacobian=False)
    for i in range(2):
        want = _closed_form_energy(float(vals["albedo"][i]), float(vals["roughness"][i]), y, 0.02)
        assert float(u[i]) == pytest.approx(want, rel=1e-9)
    # the log-Jacobian of the interval bijection, by hand: x = lo + (hi - lo) sigmoid(z)
    uj = pot.energy(z, jacobian=True)
    s = torch.sigmoid(z)
    ladj = (torch.log(s * (1 - s)) + torch.log(torch.tensor([1.0, 0.95], dtype=torch.float64))).sum(1)
    torch.testing.assert_close(uj, u - ladj)


def test_gradients_match_finite_differences():
    data, _ = _one_pixel_data()
    pot = Potential(bb.models.homogeneous(albedo="gray", sigma=0.05), (data,))
    z = pot.init(5, seed=3)
    _, g = pot.value_and_grad(z)
    h = 1e-6
    for d in range(pot.dim):
        e = torch.zeros_like(z)
        e[:, d] = h
        fd = (pot.energy(z + e) - pot.energy(z - e)) / (2 * h)
        torch.testing.assert_close(g[:, d], fd, rtol=1e-5, atol=1e-6)


def test_one_batched_run_equals_a_loop_over_particles():
    views = bb.render.collocated_views(3, 3.0, camera="rectified", resolution=8, power=10.0)
    truth = SVBRDF.constant(0.4, 0.3, dtype=torch.float64)
    obs = bb.Observations(views, render(truth, views, PlanarSample(2.0))[0].float(), PlanarSample(2.0))
    data = ModelData.from_observations(obs, dtype=torch.float64)
    model = bb.models.per_texel(8, specular="infer", normals="infer", smoothness=bb.priors.tv(3.0))
    pot = Potential(model, (data,))
    z = pot.init(4, seed=1)
    u, g = pot.value_and_grad(z)
    for i in range(4):
        ui, gi = pot.value_and_grad(z[i:i + 1])
        torch.testing.assert_close(u[i:i + 1], ui, rtol=1e-10, atol=1e-8)
        torch.testing.assert_close(g[i:i + 1], gi, rtol=1e-10, atol=1e-8)
    # rows are particles: particle i's constrained values come from row i only
    x = pot.to_constrained(z)
    torch.testing.assert_close(pot.to_constrained(z[2:3])["roughness"][0], x["roughness"][2])
    assert pot.dim == 8 * 8 * (3 + 1 + 1 + 2)


def test_init_draws_from_the_prior():
    data, _ = _one_pixel_data()
    pot = Potential(bb.models.homogeneous(albedo="gray", prior={"roughness": bb.priors.gaussian(0.2, 0.05)}), (data,))
    x = pot.to_constrained(pot.init(4000, seed=0))
    assert abs(float(x["albedo"].mean()) - 0.5) < 0.02 and abs(float(x["albedo"].var()) - 1 / 12) < 0.005
    assert abs(float(x["roughness"].mean()) - 0.2) < 0.005 and abs(float(x["roughness"].std()) - 0.05) < 0.005
    assert torch.equal(pot.init(7, seed=5), pot.init(7, seed=5))


def test_user_model_with_plates_and_factor():
    def model():
        with pyro.plate("rows", 3, dim=-1):
            a = pyro.sample("a", dist.Normal(0.0, 1.0))
        b = pyro.sample("b", dist.LogNormal(torch.zeros(2), 1.0).to_event(1))
        # plate-aware, as in any vectorised Pyro model: keep the plate dim so the particle dim lines up
        pyro.factor("coupling", -0.5 * (a.sum(-1, keepdim=True) - b.sum(-1)) ** 2)

    pot = Potential(model)
    assert pot.plate_nesting == 1 and pot.dim == 5
    z = torch.randn(6, 5, dtype=torch.float32)
    u = pot.energy(z)
    for i in range(6):
        a, lb = z[i, :3], z[i, 3:]
        b = lb.exp()
        want = -(dist.Normal(0.0, 1.0).log_prob(a).sum() + dist.LogNormal(0.0, 1.0).log_prob(b).sum()
                 - 0.5 * (a.sum() - b.sum()) ** 2 + lb.sum())
        assert float(u[i]) == pytest.approx(float(want), rel=1e-5)


def test_bad_models_are_one_line_errors():
    with pytest.raises(InputError, match="no latent sites"):
        Potential(lambda: None)

    def broken():
        pyro.sample("x", dist.Normal(0.0, 1.0))
        raise ValueError("oops")

    with pytest.raises(InputError, match="failed on a prior run: ValueError: oops"):
        Potential(broken)
    pot = Potential(lambda: pyro.sample("x", dist.Normal(0.0, 1.0)))
    with pytest.raises(InputError, match=r"expected \[n, 1\]"):
        pot.energy(torch.zeros(3, 2))


def test_minibatch_of_views_is_unbiased():
    views = bb.render.collocated_views(4, 3.0, camera="rectified", resolution=6, power=10.0)
    obs = bb.Observations(views, render(SVBRDF.constant(0.4, 0.3), views, PlanarSample(2.0))[0], PlanarSample(2.0))
    data = ModelData.from_observations(obs, dtype=torch.float64)
    # a fixed sigma: the log-likelihood is a sum over pixels, so a rescaled minibatch is unbiased (under
    # sigma = "auto" it is a consistent estimate: the minibatch's own profile sigma, docs/models.md)
    model = bb.models.homogeneous(albedo="gray", sigma=0.01)
    pot = Potential(model, (data,))
    z = pot.init(3, seed=0)
    full = pot.energy(z, jacobian=False)
    # every 2-view subset is equally likely, so the mean over all of them is the expectation
    import itertools
    from dataclasses import replace
    subs = []
    for idx in itertools.combinations(range(4), 2):
        d = replace(data, gbuffer=data.gbuffer.views_index(list(idx)), images=data.images[list(idx)],
                    weight=data.weight[list(idx)], scale=2.0)
        subs.append(Potential(model, (d,)).energy(z, jacobian=False))
    prior = -math.log(0.95)
    torch.testing.assert_close(torch.stack(subs).mean(0) - prior, full - prior)
    # and the driver's minibatch draws such subsets
    gen = torch.Generator().manual_seed(0)
    mb = pot.minibatch(gen, views=2)
    assert mb.args[0].num_views == 2 and mb.args[0].scale == 2.0


def test_fused_interval_bijection_matches_pyro_transform():
    from torch.distributions import biject_to, constraints

    from bayes_brdf.potential import IntervalBijection, _IntervalFn
    c = constraints.interval(0.05, 1.0)
    fast, ref_t = IntervalBijection.maybe(c), biject_to(c)
    u = torch.randn(4, 3, 5, dtype=torch.float64) * 4
    x, lj = fast.forward_with_ladj(u)
    torch.testing.assert_close(x, ref_t(u))
    torch.testing.assert_close(lj, ref_t.log_abs_det_jacobian(u, ref_t(u)).reshape(4, -1).sum(1))
    assert torch.autograd.gradcheck(lambda v: _IntervalFn.apply(v, 0.05, 1.0), (u.requires_grad_(True),))
    # stable where float32 sigmoids saturate
    _, lj32 = fast.forward_with_ladj(torch.tensor([[40.0, -40.0]]))
    assert torch.isfinite(lj32).all()
    assert IntervalBijection.maybe(constraints.interval(torch.tensor([0.0, 0.1]), 1.0)) is None


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_native_interval_kernel_equals_the_torch_ops(monkeypatch, dtype):
    """The native loop (CPU) against the torch ops it replaces, on a strided slice of ``z`` as ``energy``
    passes it, with both gradients (dL/dx and dL/dladj); saturated coordinates included."""
    import bayes_brdf.potential as P

    if P._interval_kernels(torch.zeros(1, dtype=dtype)) is None:
        pytest.skip("native kernels unavailable here")
    gen = torch.Generator().manual_seed(0)
    z = torch.randn(5, 2, 3001, generator=gen, dtype=dtype) * 8
    z[0, 1, :3] = torch.tensor([60.0, -60.0, 0.0], dtype=dtype)
    gx, gl = torch.randn(5, 3001, generator=gen, dtype=dtype), torch.randn(5, generator=gen, dtype=dtype)

    def run():
        u = z.detach().requires_grad_(True)
        x, lj = P._IntervalFn.apply(u[:, 1], 0.01, 1.0)
        (g,) = torch.autograd.grad((x * gx).sum() + (lj * gl).sum(), u)
        return x.detach(), lj.detach(), g

    fast = run()
    monkeypatch.setattr(P, "_interval_kernels", lambda u: None)
    ref = run()
    tol = 1e-5 if dtype == torch.float32 else 1e-12
    for a, b in zip(fast, ref):
        assert a.dtype == b.dtype and torch.isfinite(a).all()
        torch.testing.assert_close(a, b, rtol=tol, atol=tol * float(b.abs().max()))


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_constrained_values_without_a_graph_are_the_forwards(monkeypatch, dtype):
    """``IntervalBijection`` called on values without a gradient (a texel sweep's renders, the outputs' maps) runs
    the native map: the native forward's values and torch's sigmoid's within rounding (the vector and scalar exp
    differ in the last bits), on a strided slice, an expanded tensor and saturated coordinates; with a graph,
    torch's ops."""
    from torch.distributions import constraints

    import bayes_brdf.potential as P

    if P._interval_map_kernel(torch.zeros(1, dtype=dtype)) is None:
        pytest.skip("native kernels unavailable here")
    t = P.IntervalBijection.maybe(constraints.interval(0.01, 0.7))
    gen = torch.Generator().manual_seed(0)
    z = torch.randn(5, 2, 3001, generator=gen, dtype=dtype) * 8
    z[0, 1, :3] = torch.tensor([60.0, -60.0, 0.0], dtype=dtype)
    u = z[:, 1]                                                     # rows 6002 apart
    x = t(u)
    tol = 1e-6 if dtype == torch.float32 else 1e-14
    torch.testing.assert_close(x, P._IntervalFn.apply(u, t.lo, t.hi)[0], rtol=tol, atol=tol)
    torch.testing.assert_close(x, torch.sigmoid(u) * (t.hi - t.lo) + t.lo, rtol=tol, atol=tol)
    assert torch.equal(t(u[:1].expand(3, -1)), x[:1].expand(3, -1))
    g = u.clone().requires_grad_(True)
    monkeypatch.setattr(P, "_interval_map_kernel", lambda u: pytest.fail("a graph needs torch's ops"))
    assert t(g).requires_grad


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_all_sites_at_once_give_the_per_site_numbers(monkeypatch, dtype):
    """The fused unpack (every site on an interval or unconstrained: each site's gradient written into its columns
    of dL/dz) gives the per-site path's energies and gradients bit for bit, with and without the Jacobian, and
    the per-site path still serves a model with another support (a positive site)."""
    import pyro
    import pyro.distributions as dist

    import bayes_brdf.potential as P

    if P._interval_kernels(torch.zeros(1, dtype=dtype)) is None:
        pytest.skip("native kernels unavailable here")

    def model(positive=False):
        a = pyro.sample("a", dist.Uniform(torch.zeros(3, 7, dtype=dtype), 1.0).to_event(2))
        b = pyro.sample("b", dist.Normal(torch.zeros(5, dtype=dtype), 2.0).to_event(1))
        r = pyro.sample("r", dist.Uniform(torch.full((4,), 0.05, dtype=dtype), 1.0).to_event(1))
        if positive:
            s = pyro.sample("s", dist.LogNormal(torch.zeros(2, dtype=dtype), 1.0).to_event(1))
            b = b * s.sum(-1, keepdim=True)
        pyro.factor("lik", -((a.sum((-1, -2)) - 3.0) ** 2 + (b.sin() * r[..., :1]).sum(-1) ** 2))

    for positive in (False, True):
        pot = P.Potential(model, kwargs={"positive": positive})
        assert (pot._fused_plan(torch.zeros(1, pot.dim, dtype=dtype)) is None) == positive
        z = pot.init(6, seed=1) * 3
        fused = [pot.value_and_grad(z, jacobian=j) for j in (True, False)]
        with monkeypatch.context() as m:
            m.setattr(P.Potential, "_fused_plan", lambda self, z: None)
            ref = [pot.value_and_grad(z, jacobian=j) for j in (True, False)]
        for (u, g), (ur, gr) in zip(fused, ref):
            assert torch.equal(u, ur) and torch.equal(g, gr)
