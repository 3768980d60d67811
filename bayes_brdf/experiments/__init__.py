"""The paper's experiments, each reproducible from one function and one command.

Every experiment module has ``DESCRIPTION``, ``PRESETS`` (``"small"``: minutes or less on 2 CPU cores,
what CI runs; ``"full"``: the paper-sized run, documented in ``docs/experiments.md``) and
``run(out, preset="small", seed=0, progress=False, **overrides) -> dict``, which writes PNG figures and
``<name>.json`` (the numbers) into ``out`` and returns the numbers. A module may name another
``DEFAULT_PRESET`` (``wiersma``: ``"full"``, the peer's protocol), what the command runs without ``--preset``.

``bayes-brdf experiment NAME [--preset small|full] [--set key=value] --out DIR`` runs one.

Example:
    >>> sorted(EXPERIMENTS)[:2]
    ['fig2', 'fig3']
"""
from __future__ import annotations

import importlib

from ..errors import InputError

#: name -> module (imported on demand)
EXPERIMENTS = {
    "fig2": "bayes_brdf.experiments.fig2_particles",
    "fig3": "bayes_brdf.experiments.fig3_observations",
    "fig4": "bayes_brdf.experiments.fig4_image_space",
    "fig5": "bayes_brdf.experiments.fig5_prior",
    "fig6": "bayes_brdf.experiments.fig6_latent",
    "fig7": "bayes_brdf.experiments.fig7_guided",
    "wiersma": "bayes_brdf.experiments.wiersma",
}


def get(name: str):
    """The experiment module ``name`` (one-line error for an unknown name)."""
    if name not in EXPERIMENTS:
        raise InputError(f"unknown experiment '{name}'", fix=f"use one of {', '.join(sorted(EXPERIMENTS))}")
    return importlib.import_module(EXPERIMENTS[name])


def preset(module, name: str, overrides: dict | None = None) -> dict:
    """The preset table ``name`` of ``module`` with ``overrides`` applied (unknown keys and values that do not
    parse are one-line errors). A setting is parsed as its default's type (int, float), or by the module's
    ``SETTING_TYPES[key]`` where the module has one."""
    if name not in module.PRESETS:
        raise InputError(f"unknown preset '{name}'", fix=f"use one of {', '.join(module.PRESETS)}")
    cfg = dict(module.PRESETS[name])
    types = getattr(module, "SETTING_TYPES", {})
    for k, v in (overrides or {}).items():
        if k not in cfg:
            raise InputError(f"unknown setting '{k}' for this experiment", fix=f"settings: {', '.join(sorted(cfg))}")
        conv = types.get(k) or (type(cfg[k]) if isinstance(cfg[k], (int, float)) and not isinstance(cfg[k], bool)
                                else None)
        try:
            cfg[k] = conv(v) if conv is not None else v
        except InputError:
            raise
        except (TypeError, ValueError):
            raise InputError(f"bad value '{v}' for setting '{k}'", fix=f"give a value like the default {cfg[k]!r}") from None
    return cfg
