"""Keep freed memory in the process: large tensors are reused instead of returned to the OS and faulted in again.

A sampler step allocates and frees the same few tensors of megabytes thousands of times. With glibc's defaults
each such block is an ``mmap`` returned by ``munmap`` (or trimmed off the heap's top) when freed, so the next
step's allocation starts with fresh pages: a page fault per 4 KiB, measured at about 6 GB/s on the 2-core
CI-class machine against ~40 GB/s for the same op on warm memory. :func:`keep_freed_memory` raises glibc's
mmap threshold to its 32 MiB maximum and turns heap trimming off (``mallopt``), once per process; the
sampling driver and the command line call it. It changes no number, only where memory comes from; the
process's resident size then stays at its peak (which is what peak RSS reports anyway).

Measured (``benchmarks/bench_samplers.py --cases 128x20``, docs/performance.md): the energy-and-gradient
call 18.1 -> 14.8 ms before the native bijection, the SPOS step 32.0 -> 26.8 ms.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import os
import sys

_DONE = [False]
M_TRIM_THRESHOLD, M_MMAP_THRESHOLD = -1, -3
MMAP_THRESHOLD_MAX = 32 * 1024 * 1024     # glibc's upper limit on 64-bit (DEFAULT_MMAP_THRESHOLD_MAX)


def keep_freed_memory() -> bool:
    """Raise glibc's mmap threshold and stop heap trimming in this process (once); ``False`` where there is no
    glibc ``mallopt`` (macOS, musl, Windows) or ``BAYES_BRDF_KEEP_MEMORY=0``."""
    if _DONE[0]:
        return True
    if os.environ.get("BAYES_BRDF_KEEP_MEMORY", "1") == "0" or not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    ok = mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD_MAX) == 1 and mallopt(M_TRIM_THRESHOLD, 2**31 - 1) == 1
    _DONE[0] = ok
    return ok
