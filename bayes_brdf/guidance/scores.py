"""Mutual information of a not-yet-taken view (Eqs. 13-21), batched over candidate views.

For each candidate ``theta``: render every particle (``[n, V, 3, H, W]``, chunked over views), then per
counted pixel and channel the entropy of the 1-D KDE of the ``n`` values (:mod:`.entropy`), minus the
render-noise entropy ``h_noise`` (Eq. 18), summed over the pixels. Counted pixels are those that see the
sample, and, for textured models, only one pixel per texel (the paper's footprint rule for redundant
pixels: :meth:`GBuffer.unique_pixel_mask`).

Candidates may be lit by an environment (:class:`~bayes_brdf.render.environment.EnvironmentLight`), alone or
with point lights, mixed in one call with flash-only candidates. The environment's per-pixel transfer
(:mod:`~bayes_brdf.render.transfer`) is part of a candidate's G-buffer: computed once per candidate when the
candidates' G-buffers are built (and kept with them in :data:`~bayes_brdf.render.gbuffer.GBUFFERS`, so a set
scored again is not recomputed), never per particle; each particle's render then reads its tables, at about
the cost of one more light. That precomputation is most of the cost of an environment-lit candidate (see
``docs/guidance.md``, "Under an environment light").

Example:
    >>> import torch
    >>> from bayes_brdf.render import SVBRDF, PlanarSample, collocated_views
    >>> maps = SVBRDF(torch.rand(8, 3, 8, 8), torch.rand(8, 1, 8, 8) * .5 + .2,
    ...               torch.full((3, 1, 1), .04), torch.tensor([0., 0, 1]).view(3, 1, 1))
    >>> s = score_views(maps, collocated_views(5, 3.0, camera="rectified", resolution=8), PlanarSample(2.0))
    >>> s.mi.shape, int(s.pixels[0])
    (torch.Size([5]), 64)
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import torch
from torch import Tensor

from ..errors import InputError
from ..render.shade import shade_chunks
from ..render.gbuffer import GBUFFERS
from ..uncertainty import particle_maps, resolve_surface
from .entropy import kde_entropy, noise_entropy


@dataclass
class CandidateScores:
    """Per-candidate scores ``[C]``: ``mi`` (nats, Eq. 18), ``mean_std`` (mean image-space std over the
    counted pixels and channels, Eq. 11) and ``pixels`` (counted pixels)."""

    mi: Tensor
    mean_std: Tensor
    pixels: Tensor
    estimator: str
    seconds: float

    def __len__(self) -> int:
        return self.mi.shape[0]

    def to_dict(self) -> dict:
        return {"mi": self.mi.tolist(), "mean_std": self.mean_std.tolist(), "pixels": self.pixels.tolist(),
                "estimator": self.estimator, "seconds": self.seconds}


def counted_pixels(g, map_resolution, footprint: bool = True) -> Tensor:
    """``[V, H, W]`` bool: pixels that count in Eq. 18 (valid, and one per texel for a textured map)."""
    if footprint and tuple(map_resolution) != (1, 1):
        return g.unique_pixel_mask(tuple(map_resolution))
    return g.mask


def parse_noise_var(value) -> "float | str":
    """A score's noise variance as given by a user (number, numeric string or ``"observation"``), checked:
    ``"observation"`` or a float >= 0. One-line error otherwise."""
    if value == "observation":
        return value
    fix = "give a number >= 0 or 'observation'"
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise InputError(f"unknown noise_var '{value}'", fix=fix) from None
    if not x >= 0:
        raise InputError(f"noise_var must be >= 0, got {value}", fix=fix)
    return x


def observation_noise_var(post) -> float:
    """Variance of the model's observation noise ``W`` (Eq. 12): ``2 sigma^2`` for Laplace, ``sigma^2`` for Gaussian,
    plus the mean render variance of the fitted photos where a Monte Carlo renderer made them
    (``post.render_noise``): a candidate's photo, taken the same way, will carry it too."""
    model = getattr(post, "model", None)
    sigma = getattr(post, "noise_sigma", None)
    if sigma is None:
        raise InputError("noise_var='observation' needs the posterior's model (its sigma)",
                         fix="pass noise_var as a number (image units squared)")
    render = getattr(post, "render_noise", None) or 0.0
    return (2.0 if getattr(model, "likelihood", "laplace") == "laplace" else 1.0) * float(sigma) ** 2 + float(render)


def score_views(post: "Posterior | SVBRDF", candidates: list, surface=None, *, estimator: str = "mc", nodes: int = 8,
                noise_var: float | str = 0.0, seed: int = 0, footprint: bool = True, min_bandwidth: float = 1e-6,
                chunk_views: int | None = None, backend: str = "auto") -> CandidateScores:
    """Score ``candidates`` (a list of :class:`View`) by mutual information with the posterior's particles.

    Args:
        post: a :class:`~bayes_brdf.posterior.Posterior` with its model, or particle maps (``SVBRDF [n, ...]``).
        estimator: ``"mc"`` (the paper's Eq. 21, common random numbers across candidates, seeded by
            ``seed``) or ``"quadrature"`` (deterministic, ``nodes`` Gauss-Hermite nodes per kernel).
        noise_var: per-pixel noise variance; ``h_noise`` is its Gaussian entropy (0 when 0, the paper's
            deterministic renderer). ``"observation"`` uses the model's observation noise (Eq. 12's ``W``,
            as a Gaussian of equal variance): the score is then the information a *noisy* photo carries,
            and pixels whose spread is far below the noise count about 0 instead of very negative.
        footprint: count one pixel per texel (Sec. 3.4.1); off, every valid pixel counts.
        chunk_views: candidates rendered at once (memory bound); default about 16 M values per chunk.
    """
    t0 = time.perf_counter()
    noise_var = parse_noise_var(noise_var)
    if noise_var == "observation":
        noise_var = observation_noise_var(post)
    maps = particle_maps(post)
    surface = resolve_surface(post, surface)
    candidates = list(candidates)
    if not candidates:
        raise InputError("no candidate views to score", fix="pass at least one View")
    n = maps.num_particles
    if n < 2:
        raise InputError(f"scoring views needs at least 2 particles, got {n}")
    dt, dev = maps.albedo.dtype, maps.albedo.device
    C = len(candidates)
    H, W = candidates[0].resolution
    gen = torch.Generator().manual_seed(int(seed))
    u = torch.rand(3 * H * W, generator=gen, dtype=dt).to(dev)   # common random numbers, by pixel position
    e = torch.randn(3 * H * W, generator=gen, dtype=dt).to(dev)
    pos = torch.arange(3 * H * W, device=dev).reshape(3, H, W)
    h0 = noise_entropy(noise_var)
    mi = torch.zeros(C, dtype=torch.float64, device=dev)
    sdsum = torch.zeros(C, dtype=torch.float64, device=dev)
    px = torch.zeros(C, dtype=torch.long, device=dev)
    if chunk_views is None:
        chunk_views = max(1, (16 * 2**20) // (n * 3 * H * W))
    kw = dict(nodes=nodes, noise_var=noise_var, min_bandwidth=min_bandwidth, backend=backend)
    P = 3 * H * W
    with torch.no_grad():
        for b0, g in GBUFFERS.blocks(candidates, surface, dtype=dt, device=dev):
            keep = counted_pixels(g, maps.albedo.shape[-2:], footprint)
            px[b0:b0 + g.num_views] = keep.reshape(g.num_views, -1).sum(1)
            for s, stop, r in shade_chunks(maps, g, chunk_views=chunk_views):   # r [n, v, 3, H, W]
                v, c0, c1 = stop - s, b0 + s, b0 + stop
                k = keep[s:stop, None].expand(v, 3, H, W)
                if float(k.float().mean()) > 0.5:   # dense: score every pixel, weight by the counted ones
                    h, sd = kde_entropy(r.reshape(n, v * P), estimator, u=u.repeat(v), e=e.repeat(v), **kw)
                    wk = k.reshape(v, P).to(h.dtype)
                    mi[c0:c1] = ((h.view(v, P) - h0) * wk).double().sum(1)
                    sdsum[c0:c1] = (sd.view(v, P) * wk).double().sum(1)
                else:                               # sparse (many pixels per texel): gather the counted ones
                    p = pos.expand(v, 3, H, W)[k]
                    vid = torch.arange(c0, c1, device=dev)[:, None, None, None].expand(v, 3, H, W)[k]
                    h, sd = kde_entropy(r[:, k], estimator, u=u[p], e=e[p], **kw)
                    mi.index_add_(0, vid, h.double() - h0)
                    sdsum.index_add_(0, vid, sd.double())
    mean_std = sdsum / (3 * px).clamp_min(1)
    return CandidateScores(mi.cpu(), mean_std.cpu(), px.cpu(), estimator, time.perf_counter() - t0)
