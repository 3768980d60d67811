"""The one loop every sampler runs in: seeds, progress bar, NaN checks, callbacks, checkpoints, minibatches.

``run(sampler, potential, particles=20, steps=1000, seed=0, checkpoint="run.pt")``
draws the initial particles from the prior (``potential.init``), then calls
``sampler.step`` ``steps`` times. Every ``checkpoint_every`` steps, and on
Ctrl-C, it writes the sampler state and every random-number state to
``checkpoint`` (``torch.save`` of tensors and numbers; loaded with
``weights_only=True``, no pickle); a rerun with the same arguments resumes
from it and ends exactly where an uninterrupted run would have.
"""
from __future__ import annotations

import json
import logging
import os
import time
from dataclasses import dataclass, field
from pathlib import Path

import torch
from torch import Tensor
from tqdm.auto import tqdm

from ..errors import InputError
from ..memory import keep_freed_memory
from .diagnostics import Diagnostics, diagnose

FORMAT = "bayes-brdf-checkpoint/1"
#: the longest run (its energy trace is preallocated: 80 MB; at 20 ms a step, two days)
MAX_STEPS = 10_000_000
log = logging.getLogger("bayes_brdf")


def check_run_length(steps: int) -> None:
    """One line (InputError) when a run of ``steps`` would be longer than :data:`MAX_STEPS`."""
    if steps > MAX_STEPS:
        raise InputError(f"steps must be at most {MAX_STEPS:,}, got {steps:,}",
                         fix="a default run takes 500 to 8000 steps; a longer one can be resumed from its checkpoint")


class SamplerDiverged(InputError):
    """The particles left the finite numbers: a step size too large, or a model returning NaN."""


class Interrupted(KeyboardInterrupt):
    """Ctrl-C (or SIGTERM in the CLI) during a run: ``step`` steps are done and saved in ``checkpoint``."""

    def __init__(self, step: int, steps: int, checkpoint):
        self.step, self.steps, self.checkpoint = step, steps, checkpoint
        where = f"checkpoint saved to {checkpoint}" if checkpoint is not None else "no checkpoint (none was asked for)"
        super().__init__(f"interrupted at step {step} of {steps}; {where}")


@dataclass
class RunResult:
    """What a run leaves: final particles ``z [n, D]``, the sampler state, the per-step mean energy and timings."""

    z: Tensor
    state: object
    energy_trace: Tensor          # [steps] mean energy per step
    steps: int
    seconds: float
    evaluations: int              # particle evaluations of the potential
    resumed_from: int = 0
    info: dict = field(default_factory=dict)
    diagnostics: Diagnostics | None = None
    energies: Tensor | None = None   # [steps, n] per-particle energy at every step


def _plain(x):
    """A state as nested dicts of tensors and numbers, for ``torch.save``; its ``transient`` fields left out."""
    if isinstance(x, tuple) and hasattr(x, "_fields"):
        skip = getattr(type(x), "transient", ())
        return {k: _plain(v) for k, v in x._asdict().items() if k not in skip}
    if isinstance(x, Tensor):
        return x.detach().cpu()
    return x


def _fill(template, plain, device):
    """The state ``template`` (from ``init``) with the values of ``plain``; a field ``plain`` lacks (a transient one)
    keeps the template's."""
    if isinstance(template, tuple) and hasattr(template, "_fields"):
        return type(template)(**{k: _fill(v, plain[k], device) if k in plain else v
                                 for k, v in template._asdict().items()})
    if isinstance(template, Tensor):
        return plain.to(device=template.device, dtype=template.dtype)
    return plain


def _signature(sampler, n, steps, seed, minibatch, groups, init_margin=0.0, max_steps=None, identity=None) -> str:
    d = {"sampler": sampler.name, "params": sampler.params(), "particles": n, "steps": steps,
         "seed": seed, "minibatch": minibatch, "groups": groups}
    if identity is not None:
        d["run"] = identity
    if init_margin:
        d["init_margin"] = init_margin
    if max_steps and max_steps > steps:
        d["max_steps"] = max_steps
    return json.dumps(d, sort_keys=True, default=str)


def _save(path: Path, payload: dict):
    tmp = path.with_name(path.name + ".tmp")
    torch.save(payload, tmp)
    os.replace(tmp, path)


def _load(path: Path, signature: str) -> dict:
    try:
        ck = torch.load(path, weights_only=True)
    except Exception as e:  # noqa: BLE001  (a corrupt file: say so in one line)
        raise InputError(f"unreadable checkpoint ({type(e).__name__})", where=path,
                         fix="delete it to start over") from None
    if not isinstance(ck, dict) or ck.get("format") != FORMAT:
        raise InputError("not a bayes-brdf checkpoint", where=path, fix="delete it or choose another path")
    if ck["signature"] != signature:
        from ..identity import differences
        try:
            diff = differences(json.loads(ck["signature"]), json.loads(signature))
        except (TypeError, ValueError):
            diff = []
        what = f" (it differs in {', '.join(diff[:6])}{', ...' if len(diff) > 6 else ''})" if diff else ""
        raise InputError(f"the checkpoint was written by another run{what}", where=path,
                         fix="use another checkpoint path, or delete it to start over")
    return ck


def run(sampler, potential, *, particles: int = 20, steps: int = 1000, seed: int = 0, z0: Tensor | None = None,
        checkpoint=None, checkpoint_every: int = 100, callbacks=(), progress: bool = True,
        minibatch_views: int | None = None, minibatch_pixels: float | None = None, groups: int = 1,
        init_margin: float = 0.0, max_steps: int | None = None, identity: dict | None = None,
        span: tuple[int, int] | None = None) -> RunResult:
    """Run ``sampler`` on ``potential`` for ``steps`` steps; see the module docstring.

    ``span = (offset, total)``: this run is steps ``offset ..`` of a longer one of ``total`` steps (a
    phase of :func:`bayes_brdf.infer`); only the progress bar and the resume message count that way.

    ``callbacks`` are called as ``cb(t, state, info)`` after every step.
    ``minibatch_views`` / ``minibatch_pixels`` make every step use a random
    subset of the views / pixels with the likelihood rescaled (stochastic
    gradients; the potential's model data must support ``minibatch``).
    ``groups`` runs that many independent ensembles of ``particles`` each in
    one batched run (``z`` is ``[groups * particles, D]``, group by group):
    the same statistics as ``groups`` separate runs, at the cost of one.
    ``init_margin`` keeps the prior draws of bounded sites off their bounds
    (:meth:`~bayes_brdf.potential.Potential.init`). ``max_steps > steps``
    continues the run past ``steps``, half of ``steps`` at a time, until its
    convergence checks pass or ``max_steps`` is reached (``steps="auto"`` in
    :func:`bayes_brdf.infer` and the CLI); the annealing horizon stays ``steps``.
    ``identity`` (a JSON-able fingerprint of the data and model, :mod:`bayes_brdf.identity`) is
    part of the checkpoint's signature: a checkpoint of other data or another model is refused.
    A Ctrl-C saves the checkpoint and raises :class:`Interrupted` (a ``KeyboardInterrupt``).

    Example:
        >>> from bayes_brdf.potential import FunctionPotential
        >>> from bayes_brdf.samplers import SGLD
        >>> pot = FunctionPotential(lambda z: 0.5 * (z ** 2).sum(1), dim=2)
        >>> res = run(SGLD(step_size=0.1), pot, particles=200, steps=300, progress=False)
        >>> 0.7 < float(res.z.var(0).mean()) < 1.3
        True
    """
    keep_freed_memory()     # a step's large tensors are reused, not faulted in again (bayes_brdf.memory)
    # the caller's global RNG is left as it was; inside, it is seeded (Pyro's NUTS draws from it)
    with torch.random.fork_rng(devices=[]):
        return _run(sampler, potential, particles=particles, steps=steps, seed=seed, z0=z0, checkpoint=checkpoint,
                    checkpoint_every=checkpoint_every, callbacks=callbacks, progress=progress,
                    minibatch_views=minibatch_views, minibatch_pixels=minibatch_pixels, groups=groups,
                    init_margin=init_margin, max_steps=max_steps, identity=identity, span=span)


def _run(sampler, potential, *, particles: int = 20, steps: int = 1000, seed: int = 0, z0: Tensor | None = None,
        checkpoint=None, checkpoint_every: int = 100, callbacks=(), progress: bool = True,
        minibatch_views: int | None = None, minibatch_pixels: float | None = None, groups: int = 1,
        init_margin: float = 0.0, max_steps: int | None = None, identity: dict | None = None,
        span: tuple[int, int] | None = None) -> RunResult:
    if not isinstance(steps, int) or steps < 1:
        raise InputError(f"steps must be a positive integer, got {steps!r}")
    check_run_length(max(steps, max_steps if isinstance(max_steps, int) else 0))
    if not isinstance(particles, int) or particles < 1:
        raise InputError(f"particles must be a positive integer, got {particles!r}")
    if max_steps is not None and (isinstance(max_steps, bool) or not isinstance(max_steps, int) or max_steps < steps):
        raise InputError(f"max_steps must be an integer >= steps ({steps}), got {max_steps!r}")
    cap = max_steps or steps
    if isinstance(groups, bool) or not isinstance(groups, int) or groups < 1:
        raise InputError(f"groups must be a positive integer, got {groups!r}")
    if groups > 1 and not sampler.supports_groups:
        raise InputError(f"{sampler.name} cannot batch independent groups", fix="run the groups one by one")
    mb = {"views": minibatch_views or None, "pixels": minibatch_pixels if minibatch_pixels not in (None, 1.0) else None}
    use_mb = any(v is not None for v in mb.values())
    if use_mb and not hasattr(potential, "minibatch"):
        raise InputError("minibatches need a model potential (its data must support minibatch)")
    signature = _signature(sampler, particles, steps, seed, mb, groups, init_margin, cap, identity)
    total = particles * groups
    ck_path = Path(checkpoint) if checkpoint is not None else None

    rng = torch.Generator(device="cpu").manual_seed(seed)
    torch.manual_seed(seed)
    if z0 is None:
        z0 = potential.init(total, seed=seed, margin=init_margin) if init_margin else potential.init(total, seed=seed)
    elif tuple(z0.shape) != (total, potential.dim):
        raise InputError(f"initial particles have shape {tuple(z0.shape)}, expected {(total, potential.dim)}")
    state = sampler.init(z0, potential, rng, steps=steps, groups=groups)   # the horizon stays steps under max_steps
    trace = torch.full((cap,), float("nan"), dtype=torch.float64)
    rec = _Recorder(cap, total, z0.shape[1])
    start, seconds0, evals0, horizon = 0, 0.0, 0, steps
    rec.aim(horizon)
    if ck_path is not None and ck_path.exists() and sampler.exact_resume:
        ck = _load(ck_path, signature)
        state = _fill(state, ck["state"], z0.device)
        rng.set_state(ck["rng"])
        torch.set_rng_state(ck["global_rng"])
        start, trace, seconds0, evals0 = ck["t"], ck["trace"], ck["seconds"], ck["evaluations"]
        horizon = int(ck.get("horizon", steps))
        rec.load(ck.get("record"))
        rec.aim(horizon)
        off, of = span if span is not None else (0, horizon)
        log.info("resuming from step %d of %d (checkpoint %s)", off + start, of, ck_path)

    def save(t, rngs=None, seconds=None):
        if ck_path is not None:
            r, gr = rngs or (rng.get_state(), torch.get_rng_state())
            ck_path.parent.mkdir(parents=True, exist_ok=True)
            _save(ck_path, {"format": FORMAT, "signature": signature, "t": t, "state": _plain(state),
                            "rng": r, "global_rng": gr, "trace": trace, "record": rec.state(), "horizon": horizon,
                            "seconds": elapsed() if seconds is None else seconds,
                            "evaluations": evals0 + committed_evals})

    t0, e0 = time.perf_counter(), _evals(potential)
    bar = tqdm(total=horizon, initial=start, desc=sampler.name, disable=not progress, leave=False)
    done, snap = start, None   # steps whose result is in `state`; RNG states before the step in flight
    committed_evals = 0        # evaluations of the committed steps (a step cut short is redone on resume)

    def elapsed() -> float:    # sampling seconds over all sessions (a finished run reloaded adds none)
        return seconds0 + (time.perf_counter() - t0 if done > start else 0.0)

    def steps_until(end: int):
        nonlocal state, done, snap, committed_evals
        for t in range(done, end):
            snap = (rng.get_state(), torch.get_rng_state())
            pot = potential.minibatch(rng, **mb) if use_mb else potential
            new_state, info = sampler.step(state, t, pot, rng)
            z = sampler.particles(new_state)
            e = info.get("energy")
            if not _all_finite(z) or (e is not None and bool(torch.isnan(e).any())):
                bad = int((~torch.isfinite(z)).any(1).sum())
                raise SamplerDiverged(
                    f"{sampler.name} diverged at step {t}: {bad} of {z.shape[0]} particles are not finite",
                    fix=(f"lower step_size (now {sampler.step_size}) or check the model's energies"
                         if hasattr(sampler, "step_size") else "check the model's energies"))
            if e is not None:
                trace[t] = float(e.double().mean())
            rec.add(t, e, z)
            spent = _evals(potential) - e0
            # committed: a checkpoint now resumes after step t. One statement of plain stores, in which CPython
            # never runs a signal handler: a Ctrl-C lands before it (step t is redone on resume) or after it,
            # never between the state and its evaluation count.
            state, done, snap, committed_evals = new_state, t + 1, None, spent
            for cb in callbacks:
                cb(t, state, info)
            bar.update(1)
            if e is not None and bar.n % 20 == 0:
                bar.set_postfix(energy=f"{trace[t]:.4g}")
            if ck_path is not None and checkpoint_every and (t + 1) % checkpoint_every == 0 and t + 1 < cap:
                save(t + 1)

    diag = None
    try:
        while True:
            steps_until(horizon)
            zf = sampler.particles(state).detach()
            diag = diagnose_run(sampler, potential, rec, zf, horizon, groups)
            if horizon >= cap or diag.converged:
                break
            horizon = min(cap, horizon + max(1, steps // 2))   # not converged yet: another half run
            rec.aim(horizon)
            bar.total = horizon
            bar.refresh()
    except KeyboardInterrupt:
        save(done, snap)
        bar.close()
        off, of = span if span is not None else (0, horizon)
        raise Interrupted(off + done, of if span is not None else horizon, ck_path) from None
    bar.close()
    seconds = elapsed()     # one reading: the checkpoint and the result report the same time (not the save's)
    save(done, seconds=seconds)
    evals = evals0 + committed_evals
    return RunResult(zf, state, trace[:done], done, seconds, evals, resumed_from=start,
                     diagnostics=diag, energies=rec.energies[:done])


class _Recorder:
    """Per-particle energies at every step and a fixed set of up to 32 coordinates every few steps: what :func:`~bayes_brdf.samplers.diagnostics.diagnose` reads (and checkpoints keep)."""

    def __init__(self, steps: int, n: int, dim: int, track: int = 32):
        self.energies = torch.full((steps, n), float("nan"), dtype=torch.float32)
        self.idx = torch.linspace(0, dim - 1, min(dim, track)).round().long().unique()
        self.stride = max(1, steps // 800)
        self.tracked = torch.full((len(range(0, steps, self.stride)), n, len(self.idx)), float("nan"),
                                  dtype=torch.float32)
        self.snap_at, self.snapshot = 0, None     # the particles three quarters into the run (stability checks)

    def aim(self, horizon: int):
        """Keep the particles after step ``3 horizon / 4`` (called whenever the horizon is set)."""
        at = max(1, (3 * horizon) // 4)
        if at != self.snap_at:
            self.snap_at, self.snapshot = at, None

    def earlier(self, horizon: int):
        """The particles three quarters into a run of ``horizon`` steps, when they were kept."""
        return self.snapshot if self.snap_at == max(1, (3 * horizon) // 4) else None

    def add(self, t: int, e, z: Tensor):
        if e is not None and e.dim() == 1 and e.shape[0] == self.energies.shape[1]:
            self.energies[t] = e.detach().float().cpu()
        if t % self.stride == 0:
            self.tracked[t // self.stride] = z.detach()[:, self.idx.to(z.device)].float().cpu()
        if t + 1 == self.snap_at:
            self.snapshot = z.detach().float().cpu().clone()

    def second_half(self, done: int) -> tuple[Tensor, Tensor | None]:
        """Energies of steps ``[0, done)`` and the tracked rows of the second half ``[done / 2, done)``."""
        rows = self.tracked[(done // 2 + self.stride - 1) // self.stride:(done + self.stride - 1) // self.stride]
        return self.energies[:done], (rows if rows.shape[0] else None)

    def state(self) -> dict:
        st = {"energies": self.energies, "tracked": self.tracked, "snap_at": self.snap_at}
        if self.snapshot is not None:
            st["snapshot"] = self.snapshot
        return st

    def load(self, st):
        if isinstance(st, dict) and st["energies"].shape == self.energies.shape:
            self.energies, self.tracked = st["energies"], st["tracked"]
            self.snap_at, self.snapshot = int(st.get("snap_at", 0)), st.get("snapshot")


def _all_finite(z: Tensor) -> bool:
    """Whether every element of ``z`` is finite: a finite sum says so in one read (a NaN or an infinity makes the
    sum NaN or infinite); only a sum that is not finite (a non-finite element, or finite ones overflowing it) is
    checked element by element. ``isfinite(z).all()`` alone is four passes over the particles every step (1.5 ms
    of a 128² step, measured)."""
    return bool(torch.isfinite(z.sum())) or bool(torch.isfinite(z).all())


def diagnose_run(sampler, potential, rec: _Recorder, z: Tensor, steps: int, groups: int = 1) -> Diagnostics:
    """The convergence checks of a finished run (one extra gradient evaluation, not counted in the budget)."""
    grad = None
    if hasattr(potential, "value_and_grad"):
        count = getattr(potential, "_count", None)
        before = count[0] if count is not None else None
        try:
            _, grad = potential.value_and_grad(z)
        except Exception:  # noqa: BLE001  (a potential without gradients: the Stein checks are left out)
            grad = None
        if count is not None:
            count[0] = before
        elif hasattr(potential, "evaluations") and isinstance(potential.evaluations, int):
            potential.evaluations -= z.shape[0]
    energies, tracked = rec.second_half(steps)
    earlier = rec.earlier(steps)
    return diagnose(energies, tracked, z, grad, chains=sampler.particles_are_chains(z.shape[1]), steps=steps,
                    earlier=None if earlier is None else earlier.to(z), groups=groups, sampler=sampler.name)


def _evals(potential) -> int:
    return int(getattr(potential, "evaluations", 0))
