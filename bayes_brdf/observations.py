"""Observations: the photos (or renders) a posterior is conditioned on.

An :class:`Observations` bundle holds, for ``V`` views of one sample:

* ``views``  -- list of :class:`~bayes_brdf.render.views.View` (camera + lights)
* ``images`` -- ``[V, H, W, 3]`` linear radiance (float32)
* ``surface`` -- what the cameras look at (a :class:`PlanarSample` or a :class:`~bayes_brdf.render.mesh.Mesh`);
  with the views it is the :attr:`Observations.scene`
* ``mask``   -- ``[V, H, W]`` bool, ``True`` where a pixel is usable (optional)
* ``saturated`` -- ``[V, H, W]`` bool, ``True`` where the photo clipped at its
  maximum in any channel: the value is only a lower bound on the radiance (optional)
* ``variance`` -- ``[V, H, W, 3]`` the variance of each pixel's value that the renderer itself left (a Monte
  Carlo render's own noise, e.g. ``bayes-brdf render --integrator path``), added to the photo noise by the
  likelihood and the predictive (optional; :mod:`bayes_brdf.models.noise`)
* ``meta``   -- free-form provenance (source format, path, units, gamma, ...)
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import torch
from torch import Tensor

from .errors import InputError
from .render.scene import Scene
from .render.surface import PlanarSample
from .render.views import View


@dataclass
class Observations:
    """Images ``[V, H, W, 3]`` (linear) with their views and the surface they show.

    Example:
        >>> from bayes_brdf.render.views import collocated_views
        >>> vs = collocated_views(2, radius=3.0, resolution=8)
        >>> obs = Observations(vs, torch.zeros(2, 8, 8, 3), PlanarSample(2.0))
        >>> len(obs), obs.resolution
        (2, (8, 8))
    """

    views: list[View]
    images: Tensor
    surface: object = field(default_factory=PlanarSample)
    mask: Tensor | None = None
    saturated: Tensor | None = None
    meta: dict = field(default_factory=dict)
    variance: Tensor | None = None

    def __post_init__(self):
        self.views = list(self.views)
        im = self.images
        if im.dim() != 4 or im.shape[-1] != 3:
            raise InputError(f"observation images have shape {tuple(im.shape)}, expected [V, H, W, 3]")
        if im.shape[0] != len(self.views):
            raise InputError(f"{im.shape[0]} images but {len(self.views)} views",
                             fix="give exactly one view (pose + light) per image")
        for v in self.views:
            if tuple(v.resolution) != tuple(im.shape[1:3]):
                raise InputError(f"view '{v.name}' has resolution {v.resolution} but the images are {tuple(im.shape[1:3])}")
        for name in ("mask", "saturated"):
            m = getattr(self, name)
            if m is not None and tuple(m.shape) != tuple(im.shape[:3]):
                raise InputError(f"{name} has shape {tuple(m.shape)}, expected {tuple(im.shape[:3])}")
        v = self.variance
        if v is not None:
            if tuple(v.shape) != tuple(im.shape):
                raise InputError(f"variance has shape {tuple(v.shape)}, expected {tuple(im.shape)}")
            if not bool(torch.isfinite(v).all()) or bool((v < 0).any()):
                raise InputError("the render variance has negative or non-finite values",
                                 fix="give each pixel's Monte Carlo variance (>= 0)")

    @property
    def scene(self) -> Scene:
        """The geometry and the views of these observations, as one :class:`~bayes_brdf.render.scene.Scene`."""
        return Scene(self.surface, tuple(self.views))

    def __len__(self) -> int:
        return len(self.views)

    @property
    def resolution(self) -> tuple[int, int]:
        return tuple(self.images.shape[1:3])

    def subset(self, idx) -> "Observations":
        """The observations of views ``idx`` (a list of indices), e.g. for fit / hold-out splits."""
        idx = list(idx)
        for i in idx:
            if not -len(self) <= i < len(self):
                raise InputError(f"view index {i} out of range for {len(self)} views", fix=f"use 0..{len(self) - 1}")
        t = torch.as_tensor(idx, dtype=torch.long)
        pick = lambda x: None if x is None else x[t]  # noqa: E731
        return replace(self, views=[self.views[i] for i in idx], images=self.images[t],
                       mask=pick(self.mask), saturated=pick(self.saturated), meta=dict(self.meta),
                       variance=pick(self.variance))

    def append(self, other: "Observations") -> "Observations":
        """These observations followed by ``other``'s (same surface and resolution), e.g. a new capture round."""
        if tuple(other.resolution) != tuple(self.resolution):
            raise InputError(f"cannot append {other.resolution} images to {self.resolution} observations",
                             fix="capture the new views at the resolution of the existing ones")
        if other.surface != self.surface:
            raise InputError("cannot append observations of a different surface")
        dev = self.images.device

        def cat(a, b, fill):
            if a is None and b is None:
                return None
            a = a if a is not None else torch.full(self.images.shape[:3], fill, dtype=torch.bool, device=dev)
            b = b if b is not None else torch.full(other.images.shape[:3], fill, dtype=torch.bool, device=dev)
            return torch.cat([a.to(dev), b.to(dev)])
        var = None
        if self.variance is not None or other.variance is not None:       # a photo without one: no render noise
            zero = lambda o: torch.zeros_like(o.images, device=dev)  # noqa: E731
            var = torch.cat([(self.variance if self.variance is not None else zero(self)).to(dev),
                             (other.variance if other.variance is not None else zero(other)).to(dev)])
        return replace(self, views=self.views + list(other.views),
                       images=torch.cat([self.images, other.images.to(dev, self.images.dtype)]),
                       mask=cat(self.mask, other.mask, True), saturated=cat(self.saturated, other.saturated, False),
                       meta=dict(self.meta), variance=var)

    def to(self, *args, **kwargs) -> "Observations":
        mv = lambda x: None if x is None else x.to(*args, **{k: v for k, v in kwargs.items() if k != "dtype"})  # noqa: E731
        return replace(self, images=self.images.to(*args, **kwargs), mask=mv(self.mask), saturated=mv(self.saturated),
                       variance=None if self.variance is None else self.variance.to(*args, **kwargs))
