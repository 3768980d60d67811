"""Multi-start SGD/Adam: n independent point estimates from prior draws (the paper's "multiple SGD").

Not a sampler: each particle descends ``U`` without the log-Jacobian (i.e. it
maximises the target ``f(x)`` of Eq. 3 in constrained space) from its own
random start, all particles in one batched call. The spread of the results
is the naive "uncertainty" the paper compares against.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import torch
from torch import Tensor

from .base import Info, Sampler
from .config import Configurable
from .numerics import adam_direction


class MultistartState(NamedTuple):
    z: Tensor
    m: Tensor
    v: Tensor
    count: int


@dataclass
class MultistartSGD(Configurable, Sampler):
    optimizer: str = "adam"          # "adam" or "sgd"
    step_size: float = 0.05
    adam_beta1: float = 0.9
    adam_beta2: float = 0.999
    adam_eps: float = 1e-8
    jacobian: bool = False           # include the log-Jacobian (optimise in unconstrained density)

    name = "multistart_sgd"
    State = MultistartState

    def validate(self):
        self._positive("step_size", "adam_eps")
        self._unit("adam_beta1", "adam_beta2")
        self._choice("optimizer", ("adam", "sgd"))

    def particles_are_chains(self, dim: int) -> bool:
        return False     # point estimates, not chains

    def init(self, z0, potential, rng, *, steps, groups=1):
        return MultistartState(z0.clone(), torch.zeros_like(z0), torch.zeros_like(z0), 0)

    def step(self, state, t, potential, rng):
        u, grad = potential.value_and_grad(state.z, jacobian=self.jacobian)
        m, v, c = state.m, state.v, state.count + 1
        if self.optimizer == "adam":
            d, m, v = adam_direction(m, v, c, grad, self.adam_beta1, self.adam_beta2, self.adam_eps)
            z = state.z - self.step_size * d
        else:
            z = state.z - self.step_size * grad
        return MultistartState(z, m, v, c), Info(u)
