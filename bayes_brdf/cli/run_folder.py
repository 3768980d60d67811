"""The output folder of a sampling command (``infer``, ``fit``, ``recommend``): named, checked, owned by one run.

* The default folder is ``out/<command>/<capture name>``.
* It is checked (creatable, writable, room for the results) before the capture is even loaded.
* It records the run's fingerprint (:mod:`bayes_brdf.identity`) in ``run.json``: the photos'
  content digest, views, resolution, the model table with overrides, the sampler table with
  overrides, particles, steps, seed and the package version. A rerun of the same command resumes
  from its checkpoint; any other run is refused in one line unless ``--overwrite`` (start over).
* ``run_log.jsonl`` gets one line per invocation (when, resumed from which step, how long):
  the times live there and in ``summary.json``, never in ``posterior.safetensors``.
"""
from __future__ import annotations

import json
import sys
import time
from pathlib import Path

#: what a sampling command writes into its folder (removed by --overwrite)
OWNED = ("checkpoint.pt", "checkpoint_burnin.pt", "posterior.safetensors", "summary.json", "run_log.jsonl", "mean", "map", "std",
         "heldout", "recommend.json", "candidates.png")


def capture_name(capture) -> str:
    """A capture's name for folders and messages: the folder's name (of a file: its folder's)."""
    p = Path(capture)
    p = p if p.is_dir() or not p.suffix else p.parent
    return p.resolve().name or "capture"


def default_out(command: str, capture) -> Path:
    return Path("out") / command / capture_name(capture)


def output_folder(a, command: str) -> Path:
    """``--out``, or ``out/<command>/<capture name>``; checked writable before any work."""
    from ..io.outputs import check_folder

    out = Path(a.out) if a.out else default_out(command, a.capture)
    a.out = str(out)
    parts = a.particles or 32
    res = a.resolution or 128
    need = 96 * parts * res * res + 10_000_000     # posterior + checkpoint + maps, roughly
    return check_folder(out, need_bytes=need)


def _views_label(views) -> str:
    return "all views" if views is None else "views " + ",".join(str(v) for v in views)


def claim_folder(a, obs, model: dict, data: str, start: dict | None = None) -> str:
    """Claim ``a.out`` for this run (see module doc): the run of ``a``'s options on the loaded ``obs``
    with the model table ``model`` (:func:`~bayes_brdf.runs.fingerprint.model_table`) and the photos'
    digest ``data``; ``"new"``, ``"same"`` or ``"overwritten"``. ``start``: where a warm-started run's particles
    come from (``recommend --from``), part of its fingerprint."""
    from ..io.outputs import claim
    from ..runs.fingerprint import run_fingerprint

    fp = run_fingerprint(data, model=model, sampler=a.sampler, params=dict(a.param), particles=a.particles,
                         steps=a.steps, seed=a.seed, views=a.views, resolution=list(obs.resolution), start=start)
    label = (f"{capture_name(a.capture)} ({_views_label(a.views)}, {obs.resolution[0]} px, model {a.model}, "
             f"sampler {a.sampler or 'spos'}, seed {a.seed})")
    return claim(a.out, fp, label, overwrite=getattr(a, "overwrite", False), owned=OWNED)


def log_run(out: Path, record: dict) -> None:
    """Append one line to ``run_log.jsonl`` (the times and resume points of every invocation)."""
    rec = {"when": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "argv": sys.argv[1:], **record}
    with open(Path(out) / "run_log.jsonl", "a") as f:
        f.write(json.dumps(rec, default=str) + "\n")
