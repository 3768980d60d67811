"""Material models as Pyro model functions, their priors and the likelihood of Eq. (2).

A model is any Pyro function ``model(data)`` of a :class:`ModelData` whose latent
sites are the material parameters and which ends with :func:`observe`. The
built-ins are :func:`homogeneous`, :func:`per_texel`, :func:`metallic_roughness` (glTF's base colour,
metallic, roughness) and :func:`latent_decoder` (maps decoded by a StyleGAN2 generator from W+ and noise); a
user's own model is just another such function.
What downstream code needs from a model beyond that is the small protocol of
:mod:`bayes_brdf.models.base` (``maps``, ``latent_sites``, ``noise_sigma``, ``initial_values``,
``to_dict``; see ``docs/models.md``).
"""
from . import priors
from .data import ModelData
from .likelihood import RenderedImages, observe
from .base import MAPS, ObservedModel, offers_maps
from .latent_decoder import LatentDecoder, latent_decoder
from .material import Homogeneous, MaterialModel, PerTexel, from_preset, homogeneous, per_texel
from .metallic import MetallicRoughness, metallic_roughness
from .materialgan_checkpoint import load_materialgan_checkpoint
from .stylegan import Generator, GeneratorConfig

__all__ = ["priors", "ModelData", "RenderedImages", "observe", "homogeneous", "per_texel", "latent_decoder",
           "metallic_roughness", "MaterialModel", "ObservedModel", "Homogeneous", "PerTexel", "LatentDecoder",
           "MetallicRoughness", "from_preset", "MAPS",
           "offers_maps", "Generator", "GeneratorConfig", "load_materialgan_checkpoint"]
