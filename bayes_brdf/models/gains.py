"""Per-view gains: each photo's overall brightness as a nuisance (``view_gain = "estimated"``, an option).

Why: a phone's auto-exposure, a flash whose output varies from shot to shot, or a light a little off its
stated position make a whole photo brighter or darker than the capture's stated light says. Measured on
yellow_box fitted on all nine photos (docs/calibration.md): the median of photo / render over a view's lit
pixels runs from 0.83 to 1.18, a log spread of 0.10, which no choice of maps explains and no noise level
that grows with the radiance predicts (the error is the same fraction of every pixel of the view). Fitted
as if exact, such offsets distort the maps and inflate the noise level; a held-out photo with its own offset
falls outside intervals that never allowed for one.

The model: photo ``v`` is ``g_v R_v(x) + noise``, ``log g_v ~ Normal(0, tau^2)``. The gains are estimated
once, like the noise level's shape (:mod:`bayes_brdf.noise_estimate`): after the burn-in, ``log g_v`` is the
median over the view's lit, usable pixels of ``log(photo / render)`` (channel sums; the render is the
particles' mean), centred so their mean is 0 (the albedo keeps the capture's absolute scale). The fitted
photos are then divided by their gains for the rest of the run. A *new* photo (a held-out view, a novel
view's predictive) has an unknown gain: with ``V`` fitted views whose log gains have sample std ``s``, the
predictive of its log gain is Student's t with ``V - 1`` degrees of freedom and scale ``s sqrt(1 + 1/V)``
(the predictive of one more draw from a normal of unknown mean and variance); :meth:`ViewGains.new_view_nodes`
gives equal-probability nodes of it, over which the predictive of a pixel is averaged.

It is not the default (``view_gain = "none"``): on the three real captures it did not improve the held-out
calibration, because their per-view misfit is not uniform over a photo (docs/calibration.md, "Per-view
gains"). Gains are only estimated from at least :data:`MIN_VIEWS` views with at least :data:`MIN_PIXELS` lit pixels
each: a view of a few pixels would have its whole signal (the BRDF's change with angle) taken for a gain.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from ..errors import InputError

VIEW_GAIN = ("estimated", "none")
#: fewest fitted views, and lit pixels per view, from which gains are estimated
MIN_VIEWS = 3
MIN_PIXELS = 64
#: a pixel is lit when its render is at least this fraction of its view's median render
LIT_FRACTION = 0.5


def check_view_gain(kind) -> None:
    if kind not in VIEW_GAIN:
        raise InputError(f"view_gain must be one of {', '.join(VIEW_GAIN)}, got {kind!r}",
                         fix="\"estimated\": each photo's overall brightness is a nuisance estimated from the photos; "
                             "\"none\": every photo is exactly as bright as the capture states")


@dataclass(frozen=True)
class ViewGains:
    """The fitted views' log gains (mean 0) and the predictive of a new view's.

    Example:
        >>> g = ViewGains((-0.1, 0.0, 0.1))
        >>> round(g.spread, 3), g.dof
        (0.1, 2)
        >>> nodes = g.new_view_nodes(8)
        >>> nodes.shape, round(float(nodes.mean()), 6)
        (torch.Size([8]), 0.0)
    """

    log_gain: tuple

    @property
    def dof(self) -> int:
        return len(self.log_gain) - 1

    @property
    def spread(self) -> float:
        """Sample std of the fitted views' log gains (``ddof = 1``)."""
        x = torch.tensor(self.log_gain, dtype=torch.float64)
        return float(x.std()) if len(x) > 1 else 0.0

    def gains(self) -> Tensor:
        """``g_v`` per fitted view ``[V]`` (float64)."""
        return torch.tensor(self.log_gain, dtype=torch.float64).exp()

    def new_view_nodes(self, k: int = 24) -> Tensor:
        """``k`` equal-probability log gains of a new view (Student's t, ``dof`` degrees of freedom, scale
        ``spread sqrt(1 + 1/V)``), at the quantiles ``(j + 1/2) / k``; ``[0]`` when the spread is 0."""
        s = self.spread * math.sqrt(1 + 1 / len(self.log_gain))
        if not s > 0 or self.dof < 1:
            return torch.zeros(1, dtype=torch.float64)
        from scipy.stats import t

        q = (torch.arange(k, dtype=torch.float64) + 0.5) / k
        return torch.from_numpy(t.ppf(q.numpy(), self.dof)) * s

    def to_dict(self) -> dict:
        return {"log_gain": list(self.log_gain), "spread": self.spread}

    @classmethod
    def from_dict(cls, d: dict) -> "ViewGains":
        try:
            return cls(tuple(float(v) for v in d["log_gain"]))
        except (KeyError, TypeError, ValueError):
            raise InputError(f"not a table of view gains: {d!r}", fix="a table with log_gain = [...]") from None


def estimate_gains(signal: Tensor, images: Tensor, weight: Tensor) -> ViewGains | None:
    """The log gain of each view from a render ``signal [V, H, W]`` (channel mean), the photos
    ``images [V, H, W, 3]`` and the usable pixels ``weight [V, H, W]``; ``None`` when there are fewer than
    :data:`MIN_VIEWS` views or a view has fewer than :data:`MIN_PIXELS` lit pixels.

    Example:
        >>> s = torch.rand(4, 16, 16, generator=torch.Generator().manual_seed(0)) + 0.1
        >>> y = (s * torch.tensor([1.0, 1.2, 0.9, 1.0]).view(4, 1, 1))[..., None].expand(-1, -1, -1, 3)
        >>> [round(v, 3) for v in estimate_gains(s, y, torch.ones(4, 16, 16)).log_gain]
        [-0.019, 0.163, -0.125, -0.019]
    """
    if signal.shape[0] < MIN_VIEWS:
        return None
    out = []
    for v in range(signal.shape[0]):
        w = weight[v] > 0
        if int(w.sum()) < MIN_PIXELS:
            return None
        sv = signal[v][w].double()
        lit = sv >= LIT_FRACTION * sv.median()
        if int(lit.sum()) < MIN_PIXELS:
            return None
        photo = images[v][w][lit].double().mean(-1).clamp_min(1e-6)
        out.append(float(torch.log(photo / sv[lit]).median()))
    m = sum(out) / len(out)
    return ViewGains(tuple(v - m for v in out))
