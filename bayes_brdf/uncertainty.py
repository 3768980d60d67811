"""Uncertainty: parameter-space std (Eq. 9), image-space std (Eq. 11) and posterior-predictive checks.

* :func:`parameter_std` -- per-site std maps over the particles (Eq. 9).
* :func:`image_std` -- per-pixel std over the particles' renders of any views
  (Eq. 11), batched over particles and chunked over views.
* :func:`predictive_cdf` -- where an observed pixel falls in the
  posterior-predictive distribution (particles' renders plus the likelihood's
  noise): the PIT value, from which interval coverage follows.
* :func:`coverage`, :func:`interval_coverage`, :func:`correlations` -- interval
  coverage of PIT values and of particles, and std against error.

The figures of these numbers (value maps as EXR and colour-mapped PNG, the
reliability diagram, std against error) are drawn by :mod:`bayes_brdf.plots`.

Example:
    >>> import torch
    >>> from bayes_brdf.posterior import Posterior
    >>> post = Posterior({"roughness": torch.tensor([[0.2], [0.4], [0.3]])}, torch.zeros(3))
    >>> parameter_std(post)["roughness"].tolist()
    [0.10000000149011612]
"""
from __future__ import annotations

import math

import torch
from torch import Tensor

from .errors import InputError
from .render.gbuffer import GBUFFERS
from .render.maps import SVBRDF
from .render.shade import shade_chunks
from .render.surface import PlanarSample


def parameter_std(post) -> dict[str, Tensor]:
    """Parameter-space uncertainty (Eq. 9): ``{site: std over particles}`` (Bessel-corrected)."""
    return post.std()


def particle_maps(post) -> SVBRDF:
    """The maps of every particle (``[n, C, H, W]``) of a posterior, or ``post`` itself when it is such maps."""
    if isinstance(post, SVBRDF):
        if post.num_particles is None:
            raise InputError("image-space std needs maps with a particle dimension [n, C, H, W]")
        return post
    return post.maps("all")


def resolve_surface(post, surface):
    """``surface`` when given, else the posterior's (from its file); one line when neither is known."""
    if surface is not None:
        return surface
    s = getattr(post, "surface", None)
    if s is None:
        raise InputError("the sample surface of this posterior is unknown",
                         fix="pass surface= (the capture's observations.surface: a PlanarSample or a Mesh)")
    return s


def particle_renders(post, views, surface: PlanarSample | None = None, *, chunk_views: int | None = None):
    """Yield ``(start, stop, renders [n, v, 3, H, W], mask [v, H, W])`` for chunks of ``views``: every particle, every view.

    ``post`` is a :class:`~bayes_brdf.posterior.Posterior` (with its model) or
    particle maps (:class:`SVBRDF` with a particle dimension). Memory is
    bounded by ``chunk_views`` (default: about 64 M values per chunk).
    """
    maps = particle_maps(post)
    surface = resolve_surface(post, surface)
    views = list(views)
    if not views:
        raise InputError("no views given", fix="pass at least one View")
    g = GBUFFERS.get(tuple(views), surface, dtype=maps.albedo.dtype, device=maps.albedo.device)
    n, (h, w) = maps.num_particles, g.resolution
    if chunk_views is None:
        chunk_views = max(1, (64 * 2**20) // max(1, n * h * w * 3))
    with torch.no_grad():
        for s, e, img in shade_chunks(maps, g, chunk_views=chunk_views):
            yield s, e, img, g.mask[s:e]


def image_std(post, views, surface: PlanarSample | None = None, *, return_mean: bool = False,
              chunk_views: int | None = None):
    """Image-space uncertainty (Eq. 11): per-pixel std ``[V, H, W, 3]`` of the particles' renders of ``views``.

    With ``return_mean=True`` returns ``(std, mean)``. Pixels off the sample are 0.

    Example:
        >>> import torch
        >>> from bayes_brdf.render import SVBRDF, PlanarSample, collocated_views
        >>> maps = SVBRDF(torch.rand(4, 3, 8, 8), torch.rand(4, 1, 8, 8) * .5 + .2,
        ...               torch.full((3, 1, 1), .04), torch.tensor([0., 0, 1]).view(3, 1, 1))
        >>> image_std(maps, collocated_views(2, 3.0, resolution=8), PlanarSample(2.0)).shape
        torch.Size([2, 8, 8, 3])
    """
    stds, means = [], []
    for _, _, r, _ in particle_renders(post, views, surface, chunk_views=chunk_views):
        stds.append(r.std(0) if r.shape[0] > 1 else torch.zeros_like(r[0]))
        means.append(r.mean(0))
    std = torch.cat(stds).permute(0, 2, 3, 1)
    return (std, torch.cat(means).permute(0, 2, 3, 1)) if return_mean else std


def predictive_cdf(post, views, images: Tensor, surface: PlanarSample | None = None, *,
                   sigma: float | None = None, kind: str | None = None, chunk_views: int | None = None,
                   variance: Tensor | None = None):
    """PIT values ``F(y) [V, H, W, 3]`` of observed ``images`` under the posterior predictive, and the renders' std.

    The predictive of a pixel is the mixture over particles of the model's
    noise (``Laplace(R(x_i), sigma)``, or Gaussian) around each particle's
    render; ``F`` is its CDF at the observed value, exactly (no quantiles of
    samples). A pixel lies in the central ``p`` interval iff
    ``|F - 1/2| <= p/2``; calibrated predictions give uniform ``F``.
    ``sigma``/``kind`` default to the posterior's (``post.noise_sigma``: the model's
    sigma or the inferred one; ``model.likelihood``). Under signal-dependent noise
    (``post.noise_level``) a particle's scale at a pixel is ``sigma * g(R_i)``, ``g`` of the mean
    over channels of its render there. The ``views`` are new photos: where the run estimated the fitted
    photos' gains (``post.view_gains``, :mod:`bayes_brdf.models.gains`), a new photo's unknown gain is
    integrated out over equal-probability nodes of its predictive (``g R_i`` in place of ``R_i``).
    ``variance [V, H, W, 3]``: the new photos' own render noise (photos a Monte Carlo renderer made,
    ``Observations.variance``), added to the noise: a scale ``sqrt(scale^2 + variance / 2)`` (Laplace, matched
    by its variance) or ``sqrt(scale^2 + variance)`` (Gaussian).
    Returns ``(F, std, mean)``, each ``[V, H, W, 3]``; ``std`` and ``mean`` are the renders' (Eq. 11).
    """
    model = getattr(post, "model", None)
    sigma = float(sigma if sigma is not None else getattr(post, "noise_sigma", None) or 0)
    kind = kind or getattr(model, "likelihood", "laplace")
    if not sigma > 0:
        raise InputError("the predictive needs the likelihood's noise scale", fix="pass sigma= (image units)")
    y = torch.as_tensor(images)
    level = getattr(post, "noise_level", None)
    gains = getattr(post, "view_gains", None)
    nodes = [0.0] if gains is None else gains.new_view_nodes().tolist()
    Fs, stds, means = [], [], []
    for s, e, r, _ in particle_renders(post, views, surface, chunk_views=chunk_views):
        obs = y[s:e].to(r).permute(0, 3, 1, 2)[None]
        extra = None
        if variance is not None:
            from .models.noise import render_noise
            extra = render_noise(torch.as_tensor(variance)[s:e].to(r), kind, per_channel=True).permute(0, 3, 1, 2)[None]
        F = torch.zeros_like(r[0])
        for lg in nodes:
            rg = r * math.exp(lg) if lg else r
            scale = sigma if level is None else sigma * level.relative(rg.mean(2, keepdim=True)).to(r)
            if extra is not None:
                scale = (scale * scale + extra).sqrt()
            t = (obs - rg) / scale
            if kind == "laplace":
                cdf = torch.where(t < 0, 0.5 * torch.exp(t.clamp_max(0)), 1 - 0.5 * torch.exp(-t.clamp_min(0)))
            else:
                cdf = 0.5 * (1 + torch.erf(t / math.sqrt(2)))
            F += cdf.mean(0)
        Fs.append(F / len(nodes))
        stds.append(r.std(0) if r.shape[0] > 1 else torch.zeros_like(r[0]))
        means.append(r.mean(0))
    cat = lambda xs: torch.cat(xs).permute(0, 2, 3, 1)  # noqa: E731
    return cat(Fs), cat(stds), cat(means)


def predictive_std(post, std: Tensor, mean: Tensor, *, sigma: float | None = None,
                   variance: Tensor | None = None) -> Tensor:
    """The posterior predictive's std of a new photo's pixels: ``sqrt(std^2 + noise variance)``, the renders'
    spread (Eq. 11, ``std``) plus the model's noise at the particles' mean render ``mean`` (both as
    :func:`predictive_cdf` returns them): Laplace ``2 (sigma g(R))^2``, Gaussian ``(sigma g(R))^2``, with
    ``g`` the signal-dependent relative scale (1 under one noise scale). The noise is taken at the mean
    render rather than per particle (the law of total variance with ``g`` linearised): exact under one
    noise scale. What a held-out photo's ``|error|`` should follow, as Eq. 11 alone is what the particles
    disagree on.

    Example:
        >>> from types import SimpleNamespace
        >>> p = SimpleNamespace(noise_sigma=0.01, noise_level=None, model=None)
        >>> round(float(predictive_std(p, torch.tensor([0.03]), torch.tensor([0.5]))), 5)    # sqrt(0.03^2 + 2e-4)
        0.03317
    """
    model = getattr(post, "model", None)
    sigma = float(sigma if sigma is not None else getattr(post, "noise_sigma", None) or 0)
    kind = getattr(model, "likelihood", "laplace")
    level = getattr(post, "noise_level", None)
    scale = sigma if level is None else sigma * level.relative(mean.mean(-1, keepdim=True)).to(mean)
    var = (2.0 if kind == "laplace" else 1.0) * scale * scale
    if variance is not None:                  # the new photos' own render noise (Observations.variance)
        var = var + variance.to(std)
    return (std * std + var).sqrt()


def coverage(pit: Tensor, levels=(0.5, 0.9)) -> dict[str, float]:
    """Fraction of PIT values inside each central interval: ``{"50": ..., "90": ...}``."""
    p = pit.reshape(-1)
    if p.numel() == 0:
        raise InputError("no pixels to measure coverage on")
    return {f"{round(100 * q)}": float(((p - 0.5).abs() <= q / 2).float().mean()) for q in levels}


def correlations(predicted: Tensor, error: Tensor) -> dict[str, float]:
    """Pearson and Spearman correlation between predicted std and absolute error (flattened); ``nan`` when either is
    constant or there are fewer than 3 values.

    Example:
        >>> c = correlations(torch.tensor([1.0, 2.0, 2.0, 5.0]), torch.tensor([0.1, 0.3, 0.2, 0.9]))
        >>> round(c["pearson"], 4), round(c["spearman"], 4)
        (0.9906, 0.9487)
    """
    a = predicted.reshape(-1).double().cpu()
    b = error.reshape(-1).double().cpu()
    if a.numel() < 3 or not bool(a.max() > a.min()) or not bool(b.max() > b.min()):
        return {"pearson": float("nan"), "spearman": float("nan")}
    return {"pearson": pearson(a, b), "spearman": pearson(ranks(a), ranks(b))}


def pearson(a: Tensor, b: Tensor) -> float:
    """Pearson's correlation of two 1-D tensors (float64; scipy.stats.pearsonr's value, without importing scipy: 0.8
    s of a command's end)."""
    a, b = a.double() - a.double().mean(), b.double() - b.double().mean()
    return float((a @ b) / (a.norm() * b.norm()))


def ranks(x: Tensor) -> Tensor:
    """1-based ranks of a 1-D tensor, ties given their average rank (scipy.stats.rankdata's ``"average"``, which
    Spearman's correlation uses)."""
    _, inv, cnt = torch.unique(x, sorted=True, return_inverse=True, return_counts=True)
    cnt = cnt.double()
    return (cnt.cumsum(0) - (cnt - 1) / 2)[inv]


def interval_coverage(particles: Tensor, truth: Tensor, levels) -> list[float]:
    """Fraction of ``truth`` values inside the particles' central intervals (empirical quantiles over dim 0).

    Example:
        >>> interval_coverage(torch.arange(11.0)[:, None], torch.tensor([5.0, 0.5]), (0.5, 1.0))
        [0.5, 1.0]
    """
    out = []
    for q in levels:
        lo = torch.quantile(particles.float(), 0.5 - q / 2, dim=0)
        hi = torch.quantile(particles.float(), 0.5 + q / 2, dim=0)
        out.append(float(((truth >= lo) & (truth <= hi)).float().mean()))
    return out
