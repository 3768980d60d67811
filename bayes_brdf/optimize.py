"""Two small optimisers for the library's own fits (the MAP's refinement, the noise level), without ``torch.optim``.

The first ``torch.optim`` optimiser a process creates imports ``torch._dynamo`` (measured 1.1 s on the 2-core
machine), which every ``fit``, ``infer`` and ``recommend`` paid at the end of its run, for an Adam on two rows
and a three-parameter fit. :class:`Adam` is ``torch.optim.Adam``'s arithmetic on one tensor (the same operations
in the same order: the same numbers, tests/test_optimize.py); :func:`newton` is a damped Newton method for
small smooth problems whose Hessian is cheap (the noise level's three coefficients,
:func:`bayes_brdf.models.noise.fit_noise_level`). Model training (:mod:`bayes_brdf.training`) keeps
``torch.optim``.
"""
from __future__ import annotations

import math
from typing import Callable

import torch
from torch import Tensor


class Adam:
    """Adam on one tensor, in place: ``torch.optim.Adam(lr, betas, eps)`` without weight decay or amsgrad.

    Example:
        >>> x = torch.tensor([3.0, -2.0])
        >>> opt = Adam(x, lr=0.1)
        >>> for _ in range(200):
        ...     opt.step(2 * x)           # the gradient of |x|^2
        >>> bool(x.abs().max() < 0.05)
        True
    """

    def __init__(self, param: Tensor, lr: float = 1e-3, betas: tuple[float, float] = (0.9, 0.999), eps: float = 1e-8):
        self.param, self.lr, self.betas, self.eps = param, float(lr), betas, float(eps)
        self.m = torch.zeros_like(param)
        self.v = torch.zeros_like(param)
        self.t = 0

    @torch.no_grad()
    def step(self, grad: Tensor) -> None:
        b1, b2 = self.betas
        self.t += 1
        self.m.lerp_(grad, 1 - b1)
        self.v.mul_(b2).addcmul_(grad, grad, value=1 - b2)
        step_size = self.lr / (1 - b1 ** self.t)
        denom = (self.v.sqrt() / (1 - b2 ** self.t) ** 0.5).add_(self.eps)
        self.param.addcdiv_(self.m, denom, value=-step_size)


def newton(fun: Callable[[Tensor], tuple[float, Tensor, Tensor]], x0: Tensor, *, max_iter: int = 200,
           ftol: float = 1e-13, halvings: int = 30) -> Tensor:
    """Minimise ``fun(x) -> (value, gradient [d], Hessian [d, d])`` from ``x0`` (float64, a few dimensions): Newton
    steps on the Hessian with its eigenvalues made positive (``|lambda|``, at least ``1e-12`` of the largest: a
    direction of negative curvature is descended, not climbed), each shortened by halving until the value falls.
    Stops when a step's predicted decrease ``-g.d`` is under ``ftol`` (relative to the value, at least 1: the
    float precision of a mean over many terms), when ``halvings`` halvings do not lower the value, or after
    ``max_iter`` steps.

    Example:
        >>> f = lambda x: (float((x - 1).pow(4).sum()), 4 * (x - 1).pow(3), torch.diag(12 * (x - 1).pow(2)))
        >>> [round(v, 2) for v in newton(f, torch.tensor([3.0, -2.0], dtype=torch.float64)).tolist()]
        [1.0, 1.0]
    """
    x = x0.detach().clone().to(torch.float64)
    val, g, H = fun(x)
    for _ in range(max_iter):
        lam, Q = torch.linalg.eigh(0.5 * (H + H.T))
        lam = lam.abs().clamp_min(1e-12 * max(float(lam.abs().max()), 1e-300))
        d = -(Q @ ((Q.T @ g) / lam))
        if not bool(torch.isfinite(d).all()) or -float(g @ d) < ftol * max(1.0, abs(val)):
            break
        for _ in range(halvings):
            v2, g2, H2 = fun(x + d)
            if math.isfinite(v2) and v2 < val:
                break
            d = d / 2
        else:
            break
        x, val, g, H = x + d, v2, g2, H2
    return x
