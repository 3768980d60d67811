"""bayes-brdf: Bayesian SVBRDF acquisition with uncertainty and capture guidance."""
from . import io, materials, render
from .errors import InputError
from .observations import Observations

__version__ = "0.1.0"
__all__ = ["render", "io", "materials", "Observations", "InputError", "__version__"]
