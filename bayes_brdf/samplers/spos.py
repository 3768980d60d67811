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

``step_units = "spread"`` (the default preset) makes ``lambda`` per coordinate
a fraction of the ensemble's own spread, ``lambda_d = step_size * s_d`` with
``s_d`` the std of coordinate ``d`` over the group's particles: near the
posterior ``G_d`` is about the posterior scale, so the Langevin part's
diffusion ``lambda_d G_d / beta`` is about ``step_size * s_d^2 / beta``, a
*dimensionless* step (ALDI-like ensemble preconditioning, Garbuno-Inigo et al.
2020) that is the same for a texel measured to 0.1 % and one the data leave
open, and for a 2-D posterior 100x tighter than Table 1's. The state-dependent
diffusion gets its divergence term ``d M_d / d z_id`` so the step stays
consistent. ``step_units = "parameter"`` is the earlier rule (``lambda`` in
unconstrained units, which must then sit below the tightest posterior std).

``beta`` weighs the Langevin part against the Stein (kernel) part. A large
``beta`` is nearly SVGD (collapses in high dimension); ``beta = 1`` is
calibrated in high dimension. ``beta = "auto"`` picks
``max(1, beta_low_dim * 2 / D)``; the preset's ``beta_low_dim = 5`` gives 5 in
2-D and 1 from 10 dimensions up. With ``beta = 200`` in 2-D (the earlier preset)
the ensemble settled on SVGD's fixed point, which on a skewed posterior (the
three-view 0/20/40 setup, a long tail to high roughness) drops the tail: its
roughness variance kept shrinking with the run's length (0.33 of the truth at
2000 steps, 0.17 at 4000) and SVGD itself is 3.3 / 3.6x the i.i.d. floor there;
at ``beta = 5`` it holds at about 0.5-0.6 of the truth and is within 2x of the
floor (docs/calibration.md).

``adam_eps`` bounds Adam's scale ``1 / (sqrt(v) + eps)`` by ``1 / eps``. In low dimension, once the Stein
part balances the likelihood, the drift's rms falls towards ``|grad U| / beta`` and an unbounded scale
grows by up to ``beta`` (200 in 2-D with the earlier preset), and the ensemble over-contracts. ``adam_eps = "auto"`` is ``2 / D``:
a bound of 1 in 2-D, none to speak of in high dimension, where ``beta = 1`` and nothing grows.

``precond_scope`` says whose gradients set Adam's scale: ``"particle"`` (the preset) keeps one second moment
per particle (the per-chain RMSprop of pSGLD, Li et al. 2016), ``"group"`` one per group, ``"auto"`` one per
particle in at most 16 dimensions and one per group beyond (the preset until 2026-12-06).
A shared scale is set by the group's stiffest particles: on a narrow ridge (two nearly equal views, a sharp
highlight) the particles that straddle it have gradients a thousand times those of a particle out on a flat
stretch of the ridge, which then moves a thousand times too slowly and is still there when the run ends
(docs/calibration.md: two such setups were 133x and 383x the i.i.d. floor with a shared scale, and are within
2x of it with one per particle). The same holds per texel on real photos: where a texel's posterior is narrow,
a shared scale let its particles contract about four times more slowly, so a default run's roughness std on
the narrowest quarter of card_blue's texels was 0.22 where long runs settle near 0.025 (0.10 per particle;
docs/calibration.md, "Narrow texels"). A positive per-particle scale leaves the Stein part's fixed point where
it is, and the Langevin part keeps its drift and noise consistent particle by particle; against the exact
per-texel posterior (bayes_brdf.experiments.highdim) it is as calibrated as the shared one, with fewer texels
off by 2x.

``texel_moves`` (every so many steps; 0: never) adds a texel-local Metropolis sweep after the update, for
models that offer texel energies (:mod:`bayes_brdf.samplers.texel_moves`): particles stranded in a texel's
weak second mode, which gradients and Langevin noise leave there for thousands of steps, jump to where the
texel's posterior is. It draws from the same generator as the update, so a checkpointed run resumes exactly.
"""
from __future__ import annotations

import ctypes
import math
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import torch
from torch import Tensor

from ..errors import InputError
from ..render.native import native_function, ptr
from .base import Info, Sampler
from .diagnostics import LOW_DIM
from .config import Configurable
from .kernels import kernel_apply, rbf_matrix, rbf_median
from .numerics import Preconditioner, anneal, precond_init, precond_update, standard_normal
from .texel_moves import texel_move

_SPOS_SRC = Path(__file__).parent / "_native_spos.c"


class SPOSState(NamedTuple):
    z: Tensor
    precond: Preconditioner
    precond_noise: Preconditioner
    num_steps: int      # the run's horizon (annealing: T = anneal_fraction * num_steps)
    groups: int         # independent ensembles, n particles each


@dataclass
class SPOS(Configurable, Sampler):
    step_size: float = 0.05          # lambda (parameter units with the Adam preconditioner)
    beta: "float | str" = "auto"     # Langevin inverse temperature of Eq. (4), or "auto"
    beta_low_dim: float = 200.0      # "auto": beta in 2-D, decreasing as 2/D to 1
    anneal: bool = True
    anneal_delta: float = 1.0        # delta of Eq. (6)
    anneal_fraction: float = 0.2     # T of Eq. (6) as a fraction of the run's steps
    preconditioner: str = "adam"     # "adam" or "none"
    adam_beta2: float = 0.99
    adam_eps: "float | str" = 1e-8  # a number, or "auto" = 2 / D (see the module docstring)
    step_units: str = "parameter"    # "parameter": lambda in unconstrained units; "spread": a fraction of the
    #                                  particles' per-coordinate spread (std within the group)
    min_spread: float = 1e-3         # "spread": floor of the spread (a collapsed or one-particle group)
    precond_scope: str = "group"     # Adam's second moment: shared by a group's particles ("group"), one per
    #                                  "particle" (pSGLD's per-chain RMSprop), or "auto": per particle in at most
    #                                  LOW_DIM dimensions (see the module docstring)
    texel_moves: int = 0             # every so many steps a texel-local Metropolis sweep (texel_moves.py), for
    #                                  models that offer texel energies; 0: never
    texel_bandwidth: float = 2.5     # its proposal's jitter, in nearest-neighbour distances of the other half

    name = "spos"
    State = SPOSState

    def validate(self):
        self._positive("step_size", "anneal_delta", "beta_low_dim")
        self._choice("preconditioner", ("adam", "none"))
        self._choice("step_units", ("parameter", "spread"))
        self._choice("precond_scope", ("group", "particle", "auto"))

        self._positive("min_spread", "texel_bandwidth")
        if isinstance(self.texel_moves, bool) or not isinstance(self.texel_moves, int) or self.texel_moves < 0:
            raise _bad("texel_moves", self.texel_moves, "a step count >= 0 (0: no texel moves)")
        for k in ("beta", "adam_eps"):   # the dimension-aware ones: a number, or "auto" (beta_for, eps_for)
            v = getattr(self, k)
            if not (v == "auto" or (isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
                                    and v > 0)):
                raise _bad(k, v, "a positive number or \"auto\"")
        self._unit("adam_beta2")
        if not 0 < self.anneal_fraction <= 1:
            raise _bad("anneal_fraction", self.anneal_fraction, "in (0, 1]")

    def beta_for(self, dim: int) -> float:
        return max(1.0, self.beta_low_dim * 2.0 / dim) if self.beta == "auto" else float(self.beta)

    def eps_for(self, dim: int) -> float:
        return 2.0 / dim if self.adam_eps == "auto" else float(self.adam_eps)

    def per_particle(self, dim: int) -> bool:
        """Whether each particle keeps its own Adam second moment (``precond_scope``)."""
        return self.precond_scope == "particle" or (self.precond_scope == "auto" and dim <= LOW_DIM)

    def particles_are_chains(self, dim: int) -> bool:
        # with a large beta (low dimension) the Stein part dominates: particles settle like SVGD's
        return self.beta_for(dim) <= 5

    def init(self, z0, potential, rng, *, steps, groups=1):
        p0 = precond_init(z0.shape[0] if self.per_particle(z0.shape[1]) else groups, z0.shape[1], z0)
        return SPOSState(z0.clone(), p0, p0, steps, groups)

    def step(self, state, t, potential, rng):
        state, info = self._spos_step(state, t, potential, rng)
        if self.texel_moves and (t + 1) % self.texel_moves == 0:
            z, rate = texel_move(state.z, potential, rng, state.groups, self.texel_bandwidth)
            state, info = state._replace(z=z), Info(info.energy, {**info.extras, "texel_accept": rate})
        return state, info

    def _spos_step(self, state, t, potential, rng):
        z, groups = state.z, state.groups
        n, D = z.shape[0] // groups, z.shape[1]
        u, grad = potential.value_and_grad(z)
        gam = anneal(t, round(self.anneal_fraction * state.num_steps), self.anneal_delta) if self.anneal else 1.0
        beta, eps = self.beta_for(D), self.eps_for(D)
        if _native_update(z.dtype) is not None and z.device.type == "cpu" and 2 <= n <= NATIVE_MAX_PARTICLES:
            return self._fused_step(state, z, u, grad, gam, beta, eps, rng)
        K, rep = rbf_median(z, groups)
        kg = kernel_apply(K, grad)
        shape = (groups, n, D)
        pc, pn = state.precond, state.precond_noise
        if self.preconditioner == "adam" and gam < 0.99:
            # un-annealed update, for the noise's scale (see the module docstring)
            pn, G1 = precond_update(pn, (rep - kg).div_(n).sub_(grad, alpha=1 / beta), self.adam_beta2, eps)
            G1 = G1.view(groups, -1, D)                  # [G, 1, D], or [G, n, D] per particle
        drift = rep.sub_(kg, alpha=gam).div_(n).sub_(grad, alpha=gam / beta)    # in place: rep is ours
        if self.preconditioner == "adam":
            pc, G = precond_update(pc, drift, self.adam_beta2, eps)
            G = G.view(groups, -1, D)
            Gn = torch.minimum(G, G1) if gam < 0.99 else G
        else:
            G = Gn = torch.ones((), dtype=z.dtype, device=z.device)
        zg = z.view(shape)
        noise = standard_normal(z.shape, rng, z.dtype).to(z.device)
        if self.step_units == "spread":
            lam, corr = _spread_step(zg, self.step_size, self.min_spread)
        else:
            lam, corr = self.step_size, None
        M = Gn.mul(lam).div_(beta)                      # the Langevin part's diffusion, per coordinate
        noise = noise.view(shape).mul_(M.mul(2).sqrt_())
        if corr is not None:                             # d M / d z: keeps the ensemble-scaled step exact
            noise.addcmul_(M, corr)
        z = noise.addcmul_(G * lam, drift.view(shape)).add_(zg).view(z.shape)
        return state._replace(z=z, precond=pc, precond_noise=pn), Info(u, {"gamma": gam})


    def _fused_step(self, state, z, u, grad, gam, beta, eps, rng):
        """The update above as one native pass over the coordinates (``_native_spos.c``); the same numbers to
        rounding, from the same noise draw (tests/samplers/test_spos_native.py)."""
        groups = state.groups
        n, D = z.shape[0] // groups, z.shape[1]
        K, h = rbf_matrix(z, groups)
        ks = K.sum(-1).contiguous()
        c2h = (2 / h).to(z.dtype).contiguous()
        adam = self.preconditioner == "adam"
        noise_pc = adam and gam < 0.99
        pc, pn = state.precond, state.precond_noise
        v_new = torch.empty_like(pc.v)
        vn_new = torch.empty_like(pn.v) if noise_pc else pn.v
        noise = standard_normal(z.shape, rng, z.dtype).to(z.device)
        z_new = torch.empty_like(z)
        zc, gc = z.contiguous(), grad.contiguous()
        c = pc.count + 1
        cn = pn.count + 1
        _native_update(z.dtype)(
            groups, n, D, torch.get_num_threads(), *map(ptr, (zc, gc, noise, K.contiguous(), ks, c2h, pc.v, pn.v,
                                                               z_new, v_new, vn_new)),
            int(adam), int(self.per_particle(D)),
            int(noise_pc), int(self.step_units == "spread"), float(gam), float(beta), float(eps),
            float(self.adam_beta2), 1 - self.adam_beta2 ** c, 1 - self.adam_beta2 ** cn, float(self.step_size),
            float(self.min_spread))
        if adam:
            pc = Preconditioner(v_new, c)
            if noise_pc:
                pn = Preconditioner(vn_new, cn)
        return state._replace(z=z_new, precond=pc, precond_noise=pn), Info(u, {"gamma": gam})


NATIVE_MAX_PARTICLES = 64     # NMAX of _native_spos.c: particles per group in the fused update


def _native_update(dtype):
    """The fused native SPOS update for ``dtype`` (float32/float64), or ``None`` (no compiler,
    ``BAYES_BRDF_NO_NATIVE``): then the torch update runs."""
    i64, dbl, vp = ctypes.c_int64, ctypes.c_double, ctypes.c_void_p
    return native_function(_SPOS_SRC, "bb_spos_update", dtype,
                           [i64] * 4 + [vp] * 11 + [i64] * 4 + [dbl] * 8)


def _spread_step(zg: Tensor, step: float, floor: float) -> tuple[Tensor, Tensor | None]:
    """Per-coordinate step ``lambda_d = step * s_d`` from the group's spread ``s_d`` (std over its particles,
    ``[G, 1, D]``), and the divergence term of the resulting state-dependent diffusion
    ``M_d = c s_d``: ``d M_d / d z_id = M_d (z_id - m_d) / ((n - 1) s_d^2)`` (returned without the ``M``
    factor, ``[G, n, D]``). A group of one particle has no spread: ``step`` in parameter units, no term."""
    n = zg.shape[1]
    if n < 2:
        return torch.full_like(zg[:, :1], step), None
    m = zg.mean(1, keepdim=True)
    dev = zg - m
    var = dev.pow(2).sum(1, keepdim=True).div_(n - 1)
    s = var.sqrt().clamp_min_(floor)
    corr = dev.div_(var.clamp_min(floor * floor).mul_(n - 1))
    return s.mul_(step), corr


def _bad(name, value, what):
    return InputError(f"spos parameter {name} must be {what}, got {value!r}")
