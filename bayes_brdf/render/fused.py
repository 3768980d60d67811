"""Per-pixel shading kernels: ``radiance = sum_lights f(kd, r, ks; cosines) * (n.l) * scale``.

Inputs (all broadcastable, channel-first): ``kd, ks`` ``[n, V', 3, H', W']``,
``r`` ``[n, V', 1, H', W']``, cosines ``[P, V, L, 1, H, W]``, ``scale``
``[1, V, L, 3, H, W]``; output ``[n, V, 3, H, W]``.

* :func:`eager_kernel` -- the plain-torch reference, built from the named BRDF
  terms in :mod:`.brdf`; autograd differentiates it.
"""
from __future__ import annotations

from torch import Tensor

from ..errors import InputError
from .brdf import microfacet


def eager_kernel(kd: Tensor, r: Tensor, ks: Tensor, nl: Tensor, nv: Tensor, nh: Tensor, vh: Tensor,
                 scale: Tensor, ks_factor: bool = True) -> Tensor:
    """Reference kernel (plain torch ops, autograd gradients)."""
    kd, r, ks = (x.unsqueeze(2) for x in (kd, r, ks))  # add the light dimension
    f = microfacet(kd, r, ks, nl, nv, nh, vh, ks_factor)
    return (f * nl * scale).sum(2)


def get_kernel(backend: str):
    if backend in ("eager", "auto"):
        return eager_kernel
    raise InputError(f"unknown shading backend '{backend}'", fix="use auto, eager or compiled")
