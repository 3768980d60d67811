"""The bridge from a Pyro model to a batched potential ``U(z)`` on unconstrained space.

A :class:`Potential` turns any Pyro model function into what every sampler
needs: for ``n`` particles ``z`` of shape ``[n, D]`` (unconstrained, all latent
sites packed per particle, one row per particle), the energies ``U(z)`` ``[n]``
and their gradients ``[n, D]``, from ONE run of the model under a particle
plate (no Python loop over particles).

``U(z) = -log p(x(z), y) - log|det dx/dz|`` where ``x = to_constrained(z)``
maps each site through Pyro's ``biject_to(site.support)``. With
``jacobian=False`` the log-Jacobian is left out: then ``U`` is minus the log of
the paper's target ``f(x)`` (Eq. 3) in constrained space, which is what point
estimates (Eq. 7) maximise.

Models must be *particle-vectorisable*: under ``pyro.plate("particles", n)``
every latent site gets a leading particle dimension, and whatever the model
computes from it (maps, renders, factors) must keep that dimension. Declare
each site's own dimensions as event dimensions (``.to_event()``), or put them
in ``pyro.plate``\\ s of your own; both work.
"""
from __future__ import annotations

import copy
import ctypes
import math
from dataclasses import dataclass
from math import prod
from pathlib import Path
from typing import Callable

import pyro
import pyro.poutine as poutine
from pyro.distributions.util import scale_and_mask
from pyro.poutine.util import site_is_subsample
import torch
from torch import Tensor
from torch.distributions import biject_to

from .errors import InputError
from .render.native import ptr


@dataclass(frozen=True)
class Site:
    """One latent site: its per-particle shape, where it lives in ``z`` and its bijection."""

    name: str
    shape: tuple          # constrained value per particle (batch + event)
    batch_dims: int       # how many leading dims of ``shape`` are plate (batch) dims
    ushape: tuple         # unconstrained shape per particle
    offset: int
    size: int
    transform: object


_INTERVAL_SRC = Path(__file__).parent / "_native_interval.c"


def _interval_kernels(u: Tensor):
    """The native forward and backward of :class:`_IntervalFn` for tensors like ``u`` (CPU, float32/64), or
    ``None`` (then the torch ops below run: the same numbers to rounding)."""
    if u.device.type != "cpu":
        return None
    from .render.native import native_function
    i64, dbl, vp = ctypes.c_int64, ctypes.c_double, ctypes.c_void_p
    fwd = native_function(_INTERVAL_SRC, "bb_interval_fwd", u.dtype, [i64, i64, i64, dbl, dbl, i64] + [vp] * 4,
                          extra_flags=("-ffast-math",))
    bwd = native_function(_INTERVAL_SRC, "bb_interval_bwd", u.dtype, [i64, i64, i64, dbl, i64] + [vp] * 4,
                          extra_flags=("-ffast-math",))
    return None if fwd is None or bwd is None else (fwd, bwd)


def _interval_map_kernel(u: Tensor):
    """The native ``x = lo + w sigmoid(u)`` alone (``bb_interval_map``: the forward's values, no log-Jacobian) for
    tensors like ``u``, or ``None`` (CUDA, no compiler: torch's sigmoid)."""
    if u.device.type != "cpu":
        return None
    from .render.native import native_function
    i64, dbl, vp = ctypes.c_int64, ctypes.c_double, ctypes.c_void_p
    return native_function(_INTERVAL_SRC, "bb_interval_map", u.dtype, [i64, i64, i64, dbl, dbl, i64, vp, vp],
                           extra_flags=("-ffast-math",))


def _rows(u: Tensor) -> tuple[Tensor, int, int, int]:
    """``(u, n, m, stride)``: ``u`` as the interval kernels read it, ``n`` rows of ``m`` contiguous values ``stride``
    apart (a slice of ``z`` as it is; a row that is not contiguous copied first)."""
    if not u[0].is_contiguous():
        u = u.contiguous()
    n, m = u.shape[0], u[0].numel()
    return u, n, m, (u.stride(0) if n > 1 else m)


class _IntervalFn(torch.autograd.Function):
    """``x = lo + (hi - lo) sigmoid(u)`` and the per-particle ``sum log|dx/du|`` in one fused pass (a native
    loop on CPU: one read of ``u`` and one write of ``x`` forward, one pass backward; torch ops elsewhere)."""

    @staticmethod
    def forward(ctx, u, lo, hi):
        ctx.width = hi - lo
        k = _interval_kernels(u)
        if k is not None:
            u, n, m, us = _rows(u)
            x = torch.empty(u.shape, dtype=u.dtype)
            s = torch.empty(u.shape, dtype=u.dtype)
            ladj = torch.empty(n, dtype=torch.float64)
            k[0](n, m, us, float(lo), float(hi - lo), torch.get_num_threads(), *map(ptr, (u, x, s, ladj)))
            ctx.save_for_backward(s)
            ctx.native = k[1]
            return x, ladj.to(u.dtype)
        s = torch.sigmoid(u)
        x = s * (hi - lo) + lo
        a = u.abs()
        # log s(1-s) = -|u| - 2 log(1 + exp(-|u|)), stable at saturation
        ladj = (-a - 2 * torch.log1p(torch.exp(-a))).reshape(u.shape[0], -1).sum(1) + u[0].numel() * math.log(hi - lo)
        ctx.save_for_backward(s)
        ctx.native = None
        return x, ladj

    @staticmethod
    def backward(ctx, gx, gl):
        (s,) = ctx.saved_tensors
        if ctx.native is not None:
            g = torch.empty_like(s)
            gx = None if gx is None else gx.to(s.dtype).contiguous()
            gl = None if gl is None else gl.to(s.dtype).contiguous()
            ctx.native(s.shape[0], s[0].numel(), s[0].numel(), float(ctx.width), torch.get_num_threads(),
                       *map(ptr, (s, gx, gl, g)))
            return g, None, None
        shape = (-1,) + (1,) * (s.dim() - 1)
        g = None
        if gx is not None:
            g = gx * (s * (1 - s) * ctx.width)
        if gl is not None:
            gj = (1 - 2 * s) * gl.reshape(shape)
            g = gj if g is None else g + gj
        return g, None, None


class _UnpackFn(torch.autograd.Function):
    """All sites of ``z`` ``[n, D]`` at once, when each is on an interval or unconstrained (the native path):
    forward, each site's values (``x = lo + w sigmoid(u)`` read straight from its columns of ``z``, or a copy
    of them) and the summed log-Jacobian ``[n]``; backward, one ``[n, D]`` gradient that each site's native
    pass writes into its own columns (the split-and-concatenate of the per-site path, a full copy of the
    gradient per step, is not made). The same numbers as :class:`_IntervalFn` per site.

    ``plan``: per site ``(offset, size, ushape, lo, width)``, ``lo = None`` for an unconstrained site."""

    @staticmethod
    def forward(ctx, z, plan, kernels):
        n, D = z.shape
        nt = torch.get_num_threads()
        xs, ss, ladj = [], [], z.new_zeros(n)
        for off, size, ushape, lo, width in plan:
            cols = z[:, off:off + size]
            if lo is None:
                xs.append(cols.reshape(n, *ushape).clone(memory_format=torch.contiguous_format))
                ss.append(None)
                continue
            x = torch.empty(n, *ushape, dtype=z.dtype)
            sv = torch.empty(n, *ushape, dtype=z.dtype)
            lj = torch.empty(n, dtype=torch.float64)
            kernels[0](n, size, D, lo, width, nt, *map(ptr, (cols, x, sv, lj)))
            ladj = ladj + lj.to(z.dtype)     # per site in z's dtype, in site order: the per-site path's sum
            xs.append(x)
            ss.append(sv)
        ctx.save_for_backward(*(v for v in ss if v is not None))
        ctx.meta = (plan, kernels, z.shape, z.dtype)
        return (*xs, ladj)

    @staticmethod
    def backward(ctx, *grads):
        plan, kernels, (n, D), dt = ctx.meta
        saved = iter(ctx.saved_tensors)           # the sigmoids of the interval sites, in site order
        gz = torch.empty(n, D, dtype=dt)
        gl = None if grads[-1] is None else grads[-1].to(dt).contiguous()
        nt = torch.get_num_threads()
        for (off, size, _, lo, width), gx in zip(plan, grads[:-1]):
            cols = gz[:, off:off + size]
            if lo is None:                        # unconstrained: the gradient itself
                if gx is None:
                    cols.zero_()
                else:
                    cols.copy_(gx.reshape(n, size))
                continue
            gx = None if gx is None else gx.to(dt).contiguous()
            kernels[1](n, size, D, width, nt, *map(ptr, (next(saved), gx, gl, cols)))
        return gz, None, None


def _unconstrained(t) -> bool:
    """Whether a transform is the identity (``biject_to(real)``, also under ``.to_event()``)."""
    from torch.distributions.transforms import ComposeTransform, IndependentTransform
    while isinstance(t, IndependentTransform):
        t = t.base_transform
    return isinstance(t, ComposeTransform) and not t.parts


class IntervalBijection:
    """``biject_to(interval(lo, hi))`` for scalar bounds, with a fused forward + log-Jacobian (the hot path).

    Equal in value to Pyro's ``ComposeTransform([Sigmoid, Affine])``; ``inv`` and the transform
    interface are delegated to it.
    """

    def __init__(self, lo: float, hi: float, support):
        self.lo, self.hi = lo, hi
        self._t = biject_to(support)

    @classmethod
    def maybe(cls, support):
        from torch.distributions import constraints
        base = support
        while isinstance(base, constraints.independent):   # .to_event(): the same bijection elementwise
            base = base.base_constraint
        if not isinstance(base, constraints.interval):
            return None
        lo, hi = torch.as_tensor(base.lower_bound), torch.as_tensor(base.upper_bound)
        if lo.numel() == 0 or not (bool((lo == lo.reshape(-1)[0]).all()) and bool((hi == hi.reshape(-1)[0]).all())):
            return None
        return cls(float(lo.reshape(-1)[0]), float(hi.reshape(-1)[0]), support)

    def forward_with_ladj(self, u):
        return _IntervalFn.apply(u, self.lo, self.hi)

    def __call__(self, u):
        if not u.requires_grad and u.dim() > 0 and u.numel() > 0:
            k = _interval_map_kernel(u)
            if k is not None:                         # one native pass (a texel sweep's renders, the outputs' maps)
                u, n, m, us = _rows(u)
                x = torch.empty(u.shape, dtype=u.dtype)
                k(n, m, us, float(self.lo), float(self.hi - self.lo), torch.get_num_threads(), ptr(u), ptr(x))
                return x
        x = torch.sigmoid(u)
        if self.lo == 0.0 and self.hi == 1.0:
            return x                                  # x * 1 + 0: the same bits
        if x.requires_grad:
            return x * (self.hi - self.lo) + self.lo
        return x.mul_(self.hi - self.lo).add_(self.lo)   # in place (a texel sweep's renders: no graph)

    @property
    def inv(self):
        return self._t.inv

    def inverse_shape(self, shape):
        # elementwise with scalar bounds: the value's own shape. (torch's AffineTransform broadcasts it with the
        # bounds' shapes, which a value of the support already has, through torch.broadcast_shapes: that imports
        # torch._refs and sympy, half a second of every command that builds a potential.)
        return torch.Size(shape)

    def log_abs_det_jacobian(self, u, x):
        return self._t.log_abs_det_jacobian(u, x)


def _clamp_inside(v: Tensor, support, margin: float) -> Tensor:
    """``v`` clamped to the central ``1 - 2 margin`` of an interval support (other supports: unchanged)."""
    from torch.distributions import constraints
    base = support
    while isinstance(base, constraints.independent):
        base = base.base_constraint
    if not isinstance(base, constraints.interval):
        return v
    lo = torch.as_tensor(base.lower_bound, dtype=v.dtype, device=v.device)
    hi = torch.as_tensor(base.upper_bound, dtype=v.dtype, device=v.device)
    w = hi - lo
    return torch.maximum(torch.minimum(v, hi - margin * w), lo + margin * w)


class Potential:
    """``U(z)`` with gradients for a Pyro ``model(*args, **kwargs)``.

    Args:
        model: a Pyro model function.
        args: positional arguments passed to ``model`` on every run.
        kwargs: keyword arguments passed to ``model`` on every run.

    Example:
        >>> import pyro, pyro.distributions as dist, torch
        >>> def model():
        ...     pyro.sample("x", dist.Normal(torch.zeros(2), 1.0).to_event(1))
        >>> pot = Potential(model)
        >>> pot.dim
        2
        >>> u, g = pot.value_and_grad(torch.tensor([[0.0, 0.0], [1.0, 2.0]]))
        >>> [round(float(v), 4) for v in u], g[1].tolist()
        ([1.8379, 4.3379], [1.0, 2.0])
    """

    def __init__(self, model: Callable, args: tuple = (), kwargs: dict | None = None):
        self.model = model
        self.args, self.kwargs = tuple(args), dict(kwargs or {})
        self._count = [0]         # particle evaluations so far (shared with minibatch views of this potential)
        self._discover()

    @property
    def evaluations(self) -> int:
        """Particle evaluations of ``U`` so far (a budget counter)."""
        return self._count[0]

    def minibatch(self, generator, **kw) -> "Potential":
        """This potential on a random minibatch of its model data (``views=k``, ``pixels=fraction``).

        Every argument with a ``minibatch`` method (a :class:`~bayes_brdf.models.ModelData`) is replaced
        by its minibatch; the sites and the evaluation counter are shared.
        """
        new = copy.copy(self)
        mb = lambda a: a.minibatch(generator, **kw) if hasattr(a, "minibatch") else a  # noqa: E731
        new.args = tuple(mb(a) for a in self.args)
        new.kwargs = {k: mb(v) for k, v in self.kwargs.items()}
        return new

    # ------------------------------------------------------------------ set-up
    def _trace(self, fn, *, n: int | None = None):
        def run():
            if n is None:
                return fn(*self.args, **self.kwargs)
            with pyro.plate("particles", n, dim=-(self.plate_nesting + 1)):
                return fn(*self.args, **self.kwargs)
        return poutine.trace(run).get_trace()

    def _discover(self):
        try:
            with torch.random.fork_rng(devices=[]):
                torch.manual_seed(0)
                tr = poutine.trace(lambda: self.model(*self.args, **self.kwargs)).get_trace()
        except InputError:
            raise
        except Exception as e:  # a user's model failing: say where, keep it one line
            raise InputError(f"the model failed on a prior run: {type(e).__name__}: {e}",
                             fix="check the model function runs on its own") from None
        self.plate_nesting = max([len(s["cond_indep_stack"]) for s in tr.nodes.values()
                                  if s["type"] == "sample"] or [0])
        sites, off = [], 0
        for name, s in tr.nodes.items():
            if s["type"] != "sample" or s["is_observed"] or site_is_subsample(s) or s["infer"].get("_deterministic"):
                continue
            fn = s["fn"]
            if fn.has_rsample is False and fn.support.is_discrete:
                raise InputError(f"latent site '{name}' is discrete", fix="enumerate or marginalise it out")
            t = IntervalBijection.maybe(fn.support) or biject_to(fn.support)
            shape = tuple(s["value"].shape)
            ushape = tuple(t.inverse_shape(torch.Size(shape)))
            size = prod(ushape)
            sites.append(Site(name, shape, len(fn.batch_shape), ushape, off, size, t))
            off += size
        if not sites:
            raise InputError("the model has no latent sites", fix="declare parameters with pyro.sample(...)")
        self.sites = sites
        self.dim = off
        v = next(iter(tr.nodes[s.name]["value"] for s in sites))
        self.dtype, self.device = v.dtype, v.device

    # ------------------------------------------------------------------ maps z <-> x
    def _unpack(self, z: Tensor) -> list[Tensor]:
        if z.dim() != 2 or z.shape[1] != self.dim:
            raise InputError(f"particles have shape {tuple(z.shape)}, expected [n, {self.dim}]")
        # one split (its backward is one concatenation, not a zero-filled gradient per site)
        parts = torch.split(z, [s.size for s in self.sites], dim=1)
        return [p.reshape(z.shape[0], *s.ushape) for s, p in zip(self.sites, parts)]

    def _plated(self, s: Site, x: Tensor) -> Tensor:
        """Insert singleton dims so the particle dim sits at the particle plate's position."""
        pad = self.plate_nesting - s.batch_dims
        return x.reshape(x.shape[0], *([1] * pad), *s.shape) if pad > 0 else x

    def to_constrained(self, z: Tensor) -> dict[str, Tensor]:
        """``{site: [n, *shape]}`` constrained values of particles ``z`` ``[n, D]``."""
        return {s.name: s.transform(u) for s, u in zip(self.sites, self._unpack(z))}

    def to_unconstrained(self, values: dict[str, Tensor]) -> Tensor:
        """Inverse of :meth:`to_constrained`: ``{site: [n, *shape]}`` -> ``[n, D]``."""
        parts = []
        for s in self.sites:
            if s.name not in values:
                raise InputError(f"no value for latent site '{s.name}'")
            x = values[s.name]
            parts.append(s.transform.inv(x.to(self.dtype)).reshape(x.shape[0], -1))
        return torch.cat(parts, dim=1)

    def init(self, n: int, seed: int = 0, margin: float = 0.0) -> Tensor:
        """``[n, D]`` particles drawn from the prior (one model run under the particle plate), or the model's own
        start when it offers ``initial_values(data, n, seed=...)`` (``{site: [n, ...]}``, the model protocol).

        ``margin > 0`` clamps the draws of sites on an interval ``[lo, hi]`` to
        ``[lo + margin (hi - lo), hi - margin (hi - lo)]``: a draw near a bound sits where the
        sigmoid of the unconstrained coordinate saturates and the likelihood's gradient vanishes,
        and such a particle can take tens of thousands of steps to come back (docs/samplers.md).
        """
        if not 0 <= margin < 0.5:
            raise InputError(f"init margin must be in [0, 0.5), got {margin!r}")
        start = getattr(self.model, "initial_values", None)
        if callable(start):    # the model protocol: a model that says where to start (docs/models.md)
            vals = start(*self.args, n, seed=seed, **self.kwargs)
            return self.to_unconstrained({s.name: vals[s.name].reshape(n, *s.shape) for s in self.sites}).detach()
        with torch.random.fork_rng(devices=[self.device] if self.device.type == "cuda" else []):
            torch.manual_seed(seed)
            tr = self._trace(self.model, n=n)
        vals = {}
        for s in self.sites:
            v = tr.nodes[s.name]["value"]
            v = v.reshape(n, *s.shape) if v.shape[0] == n else v.expand(n, *v.shape[1:]).reshape(n, *s.shape)
            if margin > 0:
                v = _clamp_inside(v, tr.nodes[s.name]["fn"].support, margin)
            vals[s.name] = v
        return self.to_unconstrained(vals).detach()

    # ------------------------------------------------------------------ energies
    def _fused_plan(self, z: Tensor):
        """The plan of :class:`_UnpackFn` and its kernels when every site is on an interval or unconstrained
        and the native kernels run for ``z`` (else ``None``: the per-site path)."""
        kernels = _interval_kernels(z)
        if kernels is None:
            return None
        plan = []
        for s in self.sites:
            t = s.transform
            if isinstance(t, IntervalBijection):
                plan.append((s.offset, s.size, s.ushape, float(t.lo), float(t.hi - t.lo)))
            elif _unconstrained(t):
                plan.append((s.offset, s.size, s.ushape, None, None))
            else:
                return None
        return tuple(plan), kernels

    def energy(self, z: Tensor, *, jacobian: bool = True) -> Tensor:
        """``U(z)`` ``[n]``; differentiable w.r.t. ``z`` when ``z`` requires grad."""
        n = z.shape[0]
        data, ladj = {}, z.new_zeros(n)
        fused = self._fused_plan(z) if z.dim() == 2 and z.shape[1] == self.dim else None
        if fused is not None:
            *xs, lj = _UnpackFn.apply(z, *fused)
            if jacobian:
                ladj = lj
            for s, x in zip(self.sites, xs):
                data[s.name] = self._plated(s, x)
        else:
            for s, u in zip(self.sites, self._unpack(z)):
                if isinstance(s.transform, IntervalBijection):
                    x, lj = s.transform.forward_with_ladj(u)
                    if jacobian:
                        ladj = ladj + lj
                else:
                    x = s.transform(u)
                    if jacobian:
                        ladj = ladj + s.transform.log_abs_det_jacobian(u, x).reshape(n, -1).sum(1)
                data[s.name] = self._plated(s, x)
        tr = self._trace(poutine.condition(self.model, data=data), n=n)
        logp = z.new_zeros(n)
        for name, site in tr.nodes.items():
            if site["type"] != "sample" or site_is_subsample(site):
                continue
            lp = site["fn"].log_prob(site["value"])
            lp = scale_and_mask(lp, site["scale"], site["mask"])
            logp = logp + self._per_particle(lp, n, name)
        self._count[0] += n
        return -(logp + ladj)

    def _per_particle(self, lp, n: int, name: str) -> Tensor:
        if not isinstance(lp, Tensor) or lp.dim() == 0:
            return torch.as_tensor(lp, dtype=self.dtype, device=self.device).expand(n)
        k = self.plate_nesting + 1
        if lp.dim() > k:
            raise InputError(f"site '{name}' has log-prob shape {tuple(lp.shape)} with dims outside any plate",
                             fix="declare the site's own dimensions with .to_event()")
        lp = lp.reshape(*([1] * (k - lp.dim())), *lp.shape)
        lp = lp.reshape(lp.shape[0], -1).sum(1)
        return lp.expand(n)

    def value_and_grad(self, z: Tensor, *, jacobian: bool = True) -> tuple[Tensor, Tensor]:
        """Energies ``[n]`` and gradients ``[n, D]`` (detached) from one batched model run."""
        with torch.enable_grad():
            z = z.detach().requires_grad_(True)
            u = self.energy(z, jacobian=jacobian)
            (g,) = torch.autograd.grad(u.sum(), z)
        return u.detach(), g

    def __call__(self, z: Tensor) -> Tensor:
        with torch.no_grad():
            return self.energy(z)


class FunctionPotential:
    """A potential from a plain batched function ``U: [n, D] -> [n]`` (test densities, users' own targets).

    Example:
        >>> pot = FunctionPotential(lambda z: 0.5 * (z ** 2).sum(1), dim=3)
        >>> pot.value_and_grad(torch.ones(2, 3))[1].tolist()
        [[1.0, 1.0, 1.0], [1.0, 1.0, 1.0]]
    """

    def __init__(self, fn, dim: int, *, init_std: float = 1.0, dtype=torch.float64):
        self.fn, self.dim, self.init_std, self.dtype = fn, dim, init_std, dtype
        self.device = torch.device("cpu")
        self.evaluations = 0

    def energy(self, z: Tensor, *, jacobian: bool = True) -> Tensor:
        self.evaluations += z.shape[0]
        return self.fn(z)

    def value_and_grad(self, z: Tensor, *, jacobian: bool = True):
        with torch.enable_grad():
            z = z.detach().requires_grad_(True)
            u = self.energy(z)
            (g,) = torch.autograd.grad(u.sum(), z)
        return u.detach(), g

    def __call__(self, z: Tensor) -> Tensor:
        with torch.no_grad():
            return self.energy(z)

    def init(self, n: int, seed: int = 0, margin: float = 0.0) -> Tensor:
        """``[n, D]`` standard-normal draws times ``init_std`` (``margin``: no bounds here, ignored)."""
        gen = torch.Generator().manual_seed(seed)
        return torch.randn(n, self.dim, generator=gen, dtype=self.dtype) * self.init_std

    def to_constrained(self, z: Tensor) -> dict[str, Tensor]:
        return {"z": z}
