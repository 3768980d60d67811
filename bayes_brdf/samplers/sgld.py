"""Stochastic-gradient Langevin dynamics (Welling & Teh 2011), n independent chains in parallel.

``x <- x - eps_t G grad U(x) + sqrt(2 eps_t G) xi`` with the step-size schedule
``eps_t = a (b + t)^(-gamma)`` and ``G = 1`` (``preconditioner = "none"``) or the
RMSprop diagonal of Li et al. 2016 (``"rmsprop"``, pSGLD), shared by all chains.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import torch
from torch import Tensor

from ..errors import InputError
from .base import Info, Sampler
from .config import Configurable
from .numerics import Preconditioner, precond_init, precond_update


class SGLDState(NamedTuple):
    z: Tensor
    precond: Preconditioner
    groups: int         # independent ensembles (each shares one preconditioner)


@dataclass
class SGLD(Configurable, Sampler):
    step_size: float = 0.01          # a
    schedule_b: float = 1.0          # b
    schedule_gamma: float = 0.0      # gamma (0: constant step size)
    preconditioner: str = "rmsprop"  # "rmsprop" or "none"
    rms_beta2: float = 0.99
    rms_eps: float = 1e-8

    name = "sgld"
    State = SGLDState

    def validate(self):
        self._positive("step_size", "schedule_b", "rms_eps")
        self._unit("rms_beta2")
        self._choice("preconditioner", ("rmsprop", "none"))
        if not 0 <= self.schedule_gamma <= 1:
            raise InputError(f"sgld parameter schedule_gamma must be in [0, 1], got {self.schedule_gamma!r}")

    def epsilon(self, t: int) -> float:
        return self.step_size * (self.schedule_b + t) ** (-self.schedule_gamma)

    def init(self, z0, potential, rng, *, steps, groups=1):
        return SGLDState(z0.clone(), precond_init(groups, z0.shape[1], z0), groups)

    def step(self, state, t, potential, rng):
        z = state.z
        u, grad = potential.value_and_grad(z)
        eps = self.epsilon(t)
        pc = state.precond
        if self.preconditioner == "rmsprop":
            pc, G = precond_update(pc, grad, self.rms_beta2, self.rms_eps)
        else:
            G = torch.ones((), dtype=z.dtype, device=z.device)
        shape = (state.groups, z.shape[0] // state.groups, z.shape[1])
        noise = torch.randn(z.shape, generator=rng, dtype=z.dtype, device=rng.device).to(z.device).view(shape)
        z = noise.mul_(G.mul(2 * eps).sqrt_()).addcmul_(G, grad.view(shape), value=-eps).add_(z.view(shape))
        z = z.view(state.z.shape)
        return state._replace(z=z, precond=pc), Info(u, {"step_size": eps})
