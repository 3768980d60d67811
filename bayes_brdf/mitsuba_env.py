"""Mitsuba 3 for the project: the one place that imports it and picks its variant.

Mesh G-buffers are ray cast by Mitsuba (:mod:`bayes_brdf.render.raycast`). The
variant is ``cuda_ad_rgb`` when torch sees a GPU and Mitsuba has it, else
``llvm_ad_rgb`` (CPU); ``BAYES_BRDF_MITSUBA_VARIANT`` overrides. Mitsuba's
variant is process-global, so the project never leaves its choice behind for a
user who also uses Mitsuba: :func:`mitsuba_variant` switches for the duration of
a block and restores the user's variant after it (when no variant was set
before, Mitsuba cannot unset one: the project's stays, and a user's later
``mi.set_variant`` replaces it as usual).

Mitsuba's ``llvm_*`` variants JIT-compile through libLLVM; with the LLVM 15
that some systems ship they abort the process on the first render, so we point
Dr.Jit at LLVM 19 (``DRJIT_LIBLLVM_PATH``) before Mitsuba is imported, unless
the user already set it. ``scripts/setup.sh`` installs the system package
``libllvm19`` when it is missing.
"""
from __future__ import annotations

import contextlib
import glob
import os

from .errors import InputError

LLVM_CANDIDATES = ("/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1", "/usr/lib/x86_64-linux-gnu/libLLVM-19.so",
                   "/usr/lib/llvm-19/lib/libLLVM.so.19.1", "/usr/lib/aarch64-linux-gnu/libLLVM.so.19.1")


def find_llvm19() -> str | None:
    """Path of a libLLVM 19 shared library, or ``None``."""
    for p in LLVM_CANDIDATES:
        if os.path.exists(p):
            return p
    hits = sorted(glob.glob("/usr/lib/*/libLLVM*.so.19*") + glob.glob("/usr/lib/llvm-19/lib/libLLVM*.so*"))
    return hits[0] if hits else None


def import_mitsuba(variant: str = "llvm_ad_rgb"):
    """Import Mitsuba with ``variant`` set (``DRJIT_LIBLLVM_PATH`` filled in for ``llvm_*`` variants).

    Example:
        >>> mi = import_mitsuba("scalar_rgb")   # doctest: +SKIP
        >>> mi.variant()                        # doctest: +SKIP
        'scalar_rgb'
    """
    if variant.startswith("llvm") and not os.environ.get("DRJIT_LIBLLVM_PATH"):
        path = find_llvm19()
        if path is None:
            raise InputError(f"Mitsuba variant {variant} needs libLLVM 19, which is not installed",
                             fix="run scripts/setup.sh (apt-get install libllvm19) or use variant scalar_rgb")
        os.environ["DRJIT_LIBLLVM_PATH"] = path
    try:
        import mitsuba as mi
    except ImportError:
        raise InputError("Mitsuba is not installed", fix="pip install 'bayes-brdf[mitsuba]' or run make test") from None
    try:
        mi.set_variant(variant)
    except Exception as e:  # noqa: BLE001  (unknown name, no CUDA driver for cuda_*, ...)
        raise InputError(f"Mitsuba variant {variant} is unavailable ({str(e).strip()[:120]})",
                         fix="set BAYES_BRDF_MITSUBA_VARIANT=llvm_ad_rgb") from None
    return mi


def default_variant() -> str:
    """``BAYES_BRDF_MITSUBA_VARIANT``, else ``cuda_ad_rgb`` with a CUDA device, else ``llvm_ad_rgb``."""
    env = os.environ.get("BAYES_BRDF_MITSUBA_VARIANT")
    if env:
        return env
    import torch
    return "cuda_ad_rgb" if torch.cuda.is_available() else "llvm_ad_rgb"


@contextlib.contextmanager
def mitsuba_variant(variant: str | None = None):
    """``with mitsuba_variant() as mi:`` -- Mitsuba with ``variant`` (default :func:`default_variant`) active
    inside the block; the caller's own variant is active again after it.

    Example:
        >>> with mitsuba_variant("scalar_rgb") as mi:   # doctest: +SKIP
        ...     mi.variant()
        'scalar_rgb'
    """
    variant = variant or default_variant()
    before = _current_variant()
    mi = import_mitsuba(variant) if before != variant else _module()
    try:
        yield mi
    finally:
        if before is not None and before != variant:
            mi.set_variant(before)


def _module():
    import mitsuba as mi
    return mi


def _current_variant() -> str | None:
    try:
        import mitsuba as mi
    except ImportError:
        return None
    return mi.variant()
