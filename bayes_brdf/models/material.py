"""The built-in material models: ``homogeneous`` (one BRDF) and ``per_texel`` (SVBRDF maps).

Each is a callable Pyro model ``model(data)`` on a :class:`ModelData`, with
latent sites in constrained space and the likelihood of Eq. (2), plus
``model.maps(values)`` that turns site values ``{site: [n, ...]}`` into the
:class:`SVBRDF` that was rendered (for uncertainty maps and re-rendering).

Sites (per particle): ``albedo`` ``[C]`` / ``[C, R, R]`` in ``[0, 1]`` (``C`` = 1 gray
or 3 RGB), ``roughness`` ``[1]`` / ``[1, R, R]`` in ``roughness_range``, optionally
``specular`` ``[1]`` / ``[1, R, R]`` in ``[0, 1]`` and ``normal_slope`` ``[2, R, R]``
(the normal is ``normalize(-sx, -sy, 1)``, prior ``Normal(0, slope_std)``).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import pyro
import pyro.distributions as dist
import torch
from torch import Tensor

from .. import checks
from ..errors import InputError
from ..render.maps import SVBRDF, unit_vectors
from . import priors as P
from .data import ModelData
from .base import MAPS, ObservedModel  # noqa: F401  (MAPS re-exported)


@dataclass
class MaterialModel(ObservedModel):
    """Common options of the microfacet-map models (see :func:`homogeneous` and :func:`per_texel`)."""

    albedo: str = "rgb"                                # "rgb" or "gray"
    roughness_range: tuple = (0.05, 1.0)
    specular: object = 0.04                            # a fixed value / map, or "infer"
    prior: object = field(default_factory=P.uniform)   # a Prior, or {site: Prior}

    def __post_init__(self):
        super().__post_init__()
        if self.albedo not in ("rgb", "gray"):
            raise InputError(f"albedo must be 'rgb' or 'gray', got {self.albedo!r}")
        lo, hi = self.roughness_range
        if not 0 < lo < hi <= 1:
            raise InputError(f"roughness_range must satisfy 0 < low < high <= 1, got {self.roughness_range}")
        if isinstance(self.specular, str) and self.specular != "infer":
            raise InputError(f"specular must be a number, a map or 'infer', got {self.specular!r}")

    # ------------------------------------------------------------------ helpers
    def _prior(self, name: str) -> P.Prior:
        p = self.prior.get(name, P.uniform()) if isinstance(self.prior, dict) else self.prior
        return P.from_dict(p)

    def _range(self, name: str):
        return tuple(self.roughness_range) if name == "roughness" else (0.0, 1.0)

    def _sample(self, name: str, shape, data: ModelData) -> Tensor:
        lo, hi = self._range(name)
        return pyro.sample(name, self._prior(name).distribution(shape, lo, hi, dtype=data.dtype, device=data.device))

    def latent_sites(self) -> list[str]:
        return ["albedo", "roughness"] + (["specular"] if self.specular == "infer" else [])

    def to_dict(self) -> dict:
        d = super().to_dict()
        d["prior"] = ({k: P.from_dict(v).to_dict() for k, v in self.prior.items()} if isinstance(self.prior, dict)
                      else P.from_dict(self.prior).to_dict())
        return d


@dataclass
class Homogeneous(MaterialModel):
    """One BRDF for the whole sample."""

    kind = "homogeneous"

    def sample_sites(self, data: ModelData) -> dict:
        c = 3 if self.albedo == "rgb" else 1
        out = {"albedo": self._sample("albedo", (c,), data), "roughness": self._sample("roughness", (1,), data)}
        if self.specular == "infer":
            out["specular"] = self._sample("specular", (1,), data)
        return out

    def maps(self, values: dict) -> SVBRDF:
        """``SVBRDF`` of ``1 x 1`` maps with a particle dim ``[n, C, 1, 1]`` (or none for unbatched values)."""
        a = values["albedo"]
        px = lambda t: t[..., None, None]  # noqa: E731
        alb = px(a).expand(*a.shape[:-1], 3, 1, 1)
        spec = (px(values["specular"]).expand(*a.shape[:-1], 3, 1, 1) if "specular" in values
                else self._fixed(self.specular, 3, a))
        return SVBRDF(alb, px(values["roughness"]), spec, self._fixed((0.0, 0.0, 1.0), 3, a))


@dataclass
class PerTexel(MaterialModel):
    """Per-texel maps at ``resolution x resolution`` texels."""

    resolution: int = 128
    normals: object = "flat"                           # "flat", "infer" or a fixed [3, R, R] map
    slope_std: float = 0.5
    smoothness: object = None                          # a Smoothness, or {site: Smoothness}

    kind = "per_texel"

    def __post_init__(self):
        super().__post_init__()
        checks.count(self.resolution, "resolution", least=1)
        if isinstance(self.normals, str) and self.normals not in ("flat", "infer"):
            raise InputError(f"normals must be 'flat', 'infer' or a map, got {self.normals!r}")

    def latent_sites(self) -> list[str]:
        return super().latent_sites() + (["normal_slope"] if self.normals == "infer" else [])

    def sample_sites(self, data: ModelData) -> dict:
        R, c = self.resolution, (3 if self.albedo == "rgb" else 1)
        out = {"albedo": self._sample("albedo", (c, R, R), data),
               "roughness": self._sample("roughness", (1, R, R), data)}
        if self.specular == "infer":
            out["specular"] = self._sample("specular", (1, R, R), data)
        if self.normals == "infer":
            loc = torch.zeros(2, R, R, dtype=data.dtype, device=data.device)
            out["normal_slope"] = pyro.sample("normal_slope", dist.Normal(loc, self.slope_std).to_event(3))
        P.add_smoothness(out, self.smoothness)
        return out

    def maps(self, values: dict) -> SVBRDF:
        a = values["albedo"]
        lead = a.shape[:-3]
        alb = a.expand(*lead, 3, *a.shape[-2:])
        spec = (values["specular"].expand(*lead, 3, *a.shape[-2:]) if "specular" in values
                else self._fixed(self.specular, 3, a))
        if "normal_slope" in values:
            s = values["normal_slope"]
            nrm = torch.cat([-s, torch.ones_like(s[..., :1, :, :])], dim=-3)
            nrm = unit_vectors(nrm)
        elif isinstance(self.normals, str):
            nrm = self._fixed((0.0, 0.0, 1.0), 3, a)
        else:
            nrm = self._fixed(self.normals, 3, a)
        return SVBRDF(alb, values["roughness"], spec, nrm)


def homogeneous(**kw) -> Homogeneous:
    """One BRDF for the whole sample: gray or RGB albedo, roughness, optional specular.

    Example:
        >>> m = homogeneous(albedo="gray")
        >>> m.latent_sites()
        ['albedo', 'roughness']
    """
    return Homogeneous(**kw)


def per_texel(resolution: int = 128, **kw) -> PerTexel:
    """Per-texel albedo and roughness at ``resolution^2`` texels; specular and normals fixed or inferred.

    Example:
        >>> m = per_texel(64, specular="infer", smoothness=P.tv(10.0))
        >>> m.latent_sites()
        ['albedo', 'roughness', 'specular']
    """
    return PerTexel(resolution=resolution, **kw)


def _builtin():
    from .latent_decoder import LatentDecoder
    from .metallic import MetallicRoughness
    return {"homogeneous": Homogeneous, "per_texel": PerTexel, "latent_decoder": LatentDecoder,
            "metallic_roughness": MetallicRoughness}


BUILTIN_NAMES = ("homogeneous", "per_texel", "latent_decoder", "metallic_roughness")


def from_preset(table: dict) -> MaterialModel:
    """A model from a preset table (``models/*.toml``): ``model = "per_texel"`` plus its options."""
    t = dict(table)
    name = t.pop("model", None)
    if name not in BUILTIN_NAMES:
        raise InputError(f"unknown model {name!r} in the preset", fix=f"set model = one of {', '.join(BUILTIN_NAMES)}")
    cls = _builtin()[name]
    allowed = {f for f in cls.__dataclass_fields__}
    extra = set(t) - allowed
    if extra:
        raise InputError(f"unknown key(s) {sorted(extra)} in the {name} model preset", fix=f"allowed: {sorted(allowed)}")
    from .metallic import MetallicRoughness
    if not issubclass(cls, (MaterialModel, MetallicRoughness)):      # the latent decoder: its own options
        try:
            return cls(**t)
        except TypeError as e:
            raise InputError(f"bad value in the {name} model preset: {e}") from None
    if "roughness_range" in t:
        t["roughness_range"] = tuple(t["roughness_range"])
    if "prior" in t:
        p = t["prior"]
        t["prior"] = ({k: P.from_dict(v) for k, v in p.items()} if isinstance(p, dict) and "kind" not in p
                      else P.from_dict(p))
    if "smoothness" in t:
        s = t["smoothness"]
        t["smoothness"] = ({k: P.from_dict(v) for k, v in s.items()} if isinstance(s, dict) and "kind" not in s
                           else P.from_dict(s))
    try:
        return cls(**t)
    except TypeError as e:
        raise InputError(f"bad value in the {name} model preset: {e}") from None
