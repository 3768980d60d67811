"""Wall time and peak memory of ``bayes-brdf fit`` on a real capture, with defaults, as a user runs it.

Usage:
    python benchmarks/bench_fit.py                       # the three rows of issue 26 (about 6 minutes on 2 cores)
    python benchmarks/bench_fit.py --rows 128 256        # some of them: 128, 256, latent64
    python benchmarks/bench_fit.py --capture ../shared/data/captures/bath_tile

Each row runs ``bayes-brdf fit CAPTURE --views 0,2,4,6,8 --resolution R [--model latent_decoder]`` in its own
process (a fresh interpreter: imports, loading and resampling the photos, the G-buffer, sampling, the MAP
refinement, the held-out evaluation and the report all count) into a temporary folder, and prints:
the resolution, the model, the steps the run took, the wall seconds of the command, the seconds of the fit itself (from its
summary.json: sampling, noise estimate and MAP refinement), the peak resident memory of the process (``wait4``'s ``ru_maxrss``), and the held-out
coverage, so that a faster fit is seen to give the same answer. The header gives the torch threads and the
load average: on a shared machine compare rows of one run.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data" / "captures"
ROWS = {"128": (128, "per_texel"), "256": (256, "per_texel"), "latent64": (64, "latent_decoder")}


def run_fit(capture: Path, resolution: int, model: str, out: Path, extra=()) -> dict:
    cmd = [sys.executable, "-m", "bayes_brdf.cli.main", "fit", str(capture), "--views", "0,2,4,6,8",
           "--resolution", str(resolution), "--model", model, "--out", str(out), *extra]
    t = time.perf_counter()
    p = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    _, status, usage = os.wait4(p.pid, 0)
    wall = time.perf_counter() - t
    out_text, err_text = p.stdout.read(), p.stderr.read()
    if os.waitstatus_to_exitcode(status) != 0:
        sys.exit(f"fit failed ({' '.join(cmd)}):\n{err_text[-2000:]}")
    s = json.loads((out / "summary.json").read_text())
    h = s["heldout"]
    return {"wall": wall, "rss_gb": usage.ru_maxrss / 1e6, "sampling": (s.get("seconds") or {}).get("fit"), "steps": (s.get("diagnostics") or {}).get("steps"),
            "cov50": h["coverage"]["50"], "cov90": h["coverage"]["90"], "spearman": h["spearman"],
            "converged": (s.get("diagnostics") or {}).get("converged"), "line": out_text.strip().splitlines()[-1:]}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--capture", type=Path, default=SHARED / "card_blue")
    ap.add_argument("--rows", nargs="+", default=list(ROWS), choices=list(ROWS))
    ap.add_argument("--extra", default="", help="more fit options for every row, e.g. \"--steps auto\"")
    a = ap.parse_args(argv)
    import torch

    print(f"# bayes-brdf fit {a.capture.name} --views 0,2,4,6,8, defaults{' ' + a.extra if a.extra else ''}; "
          f"torch {torch.__version__}, {torch.get_num_threads()} threads, {os.cpu_count()} CPUs, "
          f"load average {', '.join(f'{x:.1f}' for x in os.getloadavg())}")
    print("\n| resolution | model | steps | wall s | fit s | peak RSS GB | held-out 50 % / 90 % | Spearman | converged |")
    print("|---|---|---|---|---|---|---|---|---|")
    for row in a.rows:
        res, model = ROWS[row]
        with tempfile.TemporaryDirectory(prefix="bench_fit_") as tmp:
            r = run_fit(a.capture, res, model, Path(tmp) / "fit", a.extra.split())
        samp = f"{r['sampling']:.1f}" if r["sampling"] is not None else "-"
        print(f"| {res}² | {model} | {r['steps']} | {r['wall']:.1f} | {samp} | {r['rss_gb']:.2f} | "
              f"{r['cov50']:.2f} / {r['cov90']:.2f} | {r['spearman']:.2f} | {r['converged']} |", flush=True)


if __name__ == "__main__":
    main()
