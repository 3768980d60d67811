"""Per-pixel differential entropy of the particles' renders: 1-D Gaussian KDE (Eq. 19), Silverman bandwidth
(Eq. 20), and two estimators of ``h = -E[log p]``:

* ``"mc"`` -- the paper's single-sample Monte Carlo estimator (Eq. 21): per pixel, draw ``r`` from the KDE
  and take ``-log p(r)``. Unbiased, noisy; the random numbers are given per pixel position so that
  candidates are compared with common random numbers.
* ``"quadrature"`` -- deterministic: ``-(1/n) sum_c E_{N(v_c, bw^2)}[log p]`` with Gauss-Hermite nodes in
  each kernel. ``nodes`` times ``n`` times the work of ``"mc"``, no noise.

:func:`kde_entropy` runs a native C kernel on CPU (OpenMP over pixels) and the same
computation in torch elsewhere (:func:`kde_entropy_torch`, also the test reference).

Example:
    >>> import torch
    >>> x = torch.randn(20, 1000, dtype=torch.float64)           # 20 particles, 1000 pixels
    >>> h, sd = kde_entropy(x, "quadrature")
    >>> abs(float(h.mean()) - 1.4189) < 0.15                     # N(0, 1): 0.5 log(2 pi e)
    True
"""
from __future__ import annotations

import ctypes
import math
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from ..errors import InputError

ESTIMATORS = ("mc", "quadrature")
_SRC = Path(__file__).with_name("_kde_entropy.c")
_NMAX: dict = {}


def _lib(dtype):
    """``(the native entropy function, its particle limit)`` for ``dtype``, or ``None`` (the torch path runs)."""
    from ..render.native import native_function
    fn = native_function(_SRC, "bb_kde_entropy", dtype,
                         [ctypes.c_int64] * 5 + [ctypes.c_void_p] * 5 + [ctypes.c_double] * 2 + [ctypes.c_void_p] * 2,
                         extra_flags=("-ffast-math",), fallback="torch")
    if fn is None:
        return None
    if dtype not in _NMAX:
        nmax = native_function(_SRC, "bb_kde_nmax", dtype, [], restype=ctypes.c_int64, extra_flags=("-ffast-math",))
        _NMAX[dtype] = int(nmax())
    return fn, _NMAX[dtype]


def hermite_nodes(nodes: int) -> tuple[Tensor, Tensor]:
    """Probabilists' Gauss-Hermite nodes and weights (summing to 1) for ``E_{N(0,1)}[f]``."""
    t, w = np.polynomial.hermite_e.hermegauss(int(nodes))
    return torch.as_tensor(t, dtype=torch.float64), torch.as_tensor(w / w.sum(), dtype=torch.float64)


def silverman(x: Tensor) -> tuple[Tensor, Tensor]:
    """Bandwidth (Eq. 20) and sample std of each column of ``x [n, cols]``: ``0.9 n^-1/5 min(sd, IQR/1.34)``.

    When the IQR is 0 (most particles agree) the std alone is used, as R's ``bw.nrd0`` does.
    """
    n = x.shape[0]
    sd = x.std(0) if n > 1 else torch.zeros_like(x[0])
    q = torch.quantile(x, torch.tensor([0.25, 0.75], dtype=x.dtype, device=x.device), dim=0)
    iqr = (q[1] - q[0]) / 1.34
    a = torch.where((iqr > 0) & (iqr < sd), iqr, sd)
    return 0.9 * n ** -0.2 * a, sd


def kde_entropy_torch(x: Tensor, estimator: str = "mc", *, u: Tensor | None = None, e: Tensor | None = None,
                      nodes: int = 8, noise_var: float = 0.0, min_bandwidth: float = 1e-6):
    """Torch implementation of :func:`kde_entropy` (same arguments and results)."""
    n = x.shape[0]
    xd = x.double()
    bw, sd = silverman(xd)
    bw = (bw * bw + noise_var).clamp_min(min_bandwidth ** 2).sqrt()
    lognorm = math.log(n) + bw.log() + 0.5 * math.log(2 * math.pi)

    def logp(r):  # r [m, cols] -> [m, cols]
        d = (r[:, None] - xd[None]) / bw  # [m, n, cols]
        return torch.logsumexp(-0.5 * d * d, dim=1) - lognorm

    if estimator == "mc":
        c = (u.double() * n).long().clamp(0, n - 1)
        r = xd.gather(0, c[None]) + bw * e.double()
        h = -logp(r)[0]
    else:
        t, w = hermite_nodes(nodes)
        t, w = t.to(xd.device), w.to(xd.device)
        r = (xd[:, None] + bw * t[:, None]).reshape(-1, x.shape[1])  # [n * nq, cols]
        h = -(logp(r).reshape(n, len(t), -1) * w[:, None]).sum(1).mean(0)
    return h.to(x.dtype), sd.to(x.dtype)


def kde_entropy(x: Tensor, estimator: str = "mc", *, u: Tensor | None = None, e: Tensor | None = None,
                nodes: int = 8, noise_var: float = 0.0, min_bandwidth: float = 1e-6, generator=None,
                backend: str = "auto"):
    """Per-column entropy ``h [cols]`` (nats) of the 1-D KDE of ``x [n, cols]``, and the columns' std ``[cols]``.

    Args:
        x: ``n`` samples (particle renders) of ``cols`` pixel values.
        estimator: ``"mc"`` (Eq. 21) or ``"quadrature"`` (deterministic, ``nodes`` Gauss-Hermite nodes).
        u: for ``"mc"``: a uniform ``[cols]`` that picks the kernel; drawn from ``generator`` when not given.
        e: for ``"mc"``: a standard normal ``[cols]``, the offset within the kernel; drawn when not given.
        noise_var: render-noise variance (image units squared) added to every kernel: the KDE is then
            of ``R + noise``, which also bounds the entropy from below.
        min_bandwidth: floor on the kernel width, so pixels on which all particles agree give a finite
            (very negative) entropy.
        backend: ``"auto"`` (native C on CPU when it builds), ``"native"`` or ``"torch"``.
    """
    if estimator not in ESTIMATORS:
        raise InputError(f"unknown entropy estimator '{estimator}'", fix=f"use one of {', '.join(ESTIMATORS)}")
    if x.dim() != 2 or x.shape[0] < 2:
        raise InputError(f"entropy needs samples [n >= 2, cols], got {tuple(x.shape)}",
                         fix="use at least 2 particles")
    if estimator == "mc" and (u is None or e is None):
        u = torch.rand(x.shape[1], generator=generator, dtype=x.dtype).to(x.device)
        e = torch.randn(x.shape[1], generator=generator, dtype=x.dtype).to(x.device)
    kw = dict(u=u, e=e, nodes=nodes, noise_var=float(noise_var), min_bandwidth=float(min_bandwidth))
    lib = _lib(x.dtype) if backend != "torch" and x.device.type == "cpu" else None
    if backend == "native" and lib is None:
        raise InputError("the native entropy kernel is unavailable here", fix="use backend='torch'")
    if lib is None or x.shape[0] > lib[1]:  # more particles than the C kernel holds
        return kde_entropy_torch(x, estimator, **kw)
    fn, _ = lib
    x = x.contiguous()
    n, cols = x.shape
    h, sd = torch.empty(cols, dtype=x.dtype), torch.empty(cols, dtype=x.dtype)
    if estimator == "mc":
        u, e = u.to(x.dtype).contiguous(), e.to(x.dtype).contiguous()
        t = w = torch.zeros(1, dtype=torch.float64)
        mode, nq = 0, 0
    else:
        t, w = hermite_nodes(nodes)
        mode, nq = 1, len(t)
    p = lambda a: None if a is None else ctypes.c_void_p(a.data_ptr())  # noqa: E731
    fn(mode, n, cols, nq, torch.get_num_threads(), p(x), p(u if mode == 0 else None), p(e if mode == 0 else None),
       p(t), p(w), float(noise_var), float(min_bandwidth), p(h), p(sd))
    return h, sd


def noise_entropy(noise_var: float) -> float:
    """``h_noise`` per pixel: the entropy of ``N(0, noise_var)`` (0 for a deterministic renderer, ``noise_var=0``)."""
    return 0.0 if noise_var <= 0 else 0.5 * math.log(2 * math.pi * math.e * noise_var)
