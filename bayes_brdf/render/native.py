"""Native CPU shading kernels, compiled on first use; the one loader of the package's C libraries.

The fused per-pixel work of :mod:`.fused` as C loop nests, so the maps are read once and gradients
accumulate in registers rather than in per-view temporaries:

* ``_native_kernels.c``: pixels that are texels (rectified views of the plane); OpenMP over pixel blocks,
  views and lights inside, SIMD over pixels.
* ``_native_texels.c``: pixels that read texel maps through bilinear taps (a mesh's pixels); SIMD over
  particles, so a pixel's four texels are vector loads and its gradients vector adds, in fixed chunks of
  pixels (:class:`~bayes_brdf.render.texels.ChunkPlan`) so that its sums do not depend on the thread count.
* ``_native_normal_maps.c``: the loss of pixels that are texels when each particle has its own normal map (a
  decoded one, or sampled normals): the cosines made per particle in the loop, the gradient w.r.t. the normals
  too (:class:`NativeNormalMapLoss`).

Both share the BRDF terms of ``_native_brdf.h``. Used by the ``"compiled"`` backend for CPU tensors when a
C compiler is available (``cc``/``gcc``), else the ``torch.compile`` path is used. Built once per source
version into ``$XDG_CACHE_HOME/bayes_brdf`` (or ``~/.cache/bayes_brdf``); set ``BAYES_BRDF_NO_NATIVE=1`` to
disable. :func:`native_function` loads any of the package's C sources (also the entropy kernel of
:mod:`bayes_brdf.guidance.entropy`).

Tests check both against the eager reference in float64 (``tests/render/test_fused.py``,
``tests/render/test_texels.py``).
"""
from __future__ import annotations

import ctypes
import hashlib
import os
import platform
import re
import shutil
import subprocess
import tempfile
import threading
import warnings
from collections import OrderedDict
from pathlib import Path

import torch
from torch import Tensor

from . import transfer
from .tensor_memo import TensorMemo

_DIR = Path(__file__).parent
_LOCK = threading.Lock()
_FUNCTIONS: dict = {}
_FAILED: set = set()
_REALS = {torch.float32: "float", torch.float64: "double"}
_KERNELS_SRC, _TEXELS_SRC, _NORMAL_MAPS_SRC = (_DIR / f for f in ("_native_kernels.c", "_native_texels.c",
                                                                  "_native_normal_maps.c"))
MODE_IMAGE_FWD, MODE_IMAGE_BWD, MODE_LOSS, MODE_PIXEL_LOSS = 0, 1, 2, 3
MAX_LIGHTS = 4  # LMAX in the C sources


def _cache_dir() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "bayes_brdf"


def _with_headers(src_path: Path) -> bytes:
    """The source and the local headers it includes (``#include "x.h"``): what a build depends on."""
    src = Path(src_path).read_bytes()
    heads = re.findall(rb'^\s*#\s*include\s*"([^"]+)"', src, flags=re.M)
    return src + b"".join(_with_headers(Path(src_path).parent / h.decode()) for h in heads)


def build_library(src_path: Path, real: str, prefix: str, extra_flags=()) -> Path:
    """Compile ``src_path`` (with ``-DREAL=real``) into a cached shared library; rebuilt when the source or a
    local header it includes changes."""
    src = _with_headers(src_path)
    flags = ["-O3", "-march=native", "-fopenmp", "-fPIC", "-shared", "-fno-math-errno", f"-DREAL={real}",
             *extra_flags]
    if platform.machine().lower() in ("x86_64", "amd64"):
        flags.append("-mprefer-vector-width=512")  # full AVX-512 width where the CPU has it (measured ~10% faster)
    key = hashlib.sha256(src + " ".join(flags).encode()).hexdigest()[:16]
    out = _cache_dir() / f"{prefix}_{real}_{key}.so"
    if out.exists():
        return out
    cc = os.environ.get("CC") or shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        raise RuntimeError("no C compiler (cc/gcc) found")
    out.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=out.parent) as tmp:
        tmp_so = Path(tmp) / out.name
        subprocess.run([cc, *flags, str(src_path), "-o", str(tmp_so), "-lm"], check=True, capture_output=True,
                       text=True)
        os.replace(tmp_so, out)  # atomic: concurrent builders agree
    return out


def native_function(src_path: Path, symbol: str, dtype: torch.dtype, argtypes, restype=None, extra_flags=(),
                    fallback: str = "torch"):
    """The ctypes function ``symbol`` of ``src_path`` built for ``dtype`` (float32/float64), or ``None`` when
    native kernels are unavailable (``BAYES_BRDF_NO_NATIVE``, no compiler, another dtype). A failed build
    warns once, naming ``fallback`` (what runs instead), and is not retried."""
    real = _REALS.get(dtype)
    if real is None or os.environ.get("BAYES_BRDF_NO_NATIVE"):
        return None
    key = (src_path, symbol, real, tuple(extra_flags))
    fn = _FUNCTIONS.get(key)    # the hot path: every kernel call looks its function up (no Path made, no lock)
    if fn is not None:
        return fn
    src_path = Path(src_path)
    if src_path in _FAILED:
        return None
    with _LOCK:
        if key not in _FUNCTIONS:
            try:
                lib = ctypes.CDLL(str(build_library(src_path, real, "bb_" + src_path.stem.lstrip("_"), extra_flags)))
            except Exception as e:  # no compiler, no OpenMP, ...: the fallback still works
                _FAILED.add(src_path)
                detail = getattr(e, "stderr", "") or e
                warnings.warn(f"bayes_brdf: native CPU kernel {src_path.name} unavailable "
                              f"({str(detail).strip()[:200]}); using {fallback}")
                return None
            fn = getattr(lib, symbol)
            fn.restype = restype
            fn.argtypes = list(argtypes)
            _FUNCTIONS[key] = fn
    return _FUNCTIONS[key]


def _lib(dtype: torch.dtype):
    """The pixel kernel for ``dtype``, or ``None`` when native kernels are unavailable."""
    return native_function(_KERNELS_SRC, "bb_shade", dtype,
                           [ctypes.c_int64] * 10 + [ctypes.c_void_p] * 16, fallback="torch.compile kernels")


def pixel_blocks(P: int, dtype: torch.dtype) -> int:
    """How many pixel blocks the pixel-block kernels (the pixel kernel, the normal-maps kernel) split ``P`` pixels
    into: the length of their per-block energies and constant maps' partial gradients (``BLK`` of
    ``_native_pixel_block.h``, asked of the built kernel)."""
    blk = _BLK.get(dtype)
    if blk is None:
        blk = _BLK[dtype] = native_function(_KERNELS_SRC, "bb_pixel_block", dtype, [], restype=ctypes.c_int64)()
    return -(-P // blk)


_BLK: dict = {}


def _texel_lib(dtype: torch.dtype, lanes: int = 8):
    """The texel kernel for ``dtype`` with ``lanes`` particles per vector (8 or 16), or ``None`` when native
    kernels are unavailable."""
    return native_function(_TEXELS_SRC, "bb_shade_texels", dtype,
                           [ctypes.c_int64] * 12 + [ctypes.c_void_p] * 24 + [ctypes.c_int64, ctypes.c_double,
                                                                               ctypes.c_double], restype=ctypes.c_int,
                           extra_flags=() if lanes == 8 else (f"-DLANES={lanes}",), fallback="sparse torch lookups")


def _normal_maps_lib(dtype: torch.dtype):
    """The per-particle-normals loss kernel for ``dtype``, or ``None`` when native kernels are unavailable."""
    return native_function(_NORMAL_MAPS_SRC, "bb_shade_normal_maps", dtype,
                           [ctypes.c_int64] * 9 + [ctypes.c_double] + [ctypes.c_void_p] * 17,
                           fallback="eager torch shading")


def texel_lanes(dtype: torch.dtype, n: int) -> int:
    """Particles per vector for the texel kernel: 16 where the compiled kernel has 64-byte vectors (AVX-512) of
    float32 and 16 lanes take fewer passes over ``n`` particles than 8 (20 particles: 2 passes instead of 3),
    else 8 (also where an environment's roughness table is longer than the 32 entries the 16-lane lookup reads). The
    lanes are independent particles, so the results are the same either way."""
    lib = _texel_lib(dtype)
    if lib is None or dtype != torch.float32 or -(-n // 16) >= -(-n // 8) or transfer.NODES + 2 > 32:
        return 8
    width = native_function(_TEXELS_SRC, "bb_texel_vector_bytes", dtype, [], restype=ctypes.c_int64)
    return 16 if width is not None and width() >= 64 else 8


def available(t: Tensor, texels: bool = False, normal_maps: bool = False) -> bool:
    """Whether the native pixel kernel (``texels``: the texel kernel; ``normal_maps``: the per-particle-normals
    loss) can run on tensors like ``t`` (CPU, float32/float64, built OK)."""
    lib = _texel_lib if texels else _normal_maps_lib if normal_maps else _lib
    return t.device.type == "cpu" and lib(t.dtype) is not None


def ptr(t: Tensor | None):
    """A tensor's data as a C pointer argument (``None``: NULL), for the package's native functions."""
    return None if t is None else ctypes.c_void_p(t.data_ptr())


def _map_flags(maps, extent: int, no_grad) -> tuple[list, int]:
    """Which of the kernel maps ``(kd, r, ks)`` are constant (one value per particle: last dimension 1 while a full
    map has ``extent``) and the kernels' flags: bit k a constant map k, bit 3 + k map k's gradient not wanted."""
    const = [m.shape[-1] == 1 and extent > 1 for m in maps]
    return const, sum(1 << k for k, c in enumerate(const) if c) + sum(8 << k for k, f in enumerate(no_grad) if f)


def _block_grads(maps, const, no_grad, grad: bool, nb: int) -> list:
    """The pixel-block kernels' gradient outputs: shaped like the map, or for a constant map its per-block partial
    sums ``[n, c, nb]`` (:func:`_summed_blocks` adds them); ``None`` where not wanted."""
    return [None if f or not grad else torch.empty(*m.shape[:-1], nb, dtype=m.dtype) if c else torch.empty_like(m)
            for m, c, f in zip(maps, const, no_grad)]


def _summed_blocks(grads, const) -> list:
    return [g.sum(-1, keepdim=True) if g is not None and c else g for g, c in zip(grads, const)]


def _call(mode, maps, geo, ks_factor, *, y=None, wgt=None, gout=None, l2=False, need_grad=False, taps=None,
          no_grad=(False, False, False), env=None):
    """Run a kernel. ``maps = (kd [n,3,P], r [n,P], ks [n,3,P])``, ``geo = (nl, nv, nh2, w, A)``; with
    ``taps`` (:class:`~bayes_brdf.render.texels.Taps` of the ``P`` pixels) the maps are texel maps
    ``[n, 3, T]``, ``[n, T]`` (or one constant texel, ``[n, 3, 1]``) read bilinearly by the texel kernel, and
    ``no_grad`` names maps whose gradients are not wanted (returned as ``None``: neither kernel writes them). A
    ``1 x 1`` map is one value per particle (``[n, 3, 1]``, ``[n, 1]``) for both kernels (flagged).

    Returns ``(images [n, V, 3, P] or None, energies [n, blocks] or None, gradients shaped like the maps)``;
    ``MODE_PIXEL_LOSS`` (the pixel kernel only) returns the per-pixel losses ``[n, 3, P]`` in place of images."""
    kd, r, ks = maps
    nl, nv, nh2, w, amp = geo
    n = r.shape[0]
    V, L, P = nl.shape
    dt = kd.dtype
    grad = mode == MODE_IMAGE_BWD or need_grad
    out = torch.empty(n, V, 3, P, dtype=dt) if mode == MODE_IMAGE_FWD else \
        torch.empty(n, 3, P, dtype=dt) if mode == MODE_PIXEL_LOSS else None
    nt = torch.get_num_threads()
    extent = P if taps is None else max(m.shape[-1] for m in maps)      # values per channel of a full map
    const, flags = _map_flags(maps, extent, no_grad)
    if taps is None:
        nb = pixel_blocks(P, dt)
        epart = torch.empty(n, nb, dtype=torch.float64) if mode == MODE_LOSS else None
        grads = _block_grads(maps, const, no_grad, grad, nb)
        _lib(dt)(mode, n, V, L, P, int(ks_factor), int(l2), int(need_grad), nt, flags,
                 *map(ptr, (kd, r, ks, nl, nv, nh2, w, amp, y, wgt, gout, out, epart, *grads)))
        return out, epart, _summed_blocks(grads, const)
    if mode == MODE_PIXEL_LOSS:
        raise ValueError("per-pixel losses are computed by the pixel kernel only (no taps)")
    T = extent
    plan = taps.plan
    epart = torch.empty(n, plan.nchunk, dtype=torch.float64) if mode == MODE_LOSS else None
    grads = [None if f or not grad else torch.empty_like(m) for m, f in zip(maps, no_grad)]
    lanes = texel_lanes(dt, n)
    env = env_layout(env, value_major=lanes == 16)
    status = _texel_lib(dt, lanes)(mode, n, V, L, P, int(ks_factor), int(l2), int(need_grad), nt, T, flags, plan.nchunk,
                            *map(ptr, (taps.idx, taps.w, plan.cstart, plan.uoff, plan.lidx, plan.rptr, plan.rsrc,
                                        kd, r, ks, nl, nv, nh2, w, amp, y, wgt, gout, out, epart, *grads, env)),
                            transfer.NODES, transfer.T0, transfer.DT)
    if status:
        raise MemoryError(f"the native texel kernel could not allocate its scratch memory ({n} particles, "
                          f"{T} texels, {P} pixels)")
    return out, epart, grads


def _flat(t: Tensor, n: int, c: int) -> Tensor:
    """A looked-up map ``[n', 1, c, H, W]`` (or ``[n', 1, c, 1, 1]``) as contiguous ``[n, c, P]``."""
    return t[:, 0].expand(n, c, *t.shape[-2:]).reshape(n, c, -1).contiguous()


_GEO: OrderedDict = OrderedDict()  # prepared geometry, by the identity of the (cached) cosine tensors


def _geometry(nl, nv, nh, vh, scale):
    """Particle-independent kernel inputs ``(n.l, n.v, (n.h)^2, w, A = scale * n.l)``, reused while the inputs are."""
    from .brdf import fresnel_weight

    key = tuple(id(t) for t in (nl, nv, nh, vh, scale))
    hit = _GEO.get(key)
    if hit is not None and all(a is b for a, b in zip(hit[0], (nl, nv, nh, vh, scale))):
        return hit[1]
    V, L = nl.shape[1:3]
    P = nv.shape[-2] * nv.shape[-1]          # explicit: a view lit by an environment alone has no point light (L = 0)
    geo = (nl.reshape(V, L, P).contiguous(), nv.reshape(V, P).contiguous(), (nh * nh).reshape(V, L, P).contiguous(),
           fresnel_weight(vh).reshape(V, L, P).contiguous(), (scale * nl).reshape(V, L, 3, P).contiguous())
    _GEO[key] = ((nl, nv, nh, vh, scale), geo)
    while len(_GEO) > 16:
        _GEO.popitem(last=False)
    return geo


def prepare(kd, r, ks, nl, nv, nh, vh, scale, hw, texels=None):
    """Kernel inputs from the shading tensors (see :mod:`.fused` for their shapes); with ``texels = (Ht, Wt)``
    the maps are texel maps of that size (or ``1 x 1``), read through taps."""
    n = max(kd.shape[0], r.shape[0], ks.shape[0])
    return n, kernel_maps(kd, r, ks, n, texels or hw), _geometry(nl, nv, nh, vh, scale)


def kernel_maps(kd, r, ks, n: int, hw) -> tuple:
    """Looked-up maps ``[n', 1, c, H, W]`` (``H x W = hw``, or ``1 x 1``) in the kernels' layout: ``kd, ks
    [n, 3, P]``, ``r [n, P]``; a ``1 x 1`` constant stays one value, ``[n, 3, 1]``, ``[n, 1]`` (the kernels flag it)."""
    full = lambda t, c: t if tuple(t.shape[-2:]) == (1, 1) else t.expand(t.shape[0], 1, c, *hw)  # noqa: E731
    return _flat(full(kd, 3), n, 3), _flat(full(r, 1), n, 1)[:, 0], _flat(full(ks, 3), n, 3)


_ENV: OrderedDict = OrderedDict()


def env_layout(env: Tensor | None, value_major: bool = False) -> Tensor | None:
    """An environment's terms ``[1, V, C, 1, P]`` in the texel kernel's layout (kept while the same tensor comes
    again): ``[V, P, C + 2]``, its roughness slots one after another (rows padded by two zeros, so that a slot's
    6 values load as one vector); or, ``value_major`` (the 16-lane kernel), ``E`` then each of the 6 values'
    ``NODES + 2`` slots in a row, padded by 14 zeros (32 entries from a value's first slot are in bounds: the
    kernel reads a value's slots as one 32-entry table)."""
    if env is None:
        return None
    hit = _ENV.get((id(env), value_major))
    if hit is not None and hit[0] is env:
        return hit[1]
    src = env[0, :, :, 0, :].transpose(1, 2)                       # [V, P, C]
    if value_major:
        V, P, _ = src.shape
        slots = transfer.NODES + 2
        out = torch.zeros(V, P, 3 + 6 * slots + 14, dtype=src.dtype)
        out[..., :3] = src[..., :3]
        out[..., 3:3 + 6 * slots] = src[..., 3:].reshape(V, P, slots, 6).transpose(2, 3).reshape(V, P, 6 * slots)
    else:
        out = torch.zeros(*src.shape[:2], src.shape[2] + 2, dtype=src.dtype)   # rows padded: a slot's vector load
        out[..., :src.shape[2]] = src
    _ENV[(id(env), value_major)] = (env, out)
    while len(_ENV) > 8:
        _ENV.popitem(last=False)
    return out


def texel_maps(t: Tensor) -> Tensor:
    """A texel map ``[n, C, Ht, Wt]`` (or ``[C, Ht, Wt]``) in the kernels' map layout ``[n, 1, C, Ht, Wt]``."""
    return (t[None] if t.dim() == 3 else t)[:, None]


class NativeShade(torch.autograd.Function):
    """Images ``[n, V, 3, H, W]`` with analytic gradients w.r.t. ``kd, r, ks``."""

    @staticmethod
    def forward(ctx, kd, r, ks, nl, nv, nh, vh, scale, ks_factor, taps=None, env=None):
        hw = nl.shape[-2:]
        n, maps, geo = prepare(kd, r, ks, nl, nv, nh, vh, scale, hw, None if taps is None else taps.grid)
        out, _, _ = _call(MODE_IMAGE_FWD, maps, geo, ks_factor, taps=taps, env=env)
        ctx.save_for_backward(*maps, *geo)
        ctx.meta = (ks_factor, taps, kd.shape, r.shape, ks.shape, env)
        return out.reshape(n, geo[0].shape[0], 3, *hw)

    @staticmethod
    def backward(ctx, gout):
        ks_factor, tp, *shapes, ev = ctx.meta
        saved = ctx.saved_tensors
        n = saved[1].shape[0]
        g = gout.reshape(n, gout.shape[1], 3, -1).contiguous()
        _, _, grads = _call(MODE_IMAGE_BWD, saved[:3], saved[3:], ks_factor, gout=g, taps=tp,
                            no_grad=tuple(not f for f in ctx.needs_input_grad[:3]), env=ev)
        return (*_unflat(grads, shapes), None, None, None, None, None, None, None, None)


class NativeLoss(torch.autograd.Function):
    """Per-particle loss ``[n]``; the gradient is computed in the same pass as the loss."""

    @staticmethod
    def forward(ctx, kd, r, ks, nl, nv, nh, vh, scale, y, wgt, ks_factor, l1, taps=None, env=None):
        hw = nl.shape[-2:]
        n, maps, geo = prepare(kd, r, ks, nl, nv, nh, vh, scale, hw, None if taps is None else taps.grid)
        need = any(ctx.needs_input_grad[:3])
        yy = y.reshape(y.shape[0], 3, -1).contiguous()
        ww = wgt.expand(y.shape[0], 1, *hw).reshape(y.shape[0], -1).contiguous()
        _, epart, grads = _call(MODE_LOSS, maps, geo, ks_factor, y=yy, wgt=ww, l2=not l1, need_grad=need,
                                taps=taps, no_grad=tuple(not f for f in ctx.needs_input_grad[:3]), env=env)
        if need:
            ctx.save_for_backward(*grads)
        ctx.shapes = (kd.shape, r.shape, ks.shape)
        return epart.sum(1).to(kd.dtype)

    @staticmethod
    def backward(ctx, ge):
        grads = [g if want else None for g, want in zip(ctx.saved_tensors, ctx.needs_input_grad[:3])]
        if not bool((ge == 1).all()):  # loss.sum().backward() passes ones: nothing to scale
            ge = ge.to(next(g.dtype for g in grads if g is not None))
            grads = [None if g is None else g * ge.reshape(-1, *([1] * (g.dim() - 1))) for g in grads]
        return (*_unflat(grads, ctx.shapes), *(None,) * 11)


_NORMAL_GEO = TensorMemo(8)


def normal_map_geometry(tangent, bitangent, normal, view_dir, light_dir, light_scale, eps: float):
    """The particle-independent inputs of :class:`NativeNormalMapLoss` from a G-buffer's ``[V, 3, H, W]`` frame and
    view directions and ``[V, L, 3, H, W]`` light directions and scales, kept while the same tensors come again:
    ``(frame [V, 9, P], v [V, 3, P], l [V, L, 3, P], h [V, L, 3, P], w(v.h) [V, L, P], scale [V, L, 3, P])``, ``h``
    and ``v.h`` as :func:`~bayes_brdf.render.shade.geometry_terms` makes them."""
    from .brdf import fresnel_weight
    from .maps import unit_vectors

    def make():
        V, L = light_dir.shape[:2]
        P = view_dir.shape[-2] * view_dir.shape[-1]
        frame = torch.cat([tangent.expand_as(view_dir), bitangent.expand_as(view_dir), normal.expand_as(view_dir)],
                          1).reshape(V, 9, P).contiguous()
        vd = view_dir.reshape(V, 3, P).contiguous()
        ld = light_dir.reshape(V, L, 3, P).contiguous()
        hd = unit_vectors(ld + vd[:, None], 2, floor=1e-15).contiguous()
        w = fresnel_weight((vd[:, None] * hd).sum(2).clamp_min(eps)).contiguous()
        return frame, vd, ld, hd, w, light_scale.reshape(V, L, 3, P).contiguous()
    return _NORMAL_GEO.get((tangent, bitangent, normal, view_dir, light_dir, light_scale), (eps,), make)


class NativeNormalMapLoss(torch.autograd.Function):
    """Per-particle loss ``[n]`` of views whose pixels are the texels, each particle with its own normal map
    (``kd, ks [n', 3, H, W]``, ``r [n', 1, H, W]``, ``normal [n', 3, H, W]``, each also ``[C, H, W]`` or ``1 x 1``
    for ``kd, r, ks``); ``geo`` from :func:`normal_map_geometry`; ``y [V, 3, H, W]``, ``wgt [V, 1, H, W]``. The
    gradients w.r.t. the maps and the normals are computed in the same pass as the loss."""

    @staticmethod
    def forward(ctx, kd, r, ks, normal, geo, y, wgt, ks_factor, l1, eps):
        frame, vd, ld, hd, w, scale = geo
        V, L, _, P = ld.shape
        hw = y.shape[-2:]
        looked = [texel_maps(t) for t in (kd, r, ks, normal)]          # [n', 1, c, H, W]: the kernels' input shape
        n = max(t.shape[0] for t in looked)
        maps = kernel_maps(*looked[:3], n, hw)
        nt = _flat(looked[3], n, 3)
        want = ctx.needs_input_grad[:4]
        grad = any(want)
        no_grad = [not f for f in want[:3]]
        const, flags = _map_flags(maps, P, no_grad)
        flags += 0 if want[3] else 64
        nb = pixel_blocks(P, nt.dtype)
        dt = nt.dtype
        epart = torch.empty(n, nb, dtype=torch.float64)
        grads = _block_grads(maps, const, no_grad, grad, nb)
        gn = torch.empty_like(nt) if grad and want[3] else None
        yy = y.reshape(V, 3, P).contiguous()
        ww = wgt.expand(V, 1, *hw).reshape(V, P).contiguous()
        _normal_maps_lib(dt)(n, V, L, P, int(ks_factor), int(not l1), int(grad), torch.get_num_threads(), flags,
                             float(eps), *map(ptr, (*maps, nt, frame, vd, ld, hd, w, scale, yy, ww, epart, *grads, gn)))
        if grad:       # per particle [n, c, H, W] (or [n, c, 1, 1]): scaled by the upstream gradient, then summed
            grads = _summed_blocks(grads, const)
            sizes = [(1, 1) if tuple(s.shape[-2:]) == (1, 1) else tuple(hw) for s in (kd, r, ks, normal)]
            ctx.save_for_backward(*(None if g is None else g.reshape(n, -1, *z) for g, z in zip((*grads, gn), sizes)))
        ctx.shapes = (kd.shape, r.shape, ks.shape, normal.shape)
        return epart.sum(1).to(dt)

    @staticmethod
    def backward(ctx, ge):
        scale = None if bool((ge == 1).all()) else ge.reshape(-1, 1, 1, 1)   # sum().backward() passes ones
        out = []
        for g, want, shape in zip(ctx.saved_tensors, ctx.needs_input_grad[:4], ctx.shapes):
            if g is None or not want:
                out.append(None)
                continue
            out.append((g if scale is None else g * scale.to(g.dtype)).sum_to_size(shape))
        return (*out, *(None,) * 6)


def pixel_losses(kd, r, ks, nl, nv, nh, vh, scale, y, wgt, ks_factor, l1) -> Tensor:
    """``[n, 3, H, W]``: per pixel and channel, ``sum_v wgt |R - y|`` (``l1``) or ``sum_v wgt (R - y)^2`` over the
    views (shapes as :class:`NativeLoss`; no gradient): the losses :class:`NativeLoss` sums, kept per pixel."""
    hw = nl.shape[-2:]
    n, maps, geo = prepare(kd, r, ks, nl, nv, nh, vh, scale, hw)
    yy = y.reshape(y.shape[0], 3, -1).contiguous()
    ww = wgt.expand(y.shape[0], 1, *hw).reshape(y.shape[0], -1).contiguous()
    with torch.no_grad():
        out, _, _ = _call(MODE_PIXEL_LOSS, maps, geo, ks_factor, y=yy, wgt=ww, l2=not l1)
    return out.reshape(n, 3, *hw)


def _unflat(grads, shapes):
    """Kernel gradients ``[n, c, P]`` back to the looked-up maps' shapes (summing broadcast dimensions)."""
    n = next(g.shape[0] for g in grads if g is not None)
    out = []
    for g, s, c in zip(grads, shapes, (3, 1, 3)):
        if g is None:
            out.append(None)
            continue
        full = g.reshape(n, 1, c, -1)
        if tuple(s[-2:]) == (1, 1):
            full = full.sum(-1, keepdim=True)[..., None]
        else:
            full = full.reshape(n, 1, c, *s[-2:])
        out.append(full.sum_to_size(s))
    return out
