"""The next view while the user holds the camera: ``recommend --from`` against a cold ``recommend``, per seed.

Usage:
    python benchmarks/bench_recommend_from.py                 # card_blue, 64^2, views 0,2,4,6,8 then + the pick, seeds 0-4
    python benchmarks/bench_recommend_from.py --capture ../shared/data/captures/bath_tile --seeds 0 1 2

For each seed: ``bayes-brdf recommend CAPTURE --views 0,2,4,6,8 --resolution 64 --seed S`` (what the user had),
then the user "takes" the recommended view P, and the next recommendation is asked twice on views
0,2,4,6,8,P: warm (``--from`` the first run) and cold (a full default fit). Each is its own process, timed from
the command to its answer (imports, loading, the G-buffer, sampling, scoring, writing: what the user waits for).
Printed per seed: P, the warm and the cold command's wall seconds, their recommended views and whether the
first pick agrees, and the mutual-information ranking of the remaining held-out views by both.
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


def recommend(capture, views, out, seed, res, extra=()) -> tuple[dict, float]:
    cmd = [sys.executable, "-m", "bayes_brdf.cli.main", "recommend", str(capture), "--views",
           ",".join(map(str, views)), "--resolution", str(res), "--seed", str(seed), "--k", "1", "--out", str(out),
           *extra]
    t = time.perf_counter()
    p = subprocess.run(cmd, capture_output=True, text=True)
    wall = time.perf_counter() - t
    if p.returncode != 0:
        sys.exit(f"failed: {' '.join(cmd)}\n{p.stderr[-2000:]}")
    return json.loads((Path(out) / "recommend.json").read_text()), wall


def ranking(r: dict) -> list:
    return [c["candidate"] for c in sorted(r["all"], key=lambda c: -c["mi"])]


def gap(r: dict) -> float:
    """How near a tie the first pick is: (MI of the first - MI of the second) / |MI of the first|."""
    mi = sorted((c["mi"] for c in r["all"]), reverse=True)
    return (mi[0] - mi[1]) / abs(mi[0]) if len(mi) > 1 else float("nan")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--capture", type=Path, default=SHARED / "card_blue")
    ap.add_argument("--resolution", type=int, default=64)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    ap.add_argument("--cold-steps", default=None,
                    help="the cold run's --steps (default: the preset's choice, auto; 2000: a full fixed run)")
    a = ap.parse_args(argv)
    first_views = [0, 2, 4, 6, 8]
    print(f"# recommend --from vs cold (steps {a.cold_steps or 'default'}) on {a.capture.name} at {a.resolution}^2; "
          f"load average "
          f"{', '.join(f'{x:.1f}' for x in os.getloadavg())}, {os.cpu_count()} CPUs")
    print("\n| seed | photo taken | warm s | cold s | warm pick | cold pick | same | warm MI gap | warm ranking | "
          "cold ranking |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    same, warm_s = 0, []
    with tempfile.TemporaryDirectory(prefix="rec_from_") as tmp:
        for s in a.seeds:
            first, _ = recommend(a.capture, first_views, Path(tmp) / f"first{s}", s, a.resolution)
            taken = first["recommended"][0]
            views = first_views + [taken]
            warm, tw = recommend(a.capture, views, Path(tmp) / f"warm{s}", s, a.resolution,
                                 ["--from", str(Path(tmp) / f"first{s}")])
            cold, tc = recommend(a.capture, views, Path(tmp) / f"cold{s}", s, a.resolution,
                                 ["--steps", a.cold_steps] if a.cold_steps else [])
            ok = warm["recommended"][0] == cold["recommended"][0]
            same += ok
            warm_s.append(tw)
            print(f"| {s} | {taken} | {tw:.1f} | {tc:.1f} | {warm['recommended'][0]} | {cold['recommended'][0]} | "
                  f"{'yes' if ok else 'no'} | {gap(warm):.2%} | {' > '.join(map(str, ranking(warm)))} | "
                  f"{' > '.join(map(str, ranking(cold)))} |", flush=True)
    print(f"\nsame first pick in {same} of {len(a.seeds)} seeds; warm command {min(warm_s):.1f}-{max(warm_s):.1f} s")


if __name__ == "__main__":
    main()
