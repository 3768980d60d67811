"""Numerics shared by the samplers: the Adam/RMSprop diagonal preconditioner, Adam's direction, annealing.

Plain functions of tensors and numbers; a sampler keeps what they carry from step to step
(:class:`Preconditioner`, Adam's moments) in its state.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import torch
from torch import Tensor


class Preconditioner(NamedTuple):
    """Running second moment of the gradients, shared by the particles of a group (RMSprop/Adam style)."""

    v: Tensor      # [G, D]
    count: int


def precond_init(groups: int, dim: int, like: Tensor) -> Preconditioner:
    return Preconditioner(torch.zeros(groups, dim, dtype=like.dtype, device=like.device), 0)


def precond_update(p: Preconditioner, grad: Tensor, beta2: float, eps: float) -> tuple[Preconditioner, Tensor]:
    """Update with ``grad [G * n, D]`` (averaged over each group's particles); return the new state and
    the Adam/RMSprop diagonal step-size scale ``G = 1 / (sqrt(v_hat) + eps)`` as ``[G, 1, D]`` (it
    broadcasts over a ``[G, n, D]`` view of the particles)."""
    groups = p.v.shape[0]
    g = grad.reshape(groups, -1, grad.shape[1])
    g2 = torch.einsum("gnd,gnd->gd", g, g).div_(g.shape[1])
    v = torch.lerp(g2, p.v, beta2)              # beta2 v + (1 - beta2) g^2
    c = p.count + 1
    scale = v.div(1 - beta2 ** c).sqrt_().add_(eps).reciprocal_()
    return Preconditioner(v, c), scale[:, None, :]


def adam_direction(m: Tensor, v: Tensor, count: int, g: Tensor, beta1: float, beta2: float,
                   eps: float) -> tuple[Tensor, Tensor, Tensor]:
    """One Adam moment update with gradient-like ``g``; returns ``(direction, m, v)`` where the step is
    ``step_size * direction`` (``count`` is the 1-based step number for the bias correction)."""
    m = beta1 * m + (1 - beta1) * g
    v = beta2 * v + (1 - beta2) * g * g
    mh, vh = m / (1 - beta1 ** count), v / (1 - beta2 ** count)
    return mh / (vh.sqrt() + eps), m, v


def anneal(t: int, horizon: int, delta: float) -> float:
    """The annealing weight ``gamma(t) = tanh((1.4 t / T)^delta)`` of Eq. (6).

    Example:
        >>> anneal(0, 100, 1.0), round(anneal(100, 100, 1.0), 3), anneal(5, 0, 1.0)
        (0.0, 0.885, 1.0)
    """
    if horizon <= 0:
        return 1.0
    return math.tanh((1.4 * t / horizon) ** delta)
