"""``benchmarks/gpu_check.py`` works: every check CPU against CPU (``--device cpu --quick``), so the script
cannot rot while no GPU runs it (docs/performance.md, "The CUDA path"); a check that raises or disagrees is a
failing row, not a crash; without a GPU ``--device cuda`` says so and exits 2."""
import importlib.util
import sys
from pathlib import Path

import pytest
import torch

SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "gpu_check.py"

# the mesh G-buffer check ray casts with Mitsuba's llvm_ad_rgb; the CPU reference is the native C kernels
pytestmark = [pytest.mark.needs_llvm, pytest.mark.needs_native]


@pytest.fixture(scope="module")
def gpu_check():
    spec = importlib.util.spec_from_file_location("gpu_check", SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    sys.modules["gpu_check"] = mod                   # dataclasses look their module up there
    try:
        spec.loader.exec_module(mod)
        yield mod
    finally:
        sys.modules.pop("gpu_check", None)


def test_every_check_passes_cpu_against_cpu(gpu_check, capsys):
    names = [c.name for c in gpu_check.checks(gpu_check.sizes(True), "cpu", "cuda_ad_rgb")]
    assert gpu_check.main(["--device", "cpu", "--quick"]) == 0
    out = capsys.readouterr().out
    rows = [line for line in out.splitlines() if line.startswith("| ") and not line.startswith("| check ")]
    assert [r.split(" | ")[0][2:] for r in rows] == names
    assert all(" | PASS | " in r for r in rows), out
    assert f"# {len(names)} of {len(names)} checks passed" in out


def test_a_check_that_raises_or_disagrees_is_a_failing_row(gpu_check):
    def boom(device, dtype):
        raise RuntimeError("no kernel\nfor this")

    row = gpu_check.run_check(gpu_check.Check("boom", boom, gpu_check.Tol(1e-3, 1e-4)), "cpu", 1)
    assert not row.ok and row.note.startswith("CPU: RuntimeError: no kernel for this [")

    def off(device, dtype):                          # float32 off by 1 % of the float64 reference
        x = torch.linspace(1, 2, 5, dtype=torch.float64)
        return lambda: {"x": x if dtype == torch.float64 else (x * 1.01).to(dtype)}

    row = gpu_check.run_check(gpu_check.Check("off", off, gpu_check.Tol(1e-3, 1e-4)), "cpu", 1)
    assert not row.ok and row.max_abs == pytest.approx(0.02, rel=1e-5) and "x (" in row.note
    row = gpu_check.run_check(gpu_check.Check("off", off, gpu_check.Tol(2e-2, 0.0)), "cpu", 1)
    assert row.ok


@pytest.mark.skipif(torch.cuda.is_available(), reason="a CUDA device is here")
def test_without_cuda_it_says_so_and_exits_2(gpu_check, capsys):
    assert gpu_check.main(["--device", "cuda"]) == 2
    assert "no CUDA device here" in capsys.readouterr().out
