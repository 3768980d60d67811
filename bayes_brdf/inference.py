"""``bb.infer``: a model, observations and a sampler in, a :class:`Posterior` out."""
from __future__ import annotations

import os
import sys
import warnings
from typing import Callable

import torch

from .errors import ConvergenceWarning, InputError
from .identity import data_digest, digest_tensor, fingerprint, model_description
from .models.data import ModelData
from .models.base import describe, infers_sigma
from .models.material import from_preset
from .observations import Observations
from .posterior import Posterior
from .potential import Potential
from .presets import load_preset
from .render.scene import surface_state
from .samplers import make_sampler
from .samplers.diagnostics import drawn
from .samplers.driver import check_run_length, run
from .noise_estimate import with_render_noise


#: ``steps="auto"`` runs at most this many times the preset's steps
AUTO_STEPS_CAP = 4
#: ``steps="auto"`` first runs this fraction of the preset's steps (its annealing over them), then half as many
#: again each time until the convergence checks pass
AUTO_FIRST = 0.25


def auto_steps(preset_steps: int) -> tuple[int, int]:
    """``(first, cap)`` of a ``steps="auto"`` run for a preset of ``preset_steps``: the first horizon (at least
    200 steps) and the most it may run.

    Example:
        >>> auto_steps(2000)
        (500, 8000)
    """
    return max(200, round(AUTO_FIRST * preset_steps)), AUTO_STEPS_CAP * preset_steps
#: under ``pixel_noise = "signal"``, the fraction of the run sampled with one noise scale before its shape is
#: estimated (SPOS's annealing is over at 38 % of a run)
NOISE_BURNIN = 0.4


def signal_noise(model, sampler=None) -> bool:
    """Whether ``model`` samples under signal-dependent noise: ``pixel_noise = "signal"`` with an inferred
    ``sigma = "auto"`` (a fixed sigma is the user's statement of the noise: it is used as it is), and a
    sampler whose run can be cut in two, the second part started from the first's particles
    (``continues_from_particles``; not NUTS, whose chain warms up again)."""
    return (getattr(model, "pixel_noise", "constant") == "signal" and getattr(model, "sigma", None) == "auto"
            and callable(getattr(model, "maps", None)) and getattr(sampler, "continues_from_particles", True))


def _phase_path(checkpoint, phase: str):
    """The checkpoint of a run's first phase: ``checkpoint.pt`` -> ``checkpoint_burnin.pt`` (``None``: none)."""
    if checkpoint is None:
        return None
    from pathlib import Path
    p = Path(checkpoint)
    return p.with_name(f"{p.stem}_{phase}{p.suffix}")


def resolve_model(model):
    """A model from a callable, a built-in name / preset path (``models/*.toml``) or a preset table."""
    if isinstance(model, dict):
        return from_preset(model)
    if isinstance(model, str):
        return from_preset(load_preset("models", model))
    if not callable(model):
        raise InputError(f"a model must be a Pyro model function or a preset, got {type(model).__name__}")
    return model


def _sample(smp, pot, model, data, kw: dict, *, seed, checkpoint, progress, callbacks, z0, identity):
    """The run: one phase, or two under signal-dependent noise (:func:`signal_noise`).

    Two phases (:mod:`bayes_brdf.noise_estimate`): a burn-in of :data:`NOISE_BURNIN` of the steps under one
    noise scale, whose particles' renders give the photos' gains (``view_gain = "estimated"``) and whose
    residuals give the noise level's shape (all particles but those its diagnostics call left behind); then the rest of the run on the corrected photos under the
    per-pixel scale, from where the burn-in ended, without a second annealing. The burn-in has its own
    checkpoint; progress, resume and Ctrl-C speak of the whole run. Returns ``(result, potential, data,
    noise level or None, view gains or None, identity)``, the last four as the second phase used them.
    """
    kw = dict(kw)
    if not signal_noise(model, smp):
        res = run(smp, pot, seed=seed, checkpoint=checkpoint, progress=progress, callbacks=callbacks, z0=z0,
                  identity=identity, **kw)
        return res, pot, data, None, None, identity
    from .noise_estimate import estimate_noise
    steps1 = max(1, round(NOISE_BURNIN * kw["steps"]))
    kw1 = {**kw, "steps": steps1, "max_steps": None}
    burnin = run(smp, pot, seed=seed, checkpoint=_phase_path(checkpoint, "burnin"), progress=progress,
                 z0=z0, identity={**identity, "phase": "burnin"}, span=(0, kw["steps"]), **kw1)
    keep = drawn(burnin.energies)          # particles left behind are no posterior draws: their residuals no noise
    z = burnin.z if keep is None else burnin.z[keep]
    data, noise_level, gains = estimate_noise(model, data, pot.to_constrained(z))
    pot = Potential(model, (data,))
    kw["steps"] = max(1, kw["steps"] - steps1)
    if kw.get("max_steps"):
        kw["max_steps"] = max(kw["steps"], kw["max_steps"] - steps1)
    if "anneal" in smp.params():          # the particles are past the burn-in: no second annealing
        smp = type(smp).from_params({**smp.params(), "anneal": False})
    identity = {**identity, "phase": "signal noise", "noise_level": noise_level.to_dict(),
                **({"view_gains": gains.to_dict()} if gains is not None else {})}
    res = run(smp, pot, seed=seed, checkpoint=checkpoint, progress=progress, callbacks=callbacks, z0=burnin.z,
              identity=identity, span=(burnin.steps, burnin.steps + kw["steps"]), **kw)
    # resumed in the second phase: from the burn-in's steps plus its own; else from where the burn-in did
    res.resumed_from = burnin.steps + res.resumed_from if res.resumed_from else burnin.resumed_from
    res.steps += burnin.steps
    res.seconds += burnin.seconds
    res.evaluations += burnin.evaluations
    if res.diagnostics is not None:        # the remedy speaks of the whole run
        res.diagnostics.steps = res.steps
    return res, pot, data, noise_level, gains, identity


def infer(model: "Callable | str | dict", observations: "Observations | ModelData", sampler: "str | dict | object" = "spos",
          *, seed: int = 0, particles: int | None = None, steps: "int | str | None" = None,
          params: dict | None = None,
          checkpoint: "str | os.PathLike | None" = None, progress: bool | None = None, dtype=torch.float32,
          device: "str | torch.device | None" = None, callbacks=(), z0: "torch.Tensor | None" = None,
          map_steps: int | None = None, observations_digest: str | None = None) -> Posterior:
    """Sample the posterior of ``model`` given ``observations`` with ``sampler``.

    Args:
        model: a Pyro model ``model(data)`` (a built-in from :mod:`bayes_brdf.models`, a user's
            function, or a preset name/path from ``models/``).
        observations: :class:`Observations` (or a :class:`ModelData`).
        sampler: a name, a preset path (``samplers/*.toml``), a table or a :class:`Sampler`.
        seed: same seed, same result.
        particles: override the preset's particle count.
        steps: override the preset's step count (a fixed run); ``"auto"``: a quarter of the preset's
            (:func:`auto_steps`), then half as many again until the convergence checks pass, at most four times
            the preset's (:data:`AUTO_STEPS_CAP`); ``None``: the preset's choice (``[run] auto_steps = true``,
            as the default ``spos`` preset has: ``"auto"``; else its fixed steps).
        params: override the preset's hyper-parameters.
        checkpoint: a file to checkpoint to and resume from.
        progress: show a progress bar (default: when stderr is a terminal).
        device: where to run; by default the observations' device.
        z0: starting particles ``[n, D]`` in unconstrained space (e.g. a previous posterior's ``z``, to
            warm-start after adding views); by default prior draws.
        map_steps: Adam steps refining the MAP from the best particle (Eq. 7; 0: the best particle;
            default ``min(300, steps)``: no longer than the run itself).
        observations_digest: :func:`~bayes_brdf.identity.observations_digest` of ``observations`` when
            the caller computed it already (e.g. for its own run folder), so the photos are hashed once
            per run; by default computed here. It goes into the checkpoint's fingerprint.

    The run's convergence checks land in ``post.diagnostics``; when one fails a
    :class:`~bayes_brdf.errors.ConvergenceWarning` says which and what to do.

    Example:
        >>> import bayes_brdf as bb
        >>> from bayes_brdf.render import SVBRDF, PlanarSample, collocated_views
        >>> from bayes_brdf.render.shade import render
        >>> views = collocated_views(3, 3.0, camera="rectified", resolution=8)
        >>> obs = bb.Observations(views, render(SVBRDF.constant(0.5, 0.3), views, PlanarSample(2.0))[0], PlanarSample(2.0))
        >>> post = bb.infer(bb.models.homogeneous(albedo="gray"), obs, "spos", steps=300, progress=False)
        >>> abs(float(post.mean("albedo")) - 0.5) < 0.05
        True
    """
    model = resolve_model(model)
    if isinstance(observations, ModelData):
        data = observations
    elif isinstance(observations, Observations):
        data = ModelData.from_observations(observations, dtype=dtype, device=device)
    else:
        raise InputError(f"observations must be Observations, got {type(observations).__name__}",
                         fix="bb.io.load_capture(path)")
    auto = steps == "auto"
    if isinstance(steps, str) and not auto:
        raise InputError(f"steps must be a positive integer or \"auto\", got {steps!r}")
    if isinstance(steps, int):
        check_run_length(steps)                                   # before the burn-in takes its share of it
    smp, cfg = make_sampler(sampler, params=params,
                            run={k: v for k, v in (("particles", particles), ("steps", None if auto else steps))
                                 if v is not None})
    auto = auto or (steps is None and cfg.auto_steps)        # the preset's default (spos: auto_steps = true)
    data = with_render_noise(model, data, estimated=signal_noise(model, smp))
    pot = Potential(model, (data,))
    if progress is None:
        progress = sys.stderr.isatty()
    kw = cfg.run_kwargs()
    if auto:
        kw["steps"], kw["max_steps"] = auto_steps(kw["steps"])
    if z0 is not None:
        z0 = torch.as_tensor(z0, dtype=dtype, device=data.device)
        if z0.dim() != 2 or z0.shape[1] != pot.dim:
            raise InputError(f"z0 has shape {tuple(z0.shape)}, expected [particles, {pot.dim}]",
                             fix="pass a posterior's z from the same model")
        kw["particles"] = z0.shape[0]
    identity = fingerprint(data=data_digest(data, observations_digest), model=model_description(model), seed=seed,
                           start="prior" if z0 is None else digest_tensor(z0))
    params = smp.params()
    res, pot, data, noise_level, gains, identity = _sample(smp, pot, model, data, kw, seed=seed, checkpoint=checkpoint,
                                                    progress=progress, callbacks=callbacks, z0=z0, identity=identity)
    with torch.no_grad():
        energies = pot.energy(res.z, jacobian=False)
    meta = {"sampler": smp.name, "params": params, "run": vars(cfg), "seed": seed,
            "evaluations": res.evaluations, "steps": res.steps, "identity": identity,
            "model": describe(model),
            "observations": observations.meta if isinstance(observations, Observations) else {},
            "surface": surface_state(data.observations.surface)[0],
            "diagnostics": res.diagnostics.to_dict() if res.diagnostics is not None else None}
    if infers_sigma(model):
        s = model.noise_sigma(data, pot.to_constrained(res.z))
        meta["noise_sigma"] = float(s.mean())
    if noise_level is not None:
        meta["noise_level"] = noise_level.to_dict()
    if gains is not None:
        meta["view_gains"] = gains.to_dict()
    var = getattr(data.observations, "variance", None)
    if var is not None and tuple(var.shape) == tuple(data.images.shape):   # photos a Monte Carlo renderer made
        w = data.weight > 0
        meta["render_noise"] = float(var.to(data.device)[w].double().mean())
    post = Posterior(pot.to_constrained(res.z), energies, z=res.z, meta=meta, potential=pot, model=model,
                     log={"seconds": res.seconds, "resumed_from": res.resumed_from, "steps": res.steps},
                     surface=data.observations.surface)
    if map_steps is None:
        map_steps = min(300, res.steps)
    if map_steps:
        post.refine_map(map_steps)
    if res.diagnostics is not None and not res.diagnostics.converged:
        warnings.warn(res.diagnostics.message(), ConvergenceWarning, stacklevel=2)
    return post


#: steps of a warm-started run (:func:`update`): the particles start at the earlier posterior
WARM_STEPS = 300


def update(posterior: Posterior, observations: "Observations | ModelData", sampler: "str | dict | object" = "spos",
           *, steps: int = WARM_STEPS, params: dict | None = None, seed: int = 0, **kw) -> Posterior:
    """The posterior after more photos: ``posterior`` (of the same model) brought up to date with
    ``observations`` (the photos it was fitted on plus the new ones), warm-started from its particles.

    The sampler starts where ``posterior``'s particles are, already near the new posterior (one or a few more
    photos move it a little), so it runs ``steps`` steps (default :data:`WARM_STEPS`, against the preset's
    2000 of a cold run) without annealing (SPOS's and SVGD's ``anneal = false``: the annealing of Eq. 6 lets particles
    drift from a prior draw before the data pull; from a posterior it would only throw the start away).
    Everything else is :func:`infer`'s (``kw``: ``checkpoint``, ``progress``, ``map_steps``, ...): the noise
    level is estimated again, the convergence checks run. This is what ``bayes-brdf recommend --from RUN``
    does before it scores the next views (docs/guidance.md has the measured time and agreement with a cold run).

    Example:
        >>> import bayes_brdf as bb
        >>> from bayes_brdf.render import SVBRDF, PlanarSample, collocated_views
        >>> from bayes_brdf.render.shade import render
        >>> views = collocated_views(4, 3.0, camera="rectified", resolution=8)
        >>> obs = bb.Observations(views, render(SVBRDF.constant(0.5, 0.3), views, PlanarSample(2.0))[0], PlanarSample(2.0))
        >>> m = bb.models.homogeneous(albedo="gray")
        >>> first = bb.infer(m, obs.subset([0, 1, 2]), "spos", steps=300, progress=False)
        >>> more = bb.inference.update(first, obs, steps=100, progress=False)
        >>> abs(float(more.mean("albedo")) - 0.5) < 0.05, more.meta["steps"]
        (True, 100)
    """
    if posterior.z is None or posterior.model is None:
        raise InputError("this posterior has no particles or no model to start from",
                         fix="use a posterior written by bb.infer or by fit/infer/recommend (posterior.safetensors)")
    return infer(posterior.model, observations, sampler, steps=steps, params=warm_params(sampler, params), seed=seed,
                 z0=posterior.z, **kw)


def warm_params(sampler, params: dict | None = None) -> dict:
    """The sampler overrides of a warm start (:func:`update`, ``recommend --from``): ``params`` with
    ``anneal = false`` when ``sampler`` (a name, a preset file, a table or a sampler) anneals (SPOS, SVGD) and
    ``params`` does not say otherwise.

    Example:
        >>> warm_params("spos"), warm_params("emcee"), warm_params("spos", {"anneal": True})
        ({'anneal': False}, {}, {'anneal': True})
    """
    anneals = hasattr(make_sampler(sampler)[0], "anneal")
    return {**({"anneal": False} if anneals else {}), **(params or {})}
