"""The RBF kernel of Eq. (5) with the median-distance bandwidth, batched over particles (and groups)."""
from __future__ import annotations

import ctypes
import math
from pathlib import Path

import torch
from torch import Tensor

from ..render.native import native_function, ptr

_RBF_SRC = Path(__file__).parent / "_native_rbf.c"


def rbf_median(z: Tensor, groups: int = 1) -> tuple[Tensor, Tensor]:
    """Kernel matrices and the summed kernel gradients for particles ``z [G * n, D]`` in ``G`` groups.

    Within each group, ``k(x_j, x_i) = exp(-log(n) / M^2 * |x_j - x_i|^2)`` with
    ``M`` the median of the group's pairwise distances (Eq. 5). Groups are
    independent ensembles (e.g. independent runs batched into one call).
    Returns ``K [G, n, n]`` and ``rep [G * n, D] = sum_j grad_{x_j} k(x_j, x_i)``
    (the repulsion, not yet divided by ``n``).

    Example:
        >>> K, rep = rbf_median(torch.tensor([[0.0], [1.0], [3.0]]))
        >>> K.shape, bool(rep[0, 0] < 0 < rep[2, 0])
        (torch.Size([1, 3, 3]), True)
    """
    N, D = z.shape
    n = N // groups
    x = z.reshape(groups, n, D)
    if n < 2:
        return torch.ones(groups, n, n, dtype=z.dtype, device=z.device), torch.zeros_like(z)
    K, h = rbf_matrix(z, groups)
    h = h[:, None, None]
    # sum_j grad_{x_j} k(x_j, x_i) = sum_j K_ij (-2/h)(x_j - x_i) = (2/h) (x_i sum_j K_ij - sum_j K_ij x_j)
    rep = (2 / h) * (x * K.sum(-1, keepdim=True) - K @ x)
    return K, rep.reshape(N, D)


def rbf_matrix(z: Tensor, groups: int = 1) -> tuple[Tensor, Tensor]:
    """The kernel matrices ``K [G, n, n]`` of :func:`rbf_median` and their bandwidths ``h = M^2 / log n``
    ``[G]`` (``h = 1`` where all particles coincide); ``n >= 2`` particles per group."""
    N, D = z.shape
    n = N // groups
    native = _native_rbf(z)
    if native is not None:       # the same in one native pass (_native_rbf.c); the torch ops below are its reference
        zc = z.contiguous()
        K = torch.empty(groups, n, n, dtype=z.dtype)
        h = torch.empty(groups, dtype=z.dtype)
        if native(groups, n, D, torch.get_num_threads(), ptr(zc), ptr(K), ptr(h)) == 0:
            return K, h
    x = z.reshape(groups, n, D)
    gram = x @ x.transpose(1, 2)                                        # [G, n, n]: one pass over z
    sq = gram.diagonal(dim1=1, dim2=2)
    d2 = (sq[:, :, None] + sq[:, None, :] - 2 * gram).clamp_min(0)
    eye = torch.eye(n, dtype=torch.bool, device=z.device)
    d2 = d2.masked_fill(eye, 0.0)
    iu = torch.triu_indices(n, n, 1, device=z.device)
    m2 = d2[:, iu[0], iu[1]].sqrt().median(dim=1).values ** 2          # [G]
    h = torch.where(m2 > 0, m2 / math.log(n), torch.ones_like(m2))
    return torch.exp(-d2 / h[:, None, None]), h


def _native_rbf(z: Tensor):
    """The native :func:`rbf_matrix` for particles like ``z`` (CPU, float32/64, not differentiated: the samplers'
    detached particles), or ``None`` (then the torch ops)."""
    if z.device.type != "cpu" or z.dim() != 2 or z.requires_grad:
        return None
    i64, vp = ctypes.c_int64, ctypes.c_void_p
    return native_function(_RBF_SRC, "bb_rbf_matrix", z.dtype, [i64] * 4 + [vp] * 3, restype=ctypes.c_int,
                           fallback="torch")


def kernel_apply(K: Tensor, g: Tensor) -> Tensor:
    """``sum_j k(x_j, x_i) g_j`` for every particle: ``K [G, n, n]``, ``g [G * n, D]`` -> ``[G * n, D]``."""
    G, n, _ = K.shape
    return (K @ g.reshape(G, n, -1)).reshape(g.shape)
