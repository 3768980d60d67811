"""Texture lookup at arbitrary pixels as a sparse matrix: pixels gather texels, gradients scatter back.

A pixel at ``grid_sample`` coordinate ``uv`` reads its map bilinearly from four texels; over ``K`` pixels
that is a ``K x T`` matrix ``S`` with four entries per row (``T`` texels), built once per G-buffer and map
size (:func:`tap_matrix`). The lookup of maps ``[n, C, T]`` is ``S`` applied to every channel, and its
gradient is ``S^T`` applied to the pixels' gradients: one sparse product each way, parallel, with no
atomics. The native kernel reads the same taps itself, through a :class:`ChunkPlan` (fixed chunks of
pixels, each with gradient rows of its own, so its sums do not depend on the thread count). Padding is
``"border"`` (coordinates clamped to the outermost texel centres), exactly as
``F.grid_sample(..., mode="bilinear", padding_mode="border")`` (tests check it): atlas texels no pixel
reads get no gradient and keep their prior.
"""
from __future__ import annotations

import warnings
from typing import NamedTuple

import torch
from torch import Tensor


#: pixels per chunk of the native texel kernel: fixed, so that its sums do not depend on the thread count
#: (256 to 4096 measured within the noise on the bunny)
CHUNK_PIXELS = 1024


class ChunkPlan(NamedTuple):
    """How the native texel kernel splits ``K`` pixels' taps into chunks (int64 offsets, int32 indices, CPU).

    ``cstart [nchunk + 1]``: the chunks' first pixels; each chunk adds its gradients into rows of its own, one
    per texel it reads: ``uoff [nchunk + 1]`` the chunks' first rows, ``lidx [K, 4]`` each tap's row within its
    chunk; ``rptr [T + 1]`` and ``rsrc [rows]``: the rows of texel ``t`` are ``rsrc[rptr[t]:rptr[t + 1]]``, in
    chunk order (so each texel sums them in one fixed order).

    Example:
        >>> p = chunk_plan(torch.tensor([[0, 1, 2, 3], [1, 1, 3, 3]], dtype=torch.int32), 4, chunk=1)
        >>> p.cstart.tolist(), p.uoff.tolist(), p.lidx.tolist()
        ([0, 1, 2], [0, 4, 6], [[0, 1, 2, 3], [0, 0, 1, 1]])
        >>> p.rptr.tolist(), p.rsrc.tolist()             # texel 1: row 1 (chunk 0), then row 4 (chunk 1)
        ([0, 1, 3, 4, 6], [0, 1, 4, 2, 3, 5])
    """

    cstart: Tensor
    uoff: Tensor
    lidx: Tensor
    rptr: Tensor
    rsrc: Tensor

    @property
    def nchunk(self) -> int:
        return self.cstart.numel() - 1


def chunk_plan(idx: Tensor, texels: int, chunk: int = CHUNK_PIXELS) -> ChunkPlan:
    """The :class:`ChunkPlan` of taps ``idx [K, 4]`` into a map of ``texels`` texels, in chunks of ``chunk`` pixels."""
    idx = idx.to("cpu", torch.int64)
    K = idx.shape[0]
    nchunk = max(1, -(-K // chunk))
    cstart = torch.clamp(torch.arange(nchunk + 1, dtype=torch.int64) * chunk, max=K)
    owner = (torch.arange(K) // chunk)[:, None].expand(K, 4)
    rows, inv = torch.unique(owner * texels + idx, return_inverse=True)       # sorted by chunk, then texel
    row_chunk, row_texel = rows // texels, rows % texels
    uoff = torch.zeros(nchunk + 1, dtype=torch.int64)
    uoff[1:] = torch.bincount(row_chunk, minlength=nchunk).cumsum(0)
    rptr = torch.zeros(texels + 1, dtype=torch.int64)
    rptr[1:] = torch.bincount(row_texel, minlength=texels).cumsum(0)
    rsrc = torch.argsort(row_texel, stable=True)                              # stable: chunk order per texel
    return ChunkPlan(cstart, uoff, (inv - uoff[owner]).to(torch.int32).contiguous(), rptr,
                     rsrc.to(torch.int32).contiguous())


class Taps(NamedTuple):
    """The bilinear lookup of ``K`` pixels in an ``(Ht, Wt)`` map: flat texel indices ``idx`` (int32 ``[K, 4]``),
    weights ``w [K, 4]``, the same as sparse matrices ``S [K, T]`` and ``St [T, K]``, and the native kernel's
    :class:`ChunkPlan` of them."""

    idx: Tensor
    w: Tensor
    S: Tensor
    St: Tensor
    grid: tuple
    plan: ChunkPlan


def taps(uv: Tensor, resolution, align_corners: bool, dtype=torch.float32, device=None) -> Taps:
    """The :class:`Taps` of pixels at ``uv [K, 2]`` in a map of ``resolution (Ht, Wt)``.

    Example:
        >>> t = taps(torch.zeros(1, 2), (2, 2), False)
        >>> t.idx.tolist(), t.w.tolist(), t.grid
        ([[0, 1, 2, 3]], [[0.25, 0.25, 0.25, 0.25]], (2, 2))
    """
    idx, w = bilinear_taps(uv, resolution, align_corners)
    S, St = tap_matrix(uv, resolution, align_corners, dtype=dtype, device=device)
    return Taps(idx.to(torch.int32).contiguous().to(device), w.to(dtype=dtype, device=device).contiguous(), S, St,
                tuple(resolution), chunk_plan(idx, resolution[0] * resolution[1]))


def bilinear_taps(uv: Tensor, resolution, align_corners: bool) -> tuple[Tensor, Tensor]:
    """Flat texel indices ``[K, 4]`` and weights ``[K, 4]`` of bilinear lookups at ``uv [K, 2]`` in an ``(H, W)`` map.

    Example:
        >>> idx, w = bilinear_taps(torch.tensor([[0.0, 0.0]]), (2, 2), align_corners=False)   # the map's centre
        >>> idx.tolist(), w.tolist()
        ([[0, 1, 2, 3]], [[0.25, 0.25, 0.25, 0.25]])
    """
    h, w = resolution
    u, v = uv[:, 0].double(), uv[:, 1].double()
    if align_corners:
        x, y = (u + 1) / 2 * (w - 1), (v + 1) / 2 * (h - 1)
    else:
        x, y = (u + 1) / 2 * w - 0.5, (v + 1) / 2 * h - 0.5
    x, y = x.clamp(0, w - 1), y.clamp(0, h - 1)                 # padding_mode="border"
    x0, y0 = x.floor().clamp(max=max(w - 2, 0)), y.floor().clamp(max=max(h - 2, 0))
    fx, fy = x - x0, y - y0
    x0, y0 = x0.long(), y0.long()
    x1, y1 = (x0 + 1).clamp(max=w - 1), (y0 + 1).clamp(max=h - 1)
    idx = torch.stack([y0 * w + x0, y0 * w + x1, y1 * w + x0, y1 * w + x1], dim=1)
    wt = torch.stack([(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy], dim=1)
    return idx, wt


def tap_matrix(uv: Tensor, resolution, align_corners: bool, dtype=torch.float32, device=None) -> tuple[Tensor, Tensor]:
    """``(S, S^T)``: the ``K x T`` lookup matrix of :func:`bilinear_taps` and its transpose, both sparse CSR."""
    idx, wt = bilinear_taps(uv, resolution, align_corners)
    K, T = idx.shape[0], resolution[0] * resolution[1]
    rows = torch.arange(K, device=idx.device).repeat_interleave(4)      # on the uv's device (CUDA too)
    with warnings.catch_warnings():      # torch calls its CSR support "beta"; the products used here are tested
        warnings.simplefilter("ignore", UserWarning)
        coo = torch.sparse_coo_tensor(torch.stack([rows, idx.reshape(-1)]), wt.reshape(-1), (K, T),
                                      check_invariants=True).coalesce()
        S = coo.to(dtype=dtype, device=device).to_sparse_csr()
        St = coo.t().coalesce().to(dtype=dtype, device=device).to_sparse_csr()
    return S, St


class _Gather(torch.autograd.Function):
    # pixel-major dense operands ([T, nC] and [K, nC], contiguous): several times faster than the transposed
    # layouts with torch's CSR products on CPU (measured: 13 + 8 ms vs 19 + 87 ms for K = 81k, nC = 80)
    @staticmethod
    def forward(ctx, x, S, St):
        ctx.St = St
        return torch.sparse.mm(S, x.t().contiguous()).t()

    @staticmethod
    def backward(ctx, g):
        return torch.sparse.mm(ctx.St, g.t().contiguous()).t(), None, None


def gather(tex: Tensor, S: Tensor, St: Tensor) -> Tensor:
    """Maps ``tex [n, C, H, W]`` read at the pixels of ``S``: ``[n, C, K]`` (differentiable w.r.t. ``tex``).

    Example:
        >>> S, St = tap_matrix(torch.tensor([[0.0, 0.0], [-0.5, -0.5]]), (2, 2), False)
        >>> gather(torch.arange(4.0).view(1, 1, 2, 2), S, St).tolist()   # the centre, then texel 0
        [[[1.5, 0.0]]]
    """
    n, c, h, w = tex.shape
    return _Gather.apply(tex.reshape(n * c, h * w), S, St).reshape(n, c, -1)


def texture_order(uv: Tensor) -> Tensor:
    """A permutation of pixels at ``uv [K, 2]`` that puts them in texture order (a Z-order curve over ``uv`` at
    2^16 steps a side; ties in their given order), so that consecutive pixels read nearby texels whatever the
    map's resolution: the native texel kernel's reads and gradient rows then stay in cache.

    Example:
        >>> texture_order(torch.tensor([[0.9, 0.9], [-0.9, -0.9], [0.9, -0.9], [-0.9, 0.9]])).tolist()
        [1, 2, 3, 0]
    """
    q = ((uv.detach().to("cpu", torch.float64).clamp(-1, 1) + 1) * 32767.5).long()

    def spread(x):                                        # 16 bits -> every other bit of 32
        x = (x | (x << 8)) & 0x00FF00FF
        x = (x | (x << 4)) & 0x0F0F0F0F
        x = (x | (x << 2)) & 0x33333333
        return (x | (x << 1)) & 0x55555555

    return torch.argsort(spread(q[:, 0]) | (spread(q[:, 1]) << 1), stable=True)
