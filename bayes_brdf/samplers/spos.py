"""Stochastic particle-optimisation sampling (SPOS; Zhang et al. 2020), exactly as the paper's Eqs. (4)-(6).

For particles ``x_i`` (rows of ``z``), with ``g_j = gamma(t) grad U(x_j)``::

    x_i <- x_i + lambda G [ -1/n sum_j k(x_j, x_i) g_j + 1/n sum_j grad_{x_j} k(x_j, x_i) - g_i / beta ]
               + sqrt(2 lambda G' / beta) xi_i

``k`` is the RBF kernel with the median bandwidth (Eq. 5), ``gamma(t) =
tanh((1.4 t / T)^delta)`` the annealing of Eq. (6) and ``G`` the diagonal
Adam step-size preconditioner: ``1 / (sqrt(v_hat) + eps)`` from the running
second moment of the deterministic update (the bracket above), per coordinate
and shared by the particles of an ensemble, so that ``lambda`` is a step in
parameter units as with Adam. The noise is scaled by ``G' = min(G, G_1)``
where ``G_1`` comes from the same update without annealing (``gamma = 1``):
once ``gamma(t) ~ 1`` the two agree and the step is the consistent
preconditioned Langevin step; early on, while the annealed drift is nearly
zero, ``G`` alone would blow the noise up and throw particles to the
saturated ends of the constrained range. ``preconditioner = "none"`` gives
the plain update with ``G = G' = 1``.

``beta`` weighs the Langevin part against the Stein (kernel) part. A large
``beta`` is nearly SVGD (good in low dimension, collapses in high dimension);
``beta = 1`` is calibrated in high dimension. ``beta = "auto"`` picks
``max(1, beta_low_dim * 2 / D)``: measured choices in docs/samplers.md.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import torch
from torch import Tensor

from ..errors import InputError
from .base import Preconditioner, Sampler, anneal, precond_init, precond_update
from .kernels import kernel_apply, rbf_median


class SPOSState(NamedTuple):
    z: Tensor
    precond: Preconditioner
    precond_noise: Preconditioner


@dataclass
class SPOS(Sampler):
    step_size: float = 0.05          # lambda (parameter units with the Adam preconditioner)
    beta: "float | str" = "auto"     # Langevin inverse temperature of Eq. (4), or "auto"
    beta_low_dim: float = 200.0      # "auto": beta in 2-D, decreasing as 2/D to 1
    anneal: bool = True
    anneal_delta: float = 1.0        # delta of Eq. (6)
    anneal_fraction: float = 0.2     # T of Eq. (6) as a fraction of the run's steps
    preconditioner: str = "adam"     # "adam" or "none"
    adam_beta2: float = 0.99
    adam_eps: float = 1e-8

    name = "spos"
    State = SPOSState

    def validate(self):
        self._positive("step_size", "anneal_delta", "adam_eps", "beta_low_dim")
        self._choice("preconditioner", ("adam", "none"))
        if not (self.beta == "auto" or (isinstance(self.beta, (int, float)) and not isinstance(self.beta, bool)
                                        and self.beta > 0)):
            raise _bad("beta", self.beta, "a positive number or \"auto\"")
        self._unit("adam_beta2")
        if not 0 < self.anneal_fraction <= 1:
            raise _bad("anneal_fraction", self.anneal_fraction, "in (0, 1]")

    def beta_for(self, dim: int) -> float:
        return max(1.0, self.beta_low_dim * 2.0 / dim) if self.beta == "auto" else float(self.beta)

    def init(self, z0, potential, rng):
        p0 = precond_init(self.groups, z0.shape[1], z0)
        return SPOSState(z0.clone(), p0, p0)

    def step(self, state, t, potential, rng):
        z = state.z
        n, D = z.shape[0] // self.groups, z.shape[1]
        u, grad = potential.value_and_grad(z)
        gam = anneal(t, round(self.anneal_fraction * self.num_steps), self.anneal_delta) if self.anneal else 1.0
        beta = self.beta_for(D)
        K, rep = rbf_median(z, self.groups)
        kg = kernel_apply(K, grad)
        shape = (self.groups, n, D)
        pc, pn = state.precond, state.precond_noise
        if self.preconditioner == "adam" and gam < 0.99:
            # un-annealed update, for the noise's scale (see the module docstring)
            pn, G1 = precond_update(pn, (rep - kg).div_(n).sub_(grad, alpha=1 / beta), self.adam_beta2,
                                    self.adam_eps)
        drift = rep.sub_(kg, alpha=gam).div_(n).sub_(grad, alpha=gam / beta)    # in place: rep is ours
        if self.preconditioner == "adam":
            pc, G = precond_update(pc, drift, self.adam_beta2, self.adam_eps)
            Gn = torch.minimum(G, G1) if gam < 0.99 else G
        else:
            G = Gn = torch.ones((), dtype=z.dtype, device=z.device)
        noise = torch.randn(z.shape, generator=rng, dtype=z.dtype, device=rng.device).to(z.device)
        noise = noise.view(shape).mul_(Gn.mul(2 * self.step_size / beta).sqrt_())
        z = noise.addcmul_(G, drift.view(shape), value=self.step_size).add_(z.view(shape)).view(z.shape)
        return SPOSState(z, pc, pn), {"energy": u, "gamma": gam}


def _bad(name, value, what):
    return InputError(f"spos parameter {name} must be {what}, got {value!r}")
