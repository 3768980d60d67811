"""Which views to take next: greedy argmax of mutual information (Algorithm 1), batched top-K with hypersphere
exclusion, and the baselines (low-discrepancy directions, max image-space std).

A view's position in *configuration space* is its unit camera direction and unit light direction seen from
the centre of the scene's geometry (``surface.center``: the origin for the planar sample), ``theta = (c, l)``
(a view with several point lights: the normalised mean of their unit directions; a view lit by an environment
alone: its camera direction); the distance between two views is the RMS chord
``sqrt((|c - c'|^2 + |l - l'|^2) / 2)`` (for collocated views: the chord between the camera directions).
``radius`` is given in degrees of that chord's angle: after each pick, candidates closer than it are
removed for the rest of the batch (Sec. 3.4.2).

Example:
    >>> import torch
    >>> from bayes_brdf.render import SVBRDF, PlanarSample, collocated_views
    >>> maps = SVBRDF(torch.rand(8, 3, 8, 8), torch.rand(8, 1, 8, 8) * .5 + .2,
    ...               torch.full((3, 1, 1), .04), torch.tensor([0., 0, 1]).view(3, 1, 1))
    >>> cands = collocated_views(50, 3.0, camera="rectified", resolution=8, max_zenith=60)
    >>> rec = recommend(maps, cands, k=3, radius=15, surface=PlanarSample(2.0))
    >>> len(rec.indices), rec.method
    (3, 'mi')
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import torch
from torch import Tensor

from ..errors import InputError
from .scores import CandidateScores, score_views

METHODS = ("mi", "std", "sobol", "fibonacci", "random")


def _unit(x: Tensor) -> Tensor:
    return x / x.norm(dim=-1, keepdim=True).clamp_min(1e-12)


def configuration(views, target=(0.0, 0.0, 0.0)) -> Tensor:
    """``[V, 6]``: unit camera direction and unit light direction of each view, seen from ``target``
    (the scene centre); for a view with several point lights, the normalised mean of their unit directions.

    An environment light is not a direction: it is the same room for every candidate, so it tells no two
    views apart. A view lit by its point lights and an environment is placed by its point lights; a view lit
    by an environment alone (no point light) takes its camera direction as its light part, so that distances
    between such views are the chords between their cameras, as between collocated flash views.

    Example:
        >>> from bayes_brdf.render.cameras import PerspectiveCamera
        >>> from bayes_brdf.render.environment import studio
        >>> from bayes_brdf.render.views import View
        >>> configuration([View(PerspectiveCamera((0.0, 0.0, 3.0)), (studio(8),))]).tolist()
        [[0.0, 0.0, 1.0, 0.0, 0.0, 1.0]]
    """
    t = torch.tensor(target, dtype=torch.float64)
    rows = []
    for v in views:
        c = _unit(torch.tensor(v.camera.position, dtype=torch.float64) - t)
        points = v.point_lights
        if not points:                          # an environment alone: the camera is the only direction
            rows.append(torch.cat([c, c]))
            continue
        ls = _unit(torch.tensor([l.position for l in points], dtype=torch.float64) - t)
        rows.append(torch.cat([c, ls[0] if len(ls) == 1 else _unit(ls.mean(0))]))
    return torch.stack(rows)


def distances(views_a, views_b, target=(0.0, 0.0, 0.0)) -> Tensor:
    """``[A, B]`` configuration-space distance (RMS chord of camera and light directions)."""
    a, b = configuration(views_a, target), configuration(views_b, target)
    return torch.cdist(a, b) / math.sqrt(2)


def _chord(radius_deg: float) -> float:
    return 2 * math.sin(math.radians(radius_deg) / 2)


@dataclass
class Recommendation:
    """Picked candidate ``indices`` (best first), with the ``scores`` they were ranked by (if any)."""

    indices: list[int]
    method: str
    scores: CandidateScores | None = None
    views: list = field(default_factory=list)

    def to_dict(self) -> dict:
        d = {"indices": self.indices, "method": self.method,
             "views": [v.to_dict() for v in self.views]}
        if self.scores is not None:
            d["picked_mi"] = [float(self.scores.mi[i]) for i in self.indices]
            d["picked_mean_std"] = [float(self.scores.mean_std[i]) for i in self.indices]
            d["scoring_seconds"] = self.scores.seconds
        return d


def top_k(values: Tensor, candidates, k: int, radius: float = 0.0, exclude=(), target=(0.0, 0.0, 0.0)) -> list[int]:
    """Greedy batch: repeatedly take the best remaining candidate, then drop all within ``radius`` degrees.

    ``exclude``: indices that may not be picked (e.g. views already taken). Returns at most ``k`` indices
    (fewer when the exclusion leaves no candidate).
    """
    vals = values.double().clone()
    alive = torch.ones(len(candidates), dtype=torch.bool)
    for i in exclude:
        alive[int(i)] = False
    conf = configuration(candidates, target) if radius > 0 else None
    chord = _chord(radius)
    out = []
    while len(out) < k and bool(alive.any()):
        i = int(torch.where(alive, vals, torch.full_like(vals, -math.inf)).argmax())
        out.append(i)
        alive[i] = False
        if conf is not None:
            alive &= (torch.linalg.vector_norm(conf - conf[i], dim=1) / math.sqrt(2)) >= chord
    return out


def low_discrepancy(candidates, k: int, *, offset: int = 0, seed: int = 0, exclude=(),
                    sequence: str = "sobol", target=(0.0, 0.0, 0.0)) -> list[int]:
    """The baseline: the next ``k`` points of a scrambled Sobol sequence of camera directions (uniform in
    solid angle over the candidates' zenith range), each mapped to the nearest free candidate camera;
    among candidates sharing that camera (a light stage), the light is picked at random.

    ``offset`` is how many baseline views were taken before, so successive calls continue one sequence.
    ``sequence="fibonacci"`` uses a Fibonacci spiral of ``k`` points instead (evenly spread for that ``k``,
    but not nested: ``offset`` is ignored). Directions are seen from ``target`` (the scene centre).
    """
    conf = configuration(candidates, target)
    cam = conf[:, :3]
    cmin = float(cam[:, 2].min().clamp(-1, 1))
    if sequence == "fibonacci":
        i = torch.arange(k, dtype=torch.float64)
        pts = torch.stack([(i + 0.5) / k, (i * (math.sqrt(5) - 1) / 2) % 1.0], -1)
    else:
        eng = torch.quasirandom.SobolEngine(2, scramble=True, seed=seed)
        if offset:
            eng.fast_forward(offset)
        pts = eng.draw(k, dtype=torch.float64)
    cos_t = 1 - pts[:, 0] * (1 - cmin)
    sin_t = (1 - cos_t ** 2).clamp_min(0).sqrt()
    phi = 2 * math.pi * pts[:, 1]
    dirs = torch.stack([sin_t * phi.cos(), sin_t * phi.sin(), cos_t], -1)
    free = torch.ones(len(candidates), dtype=torch.bool)
    for i in exclude:
        free[int(i)] = False
    g = torch.Generator().manual_seed(seed * 7919 + offset)
    out = []
    for d in dirs:
        if not bool(free.any()):
            break
        dist = torch.where(free, (cam - d).norm(dim=1), torch.full((len(candidates),), math.inf, dtype=torch.float64))
        near = torch.nonzero(dist <= dist.min() + 1e-9).flatten()
        i = int(near[torch.randint(len(near), (1,), generator=g)])
        out.append(i)
        free[i] = False
    return out


def recommend(post: "Posterior | SVBRDF", candidates: list, k: int = 1, *, method: str = "mi", radius: float = 0.0,
              exclude: "list[int] | tuple" = (),
              surface=None, seed: int = 0, offset: int = 0, scores: CandidateScores | None = None,
              executor=None, **score_kw: object) -> Recommendation:
    """Recommend ``k`` of ``candidates`` to capture next.

    Args:
        post: a :class:`~bayes_brdf.posterior.Posterior` (or particle maps); unused by ``"sobol"``/``"random"``.
        method: ``"mi"`` (mutual information, Eq. 18), ``"std"`` (max mean image-space std, a baseline),
            ``"sobol"`` (low-discrepancy directions, the paper's baseline), ``"fibonacci"`` or ``"random"``.
        radius: exclusion radius in degrees (configuration space) between picks of one batch; ``k = 1``
            is Algorithm 1's greedy step.
        exclude: candidate indices that may not be picked (already captured).
        scores: reuse scores computed before (skips rendering).
        score_kw: passed to :func:`~bayes_brdf.guidance.scores.score_views` (``estimator``, ``noise_var``...).
        executor: score the candidates in shards through this executor (``True``: a local Ray, an address: a
            Ray cluster, an :mod:`~bayes_brdf.executor` object), the particles sent once
            (:func:`~bayes_brdf.executor.score_candidates`); ``None``: one :func:`score_views` call here.
    """
    candidates = list(candidates)
    if method not in METHODS:
        raise InputError(f"unknown recommendation method '{method}'", fix=f"use one of {', '.join(METHODS)}")
    if k < 1:
        raise InputError(f"k must be >= 1, got {k}")
    if radius < 0:
        raise InputError(f"radius must be >= 0 degrees, got {radius}")
    centre = getattr(surface if surface is not None else getattr(post, "surface", None), "center", (0.0, 0.0, 0.0))
    if method in ("sobol", "fibonacci"):
        idx = low_discrepancy(candidates, k, offset=offset, seed=seed, exclude=exclude, sequence=method,
                              target=centre)
    elif method == "random":
        free = [i for i in range(len(candidates)) if i not in set(int(j) for j in exclude)]
        g = torch.Generator().manual_seed(seed * 7919 + offset)
        idx = [free[int(j)] for j in torch.randperm(len(free), generator=g)[:k]]
    else:
        if scores is None and executor is not None:
            from ..executor import score_candidates
            scores = score_candidates(post, candidates, surface, executor=executor, **{"seed": seed, **score_kw})
        elif scores is None:
            scores = score_views(post, candidates, surface, **{"seed": seed, **score_kw})
        idx = top_k(scores.mi if method == "mi" else scores.mean_std, candidates, k, radius, exclude, centre)
    return Recommendation(idx, method, scores, [candidates[i] for i in idx])
