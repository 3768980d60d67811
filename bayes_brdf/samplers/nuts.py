"""The No-U-Turn sampler through Pyro (``pyro.infer.mcmc.NUTS``): a reference for low-dimensional problems.

One chain, stepped one transition per driver step with Pyro's own kernel
(step-size and diagonal mass-matrix adaptation during ``warmup_steps``). The
``n`` "particles" are the chain's last ``n`` draws, taken every ``thin``
transitions after warm-up (a ring buffer), so a run needs at least
``warmup_steps + n * thin`` steps. NUTS is inherently sequential; it is here as
a trusted reference, not for per-texel problems. Its adaptation state lives in
Pyro's kernel, which ``init`` builds for the run and the state carries as a
transient field (not data: checkpoints leave it out), so a resumed run replays
the chain from the start (same seed, same result) rather than continuing from
the checkpoint.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import torch
from pyro.infer.mcmc import NUTS as PyroNUTS
from torch import Tensor

from ..errors import InputError
from .base import Info, Sampler
from .config import Configurable
from .ensemble import _check_start


class NUTSState(NamedTuple):
    z: Tensor          # [n, D] the retained draws
    position: Tensor   # [D] the chain's current state
    kept: int
    kernel: PyroNUTS   # this run's Pyro kernel, with its adaptation (transient: left out of checkpoints)

    transient = ("kernel",)


@dataclass
class NUTS(Configurable, Sampler):
    warmup_steps: int = 200
    thin: int = 10
    step_size: float = 0.1           # initial step size (adapted during warm-up)
    target_accept: float = 0.8
    max_tree_depth: int = 8
    adapt_mass_matrix: bool = True

    name = "nuts"
    supports_groups = False
    State = NUTSState
    exact_resume = False
    continues_from_particles = False     # a new run from z0 warms up its step size and mass matrix again

    def validate(self):
        self._positive("step_size", "thin", "max_tree_depth")
        if not 0 < self.target_accept < 1:
            raise InputError(f"nuts parameter target_accept must be in (0, 1), got {self.target_accept!r}")
        if self.warmup_steps < 0:
            raise InputError(f"nuts parameter warmup_steps must be >= 0, got {self.warmup_steps!r}")

    def particles_are_chains(self, dim: int) -> bool:
        return False     # the particles are one chain's last draws

    def init(self, z0, potential, rng, *, steps, groups=1):
        n = z0.shape[0]
        need = self.warmup_steps + n * self.thin
        if steps < need:
            raise InputError(f"nuts with {n} particles needs at least warmup_steps + n * thin = {need} steps, "
                             f"got {steps}", fix="raise steps or lower warmup_steps/thin")

        with torch.no_grad():
            _check_start(-potential.energy(z0[:1]), self.name)

        def potential_fn(params):
            return potential.energy(params["z"][None])[0]

        k = PyroNUTS(potential_fn=potential_fn, step_size=self.step_size, adapt_step_size=True,
                     adapt_mass_matrix=self.adapt_mass_matrix, target_accept_prob=self.target_accept,
                     max_tree_depth=self.max_tree_depth, full_mass=False)
        k.initial_params = {"z": z0[0].clone()}
        k.setup(self.warmup_steps)
        return NUTSState(z0.clone(), z0[0].clone(), 0, k)

    def step(self, state, t, potential, rng):
        kernel = state.kernel
        params = kernel.sample({"z": state.position})
        pos = params["z"].detach()
        z, kept = state.z, state.kept
        if t >= self.warmup_steps and (t - self.warmup_steps) % self.thin == 0:
            z = z.clone()
            z[kept % z.shape[0]] = pos
            kept += 1
        diag = kernel.logging()
        u = torch.as_tensor(float(kernel._potential_energy_last), dtype=pos.dtype).reshape(1)
        return NUTSState(z, pos, kept, kernel), Info(u, {"step_size": float(diag.get("step size", float("nan")))})
