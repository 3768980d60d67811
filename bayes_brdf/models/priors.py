"""Priors for material parameters: a box (default), a Gaussian around a value, smoothness on maps.

A :class:`Prior` says how each element of one parameter is distributed within
the parameter's valid range ``[low, high]``; a :class:`Smoothness` adds a
``pyro.factor`` coupling neighbouring texels of a map. Any user-written Pyro
distribution (with ``.to_event()`` over the map's dimensions) or
``pyro.factor`` in a user's own model works as well: these are conveniences.

Example:
    >>> import torch
    >>> p = gaussian(0.1, 0.05)          # the paper's low-roughness prior (Fig. 5)
    >>> d = p.distribution(torch.Size([1, 4, 4]), 0.05, 1.0)
    >>> d.event_shape, bool((d.sample() >= 0.05).all())
    (torch.Size([1, 4, 4]), True)
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import pyro
import torch
from pyro.distributions import TorchDistribution
from torch.distributions import constraints

from ..broadcast import broadcast_shapes
from ..errors import InputError


def _tensor(x):
    return x if isinstance(x, torch.Tensor) else torch.as_tensor(x, dtype=torch.get_default_dtype())


class Box(TorchDistribution):
    """Uniform on ``[low, high]`` with the density ``1 / (high - low)`` on the closed interval.

    (``torch``'s ``Uniform`` gives ``-inf`` at ``x == high``, which float32
    sigmoids reach; a sampler would then see an infinite energy.) The last
    ``event_dims`` dimensions are event dimensions (like ``.to_event()``); the
    log-density is a constant, computed once rather than summed per call.
    """

    arg_constraints = {}
    has_rsample = True

    def __init__(self, low, high, event_dims: int = 0, validate_args=None, _logc=None):
        self.low, self.high = torch.broadcast_tensors(_tensor(low), _tensor(high))
        shape = self.low.shape
        k = len(shape) - event_dims
        self._event_dims = event_dims
        if _logc is None:
            _logc = -(self.high - self.low).log()
            _logc = _logc.sum(dim=tuple(range(k, len(shape)))) if event_dims else _logc
        self._logc = _logc
        super().__init__(shape[:k], shape[k:], validate_args=False)

    @constraints.dependent_property(is_discrete=False, event_dim=0)
    def support(self):
        c = constraints.interval(self.low, self.high)
        return constraints.independent(c, self._event_dims) if self._event_dims else c

    def expand(self, batch_shape, _instance=None):
        shape = torch.Size(batch_shape) + self.event_shape
        return Box(self.low.expand(shape), self.high.expand(shape), self._event_dims,
                   _logc=self._logc.expand(batch_shape))

    def rsample(self, sample_shape=torch.Size()):
        shape = torch.Size(sample_shape) + self.low.shape
        u = torch.rand(shape, dtype=self.low.dtype, device=self.low.device)
        return self.low + u * (self.high - self.low)

    def log_prob(self, value):
        batch = value.shape[:value.dim() - len(self.event_shape)]
        return self._logc.expand(broadcast_shapes(batch, self.batch_shape))


class TruncatedNormal(TorchDistribution):
    """``Normal(loc, scale)`` restricted to ``[low, high]`` (exact, normalised; inverse-CDF sampling)."""

    arg_constraints = {}
    has_rsample = True

    def __init__(self, loc, scale, low, high, validate_args=None):
        self.loc, self.scale, self.low, self.high = torch.broadcast_tensors(*map(_tensor, (loc, scale, low, high)))
        a, b = (self.low - self.loc) / self.scale, (self.high - self.loc) / self.scale
        self._ca, self._cb = torch.special.ndtr(a), torch.special.ndtr(b)
        self._logz = (self._cb - self._ca).clamp_min(1e-300).log() + self.scale.log() + 0.5 * math.log(2 * math.pi)
        super().__init__(self.loc.shape, validate_args=False)

    @constraints.dependent_property(is_discrete=False, event_dim=0)
    def support(self):
        return constraints.interval(self.low, self.high)

    def expand(self, batch_shape, _instance=None):
        e = lambda x: x.expand(batch_shape)  # noqa: E731
        return TruncatedNormal(e(self.loc), e(self.scale), e(self.low), e(self.high))

    def rsample(self, sample_shape=torch.Size()):
        shape = torch.Size(sample_shape) + self.batch_shape
        u = torch.rand(shape, dtype=self.loc.dtype, device=self.loc.device)
        p = (self._ca + u * (self._cb - self._ca)).clamp(1e-12, 1 - 1e-12)
        return (self.loc + self.scale * torch.special.ndtri(p)).clamp(self.low, self.high)

    def log_prob(self, value):
        return -0.5 * ((value - self.loc) / self.scale) ** 2 - self._logz


@dataclass(frozen=True)
class Prior:
    """Independent per-element prior of one parameter on its range ``[low, high]``."""

    kind: str = "uniform"
    mean: float | None = None
    std: float | None = None

    def __post_init__(self):
        if self.kind not in ("uniform", "gaussian"):
            raise InputError(f"unknown prior kind '{self.kind}'", fix="use uniform or gaussian")
        if self.kind == "gaussian" and not (self.mean is not None and self.std is not None and self.std > 0):
            raise InputError(f"a gaussian prior needs a mean and a std > 0, got mean={self.mean}, std={self.std}")

    def distribution(self, shape, low: float, high: float, *, dtype=None, device=None):
        """The distribution of a whole parameter of ``shape`` (all dims are event dims)."""
        kw = dict(dtype=dtype or torch.get_default_dtype(), device=device)
        if self.kind == "uniform":     # scalar bounds expanded, the constant log-density from one log (every model run)
            lo, hi = torch.tensor(float(low), **kw).expand(tuple(shape)), torch.tensor(float(high), **kw).expand(tuple(shape))
            logc = torch.tensor(-math.prod(shape) * math.log(float(high) - float(low)), **kw)
            return Box(lo, hi, event_dims=len(shape), _logc=logc)
        lo, hi = torch.full(tuple(shape), float(low), **kw), torch.full(tuple(shape), float(high), **kw)
        d = TruncatedNormal(torch.full_like(lo, self.mean), torch.full_like(lo, self.std), lo, hi)
        return d.to_event(len(shape))

    def to_dict(self) -> dict:
        return {k: v for k, v in (("kind", self.kind), ("mean", self.mean), ("std", self.std)) if v is not None}


def uniform() -> Prior:
    """The default: uniform over the parameter's whole valid range."""
    return Prior("uniform")


def gaussian(mean: float, std: float) -> Prior:
    """A Gaussian around ``mean`` (truncated to the valid range), e.g. the paper's low-roughness prior."""
    return Prior("gaussian", float(mean), float(std))


@dataclass(frozen=True)
class Smoothness:
    """A smoothness prior on a map ``[n, C, H, W]``: ``kind="tv"`` (total variation) or ``"gmrf"``.

    Adds ``log p = -weight * sum |dx|`` (TV) or ``-weight / 2 * sum dx^2`` (Gaussian
    Markov random field) over horizontal and vertical neighbour differences.
    """

    kind: str = "tv"
    weight: float = 1.0

    def __post_init__(self):
        if self.kind not in ("tv", "gmrf"):
            raise InputError(f"unknown smoothness kind '{self.kind}'", fix="use tv or gmrf")
        if not self.weight >= 0:
            raise InputError(f"smoothness weight must be >= 0, got {self.weight}")

    def log_prob(self, x: torch.Tensor) -> torch.Tensor:
        """``[...]`` over the leading dims of ``x [..., C, H, W]``."""
        dx, dy = x[..., :, 1:] - x[..., :, :-1], x[..., 1:, :] - x[..., :-1, :]
        f = (lambda d: d.abs()) if self.kind == "tv" else (lambda d: 0.5 * d * d)
        return -self.weight * (f(dx).flatten(-3).sum(-1) + f(dy).flatten(-3).sum(-1))

    def add(self, name: str, x: torch.Tensor):
        """``pyro.factor`` named ``<name>_smoothness`` on map ``x``."""
        if self.weight > 0:
            pyro.factor(f"{name}_smoothness", self.log_prob(x))

    def to_dict(self) -> dict:
        return {"kind": self.kind, "weight": self.weight}


def add_smoothness(sites: dict, smoothness) -> None:
    """The smoothness factors of a per-texel model's maps: for each ``{name: map}`` in ``sites``, the
    :class:`Smoothness` that ``smoothness`` gives it (one for every map, or ``{name: Smoothness}``; ``None``:
    none), added as ``<name>_smoothness``."""
    for name, x in sites.items():
        s = from_dict(smoothness.get(name) if isinstance(smoothness, dict) else smoothness)
        if s is not None:
            s.add(name, x)


def tv(weight: float = 1.0) -> Smoothness:
    """Total-variation smoothness prior."""
    return Smoothness("tv", float(weight))


def gmrf(weight: float = 1.0) -> Smoothness:
    """Gaussian Markov random field smoothness prior."""
    return Smoothness("gmrf", float(weight))


def from_dict(d) -> Prior | Smoothness | None:
    """A prior from a preset table: ``{kind = "gaussian", mean = 0.1, std = 0.05}`` etc."""
    if d is None or isinstance(d, (Prior, Smoothness)):
        return d
    if not isinstance(d, dict) or "kind" not in d:
        raise InputError(f"a prior must be a table with a 'kind', got {d!r}")
    k = d["kind"]
    allowed = {"uniform": {"kind"}, "gaussian": {"kind", "mean", "std"}, "tv": {"kind", "weight"},
               "gmrf": {"kind", "weight"}}
    if k not in allowed:
        raise InputError(f"unknown prior kind '{k}'", fix="use uniform, gaussian, tv or gmrf")
    extra = set(d) - allowed[k]
    if extra:
        raise InputError(f"unknown key(s) {sorted(extra)} in a {k} prior", fix=f"allowed: {sorted(allowed[k])}")
    if k in ("tv", "gmrf"):
        return Smoothness(k, float(d.get("weight", 1.0)))
    return Prior(k, d.get("mean"), d.get("std"))
