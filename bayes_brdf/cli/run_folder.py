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
OWNED = ("checkpoint.pt", "posterior.safetensors", "summary.json", "run_log.jsonl", "mean", "map", "std",
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


def model_table(a, obs) -> dict:
    """The model preset table of ``a`` with its ``--model-param`` overrides (a per_texel model gets the
    photos' resolution unless overridden): what is sampled, and what the fingerprint records."""
    from ..presets import load_preset

    table = dict(load_preset("models", a.model))
    table.update(dict(a.model_param))
    if table.get("model") == "per_texel" and "resolution" not in dict(a.model_param):
        table["resolution"] = obs.resolution[0]
    if table.get("model") == "latent_decoder" and "weights_digest" not in table:
        from ..models.latent_decoder import weights_digest   # other weights, another run (and a refused resume)
        table["weights_digest"] = weights_digest(table.get("weights", "latent_decoder_64"))
    return table


def run_fingerprint(a, obs) -> tuple[dict, str]:
    """The fingerprint of ``a``'s sampling run on the loaded ``obs`` and a short label for messages."""
    from ..identity import fingerprint, observations_digest
    from ..presets import load_preset

    model = model_table(a, obs)
    sampler = dict(load_preset("samplers", a.sampler or "spos"))
    fp = fingerprint(data=observations_digest(obs), model=model, seed=a.seed,
                     views=a.views, resolution=list(obs.resolution),
                     sampler={"preset": sampler, "params": dict(a.param), "particles": a.particles,
                              "steps": a.steps})
    label = (f"{capture_name(a.capture)} ({_views_label(a.views)}, {obs.resolution[0]} px, model {a.model}, "
             f"sampler {a.sampler or 'spos'}, seed {a.seed})")
    return fp, label


def claim_folder(a, obs) -> str:
    """Claim ``a.out`` for this run (see module doc); ``"new"``, ``"same"`` or ``"overwritten"``."""
    from ..io.outputs import claim

    fp, label = run_fingerprint(a, obs)
    return claim(a.out, fp, label, overwrite=getattr(a, "overwrite", False), owned=OWNED)


def log_run(out: Path, record: dict) -> None:
    """Append one line to ``run_log.jsonl`` (the times and resume points of every invocation)."""
    rec = {"when": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "argv": sys.argv[1:], **record}
    with open(Path(out) / "run_log.jsonl", "a") as f:
        f.write(json.dumps(rec, default=str) + "\n")
