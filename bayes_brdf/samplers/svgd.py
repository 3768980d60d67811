"""Stein variational gradient descent (Liu & Wang 2016): RBF kernel, median heuristic, optional annealing.

``x_i <- x_i + lambda * Adam( 1/n sum_j [ -k(x_j, x_i) gamma(t) grad U(x_j) + grad_{x_j} k(x_j, x_i) ] )``

Deterministic: the particles converge to a set whose spread reflects the
posterior in low dimension but under-estimates it in high dimension (see
docs/samplers.md). The step is Adam on the Stein direction (the original
paper used AdaGrad), or plain gradient steps with ``optimizer = "sgd"``.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import torch
from torch import Tensor

from ..errors import InputError
from .base import Info, Sampler
from .config import Configurable
from .kernels import kernel_apply, rbf_median
from .numerics import adam_direction, anneal


class SVGDState(NamedTuple):
    z: Tensor
    m: Tensor
    v: Tensor
    count: int
    num_steps: int      # the run's horizon (annealing)
    groups: int         # independent ensembles, n particles each


@dataclass
class SVGD(Configurable, Sampler):
    step_size: float = 0.05
    optimizer: str = "adam"          # "adam" or "sgd"
    adam_beta1: float = 0.9
    adam_beta2: float = 0.999
    adam_eps: float = 1e-8
    anneal: bool = False
    anneal_delta: float = 1.0
    anneal_fraction: float = 0.5

    name = "svgd"
    State = SVGDState

    def validate(self):
        self._positive("step_size", "adam_eps", "anneal_delta")
        self._unit("adam_beta1", "adam_beta2")
        self._choice("optimizer", ("adam", "sgd"))
        if not 0 < self.anneal_fraction <= 1:
            raise InputError(f"svgd parameter anneal_fraction must be in (0, 1], got {self.anneal_fraction!r}")

    def particles_are_chains(self, dim: int) -> bool:
        return False     # deterministic: the particles settle on a fixed set

    def init(self, z0, potential, rng, *, steps, groups=1):
        return SVGDState(z0.clone(), torch.zeros_like(z0), torch.zeros_like(z0), 0, steps, groups)

    def step(self, state, t, potential, rng):
        z = state.z
        n = z.shape[0] // state.groups
        u, grad = potential.value_and_grad(z)
        gam = anneal(t, round(self.anneal_fraction * state.num_steps), self.anneal_delta) if self.anneal else 1.0
        K, rep = rbf_median(z, state.groups)
        phi = (rep - kernel_apply(K, gam * grad)) / n
        m, v, c = state.m, state.v, state.count + 1
        if self.optimizer == "adam":
            d, m, v = adam_direction(m, v, c, phi, self.adam_beta1, self.adam_beta2, self.adam_eps)
            z = z + self.step_size * d
        else:
            z = z + self.step_size * phi
        return state._replace(z=z, m=m, v=v, count=c), Info(u, {"gamma": gam})
