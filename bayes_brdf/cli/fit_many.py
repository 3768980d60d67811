"""``bayes-brdf fit-many CAPTURE... --out DIR``: ``fit`` of each capture, in its own folder, as its own run.

Each capture is fitted by the ``fit`` command itself (:func:`bayes_brdf.cli.fit.run`) with the same options,
into ``DIR/<capture name>`` (a second capture of the same name into ``DIR/<name>-2``, and so on, in the order
given): the folder has that fit's run identity (``run.json``), a rerun resumes it, a folder that holds another
run is refused (``--overwrite`` starts over), and its particles are those a plain ``bayes-brdf fit CAPTURE
--out DIR/<name>`` with the same options gets. The default ``--out`` is ``out/fit``, the parent of a plain
fit's default folder.

The captures are independent pieces of work for :mod:`bayes_brdf.executor`: one after the other in this
process by default, Ray tasks with ``--ray`` (a local Ray) or ``--ray-address ADDR`` (a cluster; each task
then needs the capture and ``DIR`` at the same paths, a shared file system). With ``--device cuda`` each Ray
task takes one GPU (Ray's ``num_gpus``; see docs/scale.md). A capture that fails (a folder of another run, a
bad capture) is reported in one line after the others ran; the exit code is then 2.
"""
from __future__ import annotations

import argparse
import contextlib
import io
import sys
import time
from pathlib import Path

from ..errors import InputError


def add_parser(sub):
    from ..executor import add_ray_args
    from .fit import add_holdout_arg
    from .infer import add_sampling_args

    f = sub.add_parser("fit-many", help="fit each of several captures into its own folder (serial, or on Ray)",
                       description="Fit each capture as 'bayes-brdf fit' does, with the same options, each into "
                                   "DIR/<capture name> with its own run identity, resume and refusal of another "
                                   "run's folder; its particles are those a plain fit gets. --ray runs the captures "
                                   "as tasks of a local Ray, --ray-address on a cluster (docs/scale.md).")
    add_sampling_args(f, "out/fit", many=True)
    add_holdout_arg(f)
    add_ray_args(f)
    f.set_defaults(func=run)


def folders(captures, out) -> list[tuple[str, Path]]:
    """``[(capture, folder)]``: each capture (absolute) with its folder ``out/<capture name>`` (``<name>-2``,
    ``<name>-3`` ... for later captures of a name already taken); one line for a capture that is not there
    or is given twice."""
    from .run_folder import capture_name

    seen, taken, plan = {}, {}, []
    for c in captures:
        p = Path(c)
        if not p.exists():
            raise InputError("capture not found", where=c, fix="give capture folders (or their JSON files)")
        key = p.resolve()
        if key in seen:
            raise InputError(f"capture given twice (also as {seen[key]!r})", where=c, fix="give each capture once")
        seen[key] = c
        name = capture_name(p)
        n = taken.get(name, 0) + 1
        taken[name] = n
        plan.append((str(key), Path(out).resolve() / (name if n == 1 else f"{name}-{n}")))
    return plan


def _fit_one(job: dict) -> dict:
    """One capture's ``fit`` (in this process or a Ray task): ``{"capture", "out", "code", "error", "stdout",
    "stderr", "seconds"}``; with ``job["capture_output"]`` its printed lines are returned, not printed."""
    from . import fit
    from .main import _log_to_stderr

    a = argparse.Namespace(**job["args"])
    rec = {"capture": a.capture, "out": a.out, "code": 0, "error": None, "stdout": "", "stderr": ""}
    out, err = io.StringIO(), io.StringIO()
    t = time.perf_counter()
    argv = sys.argv
    sys.argv = job["argv"]                 # what run_log.jsonl records, in a worker too
    try:
        with contextlib.ExitStack() as stack:
            if job["capture_output"]:
                stack.enter_context(contextlib.redirect_stdout(out))
                stack.enter_context(contextlib.redirect_stderr(err))
            _log_to_stderr()
            rec["code"] = fit.run(a)
    except InputError as e:
        rec.update(code=2, error=str(e))
    finally:
        sys.argv = argv
    rec.update(stdout=out.getvalue(), stderr=err.getvalue(), seconds=time.perf_counter() - t)
    return rec


#: parsed arguments of fit-many that are not fit's
_NOT_FIT = ("captures", "command", "func", "ray", "ray_address", "ray_cpus")


def _defaults() -> dict:
    from .main import build_parser

    a = vars(build_parser().parse_args(["fit-many", "CAPTURE"]))        # fit's defaults
    return {k: v for k, v in a.items() if k not in _NOT_FIT}


def jobs(plan, options: dict, capture_output: bool) -> list[dict]:
    """The ``fit`` of each ``(capture, folder)`` of ``plan`` (:func:`folders`) with the parsed ``fit``
    ``options`` (and this process's ``sys.argv``, for each folder's ``run_log.jsonl``)."""
    return [{"args": {**options, "capture": c, "out": str(o)}, "capture_output": capture_output,
             "argv": list(sys.argv)} for c, o in plan]


def fit_many(captures, out="out/fit", *, executor=None, **options) -> list[dict]:
    """The Python API of ``fit-many``: ``fit`` each of ``captures`` into ``out/<capture name>``, through
    ``executor`` (``None`` in this process, ``True`` a local Ray, an address a Ray cluster, or an
    :class:`~bayes_brdf.executor.Executor`). ``options`` are ``fit``'s, named as its parsed arguments
    (``steps=40``, ``resolution=16``, ``param=[("step_size", 0.02)]``, ``holdout=[3]``...). Returns one record
    per capture (``code`` 0, or 2 with the one-line ``error``); the files are in each ``out``."""
    from ..executor import SerialExecutor, using

    base = _defaults()
    bad = sorted(set(options) - set(base))
    if bad:
        raise InputError(f"unknown fit option {bad[0]!r}", fix=f"options: {', '.join(sorted(base))}")
    for k in ("param", "model_param"):
        if isinstance(options.get(k), dict):
            options[k] = list(options[k].items())
    with using(executor) as ex:
        return ex.map(_fit_one, jobs(folders(captures, out), {**base, **options},
                                     capture_output=not isinstance(ex, SerialExecutor)))


def run(a) -> int:
    from ..executor import SerialExecutor, executor_of_args

    t = time.perf_counter()
    options = {k: v for k, v in vars(a).items() if k not in _NOT_FIT}
    plan = folders(a.captures, a.out)            # a missing capture: one line, before any work
    gpus = 1 if str(a.device).startswith("cuda") and (a.ray or a.ray_address) else 0
    with executor_of_args(a, num_gpus_per_task=gpus) as ex:
        serial = isinstance(ex, SerialExecutor)
        recs = ex.map(_fit_one, jobs(plan, options, capture_output=not serial))
    failed = [r for r in recs if r["code"] != 0]
    for r in recs:                               # a Ray task's lines, in the captures' order
        sys.stdout.write(r["stdout"])
        sys.stderr.write(r["stderr"])
    done = len(recs) - len(failed)
    where = "" if serial else f" on {ex!r}"
    print(f"fit-many: {done} of {len(recs)} captures fitted in {time.perf_counter() - t:.1f} s{where} -> "
          f"{Path(a.out)}/ ({', '.join(Path(r['out']).name for r in recs if r['code'] == 0) or 'none'})")
    for r in failed:
        line = r["error"] or f"{r['capture']}: fit exited with code {r['code']}"
        print(f"bayes-brdf: error: {line}", file=sys.stderr)
    return 2 if failed else 0
