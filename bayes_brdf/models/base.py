"""The model protocol: what downstream code (posterior, uncertainty, guidance, CLI) needs from a material model.

A material model is a Pyro function ``model(data)``. Everything beyond "run me under a
particle plate" goes through these few members, all optional for a user's own
function (see docs/models.md, "The model protocol"):

* ``maps(values) -> SVBRDF`` -- the maps rendered for site values ``{site: [n, ...]}``
  (a particle dimension in, a particle dimension out). With it, ``Posterior.std``,
  ``maps``, Eq. 11 and guidance work in *map space*: for the per-texel model a site
  is a map, for the latent decoder the maps are decoded from W+ and noise.
* ``parameter_maps(values) -> {name: map}`` -- where the maps a user reads are not the renderer's
  (``metallic_roughness``: base colour, metallic, roughness rather than ``kd`` and ``F0``): what
  ``Posterior.std()`` summarises.
* ``latent_sites() -> list[str]`` -- the names of its latent sites.
* ``noise_sigma(data, values) -> [n]`` and ``sigma`` -- its noise level: a fixed number,
  or ``"auto"`` when it is inferred (then the posterior records the inferred value).
* ``pixel_noise`` -- ``"signal"`` (under ``sigma = "auto"``: a per-pixel scale that grows with the
  radiance, its shape estimated after the burn-in, :mod:`bayes_brdf.noise_estimate`) or ``"constant"``.
* ``view_gain`` -- ``"estimated"`` (under ``pixel_noise = "signal"``: each photo's overall brightness is a
  nuisance gain estimated after the burn-in, :mod:`bayes_brdf.models.gains`) or ``"none"``.
* ``initial_values(data, n, seed) -> {site: [n, ...]}`` -- where samplers start, for a
  model whose prior cannot be sampled (a flat prior) or whose prior draws are poor starts
  (the latent decoder projects the photos into its latent space).
* ``to_dict() -> dict`` -- its configuration (recorded in the posterior and the run identity;
  with ``model = <kind>`` it rebuilds the model through :func:`bayes_brdf.models.from_preset`).

:class:`ObservedModel` is the base of the built-ins: the likelihood options (``sigma``,
``likelihood``, ``saturated``, ``backend``) and ``__call__ = observe(maps(sample_sites(data)))``.

Example:
    >>> from bayes_brdf.models import per_texel
    >>> offers_maps(per_texel(8)), offers_maps(lambda data: None)
    (True, False)
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import torch
from torch import Tensor

from ..errors import InputError
from .data import ModelData
from .likelihood import KINDS, RenderedImages, check_saturated, check_sigma, observe
from .gains import check_view_gain
from .noise import check_pixel_noise

#: the maps of an SVBRDF, in the order of the map-space summaries
MAPS = ("albedo", "roughness", "specular", "normal")


def offers_maps(model) -> bool:
    """Whether ``model`` turns site values into maps (the map-space summaries need it)."""
    return callable(getattr(model, "maps", None))


def describe(model):
    """A model's configuration as the posterior records it: ``to_dict()`` (as in the run identity,
    :func:`bayes_brdf.identity.model_description`), else the function's name."""
    from ..identity import model_description
    d = model_description(model)
    return d if isinstance(d, dict) else getattr(model, "__name__", str(model))


def infers_sigma(model) -> bool:
    """Whether the model's noise level is inferred (``sigma = "auto"``) and it can report it (``noise_sigma``)."""
    return getattr(model, "sigma", None) == "auto" and callable(getattr(model, "noise_sigma", None))


@dataclass
class ObservedModel:
    """The likelihood options every built-in model shares, and its ``__call__``.

    Subclasses define ``sample_sites(data) -> {site: value}`` (the Pyro sample statements),
    ``maps(values) -> SVBRDF`` and ``latent_sites()``.
    """

    sigma: object = "auto"                             # "auto" (inferred, integrated out) or a fixed noise scale
    likelihood: str = "laplace"
    saturated: str = "censored"                        # clipped pixels: "censored" (lower bounds) or "drop"
    backend: str = "auto"
    pixel_noise: str = "signal"                        # "signal": under sigma = "auto", a scale that grows with
    #                                                    the radiance (camera-like); "constant": one scale
    view_gain: str = "none"                            # "estimated": each photo's overall brightness a nuisance
    #                                                    (with pixel_noise = "signal"); "none": as stated

    kind = "model"

    def __post_init__(self):
        check_sigma(self.sigma)
        check_saturated(self.saturated)
        check_pixel_noise(self.pixel_noise)
        check_view_gain(self.view_gain)
        if self.likelihood not in KINDS:
            raise InputError(f"unknown likelihood '{self.likelihood}'", fix=f"use one of {', '.join(KINDS)}")

    def latent_sites(self) -> list[str]:
        raise NotImplementedError

    def sample_sites(self, data: ModelData) -> dict:
        raise NotImplementedError

    def maps(self, values: dict):
        raise NotImplementedError

    def to_dict(self) -> dict:
        d = asdict(self)
        d["model"] = self.kind
        for k, v in list(d.items()):
            if isinstance(v, Tensor):
                d[k] = "fixed map"
        return d

    def __call__(self, data: ModelData):
        values = self.sample_sites(data)
        observe(data, self.maps(values), sigma=self.sigma, kind=self.likelihood, backend=self.backend,
                saturated=self.saturated)

    def noise_sigma(self, data: ModelData, values: dict) -> Tensor:
        """The noise scale per particle ``[n]`` for site values ``{site: [n, ...]}``: the fixed ``sigma``, or
        under ``sigma = "auto"`` the level the residuals show (the mode of sigma given the maps)."""
        n = next(iter(values.values())).shape[0]
        if self.sigma != "auto":
            return torch.full((n,), float(self.sigma), dtype=data.dtype, device=data.device)
        with torch.no_grad():
            return RenderedImages(self.maps(values), data, "auto", self.likelihood, self.backend).sigma_hat(data.images)

    def _fixed(self, value, channels: int, like: Tensor) -> Tensor:
        """A fixed map as a tensor, made once per dtype/device: the renderer caches the geometry
        derived from fixed maps by tensor identity, so a fresh tensor per call would defeat it."""
        key = (id(value) if isinstance(value, Tensor) else repr(value), channels, like.dtype, str(like.device))
        cache = self.__dict__.setdefault("_fixed_cache", {})
        if key not in cache:
            t = torch.as_tensor(value, dtype=like.dtype, device=like.device)
            if t.dim() <= 1:
                t = (t.reshape(-1).expand(channels) if t.numel() == 1 else t).reshape(channels, 1, 1)
            cache[key] = t.contiguous()
        return cache[key]
