"""What a material model conditions on: the G-buffer of the observed views, the images and pixel weights."""
from __future__ import annotations

from dataclasses import dataclass, replace

import torch
from torch import Tensor

from .. import checks
from ..errors import InputError
from ..observations import Observations
from ..render.gbuffer import GBUFFERS, GBuffer


@dataclass
class Censored:
    """The saturated pixels of the observations, for a censored likelihood.

    A photo clips at its maximum code, so where it saturated the radiance is at
    least what was recorded: ``level [K, 3]`` is that lower bound per channel
    (the recorded value: exact for a clipped channel, conservative for the
    others and for a downsampled pixel that averages clipped and unclipped
    photo pixels). ``gbuffer`` is their geometry as one ``1 x K`` view
    (:meth:`GBuffer.gather`), ``view [K]`` the view each came from and
    ``weight [K]`` 1, or 0 for pixels a minibatch leaves out.
    """

    gbuffer: GBuffer
    level: Tensor
    view: Tensor
    weight: Tensor
    noise: Tensor | None = None     # [K] relative noise scale (signal-dependent noise), or None

    @classmethod
    def from_pixels(cls, g: GBuffer, images: Tensor, pixels: Tensor) -> "Censored | None":
        if not bool(pixels.any()):
            return None
        v = pixels.nonzero(as_tuple=True)[0]
        return cls(g.gather(pixels), images[pixels].contiguous(), v, torch.ones(len(v), dtype=images.dtype,
                                                                               device=images.device))

    @property
    def count(self) -> int:
        return int(self.weight.count_nonzero())

    def views_index(self, idx: Tensor) -> "Censored | None":
        """The censored pixels of views ``idx`` (renumbered as in the minibatch)."""
        idx = idx.to(self.view.device)
        keep = (self.view[:, None] == idx[None]).any(1)
        if not bool(keep.any()):
            return None
        new = torch.searchsorted(idx, self.view[keep])
        return Censored(self.gbuffer.gather(keep[None, None]), self.level[keep], new, self.weight[keep],
                        None if self.noise is None else self.noise[keep])


@dataclass
class ModelData:
    """Observed images with their geometry, ready for a model's likelihood.

    ``images [V, H, W, 3]`` linear radiance; ``weight [V, H, W]`` is 1 on
    pixels that are fitted and 0 on pixels that are not (outside the sample,
    masked out, or saturated); ``censored`` holds the saturated pixels apart (a
    clipped pixel only bounds the radiance from below: see :class:`Censored`);
    ``scale`` multiplies the log-likelihood (``V / |batch|`` for a minibatch of
    views, ``1 / fraction`` for a pixel subsample) so that stochastic gradients
    are unbiased. ``noise [V, H, W]`` (``None``: one scale everywhere) is each pixel's relative noise
    scale ``g`` under signal-dependent noise (:mod:`bayes_brdf.models.noise`): the likelihood's scale
    there is ``sigma * g``.

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
    censored: Censored | None = None
    noise: Tensor | None = None

    @classmethod
    def from_observations(cls, obs: Observations, *, dtype=torch.float32, device=None) -> "ModelData":
        if not isinstance(obs, Observations):
            raise InputError(f"expected Observations, got {type(obs).__name__}",
                             fix="load a capture with bb.io.load_capture(path)")
        device = torch.device(device) if device is not None else obs.images.device
        g = GBUFFERS.get(tuple(obs.views), obs.surface, dtype=dtype, device=device)
        w = g.mask.clone()
        if obs.mask is not None:
            w &= obs.mask.to(device)
        sat = torch.zeros_like(w)
        if obs.saturated is not None:
            sat = w & obs.saturated.to(device)
            w &= ~sat
        if not bool(w.any()):
            raise InputError("no usable pixel in the observations (all masked, saturated or off the sample)")
        imgs = obs.images.to(device=device, dtype=dtype)
        if not bool(torch.isfinite(imgs[w | sat]).all()):
            raise InputError("the observed images contain NaN or infinite values on usable pixels",
                             fix="mask those pixels out (Observations.mask)")
        return cls(g, imgs.contiguous(), w.to(dtype), obs, censored=Censored.from_pixels(g, imgs, sat))

    def noise_weight(self, kind: str = "laplace") -> Tensor:
        """The pixel weights of the residual sum: ``weight / g`` (Laplace) or ``weight / g^2`` (Gaussian)."""
        if self.noise is None:
            return self.weight
        # made once per kind and kept while the same tensors hold the same values: the likelihood asks every step,
        # and the mesh path keeps its compacted copy of the weights only while the same tensor comes again
        w, g = self.weight, self.noise
        memo = self.__dict__.setdefault("_noise_weight", {})
        hit = memo.get(kind)
        if hit is None or hit[0] is not w or hit[1] is not g or hit[2] != (w._version, g._version):
            hit = memo[kind] = (w, g, (w._version, g._version), w / (g if kind == "laplace" else g * g))
        return hit[3]

    def noise_log_norm(self) -> Tensor | float:
        """``sum w log g`` over pixels and channels: the normalising term of the per-pixel scales (0 without)."""
        return 0.0 if self.noise is None else 3 * (self.weight * self.noise.log()).sum()

    def with_noise(self, relative: Tensor, censored: Tensor | None = None) -> "ModelData":
        """A copy whose pixels have relative noise scales ``relative [V, H, W]`` (and ``censored [K]`` for
        the saturated pixels, in the order of :attr:`censored`)."""
        relative = torch.as_tensor(relative, dtype=self.dtype, device=self.device)
        if tuple(relative.shape) != tuple(self.weight.shape) or not bool((relative[self.weight > 0] > 0).all()):
            raise InputError(f"relative noise scales must be positive and of shape {tuple(self.weight.shape)}")
        c = self.censored
        if c is not None:
            c = replace(c, noise=None if censored is None else torch.as_tensor(censored).to(c.level))
        return replace(self, noise=relative.clamp_min(1e-6).contiguous(), censored=c)

    def with_gains(self, gains: Tensor) -> "ModelData":
        """A copy whose photos are divided by their views' gains ``gains [V]`` (each photo's overall brightness,
        :mod:`bayes_brdf.models.gains`): the saturated pixels' lower bounds too."""
        g = torch.as_tensor(gains, dtype=self.dtype, device=self.device).reshape(-1)
        if g.shape[0] != self.num_views or not bool((g > 0).all()):
            raise InputError(f"view gains must be {self.num_views} positive numbers, got {tuple(g.shape)}")
        c = self.censored
        if c is not None:
            c = replace(c, level=(c.level / g[c.view.to(self.device)][:, None]).contiguous())
        return replace(self, images=(self.images / g.view(-1, 1, 1, 1)).contiguous(), censored=c)

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
            checks.count(views, "minibatch views", least=1)
            idx = torch.randperm(self.num_views, generator=generator)[:views].sort().values
            d = replace(d, gbuffer=d.gbuffer.views_index(idx), images=d.images[idx.to(d.device)],
                        weight=d.weight[idx.to(d.device)],
                        noise=None if d.noise is None else d.noise[idx.to(d.device)],
                        censored=None if d.censored is None else d.censored.views_index(idx))
            scale *= self.num_views / views
        if pixels is not None and pixels < 1.0:
            checks.fraction(pixels, "minibatch pixel fraction")
            keep = torch.rand(d.weight.shape, generator=generator) < pixels
            d = replace(d, weight=d.weight * keep.to(d.device, d.dtype))
            if d.censored is not None:
                c = d.censored
                kc = torch.rand(c.weight.shape, generator=generator) < pixels
                d = replace(d, censored=replace(c, weight=c.weight * kc.to(c.weight.device, c.weight.dtype)))
            scale /= pixels
        return replace(d, scale=scale)
