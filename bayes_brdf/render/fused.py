"""Per-pixel shading kernels: ``radiance = sum_lights f(kd, r, ks; cosines) * (n.l) * scale``.

Inputs (all broadcastable, channel-first): ``kd, ks`` ``[n, V', 3, H', W']``,
``r`` ``[n, V', 1, H', W']``, cosines ``[P, V, L, 1, H, W]``, ``scale``
``[1, V, L, 3, H, W]``; output ``[n, V, 3, H, W]``.

* :func:`eager_kernel` -- the plain-torch reference, built from the named BRDF
  terms in :mod:`.brdf`; autograd differentiates it.
* :func:`compiled_kernel` -- the same function with hand-derived gradients
  w.r.t. ``kd, r, ks`` (custom autograd functions): on CPU the native C loop
  nest of :mod:`.native`, elsewhere (CUDA, or no C compiler) both directions
  fused by ``torch.compile``. Used when the cosines do not depend on the
  particles (the normals are held fixed, ``P = 1``), the maps need no per-view
  texture lookup, and nothing else needs gradients; any other case falls back
  to the eager kernel. Tests check both implementations against eager, and
  gradcheck checks the analytic gradients.
* :func:`compiled_loss` -- shading fused with the L1/L2 pixel loss, per
  particle, without materialising the images (the samplers' hot path).

Analytic gradients, with ``A = scale * (n.l)``, ``w`` the Fresnel weight,
``F = ks (1 - w) + w``, ``S = D G / (4 (n.l)(n.v))`` and ``q = (1 - ks) / pi``::

    out    = sum_l A (kd q + S F)
    d/dkd  = sum_l A q
    d/dks  = sum_l A (S (1 - w) - kd / pi)
    d/dr   = sum_l A F S (d ln S / dr),
    d ln S / dr = 4 r^3 (1/alpha^2 - 2 (n.h)^2 / den) - r ((1 - n.l) / (n.l (1 - k) + k) + (1 - n.v) / (n.v (1 - k) + k))

with ``alpha = r^2``, ``k = alpha / 2``, ``den = (n.h)^2 (alpha^2 - 1) + 1``.
"""
from __future__ import annotations

import functools
import os
import warnings

import torch
from torch import Tensor

from ..errors import InputError
from . import native, texels
from . import transfer as env_transfer
from .brdf import INV_PI, fresnel_weight, microfacet


def env_radiance(kd: Tensor, r: Tensor, ks: Tensor, env: Tensor, ks_factor: bool = True) -> Tensor:
    """Radiance ``[n, V, 3, H, W]`` of an environment light from its precomputed terms ``env [1, V, C, H, W]``
    (:mod:`.transfer`): ``kd (1 - kf ks) / pi E + ks a(r) + b(r)`` (plain torch, autograd gradients)."""
    E, a, b = env_transfer.interpolate(env, r)
    q = (1 - ks) * INV_PI if ks_factor else INV_PI
    return kd * q * E + ks * a + b



def eager_kernel(kd: Tensor, r: Tensor, ks: Tensor, nl: Tensor, nv: Tensor, nh: Tensor, vh: Tensor,
                 scale: Tensor, ks_factor: bool = True, env: Tensor | None = None) -> Tensor:
    """Reference kernel (plain torch ops, autograd gradients); ``env``: an environment light's terms."""
    k3, r3, s3 = (x.unsqueeze(2) for x in (kd, r, ks))  # add the light dimension
    f = microfacet(k3, r3, s3, nl, nv, nh, vh, ks_factor)
    out = (f * nl * scale).sum(2)
    return out if env is None else out + env_radiance(kd, r, ks, env, ks_factor)


# ------------------------------------------------------------------ fused path
def _spec_terms(r, nl, nv, nh):
    """S = D G / (4 nl nv) and d ln S / dr, shapes broadcast to [n, V, L, 1, H, W]."""
    a = r * r
    a2 = a * a
    nh2 = nh * nh
    den = nh2 * (a2 - 1) + 1
    k = 0.5 * a
    gl = nl * (1 - k) + k
    gv = nv * (1 - k) + k
    s = a2 * (0.25 * INV_PI) / (den * den * gl * gv)  # D * G / (4 nl nv): the cosines cancel
    return s, a, a2, nh2, den, gl, gv


def _forward(kd, r, ks, nl, nv, nh, vh, scale, ks_factor: bool):
    kd, r, ks = (x.unsqueeze(2) for x in (kd, r, ks))
    s, *_ = _spec_terms(r, nl, nv, nh)
    w = fresnel_weight(vh)
    q = (1 - ks) * INV_PI if ks_factor else INV_PI
    A = scale * nl
    return (A * (kd * q + s * (ks * (1 - w) + w))).sum(2)


_compiled: dict = {}
_failed: set = set()


def _get_compiled(name, fn):
    """``torch.compile(fn)``, or ``fn`` itself once compiling it has failed (e.g. too many shapes)."""
    if name in _failed:
        return fn
    if name not in _compiled:
        comp = torch.compile(fn, dynamic=False, fullgraph=True)

        def call(*args):
            try:
                return comp(*args)
            except Exception as e:  # recompile limit, missing compiler, ...: stay correct, go eager
                _failed.add(name)
                warnings.warn(f"bayes_brdf: compiled shading kernel '{name}' unavailable "
                              f"({type(e).__name__}); using eager torch from now on")
                return fn(*args)

        _compiled[name] = call
    return _compiled[name]


class _FusedShade(torch.autograd.Function):
    @staticmethod
    def forward(ctx, kd, r, ks, nl, nv, nh, vh, scale, ks_factor):
        ctx.save_for_backward(kd, r, ks, nl, nv, nh, vh, scale)
        ctx.ks_factor = ks_factor
        return _get_compiled("fwd", _forward)(kd, r, ks, nl, nv, nh, vh, scale, ks_factor)

    @staticmethod
    def backward(ctx, gout):
        kd, r, ks, nl, nv, nh, vh, scale = ctx.saved_tensors
        gkd, gr, gks = _per_view_backward("bwd", _image_grad_view, gout, kd, r, ks, nl, nv, nh, vh, scale,
                                          (ctx.ks_factor,))
        return gkd, gr, gks, None, None, None, None, None, None


def _route(kd, r, ks, nl, nv, nh, vh, scale, torch_compile: bool = True) -> str:
    """Which implementation a fused call can use: ``"native"`` (C, CPU), ``"compiled"`` or ``"eager"``.

    The fused kernels need the cosines shared by all particles (normals held
    fixed, ``P = 1``), no gradient w.r.t. geometry, and maps that need no
    per-view texture lookup (``V' = 1``). The native kernel also takes ``1 x 1``
    constant maps; the ``torch.compile`` one only full-resolution maps.
    """
    if any(t.requires_grad for t in (nl, nv, nh, vh, scale)) or nl.shape[0] != 1:
        return "eager"
    hw = tuple(nl.shape[-2:])
    if any(t.shape[1] != 1 or tuple(t.shape[-2:]) not in (hw, (1, 1)) for t in (kd, r, ks)):
        return "eager"
    if nl.shape[2] <= native.MAX_LIGHTS and native.available(kd):
        return "native"
    full = all(tuple(t.shape[-2:]) == hw for t in (kd, r, ks))
    if torch_compile == "auto":  # only try torch.compile (slow to probe) when the native kernel cannot serve
        torch_compile = compile_available()
    return "compiled" if full and torch_compile else "eager"


def _texel_route(kd, r, ks, nl, nv, nh, vh, scale, taps):
    """With ``taps`` (texel maps read bilinearly at each pixel): ``"native"`` when the C kernel can gather itself,
    else the maps looked up here (``"lookup"``) for the other implementations."""
    ok = not any(t.requires_grad for t in (nl, nv, nh, vh, scale)) and nl.shape[0] == 1 and \
        nl.shape[2] <= native.MAX_LIGHTS and native.available(kd, texels=True)
    return "native" if ok else "lookup"


def _looked_up(taps, *maps):
    """Texel maps ``[n, 1, C, Ht, Wt]`` read at the pixels of ``taps``: ``[n, 1, C, 1, K]`` (1 x 1 maps as they are)."""
    out = []
    for t in maps:
        if tuple(t.shape[-2:]) == (1, 1):
            out.append(t)
        else:
            out.append(texels.gather(t[:, 0], taps.S, taps.St)[:, None, :, None, :])
    return out


def compiled_kernel(kd, r, ks, nl, nv, nh, vh, scale, ks_factor: bool = True, torch_compile: bool = True,
                    taps=None, env=None) -> Tensor:
    """Fused kernel with analytic gradients w.r.t. ``kd, r, ks`` (falls back to eager when it cannot apply).

    ``taps`` (:class:`~bayes_brdf.render.texels.Taps`): the maps are texel maps read bilinearly at each pixel
    (a mesh's pixels); the native kernel then gathers and scatters the texels itself. ``env``: an environment
    light's terms (the eager kernel shades them)."""
    if env is not None:
        if taps is not None:
            if _texel_route(kd, r, ks, nl, nv, nh, vh, scale, taps) == "native" and not env.requires_grad:
                return native.NativeShade.apply(kd, r, ks, nl, nv, nh, vh, scale, ks_factor, taps, env)
            kd, r, ks = _looked_up(taps, kd, r, ks)
        return eager_kernel(kd, r, ks, nl, nv, nh, vh, scale, ks_factor, env=env)
    if taps is not None:
        if _texel_route(kd, r, ks, nl, nv, nh, vh, scale, taps) == "native":
            return native.NativeShade.apply(kd, r, ks, nl, nv, nh, vh, scale, ks_factor, taps)
        kd, r, ks = _looked_up(taps, kd, r, ks)
    route = _route(kd, r, ks, nl, nv, nh, vh, scale, torch_compile)
    if route == "native":
        return native.NativeShade.apply(kd, r, ks, nl, nv, nh, vh, scale, ks_factor)
    if route == "compiled":
        return _FusedShade.apply(kd, r, ks, nl, nv, nh, vh, scale, ks_factor)
    return eager_kernel(kd, r, ks, nl, nv, nh, vh, scale, ks_factor)


_COMPILE_OK: bool | None = None


def compile_available() -> bool:
    """Whether ``torch.compile`` works here (checked once with a tiny function)."""
    global _COMPILE_OK
    if _COMPILE_OK is None:
        if os.environ.get("BAYES_BRDF_NO_COMPILE"):
            _COMPILE_OK = False
        else:
            try:
                torch.compile(lambda x: x * 2 + 1, dynamic=False)(torch.ones(4))
                _COMPILE_OK = True
            except Exception as e:  # no C++ compiler, unsupported platform, ...
                warnings.warn(f"torch.compile unavailable ({type(e).__name__}); using the eager shading kernel")
                _COMPILE_OK = False
    return _COMPILE_OK


#: ``backend="auto"`` compiles only from this many pixel evaluations per call
#: (particles x views x pixels); below it, compilation time is not worth it.
AUTO_COMPILE_MIN_WORK = 2**21


def get_kernel(backend: str, work: int | None = None, loss: bool = False):
    """The kernel for ``backend``: ``"eager"``, ``"compiled"`` or ``"auto"`` (``loss=True``: the fused loss).

    ``"compiled"`` uses the native C kernel on CPU when it builds, else
    ``torch.compile``. ``"auto"`` uses the native kernel whenever it applies
    (it is compiled once per machine and cached), and ``torch.compile`` only
    when the call is large enough to pay for compiling
    (``work >= AUTO_COMPILE_MIN_WORK`` pixel evaluations); otherwise eager.
    """
    if backend == "eager":
        return eager_loss if loss else eager_kernel
    fn = compiled_loss if loss else compiled_kernel
    if backend == "compiled":
        return fn
    if backend == "auto":
        big = work is None or work >= AUTO_COMPILE_MIN_WORK
        return functools.partial(fn, torch_compile="auto" if big else False)
    raise InputError(f"unknown shading backend '{backend}'", fix="use auto, eager or compiled")


# ------------------------------------------------- fused shading + pixel loss
def eager_loss(kd, r, ks, nl, nv, nh, vh, scale, y, wgt, ks_factor: bool = True, l1: bool = True,
               env: Tensor | None = None) -> Tensor:
    """Reference: per-particle ``sum(wgt * |R - y|)`` (``l1``) or ``sum(wgt * (R - y)^2)``, shape ``[n]``."""
    d = eager_kernel(kd, r, ks, nl, nv, nh, vh, scale, ks_factor, env=env) - y
    return (wgt * (d.abs() if l1 else d * d)).flatten(1).sum(1)


def _loss_forward(kd, r, ks, nl, nv, nh, vh, scale, y, wgt, ks_factor: bool, l1: bool):
    d = _forward(kd, r, ks, nl, nv, nh, vh, scale, ks_factor) - y
    return (wgt * (d.abs() if l1 else d * d)).flatten(1).sum(1)


def _view_terms(kd, r, ks, nl, nv, nh, vh, scale, ks_factor: bool):
    """Radiance of ONE view and the per-light terms its gradients need (pointwise over ``[n, 3, H, W]``).

    ``kd, ks [n, 3, H, W]``, ``r [n, 1, H, W]``, cosines ``[L, 1, H, W]`` (``n.v``: ``[1, 1, H, W]``),
    ``scale [L, 3, H, W]``.
    """
    q = (1 - ks) * INV_PI if ks_factor else INV_PI
    terms = []
    out = 0.0
    for li in range(nl.shape[0]):
        A = scale[li] * nl[li]
        s, a, a2, nh2, den, gl, gv = _spec_terms(r, nl[li], nv[0], nh[li])
        w = fresnel_weight(vh[li])
        F = ks * (1 - w) + w
        out = out + A * (kd * q + s * F)
        dlns = 4 * r * a * (1 / a2 - 2 * nh2 / den) - r * ((1 - nl[li]) / gl + (1 - nv[0]) / gv)
        terms.append((A, s, w, F, dlns))
    return out, terms, q


def _accumulate(g, kd, terms, q, ks_factor: bool):
    gkd = gr = gks = 0.0
    for A, s, w, F, dlns in terms:
        gA = g * A
        gkd = gkd + gA * q
        gks = gks + gA * (s * (1 - w) - (kd * INV_PI if ks_factor else 0.0))
        gr = gr + (gA * F).sum(1, keepdim=True) * (s * dlns)
    return gkd, gr, gks


def _image_grad_view(gout, kd, r, ks, nl, nv, nh, vh, scale, ks_factor: bool):
    """Gradient contribution of ONE view given ``d loss / d radiance`` ``gout [n, 3, H, W]``."""
    _, terms, q = _view_terms(kd, r, ks, nl, nv, nh, vh, scale, ks_factor)
    return _accumulate(gout, kd, terms, q, ks_factor)


def _loss_grad_view(ge, kd, r, ks, nl, nv, nh, vh, scale, y, wgt, ks_factor: bool, l1: bool):
    """Gradient contribution of ONE view to the loss (``y [3, H, W]``, ``wgt [1, H, W]``, ``ge [n, 1, 1, 1]``)."""
    out, terms, q = _view_terms(kd, r, ks, nl, nv, nh, vh, scale, ks_factor)
    d = out - y
    return _accumulate(ge * wgt * (torch.sign(d) if l1 else 2 * d), kd, terms, q, ks_factor)


def _per_view_backward(name, fn, first, kd, r, ks, nl, nv, nh, vh, scale, extra=()):
    """Sum the per-view gradient kernels over views.

    One compiled pointwise kernel per view, accumulated here: a reduction over
    the (non-contiguous) view axis inside one compiled graph was several times slower.
    ``first`` and each tensor of ``extra`` are indexed by view when they have
    a view axis (``first`` is ``[n, V, 3, H, W]`` for images, ``[n]`` for losses).
    """
    f = _get_compiled(name, fn)
    kd_, r_, ks_ = kd[:, 0], r[:, 0], ks[:, 0]
    gkd = gr = gks = None
    for v in range(nl.shape[1]):
        head = first[:, v].contiguous() if first.dim() == 5 else first[:, None, None, None]
        a, b, c = f(head, kd_, r_, ks_, nl[0, v], nv[0, v], nh[0, v], vh[0, v], scale[0, v],
                    *(e[v] if isinstance(e, Tensor) else e for e in extra))
        gkd, gr, gks = (a, b, c) if gkd is None else (gkd + a, gr + b, gks + c)
    # particles broadcast in the kernel: a map held fixed (n = 1) gets the sum over particles
    return gkd.sum_to_size(kd_.shape)[:, None], gr.sum_to_size(r_.shape)[:, None], gks.sum_to_size(ks_.shape)[:, None]


class _FusedLoss(torch.autograd.Function):
    @staticmethod
    def forward(ctx, kd, r, ks, nl, nv, nh, vh, scale, y, wgt, ks_factor, l1):
        ctx.save_for_backward(kd, r, ks, nl, nv, nh, vh, scale, y, wgt)
        ctx.flags = (ks_factor, l1)
        return _get_compiled("loss_fwd", _loss_forward)(kd, r, ks, nl, nv, nh, vh, scale, y, wgt, ks_factor, l1)

    @staticmethod
    def backward(ctx, ge):
        kd, r, ks, nl, nv, nh, vh, scale, y, wgt = ctx.saved_tensors
        gkd, gr, gks = _per_view_backward("loss_bwd", _loss_grad_view, ge.contiguous(), kd, r, ks, nl, nv, nh, vh,
                                          scale, (y, wgt, *ctx.flags))
        return (gkd, gr, gks) + (None,) * 9


def compiled_loss(kd, r, ks, nl, nv, nh, vh, scale, y, wgt, ks_factor: bool = True, l1: bool = True,
                  torch_compile: bool = True, taps=None, env=None) -> Tensor:
    """Fused shading + loss with analytic gradients w.r.t. ``kd, r, ks`` (eager fallback as :func:`compiled_kernel`;
    ``taps`` and ``env`` as there)."""
    if env is not None:
        if taps is not None:
            if not (y.requires_grad or wgt.requires_grad or env.requires_grad) and \
                    _texel_route(kd, r, ks, nl, nv, nh, vh, scale, taps) == "native":
                return native.NativeLoss.apply(kd, r, ks, nl, nv, nh, vh, scale, y, wgt, ks_factor, l1, taps, env)
            kd, r, ks = _looked_up(taps, kd, r, ks)
        return eager_loss(kd, r, ks, nl, nv, nh, vh, scale, y, wgt, ks_factor, l1, env=env)
    if taps is not None:
        if not (y.requires_grad or wgt.requires_grad) and \
                _texel_route(kd, r, ks, nl, nv, nh, vh, scale, taps) == "native":
            return native.NativeLoss.apply(kd, r, ks, nl, nv, nh, vh, scale, y, wgt, ks_factor, l1, taps)
        kd, r, ks = _looked_up(taps, kd, r, ks)
    route = "eager" if y.requires_grad or wgt.requires_grad else _route(kd, r, ks, nl, nv, nh, vh, scale,
                                                                           torch_compile)
    if route == "native":
        return native.NativeLoss.apply(kd, r, ks, nl, nv, nh, vh, scale, y, wgt, ks_factor, l1)
    if route == "compiled":
        return _FusedLoss.apply(kd, r, ks, nl, nv, nh, vh, scale, y, wgt, ks_factor, l1)
    return eager_loss(kd, r, ks, nl, nv, nh, vh, scale, y, wgt, ks_factor, l1)


def pixel_loss(kd, r, ks, nl, nv, nh, vh, scale, y, wgt, ks_factor: bool = True, l1: bool = True) -> Tensor:
    """``[n, 3, H, W]``: the loss of :func:`eager_loss` per pixel and channel, summed over the views only (no
    gradient): the native kernel where :func:`_route` allows it, else the eager reference."""
    with torch.no_grad():
        if _route(kd, r, ks, nl, nv, nh, vh, scale, torch_compile=False) == "native":
            return native.pixel_losses(kd, r, ks, nl, nv, nh, vh, scale, y, wgt, ks_factor, l1)
        d = eager_kernel(kd, r, ks, nl, nv, nh, vh, scale, ks_factor) - y
        return (wgt * (d.abs() if l1 else d * d)).sum(1)


def get_loss_kernel(backend: str, work: int | None = None):
    """The fused loss for ``backend`` (see :func:`get_kernel`)."""
    return get_kernel(backend, work, loss=True)
