"""Numerics shared by the samplers: the Adam/RMSprop diagonal preconditioner, Adam's direction, annealing.

Plain functions of tensors and numbers; a sampler keeps what they carry from step to step
(:class:`Preconditioner`, Adam's moments) in its state.
"""
from __future__ import annotations

import math
from pathlib import Path
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


def standard_normal(shape, generator: torch.Generator, dtype: torch.dtype) -> Tensor:
    """Standard normal draws ``shape`` on the generator's device, for a sampler's noise.

    One 63-bit seed is drawn from ``generator``, and the normals are those of the counter-based Philox4x32-10
    generator with Box-Muller for that seed (:func:`philox_normal`): on CPU by the native kernel
    (``_native_normal.c``, about a fifth of ``torch.randn``'s time, which is serial: 3.1 ms for the 1.3M normals
    of one SPOS step at 128^2 on the 2-core CI-class machine), elsewhere (CUDA, no C compiler,
    ``BAYES_BRDF_NO_NATIVE``) by the same computation in torch: the same numbers to float rounding on every
    device and any thread count. They depend only on the generator's state, so a checkpoint that saves it
    resumes byte for byte.

    Example:
        >>> z = standard_normal((200_000,), torch.Generator().manual_seed(0), torch.float64)
        >>> abs(float(z.mean())) < 0.01, abs(float(z.var()) - 1) < 0.01
        (True, True)
    """
    seed = int(torch.randint(0, 2**63 - 1, (), generator=generator, device=generator.device))
    fn = _native_normal(dtype) if generator.device.type == "cpu" else None
    if fn is None:
        return philox_normal(seed, shape, dtype, generator.device)
    out = torch.empty(shape, dtype=dtype)
    fn(seed, out.numel(), torch.get_num_threads(), out.data_ptr())
    return out


_NORMAL_SRC = Path(__file__).parent / "_native_normal.c"
_PHILOX_M = (0xD2511F53, 0xCD9E8D57)
_PHILOX_W = (0x9E3779B9, 0xBB67AE85)
_MASK = 0xFFFFFFFF


def philox_normal(seed: int, shape, dtype: torch.dtype = torch.float32, device=None) -> Tensor:
    """The normals of :func:`standard_normal` for ``seed`` in plain torch (the reference of the native kernel,
    and its path on CUDA): element ``4 k + j`` is the ``j``-th of the two Box-Muller pairs made from the four
    words of Philox4x32-10 (Salmon et al. 2011) with counter ``k`` and key ``seed``; uniforms
    ``(word + 0.5) / 2^32``, radius and angle in ``dtype``.

    Example:
        >>> philox_normal(7, (6,)).shape
        torch.Size([6])
    """
    count = 1
    for d in shape:
        count *= int(d)
    blocks = (count + 3) // 4
    dev = torch.device(device) if device is not None else torch.device("cpu")
    b = torch.arange(blocks, dtype=torch.int64, device=dev)
    c0, c1 = b & _MASK, (b >> 32) & _MASK
    c2, c3 = torch.zeros_like(b), torch.zeros_like(b)
    k0, k1 = seed & _MASK, (seed >> 32) & _MASK
    for _ in range(10):
        p0, p1 = c0 * _PHILOX_M[0], c2 * _PHILOX_M[1]          # < 2^64: exact in uint64, wraps in int64
        h0, l0 = (p0 >> 32) & _MASK, p0 & _MASK
        h1, l1 = (p1 >> 32) & _MASK, p1 & _MASK
        c0, c1, c2, c3 = h1 ^ c1 ^ k0, l1, h0 ^ c3 ^ k1, l0
        k0, k1 = (k0 + _PHILOX_W[0]) & _MASK, (k1 + _PHILOX_W[1]) & _MASK
    u = [(c.to(dtype) + 0.5) * 2.3283064365386963e-10 for c in (c0, c1, c2, c3)]
    two_pi = 6.283185307179586476925
    ra, rb = (-2 * torch.log(u[0])).sqrt(), (-2 * torch.log(u[2])).sqrt()
    aa, ab = two_pi * u[1], two_pi * u[3]
    z = torch.stack([ra * torch.sin(two_pi / 4 - aa), ra * torch.sin(aa), rb * torch.sin(two_pi / 4 - ab),
                     rb * torch.sin(ab)], dim=1)
    return z.reshape(-1)[:count].reshape(tuple(shape))


def _native_normal(dtype):
    import ctypes

    from ..render.native import native_function
    return native_function(_NORMAL_SRC, "bb_normal", dtype,
                           [ctypes.c_uint64, ctypes.c_int64, ctypes.c_int64, ctypes.c_void_p],
                           extra_flags=("-ffast-math",), fallback="torch.randn")
