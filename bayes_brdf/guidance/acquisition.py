"""Guided acquisition (Algorithm 1, batched): fit, recommend ``k`` views, capture them, repeat.

``capture(views) -> Observations | Tensor [k, H, W, 3]`` is the only contact with the world:

* :class:`SyntheticCapture` renders known maps (optionally with noise): experiments and demos;
* :class:`PoolCapture` looks the views up in captures already taken, so a real capture session can be
  replayed (the candidates are the pool's views).

Every round writes ``round_XX/`` (``posterior.safetensors`` and ``round.json``: views used, picks with
their scores, metrics, timings) under ``out``, and ``acquisition.json`` sums up all rounds. Rerunning with
the same ``out`` resumes after the last finished round.

Example:
    >>> import bayes_brdf as bb
    >>> from bayes_brdf.render import PlanarSample, collocated_views
    >>> truth = bb.materials.make_material("wood", 8, seed=0)
    >>> cands = collocated_views(40, 3.0, camera="rectified", resolution=8, power=10.0, max_zenith=60)
    >>> cap = SyntheticCapture(truth, PlanarSample(2.0))
    >>> res = guided_acquisition(bb.models.per_texel(8), cap(cands[:2]), cands, cap, rounds=1, k=2,
    ...                          steps=50, initial_indices=[0, 1])
    >>> [r["views"] for r in res.rounds]
    [2, 4]
"""
from __future__ import annotations

import hashlib
import json
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import torch

from ..io.outputs import write_text
from ..errors import InputError
from ..observations import Observations
from ..posterior import Posterior
from ..render.maps import SVBRDF
from ..render.shade import render
from ..render.surface import PlanarSample
from .recommend import recommend


class SyntheticCapture:
    """Capture by rendering known ``maps`` (``[C, H, W]`` or a particle of one), plus optional noise.

    The noise of a view is seeded by the view itself, so capturing the same view twice gives the same image.
    """

    def __init__(self, maps: SVBRDF, surface: PlanarSample | None = None, *, noise_sigma: float = 0.0,
                 noise: str = "laplace", seed: int = 0):
        self.maps, self.surface = maps, surface or PlanarSample()
        self.noise_sigma, self.noise, self.seed = float(noise_sigma), noise, int(seed)

    def __call__(self, views) -> Observations:
        views = list(views)
        with torch.no_grad():
            img = render(self.maps, views, self.surface)[0]
        if self.noise_sigma > 0:
            for i, v in enumerate(views):
                key = hashlib.sha256(json.dumps(v.to_dict(), sort_keys=True).encode()).hexdigest()
                g = torch.Generator().manual_seed(self.seed * 1_000_003 + int(key[:12], 16))
                if self.noise == "laplace":
                    e = torch.empty(img[i].shape).exponential_(generator=g) - torch.empty(img[i].shape).exponential_(generator=g)
                else:
                    e = torch.randn(img[i].shape, generator=g)
                img[i] = img[i] + self.noise_sigma * e.to(img)
        return Observations(views, img.float(), self.surface, meta={"source": "synthetic"})


class PoolCapture:
    """Capture by looking views up in already-taken ``observations`` (replay of a real session).

    ``candidates`` are the pool's views; asking for a view that is not in the pool is an error.
    """

    def __init__(self, observations: Observations):
        self.observations = observations
        self.index = {v: i for i, v in enumerate(observations.views)}

    @property
    def candidates(self) -> list:
        return list(self.observations.views)

    def __call__(self, views) -> Observations:
        idx = []
        for v in views:
            if v not in self.index:
                raise InputError(f"view '{v.name}' is not in the capture pool", fix="recommend from the pool's views")
            idx.append(self.index[v])
        return self.observations.subset(idx)


@dataclass
class Evaluation:
    """Held-out views (and optionally the true maps) to measure every round on.

    Metrics: ``novel_error`` (mean absolute error of the MAP's renders vs ``images`` over valid pixels),
    ``mean_image_std`` (mean image-space std over the same pixels, Eq. 11) and, with ``truth``,
    ``param_error`` (mean absolute error of the MAP's albedo and roughness maps).
    """

    views: list
    images: torch.Tensor
    truth: SVBRDF | None = None
    mask: torch.Tensor | None = None

    @classmethod
    def synthetic(cls, capture: SyntheticCapture, views) -> "Evaluation":
        obs = capture(views)
        return cls(list(views), obs.images, capture.maps)

    def __call__(self, post: Posterior, surface) -> dict:
        from ..render.gbuffer import GBUFFERS
        from ..uncertainty import image_std
        std, _ = image_std(post, self.views, surface, return_mean=True)
        m = post.maps("map")
        pred = render(m, self.views, surface)[0]
        g = GBUFFERS.get(tuple(self.views), surface, dtype=pred.dtype, device=pred.device)
        valid = g.mask if self.mask is None else (g.mask & self.mask.to(g.mask.device))
        y = self.images.to(pred)
        out = {"novel_error": float((pred - y).abs()[valid].mean()),
               "mean_image_std": float(std[valid].mean())}
        if self.truth is not None:
            t = self.truth
            out["param_error"] = {"albedo": float((m.albedo - t.albedo.to(m.albedo)).abs().mean()),
                                  "roughness": float((m.roughness - t.roughness.to(m.roughness)).abs().mean())}
        return out


@dataclass
class AcquisitionResult:
    """Per-round records (dicts as in ``round.json``) and the last posterior."""

    rounds: list = field(default_factory=list)
    posterior: Posterior | None = None
    observations: Observations | None = None

    def series(self, key: str) -> list:
        """``[(views, metric)]`` over rounds, e.g. ``series("novel_error")``."""
        return [(r["views"], r["metrics"][key]) for r in self.rounds if key in r.get("metrics", {})]


def _capture(capture, views, surface) -> Observations:
    got = capture(views)
    if isinstance(got, Observations):
        return got
    img = torch.as_tensor(got)
    if img.dim() != 4 or img.shape[0] != len(views):
        raise InputError(f"capture returned shape {tuple(img.shape)} for {len(views)} views",
                         fix="return Observations or images [k, H, W, 3]")
    return Observations(list(views), img.float(), surface)


def guided_acquisition(model: "Callable | str", initial: Observations, candidates: list, capture: Callable, *,
                       rounds: int = 3, k: "int | list[int]" = 5, method: str = "mi", radius: float = 0.0, sampler="spos",
                       particles: int | None = None, steps: int | None = None, params: dict | None = None,
                       seed: int = 0, warm_start: bool = True, initial_indices: "list[int] | tuple" = (),
                       evaluation: Callable | None = None, out: "str | Path | None" = None, progress: bool = False,
                       score_kw: dict | None = None, on_round: Callable | None = None,
                       map_steps: int | None = None, executor=None) -> AcquisitionResult:
    """Algorithm 1 with ``k`` views per round (hypersphere exclusion of ``radius`` degrees between them).

    Args:
        model: a material model (Pyro function or preset name).
        initial: observations before guidance (``Y_0``).
        candidates: the candidate views ``Theta-bar``.
        capture: ``capture(views) -> Observations`` (or images); see :class:`SyntheticCapture`, :class:`PoolCapture`.
        rounds: acquisition rounds; ``rounds + 1`` posteriors are drawn (the last one after the last capture).
        k: views per round, or a list with one count per round (e.g. ``[5, 10, 10]``, the paper's Fig. 7).
        method: ``"mi"`` (ours), ``"std"``, ``"sobol"`` (low-discrepancy baseline) or ``"random"``.
        warm_start: start each round's sampler from the previous round's particles.
        initial_indices: candidate indices already in ``initial`` (never recommended again).
        evaluation: ``evaluation(post, surface) -> dict`` of metrics per round (e.g. :class:`Evaluation`).
        executor: score each round's candidates in shards through it (a local Ray, a cluster; see
            :func:`~bayes_brdf.guidance.recommend.recommend`); ``None``: in this process.
        out: folder for per-round files; rerunning resumes after the last finished round.
        on_round: called as ``on_round(record, posterior)`` after every round (progress reporting).
        map_steps: the MAP refinement of every round's posterior (see :func:`bayes_brdf.infer`).
    """
    from ..inference import infer
    candidates = list(candidates)
    ks = [int(k)] * rounds if isinstance(k, int) else [int(x) for x in k]
    if rounds < 0 or len(ks) != rounds or any(x < 1 for x in ks):
        raise InputError(f"need rounds >= 0 and k >= 1 per round, got rounds={rounds}, k={k}",
                         fix="give k as one count, or a list with one count per round")
    out = Path(out) if out is not None else None
    obs, used, z, res = initial, [int(i) for i in initial_indices], None, AcquisitionResult()
    surface = initial.surface
    from ..identity import differences, fingerprint, model_description, observations_digest, views_digest
    from ..runs.fingerprint import sampler_identity
    setup = {"model": model if isinstance(model, str) else model_description(model),
             "sampler": sampler_identity(sampler),
             "particles": particles, "steps": steps, "params": params, "method": method, "k": ks, "radius": radius,
             "warm_start": warm_start, "map_steps": map_steps, "score": score_kw,
             "candidates": views_digest(candidates)}
    for r in range(rounds + 1):
        rdir = out / f"round_{r:02d}" if out is not None else None
        rec_file = rdir / "round.json" if rdir is not None else None
        fp = fingerprint(data=observations_digest(obs), model=setup["model"], seed=seed + r, round=r,
                         setup={k: v for k, v in setup.items() if k != "model"}) if rdir is not None else None
        if rec_file is not None and rec_file.is_file():  # finished before: replay its captures, keep its particles
            rec = json.loads(rec_file.read_text())
            if rec.get("fingerprint") != fp:
                diff = differences(rec.get("fingerprint") or {}, fp)
                raise InputError(f"holds round {r} of another acquisition run (it differs in "
                                 f"{', '.join(diff[:4]) or 'its format'})", where=rdir,
                                 fix="use another out folder, or delete it to start over")
            post = Posterior.load(rdir / "posterior.safetensors")
            picks = rec["picks"]["indices"] if rec.get("picks") else []
        else:
            t0 = time.perf_counter()
            post = infer(model, obs, sampler, seed=seed + r, particles=particles, steps=steps, params=params,
                         progress=progress, z0=z if warm_start else None, map_steps=map_steps,
                         observations_digest=fp["data"] if fp is not None else None)
            t_fit = time.perf_counter() - t0
            metrics = evaluation(post, surface) if evaluation is not None else {}
            t1 = time.perf_counter()
            rec = {"round": r, "views": len(obs), "method": method, "seed": seed, "fit_seconds": t_fit,
                   "metrics": metrics, "used": list(used), "picks": None}
            if r < rounds:
                pick = recommend(post, candidates, ks[r], method=method, radius=radius, exclude=used, surface=surface,
                                 seed=seed + r, offset=len(obs), executor=executor, **(score_kw or {}))
                rec["picks"] = pick.to_dict()
                rec["recommend_seconds"] = time.perf_counter() - t1
            rec["fingerprint"] = fp
            picks = rec["picks"]["indices"] if rec["picks"] else []
            if rdir is not None:
                rdir.mkdir(parents=True, exist_ok=True)
                post.save(rdir / "posterior.safetensors")
                write_text(rec_file, json.dumps(rec, indent=1))
        res.rounds.append(rec)
        if on_round is not None:
            on_round(rec, post)
        z = post.z
        if picks:
            obs = obs.append(_capture(capture, [candidates[i] for i in picks], surface))
            used += picks
    res.posterior, res.observations = post, obs
    if out is not None:
        write_text(out / "acquisition.json", json.dumps({"rounds": res.rounds}, indent=1))
    return res
