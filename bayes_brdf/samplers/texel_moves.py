"""Texel-local Metropolis jumps: particles stranded in a texel's second mode brought back.

On real photos a texel's posterior in roughness can have a second, far weaker mode: a blurred highlight
(roughness near 1) that the albedo half explains, 6 to 22 nats above the main mode behind a ridge of 5 to 17
nats (card_blue, measured: docs/calibration.md, "Stranded particles"). Particles that start there (the prior
draws put most of them above the ridge) stay for thousands of steps: SPOS moves by gradients and a little
noise. Without this move a fifth of a default run's particles sat in such modes on card_blue's narrowest
quarter of texels, whose roughness std came out 8.5x each texel's exact posterior std (quadrature:
:mod:`bayes_brdf.experiments.texel_truth`); with it, 1.8x (``benchmarks/bench_texel_truth.py``).

The move, every ``texel_moves`` steps of :class:`~bayes_brdf.samplers.spos.SPOS`, for models that offer
:func:`~bayes_brdf.models.texel_energy.texel_energies` (per-texel maps on rectified photos): the particles are
split in two halves; each particle of one half proposes, for every texel at once and independently, a new value
of the texel's coordinates drawn from a kernel density of the other half's values there (a random particle of
the other half plus Gaussian jitter of ``bandwidth`` times their median nearest-neighbour distance, so that a
particle in either mode of a bimodal texel sits inside the density; and a defensive :data:`DEFENSIVE` share
from the standard logistic, so that one alone in a mode is not kept there by the density at its own place),
and each texel's proposal is accepted with the Metropolis-Hastings probability of that texel's own energy (its prior, its pixels and the
Jacobian of the bijection) and the two proposal densities. Then the halves swap roles. The proposal of a
particle does not depend on its own state, only on the other half's, so each texel's step leaves the posterior
of that texel invariant given the rest (an ensemble move, as emcee's split stretch move); the texels are
independent given the noise scale, which is held at the particle's current level for the move (under
``sigma = "auto"`` a texel's share is the profile energy's derivative in the residual sum times its residual,
:func:`~bayes_brdf.models.texel_energy.texel_energies`: one texel shifts the level by about one part in the
number of pixels).
"""
from __future__ import annotations

import contextlib
import ctypes
import functools
import math
import weakref
from pathlib import Path

import torch
from torch import Tensor

from ..models.texel_energy import offers_texel_energy, texel_energies
from ..render.native import native_function, ptr

_KDE_SRC = Path(__file__).parent / "_native_texel_kde.c"
H_MIN = 1e-3        # the smallest kernel width (unconstrained units): identical centres still propose


_LAYOUTS: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()    # potential -> its texel_layout


def texel_layout(potential) -> Tensor | None:
    """``[T, k]``: the coordinates of ``z`` that hold each texel's values, or ``None`` when the potential's model
    does not offer texel energies (:func:`~bayes_brdf.models.texel_energy.offers_texel_energy`). Made once per
    potential (a potential's model and sites do not change) and kept while the potential lives."""
    try:
        return _LAYOUTS[potential]
    except (KeyError, TypeError):
        pass
    layout = _texel_layout(potential)
    try:
        _LAYOUTS[potential] = layout
    except TypeError:                                   # not weakly referable: made again next time
        pass
    return layout


def _texel_layout(potential) -> Tensor | None:
    model, args = getattr(potential, "model", None), getattr(potential, "args", ())
    if not (args and offers_texel_energy(model, args[0])):
        return None
    R = model.resolution
    cols = []
    for s in potential.sites:
        if tuple(s.ushape[-2:]) != (R, R) or tuple(s.ushape) != tuple(s.shape):
            return None
        cols.append(s.offset + torch.arange(s.size).reshape(s.size // (R * R), R * R).T)      # [T, c]
    return torch.cat(cols, 1)


def texel_energy(potential, z: Tensor, scale: tuple[Tensor, Tensor] | None = None,
                 jacobian: bool = True) -> tuple[Tensor, tuple]:
    """``([n, T] float64, scale)``: each texel's energy in unconstrained space (its constrained energy less the
    log-Jacobian of its coordinates; without it when not ``jacobian``) at ``scale = (sigma, kappa)`` (default: the
    particles' own, as :func:`~bayes_brdf.models.texel_energy.texel_energies` returns it)."""
    model, data = potential.model, potential.args[0]
    e, scale = texel_energies(model, data, potential.to_constrained(z), *(scale or ()))
    if not jacobian:
        return e, scale
    R = model.resolution
    for s, x in zip(potential.sites, torch.split(z, [s.size for s in potential.sites], dim=1)):
        if getattr(s.transform, "lo", None) is None:
            continue                                    # unconstrained: no Jacobian
        ladj = _log_logistic(x).reshape(z.shape[0], -1, R * R).sum(1)     # log |dx/du| less log(hi - lo)
        e = e - ladj.to(e.dtype)
    return e, scale


def texel_move(z: Tensor, potential, rng: torch.Generator, groups: int = 1, bandwidth: float = 2.5,
               layout: Tensor | None = None) -> tuple[Tensor, float]:
    """One texel-local Metropolis sweep over both halves of each group (see the module docstring).

    Returns the new particles ``[G n, D]`` and the share of texel proposals accepted. On CPU each half's move is
    the native kernel's (:func:`_half_native`), elsewhere torch's (:func:`_half_torch`, the reference); the two
    draw their randomness differently, so their particles differ, not their distribution.
    """
    covers = layout is None           # texel_layout's columns are distinct: all of z's when there are D of them
    layout = texel_layout(potential) if layout is None else layout
    N, D = z.shape
    n = N // groups
    if layout is None or n < 4:
        return z, 0.0
    z = z.clone()
    T, k = layout.shape
    half = n // 2
    native = _native_moves(z, n - half, k)
    e, scale = texel_energy(potential, z, jacobian=not native)      # the kernel adds the Jacobian's difference
    if native:                                        # what both halves' kernels read, made once
        e, layout = e.double().contiguous(), layout.contiguous()
        move = functools.partial(_half_native, jac=_interval_coordinates(potential), covers=covers and T * k == D)
    else:
        move = _half_torch
    rows = torch.arange(N).reshape(groups, n)
    accepted, proposed = 0, 0
    for a_sl, b_sl in ((slice(0, half), slice(half, n)), (slice(half, n), slice(0, half))):
        A, B = rows[:, a_sl].reshape(-1), rows[:, b_sl]              # movers [G a]; others [G, b]
        accepted += move(z, e, scale, A, B, layout, potential, rng, bandwidth)
        # e[A] is not read again: the other half moves next
        proposed += A.numel() * T
    return z, accepted / max(1, proposed)


def _half_torch(z: Tensor, e: Tensor, scale: tuple, A: Tensor, B: Tensor, layout: Tensor, potential,
                rng: torch.Generator, bandwidth: float) -> int:
    """The movers ``A [G a]`` proposed from the others ``B [G, b]`` and accepted, in torch; writes ``z`` in place and
    returns how many texels moved."""
    sigma, kappa = scale
    T, k = layout.shape
    groups, nb = B.shape
    na = A.numel() // groups
    xb = z[B.reshape(-1)][:, layout].reshape(groups, nb, T, k)    # the other half's texel values
    h = widths(xb, bandwidth)                                                      # [G, T, k]
    pick = torch.randint(nb, (groups, na, T), generator=rng).to(z.device)
    centre = torch.gather(xb, 1, pick[..., None].expand(-1, -1, -1, k))                  # [G, a, T, k]
    jitter = torch.randn(centre.shape, generator=rng, dtype=z.dtype).to(z.device)
    prop = centre + jitter * h[:, None]
    wide = torch.rand((groups, na, T), generator=rng).to(z.device) < DEFENSIVE
    v = torch.rand(centre.shape, generator=rng, dtype=torch.float64).clamp_(1e-12, 1 - 1e-12)
    prop = torch.where(wide[..., None], torch.logit(v).to(z.dtype).to(z.device), prop)
    cur = z[A][:, layout].reshape(groups, na, T, k)
    lq_cur, lq_prop = log_q(torch.cat([cur, prop], 1), xb, h).split(na, 1)         # one pass for both
    zp = z[A].clone()
    zp[:, layout] = prop.reshape(-1, T, k)
    ep, _ = texel_energy(potential, zp, (sigma[A], kappa[A]))
    log_alpha = (e[A] - ep).reshape(groups, na, T) + (lq_cur - lq_prop).double()
    u = torch.rand(log_alpha.shape, generator=rng, dtype=torch.float64).to(z.device)
    ok = (u.log() < log_alpha) & torch.isfinite(ep.reshape(groups, na, T))
    okf = ok.reshape(-1, T)
    new = torch.where(okf[..., None], prop.reshape(-1, T, k), cur.reshape(-1, T, k))
    za = z[A]
    za[:, layout] = new
    z[A] = za
    return int(ok.sum())


KERNEL_MAX = (256, 8)    # the native move's bounds: particles per half, coordinates per texel
_REFERENCE = [False]     # set inside reference_moves()


@contextlib.contextmanager
def reference_moves():
    """Inside the block every texel move takes torch's path (:func:`_half_torch`), on CPU too. Torch's path draws
    its random numbers from the run's CPU generator on every device, so a CPU run inside this block and a CUDA run
    see the same draws and differ only by rounding: what a check of the CUDA path against the CPU needs
    (``benchmarks/gpu_check.py``). Not thread-safe: it sets a module-wide switch."""
    before = _REFERENCE[0]
    _REFERENCE[0] = True
    try:
        yield
    finally:
        _REFERENCE[0] = before


def _native_moves(z: Tensor, half: int, k: int) -> bool:
    """Whether the native move (:func:`_half_native`) runs for particles like ``z`` (CPU, a compiler, not
    ``BAYES_BRDF_NO_NATIVE``, not inside :func:`reference_moves`) with halves of up to ``half`` particles and ``k``
    coordinates per texel."""
    return (not _REFERENCE[0] and half <= KERNEL_MAX[0] and k <= KERNEL_MAX[1] and z.is_contiguous()
            and _kde_kernel("bb_texel_propose", z) is not None and _kde_kernel("bb_texel_accept", z) is not None)


def _interval_coordinates(potential) -> Tensor:
    """``[k]`` int64: 1 for the texel coordinates of :func:`texel_layout` that an interval bijection maps (their
    log-Jacobian is the standard logistic's log density, less a constant), 0 for unconstrained ones."""
    R = potential.model.resolution
    return torch.cat([torch.full((s.size // (R * R),), int(getattr(s.transform, "lo", None) is not None),
                                 dtype=torch.int64) for s in potential.sites])


def _half_native(z: Tensor, e: Tensor, scale: tuple, A: Tensor, B: Tensor, layout: Tensor, potential,
                 rng: torch.Generator, bandwidth: float, *, jac: Tensor, covers: bool = False) -> int:
    """:func:`_half_torch` in two native calls around the proposals' energies (``bb_texel_propose``: draws, widths,
    both log densities and the Jacobian's difference; ``bb_texel_accept``: the decisions, written into ``z``),
    with two seeds drawn from ``rng``; ``e`` float64 and contiguous, without the Jacobian
    (``texel_energy(..., jacobian=False)``), ``layout`` contiguous, ``jac`` :func:`_interval_coordinates`;
    ``covers``: the layout's columns are all of ``z``'s, once each (the proposals' rows need no copy of the movers'
    first: the kernel writes every column)."""
    propose, accept = _kde_kernel("bb_texel_propose", z), _kde_kernel("bb_texel_accept", z)
    sigma, kappa = scale
    T, k = layout.shape
    groups, nb = B.shape
    na, D = A.numel() // groups, z.shape[1]
    Ai, Bi = A.contiguous(), B.reshape(-1).contiguous()
    seeds = torch.randint(0, 2 ** 62, (2,), generator=rng).tolist()
    zp = torch.empty(Ai.numel(), D, dtype=z.dtype) if covers else z[Ai]    # the movers' rows, texels replaced below
    dlq = torch.empty(na * groups, T, dtype=torch.float64)
    threads = torch.get_num_threads()
    if propose(groups, T, na, nb, k, D, threads, ptr(z), ptr(layout), ptr(jac), ptr(Ai), ptr(Bi), seeds[0],
               float(bandwidth), H_MIN, DEFENSIVE, ptr(zp), ptr(dlq)) != 0:
        raise RuntimeError(f"bb_texel_propose refused {na} + {nb} particles of {k} coordinates")
    ep, _ = texel_energy(potential, zp, (sigma[Ai], kappa[Ai]), jacobian=False)
    ep = ep.double().contiguous()
    return int(accept(na * groups, T, k, D, threads, ptr(z), ptr(layout), ptr(Ai), ptr(zp), ptr(e), ptr(ep), ptr(dlq),
                      seeds[1]))


def widths(xb: Tensor, bandwidth: float) -> Tensor:
    """``[G, T, k]``: the kernel density's widths per texel and coordinate from the centres ``xb [G, b, T, k]``:
    ``bandwidth`` times their median nearest-neighbour distance (:func:`_local_scale`), at least :data:`H_MIN`. The
    native kernel where it runs (CPU), else the torch reference."""
    fn = _kde_kernel("bb_texel_scale", xb)
    if fn is not None:
        c = xb.permute(0, 2, 1, 3).contiguous()                                         # [G, T, b, k]
        G, T, b, k = c.shape
        h = torch.empty(G, T, k, dtype=xb.dtype)
        if fn(G, T, b, k, torch.get_num_threads(), ptr(c), float(bandwidth), H_MIN, ptr(h)) == 0:
            return h
    return _local_scale(xb).mul_(bandwidth).clamp_min_(H_MIN)


def log_q(x: Tensor, centres: Tensor, h: Tensor) -> Tensor:
    """``[G, a, T]``: the proposal's log density at ``x [G, a, T, k]`` (:func:`_log_q`, the torch reference), from the
    native kernel where it runs."""
    fn = _kde_kernel("bb_texel_logq", x)
    if fn is not None:
        c = centres.permute(0, 2, 1, 3).contiguous()                                    # [G, T, b, k]
        xs = x.permute(0, 2, 1, 3).contiguous()                                         # [G, T, a, k]
        G, T, a, k = xs.shape
        hh = h.to(x.dtype).contiguous()
        out = torch.empty(G, T, a, dtype=x.dtype)
        if fn(G, T, a, c.shape[2], k, torch.get_num_threads(), ptr(c), ptr(xs), ptr(hh), DEFENSIVE, ptr(out)) == 0:
            return out.transpose(1, 2)
    return _log_q(x, centres, h)


def _kde_kernel(name: str, like: Tensor):
    """The native kernel ``name`` of ``_native_texel_kde.c`` for tensors like ``like``, or ``None`` (CUDA, no
    compiler, ``BAYES_BRDF_NO_NATIVE``): the torch reference runs instead."""
    if like.device.type != "cpu":
        return None
    i64, vp, dbl = ctypes.c_int64, ctypes.c_void_p, ctypes.c_double
    u64 = ctypes.c_uint64
    args, res = {"bb_texel_scale": ([i64] * 5 + [vp, dbl, dbl, vp], ctypes.c_int),
                 "bb_texel_logq": ([i64] * 6 + [vp] * 3 + [dbl, vp], ctypes.c_int),
                 "bb_texel_propose": ([i64] * 7 + [vp] * 5 + [u64, dbl, dbl, dbl, vp, vp], ctypes.c_int),
                 "bb_texel_accept": ([i64] * 5 + [vp] * 7 + [u64], i64)}[name]
    return native_function(_KDE_SRC, name, like.dtype, args, restype=res, extra_flags=("-ffast-math",),
                           fallback="torch")


def _local_scale(xb: Tensor) -> Tensor:
    """``[G, T, k]``: per texel and coordinate, the median over the particles ``xb [G, b, T, k]`` of the distance
    to their nearest neighbour (in the texel's coordinates): the width of one mode, not the distance between
    two, so a particle in either mode of a bimodal texel sits inside the kernel density."""
    x = xb.permute(0, 2, 1, 3)                                                      # [G, T, b, k]
    d = torch.cdist(x, x)                                                           # [G, T, b, b]
    d.diagonal(dim1=-2, dim2=-1).fill_(float("inf"))
    nn = d.argmin(-1)                                                               # [G, T, b]
    near = torch.gather(x, 2, nn[..., None].expand(-1, -1, -1, x.shape[-1]))
    return (x - near).abs().median(2).values


DEFENSIVE = 0.1     # share of proposals drawn from the standard logistic (a uniform prior's image in u-space)


def _log_q(x: Tensor, centres: Tensor, h: Tensor) -> Tensor:
    """The proposal's log density: the kernel density, and a defensive share of the standard logistic in every
    coordinate. Without it a particle alone in a weak mode has no partner near it, the proposal's density at
    its own place is tiny, and the move that would take it out is refused for that reason alone."""
    wide = _log_logistic(x).sum(-1)
    return torch.logaddexp(math.log1p(-DEFENSIVE) + _log_kde(x, centres, h), math.log(DEFENSIVE) + wide)


def _log_logistic(u: Tensor) -> Tensor:
    """``log sigmoid(u) (1 - sigmoid(u))``, stable: the standard logistic's log density, which is also the
    log-Jacobian of an interval bijection less ``log(hi - lo)``."""
    a = u.abs()
    return -a - 2 * torch.log1p(torch.exp(-a))


def _log_kde(x: Tensor, centres: Tensor, h: Tensor) -> Tensor:
    """``[G, a, T]``: log density at ``x [G, a, T, k]`` of the equal mixture of ``N(centre_j, diag h^2)`` over
    ``centres [G, b, T, k]`` (``h [G, T, k]``)."""
    xs = (x / h[:, None]).permute(0, 2, 1, 3)                                       # [G, T, a, k]
    cs = (centres / h[:, None]).permute(0, 2, 1, 3)                                 # [G, T, b, k]
    lp = torch.cdist(xs, cs).square_().mul_(-0.5)                                   # [G, T, a, b]
    norm = h.log().sum(-1) + 0.5 * h.shape[-1] * math.log(2 * math.pi)              # [G, T]
    m = lp.amax(-1, keepdim=True)
    lse = lp.sub_(m).clamp_min_(-80).exp_().sum(-1).log_().add_(m[..., 0])     # logsumexp over b (no denormals)
    return (lse - (math.log(centres.shape[1]) + norm)[..., None]).transpose(1, 2)
