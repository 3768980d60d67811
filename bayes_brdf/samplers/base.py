"""The sampler contract (blackjax style): :class:`Potential` and :class:`Sampler` protocols, the :class:`Info` tuple.

A sampler's hyper-parameters are captured once, when it is built (a dataclass, :mod:`.config`); a
run then goes through two methods and nothing else is written onto the sampler:

* ``init(z0, potential, rng, *, steps, groups=1) -> state`` -- the starting state from particles
  ``z0 [groups * n, D]``. ``steps`` is the run's horizon (SPOS's and SVGD's annealing, NUTS's
  warm-up check) and ``groups`` the number of independent ensembles batched in the run (``n``
  particles each, group by group); whatever ``step`` needs of them goes into the state.
* ``step(state, t, potential, rng) -> (state, info)`` -- step ``t`` (0-based) from ``state``,
  drawing its randomness from ``rng`` (a ``torch.Generator``); ``potential`` is the run's, or a
  minibatch of it.

Samplers see only a :class:`Potential` (:class:`bayes_brdf.potential.Potential` for a Pyro model,
:class:`~bayes_brdf.potential.FunctionPotential` for a plain density) and import nothing from
``render`` or ``models``, so the same sampler runs on any model.

States are ``NamedTuple``\\ s of tensors and numbers (and ``NamedTuple``\\ s of them): what the
driver checkpoints, so that a resumed run ends exactly where an uninterrupted one would. A field
that holds a live object rather than data (emcee's ``EnsembleSampler``, Pyro's NUTS kernel) is named
in the state class's ``transient`` tuple: checkpoints leave it out and a resume keeps the one its
own ``init`` built (NUTS's kernel carries its adaptation, which is why NUTS sets
``exact_resume = False`` and replays instead).

:class:`bayes_brdf.samplers.driver.run` owns the loop around them: seeds, progress, NaN checks,
callbacks, checkpoints, minibatches, the convergence checks.
"""
from __future__ import annotations

from collections.abc import Mapping
from types import MappingProxyType
from typing import NamedTuple, Protocol, runtime_checkable

import torch
from torch import Tensor


@runtime_checkable
class Potential(Protocol):
    """What a sampler sees of a model: ``U(z) = -log p(z)`` and its gradient for particles ``z [n, D]``.

    The driver also calls ``init(n, seed=..., margin=...)`` (prior draws) when it is given no
    starting particles, and ``minibatch(rng, views=..., pixels=...)`` for minibatched runs.
    """

    dim: int
    dtype: torch.dtype
    device: torch.device

    def energy(self, z: Tensor, *, jacobian: bool = True) -> Tensor:
        """``U(z)``: per-particle energies ``[n]`` (``jacobian=False``: without the log-Jacobian)."""

    def value_and_grad(self, z: Tensor, *, jacobian: bool = True) -> tuple[Tensor, Tensor]:
        """``(U(z) [n], dU/dz [n, D])`` from one batched evaluation."""


_NO_EXTRAS: Mapping[str, float] = MappingProxyType({})


class Info(NamedTuple):
    """What one step reports: ``energy``, the energies it evaluated (SPOS, SVGD, SGLD, multi-start: ``[n]``
    of the particles it started from; emcee: ``[n]`` of the walkers it ends with; NUTS: the chain's,
    ``[1]``), or ``None``; and sampler-specific ``extras`` (SPOS/SVGD ``gamma``, SGLD/NUTS
    ``step_size``, emcee ``accepted``).

    It also reads as the mapping ``info`` used to be (``info["energy"]``, ``info.get("gamma")``,
    ``"gamma" in info``), so callbacks written for a dict keep working.

    Example:
        >>> info = Info(torch.zeros(3), {"gamma": 0.5})
        >>> info.extras["gamma"], info["gamma"], info.get("energy").shape, info.get("accepted")
        (0.5, 0.5, torch.Size([3]), None)
    """

    energy: Tensor | None
    extras: Mapping[str, float] = _NO_EXTRAS

    def __getitem__(self, key):
        if isinstance(key, str):
            return self.energy if key == "energy" else self.extras[key]
        return tuple.__getitem__(self, key)

    def __contains__(self, key) -> bool:
        if isinstance(key, str):
            return key == "energy" or key in self.extras
        return tuple.__contains__(self, key)

    def get(self, key: str, default=None):
        return self[key] if key in self else default

    def keys(self) -> tuple[str, ...]:
        return ("energy", *self.extras)


@runtime_checkable
class Sampler(Protocol):
    """The sampler contract (see the module docstring).

    Subclass it to inherit the defaults below (``exact_resume``, ``uses_gradients``,
    ``supports_groups``, ``continues_from_particles``, :meth:`particles`, :meth:`particles_are_chains`); any object with these
    members works with the driver. The built-in samplers are dataclasses that also derive from
    :class:`~bayes_brdf.samplers.config.Configurable` (``from_params``, ``params``, ``validate``).
    """

    #: the registry name (``SAMPLERS``), also what progress bars and errors say
    name: str
    #: whether resuming from a checkpoint continues exactly like an uninterrupted run
    exact_resume: bool = True
    #: whether ``step`` uses gradients (emcee does not)
    uses_gradients: bool = True
    #: whether the sampler can run ``groups`` independent ensembles in one call
    supports_groups: bool = True
    #: whether a run started from another run's particles (``z0``) carries that run on: its state is the
    #: particles (and what ``init`` rebuilds from them), not a chain's adaptation (NUTS warms up anew).
    #: ``bb.infer`` cuts a signal-dependent-noise run in two phases only for such samplers.
    continues_from_particles: bool = True

    def params(self) -> dict:
        """The hyper-parameters, ``{name: value}`` (part of a checkpoint's signature)."""
        raise NotImplementedError

    def init(self, z0: Tensor, potential: Potential, rng: torch.Generator, *, steps: int, groups: int = 1):
        """The starting state for particles ``z0 [groups * n, D]``, a run of horizon ``steps``."""
        raise NotImplementedError

    def step(self, state, t: int, potential: Potential, rng: torch.Generator) -> tuple[tuple, Info]:
        """Step ``t``: ``(new state, Info)``."""
        raise NotImplementedError

    def particles(self, state) -> Tensor:
        """The current samples ``[n, D]``."""
        return state.z

    def particles_are_chains(self, dim: int) -> bool:
        """Whether R-hat / ESS over the particles mean something for a ``dim``-dimensional problem: not
        for samplers whose particles settle on fixed points (SVGD, multi-start) or that keep one chain (NUTS)."""
        return True
