"""The RBF kernel of Eq. (5) with the median-distance bandwidth, batched over particles."""
from __future__ import annotations

import math

import torch
from torch import Tensor


def rbf_median(z: Tensor) -> tuple[Tensor, Tensor]:
    """Kernel matrix and the summed kernel gradients for particles ``z [n, D]``.

    ``k(x_j, x_i) = exp(-log(n) / M^2 * |x_j - x_i|^2)`` with ``M`` the median of
    the pairwise distances (Eq. 5). Returns ``K [n, n]`` and
    ``rep [n, D] = sum_j grad_{x_j} k(x_j, x_i)`` (the repulsion, not yet divided
    by ``n``).

    Example:
        >>> K, rep = rbf_median(torch.tensor([[0.0], [1.0], [3.0]]))
        >>> K.shape, bool(rep[0, 0] < 0 < rep[2, 0])
        (torch.Size([3, 3]), True)
    """
    n = z.shape[0]
    x = z
    if n < 2:
        return torch.ones(n, n, dtype=z.dtype, device=z.device), torch.zeros_like(z)
    sq = (x * x).sum(1)
    d2 = (sq[:, None] + sq[None, :] - 2 * x @ x.T).clamp_min(0)
    d2.fill_diagonal_(0)
    iu = torch.triu_indices(n, n, 1, device=z.device)
    m2 = d2[iu[0], iu[1]].sqrt().median() ** 2
    h = m2 / math.log(n) if float(m2) > 0 else torch.ones((), dtype=z.dtype, device=z.device)
    K = torch.exp(-d2 / h)
    # sum_j grad_{x_j} k(x_j, x_i) = sum_j K_ij * (-2/h) (x_j - x_i) = (2/h) (x_i sum_j K_ij - sum_j K_ij x_j)
    rep = (2 / h) * (x * K.sum(1, keepdim=True) - K @ x)
    return K, rep
