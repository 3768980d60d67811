"""Run identity: a fingerprint of everything that determines a posterior.

A checkpoint, a posterior file and an output folder all record one
(:func:`fingerprint`): the content of the observations (a hash of the images,
masks and poses, so the same photos at another path are the same capture), the
model configuration, the sampler configuration, the seed and the package
version. A run resumes from a checkpoint only when the fingerprints agree;
otherwise :func:`differences` names what changed, for a one-line message.

Example:
    >>> a = {"data": "ab12", "model": {"sigma": 0.01}, "seed": 0}
    >>> differences(a, {**a, "model": {"sigma": 0.05}})
    ['model.sigma']
"""
from __future__ import annotations

import hashlib
import json

from .render.scene import surface_key

#: the format tag of a fingerprint
FORMAT = "bayes-brdf-run/1"


def _update(h, t) -> None:
    if t is None:
        h.update(b"none")
        return
    t = t.detach().cpu().contiguous()
    h.update(f"{t.dtype}{tuple(t.shape)}".encode())
    h.update(t.numpy().tobytes())


def views_digest(views) -> str:
    """SHA-256 (hex, 16 characters) of a list of views (poses and lights), e.g. a candidate set."""
    return hashlib.sha256(_views_json(views)).hexdigest()[:16]


def _views_json(views) -> bytes:
    return json.dumps([v.to_dict() for v in views], sort_keys=True, default=str).encode()


def observations_digest(obs) -> str:
    """SHA-256 (hex, 16 characters) of the observations' images, masks, views and surface.

    Two loads of the same photos at the same resolution give the same digest wherever the folder is;
    another view subset, resolution, pose or pixel gives another.
    """
    h = hashlib.sha256()
    _update(h, obs.images.float())
    _update(h, obs.mask)
    _update(h, obs.saturated)
    h.update(_views_json(obs.views))
    h.update(surface_key(obs.surface).encode())
    return h.hexdigest()[:16]


def digest_tensor(t) -> str:
    """SHA-256 (hex, 16 characters) of one tensor's dtype, shape and values."""
    h = hashlib.sha256()
    _update(h, t)
    return h.hexdigest()[:16]


def data_digest(data, observations: str | None = None) -> str:
    """The digest of a :class:`~bayes_brdf.models.data.ModelData`: its observations and pixel weights.

    ``observations``: the :func:`observations_digest` of ``data.observations`` when the caller has it
    already (the photos are then hashed once per run); computed here by default.
    """
    h = hashlib.sha256((observations or observations_digest(data.observations)).encode())
    _update(h, data.weight)
    h.update(repr(float(data.scale)).encode())
    return h.hexdigest()[:16]


def model_description(model):
    """What identifies a model: a built-in's configuration (``to_dict``), else a function's qualified name."""
    if hasattr(model, "to_dict"):
        return model.to_dict()
    return f"{getattr(model, '__module__', '?')}.{getattr(model, '__qualname__', getattr(model, '__name__', repr(model)))}"


def fingerprint(*, data: str, model, seed: int, **extra) -> dict:
    """The fingerprint of a run: observations digest, model, seed, version, plus ``extra`` fields."""
    from . import __version__

    return json.loads(json.dumps({"format": FORMAT, "data": data, "model": model, "seed": seed,
                                  "version": __version__, **extra}, sort_keys=True, default=str))


def digest(fp: dict) -> str:
    """A short hash of a fingerprint (for file names and quick comparisons)."""
    return hashlib.sha256(json.dumps(fp, sort_keys=True, default=str).encode()).hexdigest()[:16]


def differences(old: dict, new: dict, prefix: str = "") -> list[str]:
    """The dotted keys at which two fingerprints differ (leaves only; ``[]`` when equal)."""
    out = []
    for k in sorted(set(old) | set(new), key=str):
        a, b = old.get(k), new.get(k)
        if isinstance(a, dict) and isinstance(b, dict):
            out += differences(a, b, f"{prefix}{k}.")
        elif a != b:
            out.append(f"{prefix}{k}")
    return out
