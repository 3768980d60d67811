"""Material models as Pyro model functions, their priors and the likelihood of Eq. (2).

A model is any Pyro function ``model(data)`` of a :class:`ModelData` whose latent
sites are the material parameters and which ends with :func:`observe`. The
built-ins are :func:`homogeneous` and :func:`per_texel`; a user's own model is
just another such function (see ``docs/models.md``).
"""
from . import priors
from .data import ModelData
from .likelihood import RenderedImages, observe
from .material import Homogeneous, MaterialModel, PerTexel, from_preset, homogeneous, per_texel

__all__ = ["priors", "ModelData", "RenderedImages", "observe", "homogeneous", "per_texel", "MaterialModel",
           "Homogeneous", "PerTexel", "from_preset"]
