"""Where independent pieces of work run: in this process (the default) or on Ray (one machine or a cluster).

Every fan-out of the library goes through one seam, an :class:`Executor`: ``executor.map(fn, items,
shared=...)`` calls ``fn(item)`` (or ``fn(item, shared)``) for each item and returns the results in the
items' order. ``fit-many`` (one capture per item), ``compare`` (samplers and their runs), the experiments'
seeds (``fig3``, ``fig7``) and candidate scoring (:func:`score_candidates`: shards of candidates) use it.

* :class:`SerialExecutor` -- one item after the other, in this process (no extra dependency).
* :class:`RayExecutor` -- one Ray task per item: ``shared`` is put into Ray's object store once
  (``ray.put``) and every task reads it from there; the results are fetched in the items' order.
  ``address=None`` starts a local Ray for the executor's lifetime (``num_cpus``: its CPUs, default all),
  an address joins a running cluster (``ray start --head`` on one machine, ``ray start --address`` on
  the others). A task takes one CPU and ``num_gpus_per_task`` GPUs (Ray then sets ``CUDA_VISIBLE_DEVICES``
  for it, which is what Dr.Jit and torch look at) and runs torch on ``threads_per_task`` threads
  (default: its CPUs, 1).

The numbers do not depend on the executor: before each item the global random generators (``random``,
NumPy, torch) are seeded from the item's seed (``seeds[i]``, default its position ``i``) -- in this
process they are restored afterwards -- and everything else a worker computes comes from the item itself.
The functions sent to Ray must be importable (module level), and items, ``shared`` and results picklable.

``make_executor(ray)`` turns the command line's choice into one: ``None``/``False`` serial, ``True`` a local
Ray (``--ray``), a string the address of a cluster (``--ray-address``); without Ray installed it raises
:class:`~bayes_brdf.errors.InputError` saying how to install it. Use it as a context manager (a local Ray
is shut down on exit).

Example:
    >>> with make_executor(None) as ex:
    ...     ex.map(pow, [2, 3], shared=2)
    [4, 9]
"""
from __future__ import annotations

import contextlib
import random
import time
from typing import Any, Callable, Iterable, Protocol, Sequence, runtime_checkable

from .errors import InputError

#: how to get Ray, in the one line a missing Ray is answered with
INSTALL = "install it with: pip install 'bayes-brdf[ray]'"


@runtime_checkable
class Executor(Protocol):
    """Runs ``fn`` on each item; ``map`` returns the results in the items' order."""

    def map(self, fn: Callable, items: Iterable, *, shared: Any = None,
            seeds: Sequence[int] | None = None) -> list: ...

    def close(self) -> None: ...


def _item_seed(seeds, i: int) -> int:
    return int(seeds[i]) if seeds is not None else i


@contextlib.contextmanager
def _seeded(seed: int, restore: bool):
    """The global generators seeded with ``seed`` for one item (restored after when ``restore``)."""
    import numpy as np
    import torch

    state = (random.getstate(), np.random.get_state(), torch.get_rng_state()) if restore else None
    random.seed(seed)
    np.random.seed(seed % 2**32)
    torch.manual_seed(seed)
    try:
        yield
    finally:
        if state is not None:
            random.setstate(state[0])
            np.random.set_state(state[1])
            torch.set_rng_state(state[2])


def _call(fn: Callable, item, shared, has_shared: bool):
    return fn(item, shared) if has_shared else fn(item)


def _checked(items, seeds) -> list:
    items = list(items)
    if seeds is not None and len(seeds) != len(items):
        raise ValueError(f"{len(seeds)} seeds for {len(items)} items")
    return items


class SerialExecutor:
    """Each item in turn, in this process (the default executor)."""

    def map(self, fn: Callable, items: Iterable, *, shared: Any = None, seeds: Sequence[int] | None = None) -> list:
        items = _checked(items, seeds)
        out = []
        for i, item in enumerate(items):
            with _seeded(_item_seed(seeds, i), restore=True):
                out.append(_call(fn, item, shared, shared is not None))
        return out

    def close(self) -> None:
        pass

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def __repr__(self) -> str:
        return "SerialExecutor()"


def _import_ray(option: str = "Ray"):
    try:
        import ray
    except ImportError:
        raise InputError(f"{option} needs Ray, which is not installed", fix=INSTALL) from None
    return ray


class _Failed:
    """An exception raised by an item in a Ray task, carried back so that the caller sees the original."""

    def __init__(self, error: BaseException):
        self.error = error


def _ray_task(fn: Callable, item, shared, has_shared: bool, seed: int, threads: int):
    """What each Ray task runs (module level: Ray pickles it by reference)."""
    import torch

    torch.set_num_threads(max(1, int(threads)))
    with _seeded(seed, restore=False):
        try:
            return _call(fn, item, shared, has_shared)
        except Exception as e:      # noqa: BLE001 -- re-raised by the caller, as the serial executor would
            return _Failed(e)


_REMOTE = None


class RayExecutor:
    """One Ray task per item (see the module doc). ``address``: join that cluster (``"auto"``: the one this
    machine belongs to), else start a local Ray of ``num_cpus`` CPUs (default: all); a Ray already
    initialised in this process is used as it is (and left running)."""

    def __init__(self, address: str | None = None, num_cpus: int | None = None, num_gpus_per_task: float = 0,
                 threads_per_task: int | None = None, option: str = "Ray"):
        ray = _import_ray(option)
        self.address, self.num_gpus_per_task = address, float(num_gpus_per_task)
        self.threads_per_task = int(threads_per_task or 1)
        self._started = False
        if not ray.is_initialized():
            import os

            env = {k: os.environ[k] for k in ("DRJIT_LIBLLVM_PATH",) if k in os.environ}
            kw = dict(include_dashboard=False, log_to_driver=False, configure_logging=False)
            if env:
                kw["runtime_env"] = {"env_vars": env}
            try:
                if address:
                    ray.init(address=address, **kw)
                else:
                    ray.init(num_cpus=num_cpus, **kw)
            except ConnectionError as e:
                raise InputError(f"cannot join the Ray cluster at {address!r} ({e})",
                                 fix="start it with 'ray start --head' and give its address") from None
            self._started = True

    @property
    def workers(self) -> int:
        """The tasks that can run at once (the cluster's CPUs, or its GPUs for GPU tasks)."""
        import ray

        res = ray.cluster_resources()
        if self.num_gpus_per_task:
            return max(1, int(res.get("GPU", 0) // self.num_gpus_per_task))
        return max(1, int(res.get("CPU", 1)))

    def map(self, fn: Callable, items: Iterable, *, shared: Any = None, seeds: Sequence[int] | None = None) -> list:
        import ray

        global _REMOTE
        items = _checked(items, seeds)
        if not items:
            return []
        if _REMOTE is None:
            _REMOTE = ray.remote(_ray_task)
        task = _REMOTE.options(num_cpus=1, num_gpus=self.num_gpus_per_task, max_retries=0)
        ref = ray.put(shared) if shared is not None else None        # once, whatever the number of tasks
        refs = [task.remote(fn, item, ref, shared is not None, _item_seed(seeds, i), self.threads_per_task)
                for i, item in enumerate(items)]
        out = ray.get(refs)
        failed = next((r for r in out if isinstance(r, _Failed)), None)
        if failed is not None:
            raise failed.error
        return out

    def close(self) -> None:
        if self._started:
            import ray

            ray.shutdown()
            self._started = False

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def __repr__(self) -> str:
        return f"RayExecutor(address={self.address!r})"


def make_executor(ray: "bool | str | None" = None, *, num_cpus: int | None = None, num_gpus_per_task: float = 0,
                  option: str | None = None) -> "SerialExecutor | RayExecutor":
    """The executor of a choice: ``None``/``False`` serial in-process, ``True`` a local Ray (``num_cpus``:
    its CPUs), a string the address of a Ray cluster to join. ``option`` names the choice in the one-line
    error a missing Ray gives (default ``--ray`` / ``--ray-address``)."""
    if ray is None or ray is False:
        return SerialExecutor()
    if ray is True:
        return RayExecutor(num_cpus=num_cpus, num_gpus_per_task=num_gpus_per_task, option=option or "--ray")
    if isinstance(ray, str) and ray:
        return RayExecutor(address=ray, num_gpus_per_task=num_gpus_per_task, option=option or "--ray-address")
    raise InputError(f"unknown executor choice {ray!r}", fix="give None (serial), True (a local Ray) or an address")


@contextlib.contextmanager
def using(executor: "Executor | bool | str | None" = None):
    """``executor`` itself when it is an :class:`Executor` (left open), else :func:`make_executor` of the
    choice, closed on exit: what the Python API's ``executor=`` arguments accept."""
    if isinstance(executor, Executor):
        yield executor
        return
    ex = make_executor(executor, option="executor=" + repr(executor))
    try:
        yield ex
    finally:
        ex.close()


def add_ray_args(p) -> None:
    """``--ray`` / ``--ray-address ADDR`` (and ``--ray-cpus N``) on a command that fans out."""
    g = p.add_mutually_exclusive_group()
    g.add_argument("--ray", action="store_true",
                   help="run the independent pieces as tasks of a local Ray started for this run (needs "
                        "pip install 'bayes-brdf[ray]'); the numbers are the same as without it")
    g.add_argument("--ray-address", metavar="ADDR", default=None,
                   help="run them on the Ray cluster at ADDR (e.g. 10.0.0.1:6379, or auto); see docs/scale.md")
    p.add_argument("--ray-cpus", type=int, default=None, metavar="N",
                   help="--ray: the local Ray's CPUs, the tasks that run at once (default: all)")


def executor_of_args(a, num_gpus_per_task: float = 0) -> "SerialExecutor | RayExecutor":
    """The executor the parsed ``--ray`` / ``--ray-address`` / ``--ray-cpus`` ask for."""
    if a.ray_cpus is not None and not a.ray:
        raise InputError("--ray-cpus applies to --ray (a local Ray)", fix="add --ray, or leave --ray-cpus out")
    if a.ray_cpus is not None and a.ray_cpus < 1:
        raise InputError(f"--ray-cpus must be at least 1, got {a.ray_cpus}")
    choice = a.ray_address or (True if a.ray else None)
    return make_executor(choice, num_cpus=a.ray_cpus, num_gpus_per_task=num_gpus_per_task)


# ------------------------------------------------------------------ candidate scoring in shards
#: candidates per task of :func:`score_candidates` (fixed: the shards, and so the numbers, do not depend on
#: the executor)
SHARD = 256


def _score_shard(shard, shared):
    score, maps, surface, kw = shared
    return score(maps, shard, surface, **kw)


def score_candidates(post, candidates: list, surface=None, *, executor: "Executor | bool | str | None" = None,
                     shard_size: int | None = None, score: Callable | None = None, **score_kw):
    """Score ``candidates`` in shards through ``executor``: the posterior's particle maps (and the surface)
    are sent once, each shard of ``shard_size`` candidates (default :data:`SHARD`, whatever the executor, so
    that the numbers are too) is one task, and the shards' :class:`~bayes_brdf.guidance.scores.CandidateScores`
    are joined in the candidates' order (``seconds``: the wall time of the whole).

    ``score`` is the scoring callable ``score(maps, candidates, surface, **score_kw) -> CandidateScores``
    (default :func:`~bayes_brdf.guidance.scores.score_views`); ``noise_var="observation"`` is resolved here,
    from ``post``'s model, before the particles leave. The Monte Carlo estimator's common random numbers go
    by pixel position and ``seed``, so a candidate's score does not depend on its shard; equal to one
    ``score_views`` call up to the order of float additions.
    """
    import torch

    from .guidance.scores import CandidateScores, observation_noise_var, parse_noise_var, score_views
    from .uncertainty import particle_maps, resolve_surface

    candidates = list(candidates)
    if not candidates:
        raise InputError("no candidate views to score", fix="pass at least one View")
    score = score or score_views
    kw = dict(score_kw)
    if "noise_var" in kw and parse_noise_var(kw["noise_var"]) == "observation":
        kw["noise_var"] = observation_noise_var(post)
    maps, surface = particle_maps(post), resolve_surface(post, surface)
    size = int(shard_size or SHARD)
    if size < 1:
        raise InputError(f"shard_size must be at least 1, got {shard_size}")
    t0 = time.perf_counter()
    shards = [candidates[i:i + size] for i in range(0, len(candidates), size)]
    with using(executor) as ex:
        parts = ex.map(_score_shard, shards, shared=(score, maps, surface, kw))
    return CandidateScores(torch.cat([p.mi for p in parts]), torch.cat([p.mean_std for p in parts]),
                           torch.cat([p.pixels for p in parts]), parts[0].estimator, time.perf_counter() - t0)
