"""``bayes-brdf experiment NAME``: reproduce one of the paper's figures on synthetic data."""
from __future__ import annotations

import inspect
import json
import sys
import time
from pathlib import Path

from ..errors import InputError
from ..executor import add_ray_args, executor_of_args
from .common import key_value


def add_parser(sub):
    e = sub.add_parser("experiment", help="reproduce one of the paper's experiments (fig2 ... fig7), or compare with a "
                                          "peer (wiersma)",
                       description="Run one experiment of the paper on synthetic data and write its PNG figures and "
                                   "a JSON of the numbers to --out. 'small' presets take about a minute on 2 CPU "
                                   "cores (what CI runs); 'full' is paper-sized. 'bayes-brdf experiment list' shows "
                                   "them all.")
    e.add_argument("name", help="experiment name (fig2, fig3, fig4, fig5, fig6, fig7, wiersma) or 'list'")
    e.add_argument("--preset", default=None,
                   help="small or full; fig4 and fig7 also mesh_small and mesh (the same on a mesh: the bowl, the "
                        "bunny of ../shared/data); under a known environment map (the ballroom of ../shared/data): "
                        "fig3 env_small and env_full (the environment-lit rows), fig4 mesh_env_small and mesh_env; "
                        "'experiment list' shows every preset (default: small; wiersma: full, the peer's protocol)")
    e.add_argument("--set", type=key_value, action="append", default=[], metavar="KEY=VALUE",
                   help="override a preset setting, e.g. steps=2000 (repeatable)")
    e.add_argument("--seed", type=int, default=0, help="random seed (default: %(default)s)")
    e.add_argument("--out", default=None, help="output folder (default: out/experiments/NAME)")
    e.add_argument("--json", action="store_true",
                   help="also print the summary numbers as JSON on stdout (they are always in the folder's JSON)")
    add_ray_args(e)
    e.set_defaults(func=run)


def run(a) -> int:
    from ..experiments import EXPERIMENTS, get, preset

    if a.name == "list":
        for name in sorted(EXPERIMENTS):
            m = get(name)
            print(f"{name}: {m.DESCRIPTION}")
            for p, cfg in m.PRESETS.items():
                print(f"    {p}: " + ", ".join(f"{k}={v}" for k, v in cfg.items()))
        return 0
    from ..io.outputs import check_folder

    m = get(a.name)
    a.preset = a.preset or getattr(m, "DEFAULT_PRESET", "small")
    cfg = preset(m, a.preset, dict(a.set))
    out = check_folder(a.out or f"out/experiments/{a.name}")
    fans_out = "executor" in inspect.signature(m.run).parameters      # its seeds are independent pieces
    if not fans_out and (a.ray or a.ray_address or a.ray_cpus is not None):
        fan = [n for n in sorted(EXPERIMENTS) if "executor" in inspect.signature(get(n).run).parameters]
        raise InputError(f"experiment {a.name} runs in one process, --ray does not apply to it",
                         fix=f"leave it out (the experiments that fan out: {', '.join(fan)})")
    t = time.perf_counter()
    with executor_of_args(a) as ex:              # the experiment's seeds: in this process, or Ray tasks
        res = m.run(out, preset=a.preset, seed=a.seed, progress=sys.stderr.isatty(), **dict(a.set),
                    **({"executor": ex} if fans_out else {}))
    secs = time.perf_counter() - t
    files = sorted(p.name for p in out.iterdir() if p.suffix in (".png", ".json"))
    print(f"{a.name} ({a.preset}, {', '.join(f'{k}={v}' for k, v in cfg.items())}) in {secs:.0f} s -> {out}/: "
          f"{', '.join(files)}")
    summary = res.get("summary") if isinstance(res, dict) else None
    if summary and a.json:
        print(json.dumps(summary, indent=1, default=float))
    return 0
