"""bayes-brdf: Bayesian SVBRDF acquisition with uncertainty and capture guidance."""
from . import guidance, io, materials, models, render, samplers, uncertainty
from .errors import InputError
from .inference import infer
from .models import priors
from .observations import Observations
from .posterior import Posterior

__version__ = "0.1.0"
__all__ = ["render", "uncertainty", "guidance", "io", "materials", "models", "priors", "samplers", "infer", "Posterior", "Observations",
           "InputError", "__version__"]
