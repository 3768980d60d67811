"""What a material model conditions on: the G-buffer of the observed views, the images and pixel weights."""
from __future__ import annotations

from dataclasses import dataclass, replace

import torch
from torch import Tensor

from ..errors import InputError
from ..observations import Observations
from ..render.gbuffer import GBuffer, GBufferCache

_CACHE = GBufferCache()


@dataclass
class ModelData:
    """Observed images with their geometry, ready for a model's likelihood.

    ``images [V, H, W, 3]`` linear radiance; ``weight [V, H, W]`` is 1 on
    pixels that count and 0 on pixels that do not (outside the sample, masked
    out, or saturated: a clipped pixel only bounds the radiance from below, so it
    is left out rather than fitted); ``scale`` multiplies the log-likelihood
    (``V / |batch|`` for a minibatch of views, ``1 / fraction`` for a pixel
    subsample) so that stochastic gradients are unbiased.

    Example:
        >>> from bayes_brdf.render.views import collocated_views
        >>> obs = Observations(collocated_views(3, 3.0, resolution=8), torch.zeros(3, 8, 8, 3))
        >>> d = ModelData.from_observations(obs)
        >>> d.images.shape, float(d.weight.sum())
        (torch.Size([3, 8, 8, 3]), 101.0)
    """

    gbuffer: GBuffer
    images: Tensor
    weight: Tensor
    observations: Observations
    scale: float = 1.0

    @classmethod
    def from_observations(cls, obs: Observations, *, dtype=torch.float32, device=None) -> "ModelData":
        if not isinstance(obs, Observations):
            raise InputError(f"expected Observations, got {type(obs).__name__}",
                             fix="load a capture with bb.io.load_capture(path).observations")
        device = torch.device(device) if device is not None else obs.images.device
        g = _CACHE.get(tuple(obs.views), obs.surface, dtype=dtype, device=device)
        w = g.mask.clone()
        if obs.mask is not None:
            w &= obs.mask.to(device)
        if obs.saturated is not None:
            w &= ~obs.saturated.to(device)
        if not bool(w.any()):
            raise InputError("no usable pixel in the observations (all masked, saturated or off the sample)")
        imgs = obs.images.to(device=device, dtype=dtype)
        if not bool(torch.isfinite(imgs[w]).all()):
            raise InputError("the observed images contain NaN or infinite values on usable pixels",
                             fix="mask those pixels out (Observations.mask)")
        return cls(g, imgs.contiguous(), w.to(dtype), obs)

    @property
    def num_views(self) -> int:
        return self.images.shape[0]

    @property
    def dtype(self):
        return self.images.dtype

    @property
    def device(self):
        return self.images.device

    def minibatch(self, generator: torch.Generator, *, views: int | None = None,
                  pixels: float | None = None) -> "ModelData":
        """A random minibatch: ``views`` of the views (without replacement) and/or a ``pixels`` fraction of pixels.

        The log-likelihood is rescaled by ``V / views`` and ``1 / pixels`` so its
        expectation over minibatches is the full log-likelihood.
        """
        d, scale = self, self.scale
        if views is not None and views < self.num_views:
            if views < 1:
                raise InputError(f"minibatch views must be >= 1, got {views}")
            idx = torch.randperm(self.num_views, generator=generator)[:views].sort().values
            d = replace(d, gbuffer=d.gbuffer.views_index(idx), images=d.images[idx.to(d.device)],
                        weight=d.weight[idx.to(d.device)])
            scale *= self.num_views / views
        if pixels is not None and pixels < 1.0:
            if not 0.0 < pixels:
                raise InputError(f"minibatch pixel fraction must be in (0, 1], got {pixels}")
            keep = torch.rand(d.weight.shape, generator=generator) < pixels
            d = replace(d, weight=d.weight * keep.to(d.device, d.dtype))
            scale /= pixels
        return replace(d, scale=scale)
