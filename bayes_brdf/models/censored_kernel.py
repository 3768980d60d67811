"""The saturated pixels' censored Laplace terms and their derivatives in one native pass (``_native_censored.c``).

What :class:`~bayes_brdf.models.likelihood.RenderedImages` adds per step for clipped highlights, and what the texel
energies of :mod:`~bayes_brdf.models.texel_energy` add per texel move: ``log P(R + noise >= level)`` for every
saturated pixel and channel, its derivative in the renders and in the noise scale. In torch that is a dozen
elementwise passes with both branches of the Laplace survival function (about 5 ms for card_blue's 5 418
saturated pixels x 20 particles at 128², as much as the rest of the likelihood); the kernel reads each value once.
The torch expressions stay where it does not run (CUDA, no compiler, ``BAYES_BRDF_NO_NATIVE``, Gaussian noise) and
are what it is tested against (tests/models/test_censored.py).
"""
from __future__ import annotations

import ctypes
from pathlib import Path

import torch
from torch import Tensor

from ..render.native import native_function, ptr
from ..render.tensor_memo import TensorMemo

_SRC = Path(__file__).parent / "_native_censored.c"


def censored_laplace(r: Tensor, level: Tensor, sigma: Tensor, noise: Tensor | None, weight: Tensor, *,
                     terms: bool = False, grad: bool = False):
    """For renders ``r [n, K, 3]`` of the saturated pixels, their clip ``level [K, 3]``, the noise scale
    ``sigma [n]`` (times ``noise [K]``, the pixels' relative scales, when given) and weights ``weight [K]``:
    ``(total, dsigma, per_pixel, d_r)``, where ``total [n]`` float64 is ``sum w log S``, ``dsigma [n]`` float64
    its derivative in ``sigma``, ``per_pixel [n, K]`` float64 (with ``terms``) the sums over each pixel's channels
    and ``d_r [n, K, 3]`` (with ``grad``) the derivative of ``total`` in ``r``, in ``r``'s dtype. ``None`` where
    the kernel does not run (then the torch expressions do). The kernel computes in double whatever ``r``'s dtype:
    float32 renders give the same numbers as their float64 copies."""
    if r.device.type != "cpu" or r.dim() != 3 or r.shape[2] != 3:
        return None
    fn = native_function(_SRC, "bb_censored_laplace", r.dtype,
                         [ctypes.c_int64] * 4 + [ctypes.c_void_p] * 9, restype=ctypes.c_int,
                         extra_flags=("-ffast-math",))
    if fn is None:
        return None
    n, K, _ = r.shape
    rc = r.detach().contiguous()
    lev, g, w = _per_value(level, noise, weight, r.dtype)
    s = sigma.detach().reshape(-1).expand(n).double().contiguous()
    total = torch.empty(n, dtype=torch.float64)
    dsig = torch.empty(n, dtype=torch.float64)
    per = torch.empty(n, K, dtype=torch.float64) if terms else None
    dr = torch.empty(n, K, 3, dtype=r.dtype) if grad else None
    if fn(n, K, 3, torch.get_num_threads(), *map(ptr, (rc, lev, s, g, w, total, dsig, per, dr))) != 0:
        return None
    return total, dsig, per, dr


_PER_VALUE = TensorMemo(8)     # the kernel layouts of level, noise and weight, by their identity


def _per_value(level: Tensor, noise: Tensor | None, weight: Tensor, dtype) -> tuple:
    """``(level [K, 3], noise [3 K] or None, weight [3 K])`` contiguous in ``dtype``, noise and weight repeated over
    each pixel's channels: the kernel's layout, made once per data (they are the same tensors every step)."""
    return _PER_VALUE.get((level, noise, weight), (dtype,), lambda: (
        level.detach().to(dtype).contiguous(),
        None if noise is None else noise.detach().to(dtype).repeat_interleave(3).contiguous(),
        weight.detach().to(dtype).repeat_interleave(3).contiguous()))
