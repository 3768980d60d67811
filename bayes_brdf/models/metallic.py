"""The metallic-roughness material model: glTF 2.0's (and Substance's, Blender's) base colour, metallic, roughness.

Sites (per particle, per texel at ``resolution x resolution``): ``base_color`` ``[3, R, R]`` in ``[0, 1]``,
``metallic`` ``[1, R, R]`` in ``[0, 1]``, ``roughness`` ``[1, R, R]`` in ``roughness_range``. They are
rendered through the same microfacet BRDF as every other model (:mod:`bayes_brdf.render.brdf`) with

* diffuse albedo ``kd = base_color (1 - metallic)``,
* specular albedo (Fresnel's ``F0``) ``ks = lerp(dielectric_f0, base_color, metallic)``
  ``= dielectric_f0 (1 - metallic) + base_color metallic`` (``dielectric_f0 = 0.04``, glTF's),
* GGX with ``alpha = roughness^2`` (glTF's perceptual roughness).

So a metal's reflection is tinted by its base colour and it has no diffuse part, a dielectric has a
white 4 % specular and its base colour as diffuse albedo. Where this differs from glTF's reference
BRDF and from Mitsuba's ``principled`` BSDF (docs/models.md): the renderer's diffuse term is
``kd (1 - ks) / pi`` (Schlick's ``F`` at normal incidence, not ``1 - F(v.h)``), its Fresnel the
spherical-Gaussian Schlick form, its masking Smith-Schlick with ``k = alpha / 2`` (glTF: the
height-correlated Smith-GGX; Mitsuba's principled: separable Smith-GGX); ``principled`` also has
specular tint, sheen, clearcoat and transmission (all 0 here) and a dielectric Fresnel for
``metallic = 0`` from its ``specular`` (0.5 gives ``F0 = 0.04``).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import pyro
import torch
from torch import Tensor

from .. import checks
from ..errors import InputError
from ..render.maps import SVBRDF
from . import priors as P
from .base import ObservedModel
from .data import ModelData

#: the sites of :class:`MetallicRoughness`, in the order of its map-space summaries
SITES = ("base_color", "metallic", "roughness")


def metallic_to_svbrdf(base_color: Tensor, metallic: Tensor, roughness: Tensor, normal: Tensor,
                       dielectric_f0: float = 0.04) -> SVBRDF:
    """The renderer's maps of a metallic-roughness material: ``kd = b (1 - m)``, ``ks = f0 (1 - m) + b m``.

    Example:
        >>> b, m = torch.tensor([[[0.9]], [[0.6]], [[0.2]]]), torch.tensor([[[1.0]]])
        >>> s = metallic_to_svbrdf(b, m, torch.tensor([[[0.3]]]), torch.tensor([[[0.0]], [[0.0]], [[1.0]]]))
        >>> s.albedo.flatten().tolist(), [round(x, 6) for x in s.specular.flatten().tolist()]   # a metal
        ([0.0, 0.0, 0.0], [0.9, 0.6, 0.2])
    """
    kd = base_color * (1 - metallic)
    ks = dielectric_f0 * (1 - metallic) + base_color * metallic
    return SVBRDF(kd, roughness, ks, normal)


@dataclass
class MetallicRoughness(ObservedModel):
    """Per-texel base colour, metallic and roughness maps at ``resolution x resolution`` texels (see the module)."""

    resolution: int = 128
    roughness_range: tuple = (0.05, 1.0)
    dielectric_f0: float = 0.04
    normals: object = "flat"                           # "flat" or a fixed [3, R, R] map
    prior: object = field(default_factory=P.uniform)   # a Prior, or {site: Prior}
    smoothness: object = None                          # a Smoothness, or {site: Smoothness}

    kind = "metallic_roughness"

    def __post_init__(self):
        super().__post_init__()
        checks.count(self.resolution, "resolution", least=1)
        lo, hi = self.roughness_range
        if not 0 < lo < hi <= 1:
            raise InputError(f"roughness_range must satisfy 0 < low < high <= 1, got {self.roughness_range}")
        if not 0 <= float(self.dielectric_f0) < 1:
            raise InputError(f"dielectric_f0 must be in [0, 1), got {self.dielectric_f0!r}",
                             fix="0.04 is glTF's (an index of refraction of 1.5)")
        if isinstance(self.normals, str) and self.normals != "flat":
            raise InputError(f"normals must be 'flat' or a fixed map for metallic_roughness, got {self.normals!r}")
        if isinstance(self.prior, dict):
            extra = set(self.prior) - set(SITES)
            if extra:
                raise InputError(f"prior for unknown site(s) {sorted(extra)}", fix=f"sites: {', '.join(SITES)}")

    def latent_sites(self) -> list[str]:
        return list(SITES)

    def _prior(self, name: str) -> P.Prior:
        p = self.prior.get(name, P.uniform()) if isinstance(self.prior, dict) else self.prior
        return P.from_dict(p)

    def sample_sites(self, data: ModelData) -> dict:
        R = self.resolution
        out = {}
        for name, c in (("base_color", 3), ("metallic", 1), ("roughness", 1)):
            lo, hi = tuple(self.roughness_range) if name == "roughness" else (0.0, 1.0)
            d = self._prior(name).distribution((c, R, R), lo, hi, dtype=data.dtype, device=data.device)
            out[name] = pyro.sample(name, d)
        P.add_smoothness(out, self.smoothness)
        return out

    def maps(self, values: dict) -> SVBRDF:
        b = values["base_color"]
        nrm = self._fixed((0.0, 0.0, 1.0) if isinstance(self.normals, str) else self.normals, 3, b)
        return metallic_to_svbrdf(b, values["metallic"], values["roughness"], nrm, float(self.dielectric_f0))

    def parameter_maps(self, values: dict) -> dict:
        """The maps a user reads and edits, ``{base_color, metallic, roughness}`` (the sites themselves):
        :meth:`bayes_brdf.posterior.Posterior.std` summarises these rather than the renderer's ``kd, ks``."""
        return {k: values[k] for k in SITES}

    def to_dict(self) -> dict:
        d = super().to_dict()
        d["prior"] = ({k: P.from_dict(v).to_dict() for k, v in self.prior.items()} if isinstance(self.prior, dict)
                      else P.from_dict(self.prior).to_dict())
        return d


def metallic_roughness(resolution: int = 128, **kw) -> MetallicRoughness:
    """Per-texel base colour, metallic and roughness (glTF's metallic-roughness convention; see the module).

    Example:
        >>> m = metallic_roughness(16)
        >>> m.latent_sites()
        ['base_color', 'metallic', 'roughness']
    """
    return MetallicRoughness(resolution=resolution, **kw)


__all__ = ["MetallicRoughness", "metallic_roughness", "metallic_to_svbrdf", "SITES"]
