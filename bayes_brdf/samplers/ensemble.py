"""Ensemble MH with the affine-invariant stretch move (Goodman & Weare 2010), through the ``emcee`` package.

Gradient-free. One driver step is one ensemble step of ``emcee.EnsembleSampler``
with ``vectorize=True``: emcee updates the walkers in two halves, so the
potential is called with ``n / 2`` particles at a time (still one batched
model run per call). emcee's random state travels in our state, so a resumed
run continues exactly. The ``EnsembleSampler`` itself is built once per run by
``init`` (building one costs about as much as a step) and rides in the state
as a transient field: it holds nothing of the chain, so checkpoints leave it
out. With fewer than ``2 D`` walkers the stretch move cannot explore the space
(the ensemble spans a subspace): a clear warning says so.

Walkers left behind. A stretch move puts a walker on the line through itself and another walker, never
onto the other walker, so a walker that a prior draw started in a far local mode of a narrow posterior
stays there for good (measured: 7 of 10 seeds on a 2-D BRDF seen by 1 280 pixels kept 1-3 of 20 walkers
at roughness 0.07 or 0.77 after 4 000 steps; more steps changed nothing). During the first ``relocate``
of the run (burn-in; the convergence checks read the second half), every ``relocate_every`` steps a
walker whose log-probability is below the median by more than ``max(10, 10 * 1.4826 MAD)`` (the
``behind`` check's rule) restarts at a walker drawn uniformly from those that are not, plus a Gaussian
jitter of ``0.1`` times their per-coordinate spread. After that the chain is plain emcee.
"""
from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import torch
from torch import Tensor

from ..errors import InputError
from .base import Info, Sampler
from .config import Configurable


class EnsembleState(NamedTuple):
    z: Tensor
    log_prob: Tensor
    rng_keys: Tensor       # numpy MT19937 state, as tensors (checkpointable without pickle)
    rng_pos: int
    acceptance: Tensor     # running acceptance count per walker
    relocate_until: int    # walkers left behind are relocated at steps before this one (burn-in)
    relocated: int         # how many walker relocations so far
    ensemble: "_EmceeRun"  # this run's emcee.EnsembleSampler (transient: not data, left out of checkpoints)

    transient = ("ensemble",)


@dataclass
class Emcee(Configurable, Sampler):
    stretch_a: float = 2.0          # the stretch move's scale parameter a
    relocate: float = 0.5           # fraction of the run during which walkers left behind are relocated
    relocate_every: int = 25        # ... every this many steps

    name = "emcee"
    supports_groups = False
    State = EnsembleState
    uses_gradients = False

    def validate(self):
        if not self.stretch_a > 1:
            raise InputError(f"emcee parameter stretch_a must be > 1, got {self.stretch_a!r}")
        if not 0 <= self.relocate < 1:
            raise InputError(f"emcee parameter relocate must be in [0, 1), got {self.relocate!r}",
                             fix="the fraction of the run (burn-in) during which walkers left behind are moved")
        if isinstance(self.relocate_every, bool) or not isinstance(self.relocate_every, int) or self.relocate_every < 1:
            raise InputError(f"emcee parameter relocate_every must be a positive integer, got {self.relocate_every!r}")

    def init(self, z0, potential, rng, *, steps, groups=1):
        n, D = z0.shape
        if n < 2 or n % 2:
            raise InputError(f"emcee needs an even number of walkers >= 2, got {n}", fix="set particles to an even number")
        if n < 2 * D:
            warnings.warn(f"emcee with {n} walkers in {D} dimensions: the stretch move needs at least 2*D = {2 * D} "
                          "walkers to explore the space, expect it to stay near its start", stacklevel=2)
        seed = int(torch.randint(0, 2 ** 31 - 1, (1,), generator=rng))
        st = np.random.RandomState(seed).get_state()
        with torch.no_grad():
            lp = -potential.energy(z0)
        _check_start(lp, self.name)
        return EnsembleState(z0.clone(), lp.double(), torch.from_numpy(st[1].astype(np.int64)), int(st[2]),
                             torch.zeros(n, dtype=torch.float64), int(self.relocate * steps), 0,
                             _EmceeRun(n, D, self.stretch_a))

    def step(self, state, t, potential, rng):
        rs = ("MT19937", state.rng_keys.numpy().astype(np.uint32), state.rng_pos, 0, 0.0)
        import emcee   # here, not at import: emcee pulls in scipy.stats (0.8 s of every command's start)

        cur = emcee.State(state.z.detach().cpu().double().numpy(), log_prob=state.log_prob.numpy(), random_state=rs)
        before = cur.coords.copy()
        new = state.ensemble.step(cur, potential)
        rs = new.random_state
        z = torch.as_tensor(new.coords, dtype=state.z.dtype, device=state.z.device)
        moved = torch.from_numpy((new.coords != before).any(1).astype(np.float64))
        lp = torch.from_numpy(np.asarray(new.log_prob, dtype=np.float64))
        relocated = state.relocated
        if t + 1 < state.relocate_until and (t + 1) % self.relocate_every == 0:
            z, lp, k = relocate_behind(z, lp, potential, rng)
            relocated += k
        return (state._replace(z=z, log_prob=lp, rng_keys=torch.from_numpy(rs[1].astype(np.int64)), rng_pos=int(rs[2]),
                               acceptance=state.acceptance + moved, relocated=relocated),
                Info(-lp, {"accepted": float(moved.mean())}))


def relocate_behind(z: Tensor, log_prob: Tensor, potential, rng: torch.Generator, jitter: float = 0.1):
    """Walkers ``z [n, D]`` whose ``log_prob`` is far below the median (:func:`~.diagnostics.behind_mask`)
    moved to walkers drawn uniformly from the others plus ``jitter`` times those walkers' per-coordinate
    std of Gaussian noise; returns ``(z, log_prob, how many moved)``. Nothing moves when fewer than two
    walkers would be left to draw from.

    Example:
        >>> from bayes_brdf.potential import FunctionPotential
        >>> pot = FunctionPotential(lambda z: 50 * (z ** 2).sum(1), dim=2)
        >>> z = torch.cat([0.1 * torch.randn(9, 2, generator=torch.Generator().manual_seed(0)),
        ...                torch.tensor([[3.0, 3.0]])])
        >>> z2, lp, k = relocate_behind(z, -pot.energy(z).double(), pot, torch.Generator().manual_seed(1))
        >>> k, bool(z2[-1].abs().max() < 1), torch.equal(z2[:9], z[:9])
        (1, True, True)
    """
    from .diagnostics import behind_mask
    bad = behind_mask(-log_prob)
    good = (~bad).nonzero().flatten()
    k = int(bad.sum())
    if not k or good.numel() < 2:
        return z, log_prob, 0
    src = good[torch.randint(0, good.numel(), (k,), generator=rng)]
    sd = z[good].std(0)
    noise = torch.randn(k, z.shape[1], generator=rng, dtype=torch.float64).to(z)
    z, log_prob = z.clone(), log_prob.clone()
    z[bad] = z[src] + jitter * sd * noise
    with torch.no_grad():
        log_prob[bad] = torch.nan_to_num(-potential.energy(z[bad]).double().cpu(), nan=-math.inf)
    return z, log_prob, k


class _EmceeRun:
    """One run's ``emcee.EnsembleSampler`` (``n`` walkers in ``D`` dimensions, the stretch move): it keeps
    nothing of the chain (positions, log-probabilities and the random state travel in the state), and
    each :meth:`step` evaluates the potential it is given (the run's, or a minibatch of it)."""

    def __init__(self, n: int, D: int, stretch_a: float):
        self.potential = None
        import emcee

        # we warn ourselves when n < 2 D (in init); emcee would raise instead
        move = emcee.moves.StretchMove(a=stretch_a, live_dangerously=n < 2 * D)
        self.sampler = emcee.EnsembleSampler(n, D, self._log_prob, moves=move, vectorize=True)

    def _log_prob(self, x):
        pot = self.potential
        zz = torch.as_tensor(np.ascontiguousarray(x), dtype=pot.dtype, device=pot.device)
        with torch.no_grad():
            lp = -pot.energy(zz)
        return np.nan_to_num(lp.double().cpu().numpy(), nan=-np.inf)

    def step(self, cur: "emcee.State", potential) -> "emcee.State":
        """One ensemble step from ``cur`` (its random state included) on ``potential``."""
        self.potential = potential
        try:
            return next(self.sampler.sample(cur, iterations=1, store=False, skip_initial_state_check=True))
        finally:
            self.potential = None


def _check_start(neg_energy: Tensor, name: str):
    """A NaN energy at the start: one clear line instead of an error from deep inside a library."""
    from .driver import SamplerDiverged
    bad = int(torch.isnan(neg_energy).sum())
    if bad:
        raise SamplerDiverged(f"{name} diverged at step 0: the energy is NaN at {bad} of {neg_energy.numel()} "
                              "starting points",
                              fix="check the model's energies where the prior draws its samples")
