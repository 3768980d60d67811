"""bayes-brdf: Bayesian SVBRDF acquisition with uncertainty and capture guidance.

The subpackages and the names below load on first use (PEP 562), so ``import bayes_brdf``
and ``bayes-brdf --help`` do not pay for torch, Pyro and Mitsuba until they are needed.
"""
from __future__ import annotations

import importlib

__version__ = "0.1.0"

_SUBMODULES = ("render", "uncertainty", "plots", "guidance", "io", "materials", "models", "samplers", "experiments",
               "inference", "posterior", "observations", "errors", "presets", "identity", "potential", "report")
_NAMES = {"infer": "inference", "Posterior": "posterior", "Observations": "observations", "InputError": "errors",
          "priors": "models.priors"}
__all__ = ["render", "uncertainty", "plots", "guidance", "io", "materials", "models", "priors", "samplers", "infer",
           "Posterior", "Observations", "InputError", "__version__"]


def __getattr__(name: str):
    if name in _NAMES:
        mod = importlib.import_module(f".{_NAMES[name]}", __name__)
        value = mod if name == "priors" else getattr(mod, name)
    elif name in _SUBMODULES:
        value = importlib.import_module(f".{name}", __name__)
    else:
        raise AttributeError(f"module 'bayes_brdf' has no attribute '{name}'")
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(_NAMES) | set(_SUBMODULES))
