"""The sampler contract: ``init(z0, potential, rng) -> state`` and ``step(state, t, potential, rng) -> (state, info)``.

Samplers see only a *potential*: an object with ``value_and_grad(z, jacobian=...)
-> (U [n], dU/dz [n, D])``, ``energy(z) -> [n]``, ``dim`` and ``dtype``
(:class:`bayes_brdf.potential.Potential` for a Pyro model,
:class:`~bayes_brdf.potential.FunctionPotential` for a plain density). They
import nothing from ``render`` or ``models``, so the same sampler runs on any
model. States are ``NamedTuple``\\ s of tensors and numbers (blackjax style),
which is what the driver checkpoints. Hyper-parameters are dataclass fields,
so a preset file spells them out and an unknown key is an error.
"""
from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import torch
from torch import Tensor

from ..errors import InputError


class Sampler:
    """Base class: hyper-parameters as dataclass fields plus the init/step contract."""

    name = "sampler"
    #: whether resuming from a checkpoint continues exactly like an uninterrupted run
    exact_resume = True
    #: whether ``step`` uses gradients (emcee does not)
    uses_gradients = True

    #: whether the sampler can run ``groups`` independent ensembles in one call
    supports_groups = True
    #: whether every particle is a Markov chain (R-hat / ESS over particles are meaningful); not for
    #: samplers whose particles settle on fixed points (SVGD, multi-start) or that keep one chain (NUTS)
    chains = True
    num_steps: int = 1000  # set by the driver before ``init`` (annealing needs the horizon)
    groups: int = 1        # set by the driver: independent ensembles batched in one run

    def init(self, z0: Tensor, potential, rng: torch.Generator):
        raise NotImplementedError

    def step(self, state, t: int, potential, rng: torch.Generator):
        raise NotImplementedError

    def particles_are_chains(self, dim: int) -> bool:
        """Whether R-hat / ESS over the particles mean something for a ``dim``-dimensional problem."""
        return self.chains

    def particles(self, state) -> Tensor:
        """The current samples ``[n, D]``."""
        return state.z

    def state_type(self):
        return self.State  # noqa

    # ------------------------------------------------------------------ configuration
    @classmethod
    def from_params(cls, params: dict | None = None) -> "Sampler":
        """Build from a ``{hyper-parameter: value}`` table; unknown keys and bad values are one-line errors."""
        params = dict(params or {})
        fields = {f.name: f for f in dataclasses.fields(cls)}
        extra = set(params) - set(fields)
        if extra:
            raise InputError(f"unknown {cls.name} parameter(s) {sorted(extra)}", fix=f"allowed: {sorted(fields)}")
        kw = {}
        for k, v in params.items():
            kw[k] = _coerce(cls.name, k, v, fields[k])
        s = cls(**kw)
        s.validate()
        return s

    def params(self) -> dict:
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}

    def validate(self):
        """Check hyper-parameter values (one-line :class:`InputError`)."""

    def _positive(self, *names):
        for k in names:
            v = getattr(self, k)
            if not (isinstance(v, (int, float)) and v > 0 and math.isfinite(v)):
                raise InputError(f"{self.name} parameter {k} must be a positive number, got {v!r}")

    def _unit(self, *names):
        """Parameters that must lie strictly inside (0, 1) (decay rates)."""
        for k in names:
            v = getattr(self, k)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0 < v < 1:
                raise InputError(f"{self.name} parameter {k} must be in (0, 1), got {v!r}")

    def _choice(self, name, options):
        v = getattr(self, name)
        if v not in options:
            raise InputError(f"{self.name} parameter {name} must be one of {list(options)}, got {v!r}")


def _coerce(sampler: str, key: str, value, field):
    default = field.default if field.default is not dataclasses.MISSING else None
    if isinstance(default, bool):
        if not isinstance(value, bool):
            raise InputError(f"{sampler} parameter {key} must be true or false, got {value!r}")
        return value
    if isinstance(default, float) and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    if isinstance(default, (int, float)) and not isinstance(default, bool):
        if isinstance(value, bool) or not isinstance(value, (int, float)) or \
                (isinstance(default, int) and not isinstance(default, bool) and not isinstance(value, int)):
            if not (isinstance(field.type, str) and "str" in field.type and isinstance(value, str)):
                what = "an integer" if isinstance(default, int) and isinstance(value, float) else "a number"
                raise InputError(f"{sampler} parameter {key} must be {what}, got {value!r}")
    if isinstance(default, str) and not isinstance(value, str):
        if not (isinstance(field.type, str) and ("float" in field.type or "int" in field.type)
                and isinstance(value, (int, float)) and not isinstance(value, bool)):
            raise InputError(f"{sampler} parameter {key} must be a string, got {value!r}")
    return value


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
    """The annealing weight ``gamma(t) = tanh((1.4 t / T)^delta)`` of Eq. (6)."""
    if horizon <= 0:
        return 1.0
    return math.tanh((1.4 * t / horizon) ** delta)
