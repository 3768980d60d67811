"""Particles are packed per particle (rows of ``z [n, D]``), and Pyro 1.9.2's own SVGD is not.

The model has two latent sites with known moments: ``a ~ Normal(LOC_A, SC_A)`` (a 3-vector)
and ``b ~ LogNormal(MU_B, S_B)`` (positive, so its bijection ``u = log b`` matters). On the
unconstrained space ``z = (a, log b)`` its density is exactly that of the one-site model
``x ~ Normal((LOC_A, MU_B), (SC_A, S_B))``, so any particle method must give the same particles on
both models when started from the same particles, unless it mixes particles.

Pyro 1.9.2's ``pyro.infer.SVGD`` does: its guide (``AutoContinuous``) packs the latent vector site
by site (``[a of all particles, log b of all particles]``) and ``SVGD.step`` reshapes it to
``(num_particles, -1)``, so with two or more sites each "particle" its kernel sees is a slice
across several particles (../shared/DESIGN.md). The tests below record what Pyro's kernel is given
and compute the mixing explicitly; only the end-to-end comparison, which would pass once Pyro is
fixed, is an ``xfail(strict=False)``.
"""
from __future__ import annotations

import pyro
import pyro.distributions as dist
import pytest
import torch
from packaging.version import Version
from pyro.infer import SVGD as PyroSVGD
from pyro.infer import RBFSteinKernel
from pyro.optim import Adam

from bayes_brdf.potential import Potential
from bayes_brdf.samplers import SVGD, run

LOC_A = torch.tensor([1.0, -2.0, 0.5])
SC_A = torch.tensor([0.5, 1.0, 0.25])
MU_B, S_B = 0.3, 0.4
MEAN = torch.cat([LOC_A, torch.tensor([MU_B])])   # of z = (a, log b)
STD = torch.cat([SC_A, torch.tensor([S_B])])
PYRO_KNOWN_BUG = Version(pyro.__version__) <= Version("1.9.2")


def two_sites():
    pyro.sample("a", dist.Normal(LOC_A, SC_A).to_event(1))
    pyro.sample("b", dist.LogNormal(MU_B, S_B))


def one_site():
    """The same density on the unconstrained space of :func:`two_sites` (``x = (a, log b)``)."""
    pyro.sample("x", dist.Normal(MEAN, STD).to_event(1))


def coded_particles(n: int) -> dict:
    """Site values that say which particle they belong to: ``a[i] = i``, ``log b[i] = i``."""
    i = torch.arange(n, dtype=torch.float32)
    return {"a": i[:, None].expand(n, 3).clone(), "b": i.exp()}


# ------------------------------------------------------------------ our packing
def test_potential_packs_one_row_per_particle():
    pot = Potential(two_sites)
    assert pot.dim == 4 and [(s.name, s.offset, s.size) for s in pot.sites] == [("a", 0, 3), ("b", 3, 1)]
    n = 5
    vals = coded_particles(n)
    z = pot.to_unconstrained(vals)
    owner = z.round().long()                       # every coordinate says which particle it came from
    assert torch.equal(owner, torch.arange(n)[:, None].expand(n, 4))
    back = pot.to_constrained(z)
    assert back["a"].shape == (n, 3) and back["b"].shape == (n,)
    torch.testing.assert_close(back["a"], vals["a"])
    torch.testing.assert_close(back["b"], vals["b"])


def test_potential_energies_match_a_per_particle_loop():
    pot = Potential(two_sites)
    z = MEAN + STD * torch.randn(7, 4, generator=torch.Generator().manual_seed(0))
    u, g = pot.value_and_grad(z)
    assert u.shape == (7,) and g.shape == (7, 4)
    for i in range(7):
        # the reference: one particle at a time, by hand (log-Jacobian of b = exp(u) is u)
        zi = z[i].clone().requires_grad_(True)
        a, ub = zi[:3], zi[3]
        ui = -(dist.Normal(LOC_A, SC_A).log_prob(a).sum() + dist.LogNormal(MU_B, S_B).log_prob(ub.exp()) + ub)
        (gi,) = torch.autograd.grad(ui, zi)
        torch.testing.assert_close(u[i], ui.detach())
        torch.testing.assert_close(g[i], gi)
        torch.testing.assert_close(pot.energy(z[i:i + 1]), ui.detach().reshape(1))   # a batch of one
    # without the Jacobian: -log p(a, b) at the constrained values
    x = pot.to_constrained(z)
    ref = -(dist.Normal(LOC_A, SC_A).log_prob(x["a"]).sum(1) + dist.LogNormal(MU_B, S_B).log_prob(x["b"]))
    torch.testing.assert_close(pot.energy(z, jacobian=False), ref)
    # and the same energies as the one-site model of the same density
    torch.testing.assert_close(u, Potential(one_site).value_and_grad(z)[0])


def test_our_svgd_is_the_same_on_two_sites_and_one_site_and_recovers_the_moments():
    n = 60
    z0 = MEAN + STD * torch.randn(n, 4, generator=torch.Generator().manual_seed(1))
    two, one = Potential(two_sites), Potential(one_site)
    r2 = run(SVGD(step_size=0.05), two, particles=n, steps=20, z0=z0, progress=False)
    r1 = run(SVGD(step_size=0.05), one, particles=n, steps=20, z0=z0, progress=False)
    torch.testing.assert_close(r2.z, r1.z, atol=1e-5, rtol=1e-5)   # the same up to float32 rounding
    r2 = run(SVGD(step_size=0.05), two, particles=n, steps=300, z0=z0, progress=False)
    assert float((r2.z.mean(0) - MEAN).abs().div(STD).max()) < 0.05
    ratio = r2.z.std(0) / STD                       # SVGD is under-dispersed (measured 0.84-0.90 here)
    assert bool(((ratio > 0.75) & (ratio < 1.1)).all()), ratio


# ------------------------------------------------------------------ Pyro's packing
class RecordingKernel(RBFSteinKernel):
    """Pyro's RBF kernel that keeps a copy of the ``[num_particles, D]`` rows ``SVGD.step`` hands it."""

    seen: list

    def log_kernel_and_grad(self, particles):
        self.seen = getattr(self, "seen", []) + [particles.detach().clone()]
        return super().log_kernel_and_grad(particles)


def pyro_svgd(model, n: int, latent: torch.Tensor, kernel=None, lr: float = 0.05, mode: str = "univariate"):
    """Pyro's SVGD on ``model`` with its packed latent vector (``svgd_particles``) set to ``latent``."""
    pyro.clear_param_store()
    svgd = PyroSVGD(model, kernel or RBFSteinKernel(), Adam({"lr": lr}), num_particles=n, max_plate_nesting=0,
                    mode=mode)
    svgd.guide()                                         # creates the parameter "svgd_particles"
    p = pyro.param("svgd_particles").unconstrained()
    assert p.shape == latent.shape
    with torch.no_grad():
        p.copy_(latent)
    return svgd


def pyro_kernel_owner_rows(n: int) -> tuple[torch.Tensor, torch.Tensor]:
    """For every coordinate of the rows Pyro's kernel receives, the particle it belongs to; and those rows."""
    D = 4
    svgd = pyro_svgd(two_sites, n, torch.arange(n * D, dtype=torch.float32), RecordingKernel())
    # which particle owns which entry of the packed vector, by Pyro's own account (get_named_particles)
    named = svgd.get_named_particles()
    owner_of_entry = torch.empty(n * D, dtype=torch.long)
    owner_of_entry[named["a"].round().long()] = torch.arange(n)[:, None].expand(n, 3)
    owner_of_entry[named["b"].log().round().long()] = torch.arange(n)
    svgd.step()
    rows = svgd.kernel.seen[0]                             # what SVGD.step treats as particle i: rows[i]
    assert rows.shape == (n, D)
    pyro.clear_param_store()
    return owner_of_entry[rows.round().long()], rows


def test_pyro_svgd_particle_mixing_computed_explicitly():
    n = 4
    owner, rows = pyro_kernel_owner_rows(n)
    mixed = [i for i in range(n) if owner[i].unique().numel() > 1]
    if not PYRO_KNOWN_BUG and not mixed:
        pytest.skip(f"pyro {pyro.__version__} hands its kernel whole particles (the 1.9.2 bug is fixed)")
    # Known Pyro 1.9.2 bug (../shared/DESIGN.md): the packed vector is [a_0 a_1 a_2 a_3 | u_0 u_1 u_2 u_3]
    # (site by site, u = log b), SVGD.step reshapes it to (4, 4), so its "particle" 0 is (a_0, a_1[0]),
    # particle 1 is (a_1[1:], a_2[:2]), ..., particle 3 is (u_0, u_1, u_2, u_3).
    site_major = torch.cat([torch.arange(n)[:, None].expand(n, 3).reshape(-1), torch.arange(n)])
    assert torch.equal(owner, site_major.reshape(n, 4))
    assert mixed == [0, 1, 2, 3]
    assert torch.equal(owner[3], torch.arange(n))          # one "particle" holds log b of every particle
    # while ours packs rows = particles (see test_potential_packs_one_row_per_particle)
    ours = Potential(two_sites).to_unconstrained(coded_particles(n)).round().long()
    assert torch.equal(ours, torch.arange(n)[:, None].expand(n, 4))


@pytest.mark.xfail(PYRO_KNOWN_BUG, strict=False,
                   reason="Pyro 1.9.2 SVGD mixes particles of multi-site models (site-major packing, "
                          "reshape to (num_particles, -1)); see ../shared/DESIGN.md")
def test_pyro_svgd_is_the_same_on_two_sites_and_one_site():
    n, steps = 8, 100
    z0 = MEAN + STD * torch.randn(n, 4, generator=torch.Generator().manual_seed(2))
    s1 = pyro_svgd(one_site, n, z0.reshape(-1))
    for _ in range(steps):
        s1.step()
    x1 = s1.get_named_particles()["x"].detach()
    s2 = pyro_svgd(two_sites, n, torch.cat([z0[:, :3].reshape(-1), z0[:, 3]]))    # Pyro's own layout of z0
    for _ in range(steps):
        s2.step()
    p = s2.get_named_particles()
    x2 = torch.cat([p["a"], p["b"].log()[:, None]], 1).detach()
    pyro.clear_param_store()
    # measured with pyro 1.9.2: max |x2 - x1| = 1.05; mean of a[0] 0.81 (true 1.0), of log b 0.53 (true 0.3),
    # while the one-site run has 1.000 and 0.301
    torch.testing.assert_close(x2, x1, atol=1e-3, rtol=1e-3)
