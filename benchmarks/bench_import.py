"""Start-up time: ``import bayes_brdf``, ``bayes-brdf --help`` and every command's ``--help`` (lazy imports:
none of them may load torch), against importing the full library.

    .venv/bin/python benchmarks/bench_import.py [--repeat 5]

Prints the best of ``--repeat`` wall times per row, each in a fresh process.
"""
from __future__ import annotations

import argparse
import subprocess
import sys
import time

COMMANDS = ["render", "inspect", "infer", "fit", "recommend", "demo", "compare", "experiment"]


def best(argv, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        subprocess.run(argv, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        times.append(time.perf_counter() - t)
    return min(times)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=5)
    a = ap.parse_args()
    py = sys.executable
    rows = [("python -c pass (interpreter alone)", [py, "-c", "pass"]),
            ("import bayes_brdf", [py, "-c", "import bayes_brdf"]),
            ("import bayes_brdf.cli.main (exit 1 if it loaded torch)", [py, "-c", "import sys, bayes_brdf.cli.main; "
                                                        "sys.exit('torch' in sys.modules)"]),
            ("bayes-brdf --help", [py, "-m", "bayes_brdf", "--help"])]
    rows += [(f"bayes-brdf {c} --help", [py, "-m", "bayes_brdf", c, "--help"]) for c in COMMANDS]
    rows += [("import bayes_brdf.inference (torch, Pyro)", [py, "-c", "import bayes_brdf.inference"])]
    print(f"| what | best of {a.repeat} (s) |\n|---|---|")
    for label, argv in rows:
        print(f"| {label} | {best(argv, a.repeat):.3f} |", flush=True)


if __name__ == "__main__":
    main()
