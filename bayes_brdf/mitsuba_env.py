"""Importing Mitsuba 3 with the right LLVM for its CPU variants.

Mitsuba's ``llvm_*`` variants JIT-compile through libLLVM; with the LLVM 15
that some systems ship they abort the process on the first render, so we point
Dr.Jit at LLVM 19 (``DRJIT_LIBLLVM_PATH``) before Mitsuba is imported, unless
the user already set it. ``scripts/setup.sh`` installs the system package
``libllvm19`` when it is missing.
"""
from __future__ import annotations

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
    mi.set_variant(variant)
    return mi
