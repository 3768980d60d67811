"""Shared pytest fixtures and backend markers (keep this small and generic).

Backends are markers, as in Mitsuba's own test suite: a test (or a module's ``pytestmark``, or a
``pytest.param``) marked

* ``needs_llvm`` -- runs where Mitsuba's CPU variant ``llvm_ad_rgb`` can (libLLVM 19 is installed);
* ``needs_native`` -- runs where the native C kernels build (``needs_native(kernel="texels")``: the texel
  kernel, ``kernel="entropy"``: the KDE entropy's; see :func:`bayes_brdf.render.native.available`);
* ``needs_cuda`` -- runs where torch sees a CUDA device;

and is skipped elsewhere with a reason that says what to install (``pytest -m needs_cuda`` selects them).
"""
from __future__ import annotations

import functools
from pathlib import Path

import pytest

SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


@functools.cache
def _llvm() -> bool:
    from bayes_brdf.mitsuba_env import find_llvm19
    return find_llvm19() is not None


@functools.cache
def _native(kernel: str = "pixels") -> bool:
    """Whether the native ``kernel`` builds: ``"pixels"`` (the plane's), ``"texels"`` or ``"entropy"``."""
    import torch

    if kernel == "entropy":
        from bayes_brdf.guidance import entropy
        return all(entropy._lib(dt) is not None for dt in (torch.float32, torch.float64))
    from bayes_brdf.render import native
    return native.available(torch.ones(1), texels=kernel == "texels")


@functools.cache
def _cuda() -> bool:
    import torch
    return torch.cuda.is_available()


#: marker -> (is the backend here (given the marker's kwargs), what it needs, how to get it)
BACKENDS = {
    "needs_llvm": (_llvm, "libLLVM 19 for Mitsuba's CPU variant llvm_ad_rgb",
                   "install the system package libllvm19 (scripts/setup.sh does, as root)"),
    "needs_native": (_native, "the native C kernels (bayes_brdf.render.native)",
                     "install a C compiler (cc or gcc, e.g. the system package build-essential) and leave "
                     "BAYES_BRDF_NO_NATIVE unset"),
    "needs_cuda": (_cuda, "a CUDA device", "run on a machine with a GPU and a CUDA build of torch"),
}


def pytest_configure(config):
    for name, (_, what, _) in BACKENDS.items():
        config.addinivalue_line("markers", f"{name}: needs {what}; skipped without it")


def pytest_runtest_setup(item):
    for name, (available, what, how) in BACKENDS.items():
        marker = item.get_closest_marker(name)
        if marker is not None and not available(**marker.kwargs):
            pytest.skip(f"needs {what}: {how}")


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """``../shared/data`` beside the repository (real captures, peer data); skips the test when absent."""
    if not SHARED_DATA.is_dir():
        pytest.skip("../shared/data not found: real captures live beside the repo, see README")
    return SHARED_DATA


@pytest.fixture
def one_thread():
    """torch on one thread for the test (restored after): the environment transfer's many small torch
    operations slow down about 17x when two busy-waiting OpenMP threads share the 2 cores with another job."""
    import torch

    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


@pytest.fixture(scope="session")
def ray_local():
    """A local Ray of 2 CPUs, started once per test session (shut down at its end); skips without Ray.
    :class:`~bayes_brdf.executor.RayExecutor` uses it as it is (and leaves it running)."""
    ray = pytest.importorskip("ray", reason="Ray is not installed: pip install 'bayes-brdf[ray]'")
    started = not ray.is_initialized()
    if started:
        ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, configure_logging=False)
    yield ray
    if started:
        ray.shutdown()
