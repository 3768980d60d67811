"""Interchangeable posterior samplers with one init/step contract and one driver.

=================  ===========================================================
``spos``           stochastic particle-optimisation sampling (Eqs. 4-6)
``svgd``           Stein variational gradient descent
``sgld``           stochastic-gradient Langevin dynamics
``emcee``          ensemble MH (stretch move) through emcee, gradient-free
``multistart_sgd`` independent Adam/SGD point estimates from prior draws
``nuts``           Pyro's NUTS, one chain (a low-dimensional reference)
=================  ===========================================================

:func:`make_sampler` builds one from a name, a preset file (top-level
``samplers/*.toml``) or a table; :func:`~bayes_brdf.samplers.driver.run` runs it.
"""
from __future__ import annotations

import sys
from dataclasses import dataclass, fields

from ..errors import InputError
from ..presets import load_preset
from .base import Info, Sampler
from .driver import Interrupted, RunResult, SamplerDiverged, run
from .ensemble import Emcee
from .multistart import MultistartSGD
from .nuts import NUTS
from .sgld import SGLD
from .spos import SPOS
from .svgd import SVGD

#: old preset names: ``{old: (new, the one line printed when the old one is used)}``
DEPRECATED_ALIASES = {"spos_maps": ("spos", "the sampler preset 'spos_maps' is deprecated: 'spos' is now calibrated "
                                            "on per-texel maps as well (docs/samplers.md); using 'spos'")}

SAMPLERS = {c.name: c for c in (SPOS, SVGD, SGLD, Emcee, MultistartSGD, NUTS)}


@dataclass
class RunConfig:
    """How long and how big a run is (the ``[run]`` table of a sampler preset)."""

    particles: int = 20
    steps: int = 1000
    checkpoint_every: int = 100
    minibatch_views: int = 0        # 0: all views every step
    minibatch_pixels: float = 1.0   # fraction of pixels per step (1: all)
    init_margin: float = 0.0        # keep prior draws this fraction of each bounded range off its bounds
    auto_steps: bool = False        # bb.infer with no steps given runs steps="auto" (a quarter of steps, then more
    #                                 until the convergence checks pass, at most 4 x steps); a number given: fixed

    def __post_init__(self):
        for k in ("particles", "steps"):
            v = getattr(self, k)
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise InputError(f"run.{k} must be a positive integer, got {v!r}")
        if isinstance(self.checkpoint_every, bool) or not isinstance(self.checkpoint_every, int) \
                or self.checkpoint_every < 0:
            raise InputError(f"run.checkpoint_every must be an integer >= 0, got {self.checkpoint_every!r}")
        if isinstance(self.minibatch_views, bool) or not isinstance(self.minibatch_views, int) \
                or self.minibatch_views < 0:
            raise InputError(f"run.minibatch_views must be an integer >= 0, got {self.minibatch_views!r}")
        if not isinstance(self.minibatch_pixels, (int, float)) or not 0 < self.minibatch_pixels <= 1:
            raise InputError(f"run.minibatch_pixels must be in (0, 1], got {self.minibatch_pixels!r}")
        if isinstance(self.init_margin, bool) or not isinstance(self.init_margin, (int, float)) \
                or not 0 <= self.init_margin < 0.5:
            raise InputError(f"run.init_margin must be in [0, 0.5), got {self.init_margin!r}")
        if not isinstance(self.auto_steps, bool):
            raise InputError(f"run.auto_steps must be true or false, got {self.auto_steps!r}")

    def run_kwargs(self) -> dict:
        return {"particles": self.particles, "steps": self.steps, "checkpoint_every": self.checkpoint_every,
                "minibatch_views": self.minibatch_views or None,
                "minibatch_pixels": None if self.minibatch_pixels == 1 else float(self.minibatch_pixels),
                "init_margin": float(self.init_margin)}


def make_sampler(spec="spos", params: dict | None = None, run: dict | None = None) -> tuple[Sampler, RunConfig]:
    """``(sampler, run config)`` from a name (``"spos"``), a preset path, a preset table or a ``Sampler``.

    ``params`` / ``run`` override the preset's ``[params]`` / ``[run]`` entries.

    Example:
        >>> s, cfg = make_sampler("spos", params={"step_size": 0.02}, run={"steps": 10})
        >>> s.step_size, cfg.steps, cfg.particles
        (0.02, 10, 20)
    """
    if isinstance(spec, Sampler):
        return spec, _run_config(run or {})
    if isinstance(spec, dict):
        table = dict(spec)
    else:
        name = DEPRECATED_ALIASES.get(str(spec), (str(spec),))[0]
        if name != str(spec):
            print(f"note: {DEPRECATED_ALIASES[str(spec)][1]}", file=sys.stderr)
        table = load_preset("samplers", name) if not (name in SAMPLERS and _no_preset(name)) else {"sampler": name}
    extra = set(table) - {"sampler", "params", "run", "description"}
    if extra:
        raise InputError(f"unknown key(s) {sorted(extra)} in the sampler preset",
                         fix="use sampler = ..., [params] and [run]")
    name = table.get("sampler")
    if name not in SAMPLERS:
        raise InputError(f"unknown sampler {name!r}", fix=f"use one of {', '.join(SAMPLERS)}")
    p = {**table.get("params", {}), **(params or {})}
    r = {**table.get("run", {}), **(run or {})}
    return SAMPLERS[name].from_params(p), _run_config(r)


def _no_preset(name: str) -> bool:
    from ..presets import list_presets
    return name not in list_presets("samplers")


def _run_config(r: dict) -> RunConfig:
    allowed = {f.name for f in fields(RunConfig)}
    extra = set(r) - allowed
    if extra:
        raise InputError(f"unknown key(s) {sorted(extra)} in [run]", fix=f"allowed: {sorted(allowed)}")
    return RunConfig(**r)


__all__ = ["Sampler", "Info", "SPOS", "SVGD", "SGLD", "Emcee", "MultistartSGD", "NUTS", "SAMPLERS", "make_sampler",
           "RunConfig", "run", "RunResult", "SamplerDiverged", "Interrupted"]
