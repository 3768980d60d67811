"""High-dimensional truth check: samplers on a per-texel posterior with an exact per-texel answer.

Problem: a ``per_texel`` gray model (albedo and roughness per texel, ``R x R``
texels, so ``D = 2 R^2`` unconstrained dimensions; 2048 at ``R = 32``), uniform
prior, NO smoothness prior, ``V`` collocated flash views through rectified
cameras at resolution ``R`` (pixel ``(i, j)`` of every view *is* texel
``(i, j)``, so the fast native kernel applies and there is no texture
lookup), L1 (Laplace) likelihood with ``sigma``. The observations are the
noiseless renders of a seeded synthetic material (``noise=True`` adds seeded
Laplace noise of scale ``sigma`` instead).

Without a smoothness prior the posterior factorises over texels:
``p(x | y) = prod_t p(a_t, r_t | y_t)`` where ``y_t`` are texel ``t``'s pixels
in all views. So each texel's exact posterior mean and std come from a 2-D
quadrature of its own energy ``e_t(a, r) = sum_{v, c} |y_{v,t,c} - R_{v,t}(a, r)| / sigma``.

Quadrature (:func:`exact_std`). The render is affine in the albedo,
``R(a, r) = R(0, r) + a (R(1, r) - R(0, r))`` (the second term does not depend
on ``r``), so for fixed ``r`` the L1 energy is convex and piecewise linear in
``a`` with kinks at ``(y - R(0, r)) / (R(1, r) - R(0, r))``: the albedo
integrals ``int_0^1 a^k exp(-e_t(a, r)) da`` (k = 0, 1, 2) are sums of
exponential integrals, done in closed form. The roughness is integrated by
the midpoint rule on ``cells`` cells over the whole prior range (4000 by
default: one render of all texels per cell). Streaming log-sum-exp moments
keep memory bounded. Why not a plain 2-D midpoint grid: with noiseless data
the L1 posterior has a cusp at the truth (``exp(-|x| / b)``), for some
texels narrower than a grid cell; a 300 x 300 grid over the whole domain is
off by 0.6% (median over texels) but up to 11% (albedo) / 30% (roughness)
on single texels, and local grids on windows around each texel's mode
were worse (the cusp between cell centres).

Checks (``check=True``): the same with ``2 cells`` cells (convergence); the
closed-form albedo integral against a fine midpoint rule at a few
roughness values; the affine-in-albedo renders against direct renders; and
the factorised energy against ``Potential.energy(z, jacobian=False)`` for
random full maps (they must differ by one constant). :func:`iid_draws`
gives exact independent draws from the quadrature posterior: ``n = 20`` of
them show what a perfect sampler's ratios look like (about 0.98 median std
ratio, ~0.15 std median mean error, from sampling noise alone).

:func:`std_ratios` runs a sampler with ``n = 20`` particles on the model's
``Potential`` and reports, per map, the median over texels of
``(estimated std / exact std)`` (ddof = 1), of
``|estimated mean - exact mean| / exact std`` and of the particles' median
absolute deviation / exact std (a std ratio near 1 can also come from most
particles collapsed on one point plus a few stragglers: the MAD tells).

Measured (samplers of git e015b41, 2 CPU cores): with plain prior draws as the
start, 1-6% of the particles start where the logit of the albedo saturates
and, with the preconditioner shared by the particles, stay there for
thousands of steps (``init_margin`` avoids it). SPOS with ``beta = 3``,
``step_size = 0.005`` is calibrated for both maps (std ratio and MAD as the
``iid`` row) after 4000 steps from ``init_margin = 0.05``; larger steps
over-disperse the albedo (0.01: +10-15%, the preset's 0.05: x2); SVGD and
multi-start SGD collapse (MAD / std < 0.1 against 0.6). See
``benchmarks/bench_highdim_std.py`` for the commands.

Run ``python benchmarks/bench_highdim_std.py`` for the table of all samplers.
"""
from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass

import torch
import torch.nn.functional as F

from ..models.data import ModelData
from ..models.material import per_texel
from ..observations import Observations
from ..potential import Potential
from ..render.gbuffer import GBuffer
from ..render.maps import SVBRDF
from ..render.shade import render, shade
from ..render.surface import PlanarSample
from ..render.views import collocated_views
from ..samplers import make_sampler
from ..samplers.driver import SamplerDiverged, run

SAMPLERS = ("spos", "svgd", "sgld", "emcee", "multistart_sgd", "nuts")

#: budgets used by :func:`main` where a sampler's default would not fit (NUTS: one chain in 2048-D)
DEFAULT_PARAMS = {"nuts": {"warmup_steps": 100, "max_tree_depth": 6}}


@dataclass(frozen=True)
class HighDimSetup:
    """The problem. Defaults: 32 x 32 texels, 5 views, pixel values ~0.05-0.5 (median ~0.2), sigma 0.01."""

    resolution: int = 32
    views: int = 5
    radius: float = 3.0              # camera/flash distance from the sample centre
    power: float = 20.0              # flash power (RGB equal)
    size: float = 2.0                # side of the planar sample
    max_zenith: float = 60.0         # views: Fibonacci directions within this zenith angle
    albedo_range: tuple = (0.2, 0.8)         # the true maps' ranges
    roughness_true_range: tuple = (0.2, 0.7)
    sigma: float = 0.01
    noise: bool = False              # False: noiseless observations; True: seeded Laplace(0, sigma) noise
    seed: int = 0
    dtype: str = "float32"           # the sampler's Potential (the quadrature always runs in float64)


@dataclass
class HighDimProblem:
    setup: HighDimSetup
    model: object
    data: ModelData                  # in setup.dtype (for the samplers)
    data64: ModelData                # float64 (for the quadrature)
    truth: dict                      # {"albedo": [R, R], "roughness": [R, R]} float64


def _smooth_field(R: int, gen: torch.Generator, coarse: int = 6, jitter: float = 0.15) -> torch.Tensor:
    """A field in [0, 1] ``[R, R]``: bicubic up-sampled coarse noise plus a little per-texel jitter."""
    c = torch.rand(1, 1, coarse, coarse, generator=gen, dtype=torch.float64)
    f = F.interpolate(c, size=(R, R), mode="bicubic", align_corners=True)[0, 0]
    f = (f - f.min()) / (f.max() - f.min())
    f = (1 - jitter) * f + jitter * torch.rand(R, R, generator=gen, dtype=torch.float64)
    return f.clamp(0, 1)


def setup(cfg: HighDimSetup | None = None, **kw) -> HighDimProblem:
    """The synthetic per-texel gray material, its 5 rectified collocated views and the model (see module doc)."""
    cfg = cfg or HighDimSetup(**kw)
    R = cfg.resolution
    gen = torch.Generator().manual_seed(cfg.seed)
    (alo, ahi), (rlo, rhi) = cfg.albedo_range, cfg.roughness_true_range
    alb = alo + (ahi - alo) * _smooth_field(R, gen)
    rough = rlo + (rhi - rlo) * _smooth_field(R, gen)
    views = collocated_views(cfg.views, cfg.radius, camera="rectified", resolution=R, power=cfg.power,
                             max_zenith=cfg.max_zenith)
    surf = PlanarSample(cfg.size)
    truth = SVBRDF(alb[None].expand(3, R, R), rough[None], torch.full((3, 1, 1), 0.04, dtype=torch.float64),
                   torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64).reshape(3, 1, 1))
    y = render(truth, views, surf)[0]
    if cfg.noise:
        ng = torch.Generator().manual_seed(cfg.seed + 1)
        u = torch.rand(y.shape, generator=ng, dtype=torch.float64) - 0.5      # Laplace by inverse CDF
        y = y - cfg.sigma * u.sign() * torch.log1p(-2 * u.abs())
    obs = Observations(views, y.float(), surf, meta={"problem": "highdim", **asdict(cfg)})
    model = per_texel(R, albedo="gray", sigma=cfg.sigma, specular=0.04)
    return HighDimProblem(cfg, model, ModelData.from_observations(obs, dtype=getattr(torch, cfg.dtype)),
                          ModelData.from_observations(obs, dtype=torch.float64), {"albedo": alb, "roughness": rough})


# ---------------------------------------------------------------- per-texel energies
def texel_energies(problem: HighDimProblem, a: torch.Tensor, r: torch.Tensor, *, chunk: int = 500) -> torch.Tensor:
    """Per-texel energies ``[n, T]`` (float64, without constants) of ``n`` rows of values.

    ``a, r``: ``[n]`` (one value for every texel: constant maps) or ``[n, T]``
    (per-texel values). ``e[k, t] = sum_{v, c} w |y - R(a[k, t], r[k, t])| / sigma``
    (Laplace; ``(y - R)^2 / (2 sigma^2)`` for a Gaussian likelihood), times the data's scale.
    """
    d, m = problem.data64, problem.model
    g: GBuffer = d.gbuffer
    H, W = g.resolution
    y = d.images.permute(0, 3, 1, 2)                      # [V, 3, H, W]
    w = (d.weight * d.scale)[:, None]                     # [V, 1, H, W]
    spec = torch.full((3, 1, 1), float(m.specular), dtype=torch.float64)
    nrm = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64).reshape(3, 1, 1)
    out = []
    with torch.no_grad():
        for s in range(0, a.shape[0], chunk):
            ac, rc = a[s:s + chunk].double(), r[s:s + chunk].double()
            n = ac.shape[0]
            if ac.dim() == 1:
                ac, rc = ac.reshape(n, 1, 1, 1), rc.reshape(n, 1, 1, 1)
            else:
                ac, rc = ac.reshape(n, 1, H, W), rc.reshape(n, 1, H, W)
            img = shade(SVBRDF(ac.expand(n, 3, *ac.shape[-2:]), rc, spec, nrm), g, channels_last=False)
            diff = img - y                                # [n, V, 3, H, W]
            if m.likelihood == "laplace":
                e = (w * diff.abs()).sum((1, 2)) / m.sigma
            else:
                e = (w * diff * diff).sum((1, 2)) / (2 * m.sigma ** 2)
            out.append(e.reshape(n, H * W))
    return torch.cat(out)


class _Moments:
    """Streaming per-texel posterior moments from weighted cells (log-sum-exp stabilised).

    ``add(e, a, r, edge, aa)``: cell energies ``e [n, T]`` (weight ``exp(-e)``),
    the cells' albedo ``a`` and roughness ``r`` (``[n]`` or ``[n, T]``; or the
    conditional means of the albedo within the cell, with ``aa`` its conditional
    second moment), and whether each cell is on the domain's edge ``[n]``.
    """

    def __init__(self, T: int):
        z = lambda: torch.zeros(T, dtype=torch.float64)  # noqa: E731
        self.emin = torch.full((T,), math.inf, dtype=torch.float64)
        self.s0, self.sa, self.sr, self.saa, self.srr = z(), z(), z(), z(), z()
        self.edge = z()

    def add(self, e, a, r, edge, aa=None):
        new_min = torch.minimum(self.emin, e.min(0).values)
        f = torch.exp(new_min - self.emin)            # re-reference the sums to the new minimum (<= 1)
        f = torch.where(torch.isfinite(self.emin), f, torch.zeros_like(f))
        for k in ("s0", "sa", "sr", "saa", "srr", "edge"):
            setattr(self, k, getattr(self, k) * f)
        self.emin = new_min
        wt = torch.exp(-(e - new_min))                 # [n, T]
        col = lambda x: x[:, None] if x.dim() == 1 else x  # noqa: E731
        a, r = col(a), col(r)
        aa = a * a if aa is None else col(aa)
        self.s0 += wt.sum(0)
        self.sa += (wt * a).sum(0)
        self.sr += (wt * r).sum(0)
        self.saa += (wt * aa).sum(0)
        self.srr += (wt * r * r).sum(0)
        self.edge += (wt * col(edge.to(wt.dtype))).sum(0)

    def result(self) -> dict:
        ma, mr = self.sa / self.s0, self.sr / self.s0
        va = (self.saa / self.s0 - ma * ma).clamp_min(0)
        vr = (self.srr / self.s0 - mr * mr).clamp_min(0)
        return {"mean_albedo": ma, "mean_roughness": mr, "std_albedo": va.sqrt(), "std_roughness": vr.sqrt(),
                "edge_mass": self.edge / self.s0}


# ---------------------------------------------------------------- the albedo integral in closed form
def _phis(x: torch.Tensor):
    """``phi_k(x) = int_0^1 t^k exp(-x t) dt`` for ``k = 0, 1, 2`` and ``x >= 0`` (Taylor near 0)."""
    small = x < 1e-2
    xs = torch.where(small, torch.ones_like(x), x)
    em = torch.exp(-xs)
    p0 = -torch.expm1(-xs) / xs
    p1 = (1 - em * (1 + xs)) / xs ** 2
    p2 = (2 - em * (xs * xs + 2 * xs + 2)) / xs ** 3
    t0 = 1 - x / 2 + x * x / 6 - x ** 3 / 24
    t1 = 0.5 - x / 3 + x * x / 8 - x ** 3 / 30
    t2 = 1 / 3 - x / 4 + x * x / 10 - x ** 3 / 36
    return torch.where(small, t0, p0), torch.where(small, t1, p1), torch.where(small, t2, p2)


def _albedo_segments(res: torch.Tensor, dd: torch.Tensor, w: torch.Tensor, sigma: float):
    """The Laplace energy as a function of the albedo, ``E(a) = sum_k w_k |res_k - a dd_k| / sigma`` on ``[0, 1]``.

    ``res [n, K, T]`` (observed minus the albedo-free render), ``dd, w [1, K, T]``.
    Convex and piecewise linear with kinks at ``res_k / dd_k``: returns its
    breakpoints ``p [n, K + 2, T]`` (sorted, in ``[0, 1]``) and the energies there.
    """
    lit = dd > 0
    c = torch.where(lit, w * dd / sigma, torch.zeros_like(dd))                  # slopes
    b = torch.where(lit, res / torch.where(lit, dd, torch.ones_like(dd)), torch.zeros_like(res))
    c0 = (torch.where(lit, torch.zeros_like(res), w * res.abs()) / sigma).sum(1, keepdim=True)
    bs, order = b.sort(1)                                                      # [n, K, T]
    cs = c.expand_as(b).gather(1, order)
    C, B = cs.cumsum(1), (cs * bs).cumsum(1)                                   # sums over the kinks <= bs_i
    Ekink = c0 + bs * (2 * C - C[:, -1:]) - (2 * B - B[:, -1:])                # E at each kink (exact there)
    E0 = c0 + (c * b.abs()).sum(1, keepdim=True)                               # E(0), E(1)
    E1 = c0 + (c * (1 - b).abs()).sum(1, keepdim=True)
    Ekink = torch.where(bs < 0, E0, torch.where(bs > 1, E1, Ekink))            # kinks outside [0, 1] sit on an end
    return torch.cat([torch.zeros_like(E0), bs.clamp(0, 1), torch.ones_like(E0)], 1), torch.cat([E0, Ekink, E1], 1)


def _segment_terms(p: torch.Tensor, E: torch.Tensor):
    """Per segment of the piecewise-linear ``E(a)``: its lower-energy end ``anchor``, the direction ``sgn``
    into the segment, its length ``L``, the energy rise ``x`` across it and its weight
    ``int exp(-(E - min E))`` over it (``[n, K + 1, T]`` each), and ``min E`` ``[n, T]``."""
    lo, hi, Elo, Ehi = p[:, :-1], p[:, 1:], E[:, :-1], E[:, 1:]
    L = hi - lo
    left = Elo <= Ehi                                     # integrate from the lower-energy end, inwards
    anchor = torch.where(left, lo, hi)
    sgn = torch.where(left, 1.0, -1.0).to(p.dtype)
    x = (Ehi - Elo).abs()
    emin = E.min(1).values
    return anchor, sgn, L, x, torch.exp(-(torch.minimum(Elo, Ehi) - emin[:, None])), emin


def _albedo_moments(p: torch.Tensor, E: torch.Tensor):
    """Exact ``-log int_0^1 exp(-E(a)) da`` and the conditional ``E[a]``, ``E[a^2]`` (each ``[n, T]``)."""
    anchor, sgn, L, x, wgt, emin = _segment_terms(p, E)
    f0, f1, f2 = _phis(x)
    J0, J1, J2 = L * f0, L * L * f1, L ** 3 * f2          # int_0^L t^k exp(-x t / L) dt
    m0 = (wgt * J0).sum(1)
    m1 = (wgt * (anchor * J0 + sgn * J1)).sum(1)
    m2 = (wgt * (anchor * anchor * J0 + 2 * sgn * anchor * J1 + J2)).sum(1)
    return emin - m0.log(), m1 / m0, m2 / m0


def _r_slices(problem: HighDimProblem, r: torch.Tensor, block: int = 32, segments: bool = False):
    """For roughness values ``r [Nr]`` (shared) or ``[Nr, T]`` (per texel): yields ``(j, e, ma, maa)`` per block,
    ``e [k, T] = -log int exp(-E(a, r_j)) da`` and the conditional albedo moments (exact, Laplace likelihood);
    ``segments=True``: ``(j, p, E)``, the breakpoints of ``E(a)`` and the energies there.

    When the three channels of the data, the weights and the lights are equal (a gray setup, noiseless)
    they are merged into one with three times the weight: same energies, a third of the work.
    """
    d, m = problem.data64, problem.model
    if m.likelihood != "laplace":
        raise NotImplementedError("the closed-form albedo integral is for the Laplace likelihood")
    g: GBuffer = d.gbuffer
    V, (H, W) = g.num_views, g.resolution
    T = H * W
    y = d.images.permute(0, 3, 1, 2)                                   # [V, 3, H, W]
    w = (d.weight * d.scale)[:, None].expand(V, 3, H, W)
    ls = g.light_scale
    gray = all(bool((t[..., :1, :, :] == t).all()) for t in (y, ls.reshape(-1, 3, H, W)))
    C = 1 if gray else 3
    y = y[:, :C].reshape(1, V * C, T)
    w = (w[:, :C] * (3 // C)).reshape(1, V * C, T)
    spec = torch.full((3, 1, 1), float(m.specular), dtype=torch.float64)
    nrm = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64).reshape(3, 1, 1)

    def img(alb, rough):
        n = alb.shape[0]
        out = shade(SVBRDF(alb.expand(n, 3, *alb.shape[-2:]), rough, spec, nrm), g, channels_last=False)
        return out[:, :, :C].reshape(n, V * C, T)

    with torch.no_grad():
        one = torch.ones(1, 1, 1, 1, dtype=torch.float64)
        dd = img(one, 0.5 * one) - img(0 * one, 0.5 * one)
        Nr = r.shape[0]
        rr = r.reshape(Nr, 1, 1, 1) if r.dim() == 1 else r.reshape(Nr, 1, H, W)
        for s in range(0, Nr, block):
            res = y - img(torch.zeros_like(rr[s:s + block]), rr[s:s + block])
            j = torch.arange(s, s + res.shape[0])
            if segments:
                yield (j, *_albedo_segments(res, dd, w, m.sigma))
            else:
                yield (j, *_albedo_moments(*_albedo_segments(res, dd, w, m.sigma)))


def _r_pass(problem, Nr: int, keep: bool = False) -> dict:
    """Midpoint rule over ``Nr`` roughness cells, the albedo integrated exactly within each."""
    lo, hi = problem.model.roughness_range
    T = problem.setup.resolution ** 2
    r = lo + (hi - lo) * (torch.arange(Nr, dtype=torch.float64) + 0.5) / Nr
    acc = _Moments(T)
    kept = []
    for j, e, ma, maa in _r_slices(problem, r):
        acc.add(e, ma, r[j], (j == 0) | (j == Nr - 1), aa=maa)
        if keep:
            kept.append(e)
    out = acc.result()
    if keep:
        out["r_cells"], out["r_energy"] = r, torch.cat(kept)   # [Nr], [Nr, T]: for exact i.i.d. draws
    return out


def check_albedo_integral(problem: HighDimProblem, n_r: int = 4, n_a: int = 8000, seed: int = 0) -> float:
    """Max difference between the closed-form albedo integral and a fine midpoint rule (``n_a`` cells) at
    ``n_r`` random roughness values, over all texels: ``|d log Z|`` and ``|d E[a]|, |d std(a)|`` / std(a)."""
    lo, hi = problem.model.roughness_range
    gen = torch.Generator().manual_seed(seed)
    r = lo + (hi - lo) * torch.rand(n_r, generator=gen, dtype=torch.float64)
    (_, e, ma, maa), = list(_r_slices(problem, r, block=n_r))
    a = (torch.arange(n_a, dtype=torch.float64) + 0.5) / n_a
    T = e.shape[1]
    worst = 0.0
    for k in range(n_r):
        acc = _Moments(T)
        for ac in a.split(1000):
            for _, _, eg in _grid_energies(problem, ac, r[k:k + 1]):
                acc.add(eg, ac, torch.zeros(ac.shape[0], dtype=torch.float64), torch.zeros(ac.shape[0], dtype=torch.bool))
        q = acc.result()
        sd = (maa[k] - ma[k] ** 2).clamp_min(0).sqrt()
        logz = -acc.emin + (acc.s0 / n_a).log()
        worst = max(worst, float((logz + e[k]).abs().max()), float(((q["mean_albedo"] - ma[k]).abs() / sd).max()),
                    float(((q["std_albedo"] - sd).abs() / sd).max()))
    return worst


def iid_draws(problem: HighDimProblem, exact: dict, n: int = 20, seed: int = 0) -> dict:
    """``n`` exact independent draws per texel from the quadrature posterior: ``{"albedo", "roughness"}`` ``[n, T]``.

    Roughness: a cell of the roughness grid by its marginal weight, uniform within it; albedo: exactly from
    its conditional given that roughness (a segment of the piecewise-linear energy by its weight, then a
    truncated exponential within it).
    """
    gen = torch.Generator().manual_seed(seed)
    r_cells, e = exact["r_cells"], exact["r_energy"]                  # [Nr], [Nr, T]
    T = e.shape[1]
    h = float(r_cells[1] - r_cells[0])
    prob = torch.exp(-(e - e.min(0).values)).T                        # [T, Nr]
    idx = torch.multinomial(prob, n, replacement=True, generator=gen).T   # [n, T]
    r = r_cells[idx] + (torch.rand(n, T, generator=gen, dtype=torch.float64) - 0.5) * h
    (_, p, E), = list(_r_slices(problem, r, block=n, segments=True))
    anchor, sgn, L, x, wgt, _ = _segment_terms(p, E)
    f0, _, _ = _phis(x)
    mass = (wgt * L * f0).permute(0, 2, 1).reshape(n * T, -1)         # [n T, segments]
    k = torch.multinomial(mass, 1, generator=gen)[:, 0].reshape(n, T)
    pick = lambda t: t.gather(1, k[:, None]).squeeze(1)               # noqa: E731
    anchor, sgn, L, x = pick(anchor), pick(sgn), pick(L), pick(x)
    u = torch.rand(n, T, generator=gen, dtype=torch.float64)
    xs = x.clamp_min(1e-12)
    frac = torch.where(x < 1e-9, u, -torch.log1p(u * torch.expm1(-xs)) / xs)   # truncated exponential on [0, 1]
    return {"albedo": anchor + sgn * L * frac, "roughness": r}


def _grid_energies(problem: HighDimProblem, a: torch.Tensor, r: torch.Tensor, block: int = 2000):
    """Energies on the tensor grid ``a x r``, per texel, as blocks ``(i, j, e [len(i), T])``.

    ``a [Na]`` / ``[Na, T]`` and ``r [Nr]`` / ``[Nr, T]`` (shared or per-texel values);
    row ``k`` of a block is the grid point ``(a[i[k]], r[j[k]])``. Uses that the
    render is affine in the albedo, ``R(a, r) = R(0, r) + a (R(1, r) - R(0, r))``
    with the second term independent of ``r``: one render per roughness value
    instead of one per grid point (checked against :func:`texel_energies`).
    """
    d, m = problem.data64, problem.model
    g: GBuffer = d.gbuffer
    V, (H, W) = g.num_views, g.resolution
    T = H * W
    y = d.images.permute(0, 3, 1, 2).reshape(1, V * 3, T)
    w = (d.weight * d.scale)[:, None].expand(V, 3, H, W).reshape(1, V * 3, T)
    spec = torch.full((3, 1, 1), float(m.specular), dtype=torch.float64)
    nrm = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64).reshape(3, 1, 1)

    def img(alb, rough):  # alb, rough [n, 1, h, w] -> [n, V*3, T]
        n = alb.shape[0]
        out = shade(SVBRDF(alb.expand(n, 3, *alb.shape[-2:]), rough, spec, nrm), g, channels_last=False)
        return out.reshape(n, V * 3, T)

    with torch.no_grad():
        one = torch.ones(1, 1, 1, 1, dtype=torch.float64)
        dd = img(one, 0.5 * one) - img(0 * one, 0.5 * one)             # [1, V*3, T]: the diffuse part per unit albedo
        Na, Nr = a.shape[0], r.shape[0]
        rr = r.reshape(Nr, 1, 1, 1) if r.dim() == 1 else r.reshape(Nr, 1, H, W)
        aa = a.reshape(Na, 1, 1) if a.dim() == 1 else a.reshape(Na, 1, T)
        nr = max(1, block // Na)
        ia = torch.arange(Na)
        for s in range(0, Nr, nr):
            res = y - img(torch.zeros_like(rr[s:s + nr]), rr[s:s + nr])   # [nr, V*3, T]
            k = res.shape[0]
            diff = res[:, None] - aa[None] * dd[None]                     # [nr, Na, V*3, T]
            if m.likelihood == "laplace":
                e = (w * diff.abs()).sum(2) / m.sigma
            else:
                e = (w * diff * diff).sum(2) / (2 * m.sigma ** 2)
            j = torch.arange(s, s + k)
            yield ia.repeat(k), j.repeat_interleave(Na), e.reshape(k * Na, T)


def _grid_pass(problem, a: torch.Tensor, r: torch.Tensor) -> dict:
    """Posterior moments per texel on the midpoint grid ``a x r`` (``[N]`` shared or ``[N, T]`` per-texel values)."""
    T = problem.setup.resolution ** 2
    Na, Nr = a.shape[0], r.shape[0]
    acc = _Moments(T)
    for i, j, e in _grid_energies(problem, a, r):
        edge = (i == 0) | (i == Na - 1) | (j == 0) | (j == Nr - 1)
        acc.add(e, a[i], r[j], edge)
    return acc.result()


def _global_pass(problem, grid: int) -> dict:
    lo, hi = problem.model.roughness_range
    ca = (torch.arange(grid, dtype=torch.float64) + 0.5) / grid
    cr = lo + (hi - lo) * (torch.arange(grid, dtype=torch.float64) + 0.5) / grid
    out = _grid_pass(problem, ca, cr)
    out["cell"] = (1.0 / grid, (hi - lo) / grid)
    return out


def check_fast_path(problem: HighDimProblem, n: int = 7, seed: int = 0) -> float:
    """Max relative difference between the affine-in-albedo grid energies and :func:`texel_energies`."""
    gen = torch.Generator().manual_seed(seed)
    T = problem.setup.resolution ** 2
    lo, hi = problem.model.roughness_range
    a = torch.rand(n, T, generator=gen, dtype=torch.float64)
    r = lo + (hi - lo) * torch.rand(n + 1, T, generator=gen, dtype=torch.float64)
    worst = 0.0
    for i, j, e in _grid_energies(problem, a, r):
        ref = texel_energies(problem, a[i], r[j])
        worst = max(worst, float(((e - ref).abs() / ref.abs().clamp_min(1e-6)).max()))
    return worst


def check_factorisation(problem: HighDimProblem, n: int = 6, seed: int = 0) -> dict:
    """How far ``Potential.energy(z, jacobian=False) - sum_t e_t(a_t, r_t)`` is from one constant.

    Random full maps around the truth (16 texels redrawn anywhere in the
    domain, the rest jittered by 0.02): the difference must be one constant
    (the likelihood's and the prior's normalisation). Returns the spread (max
    deviation from the mean difference, energy units) for the Potential in
    float64 (``"float64"``, ~1e-9: exact) and in the samplers' dtype
    (``"sampler_dtype"``, float32 rounding of energies ~1e4-1e5), and the
    largest energy (``"energy_scale"``).
    """
    R = problem.setup.resolution
    gen = torch.Generator().manual_seed(seed)
    lo, hi = problem.model.roughness_range
    a = (problem.truth["albedo"][None] + 0.02 * torch.randn(n, R, R, generator=gen, dtype=torch.float64))
    r = (problem.truth["roughness"][None] + 0.02 * torch.randn(n, R, R, generator=gen, dtype=torch.float64))
    a[:, :4, :4] = torch.rand(n, 4, 4, generator=gen, dtype=torch.float64)
    r[:, :4, :4] = lo + (hi - lo) * torch.rand(n, 4, 4, generator=gen, dtype=torch.float64)
    a, r = a.clamp(0.01, 0.99), r.clamp(lo + 0.01, hi - 0.01)
    e = texel_energies(problem, a.reshape(n, -1), r.reshape(n, -1)).sum(1)

    def spread(data, default):
        # The model's Box prior casts its sites to the *default* dtype whatever the data's dtype
        # (bayes_brdf/models/priors.py), so a float64 Potential needs the float64 default as well.
        old = torch.get_default_dtype()
        torch.set_default_dtype(default)
        try:
            pot = Potential(problem.model, (data,))
            with torch.no_grad():
                z = pot.to_unconstrained({"albedo": a[:, None], "roughness": r[:, None]})
                u = pot.energy(z, jacobian=False).double()
        finally:
            torch.set_default_dtype(old)
        diff = u - e
        return float((diff - diff.mean()).abs().max())

    return {"float64": spread(problem.data64, torch.float64),
            "sampler_dtype": spread(problem.data, torch.get_default_dtype()), "energy_scale": float(e.max())}


_EXACT: dict = {}


def exact_std(problem: HighDimProblem, *, cells: int = 4000, check: bool = True, grid: int = 0,
              verbose: bool = False) -> dict:
    """Exact per-texel posterior means and stds (see the module doc).

    The albedo integral is done in closed form (the energy is convex piecewise
    linear in the albedo), the roughness by the midpoint rule on ``cells`` cells
    over the whole roughness range. Returns ``{"mean_albedo", "std_albedo",
    "mean_roughness", "std_roughness"}`` (``[R, R]`` float64 each), the
    roughness grid with every texel's energies there (``"r_cells"``,
    ``"r_energy"``, for :func:`iid_draws`), and with ``check``:
    ``"converged"`` (max relative change of the stds, and max change of the
    means in stds, against ``2 * cells`` cells), ``"albedo_integral"``
    (:func:`check_albedo_integral`), ``"factorisation"``
    (:func:`check_factorisation`), ``"fast_path"`` (:func:`check_fast_path`);
    ``grid > 0`` adds ``"grid2d"``: what a plain ``grid x grid`` 2-D midpoint
    rule over the whole domain gives (it is NOT converged at 300: see the
    module doc). ``"seconds"``. Cached per setup.
    """
    key = (problem.setup, cells, check, grid)
    if key in _EXACT:
        return _EXACT[key]
    t0 = time.perf_counter()
    R = problem.setup.resolution
    log = print if verbose else (lambda *a, **k: None)
    q = _r_pass(problem, cells, keep=True)
    log(f"  {cells} roughness cells: {time.perf_counter() - t0:.1f}s")
    out = {k: v.reshape(R, R) for k, v in q.items() if k.startswith(("mean_", "std_"))}
    out["r_cells"], out["r_energy"] = q["r_cells"], q["r_energy"]
    out["settings"] = {"cells": cells}
    maps = ("albedo", "roughness")

    def rel(a, b):
        return {"max_rel_std_change": max(float(((a[f"std_{m}"] - b[f"std_{m}"]).abs() / b[f"std_{m}"]).max())
                                          for m in maps),
                "max_mean_change_in_std": max(float(((a[f"mean_{m}"] - b[f"mean_{m}"]).abs() / b[f"std_{m}"]).max())
                                              for m in maps),
                "median_rel_std_error": max(float(((a[f"std_{m}"] - b[f"std_{m}"]).abs() / b[f"std_{m}"]).median())
                                            for m in maps)}
    if check:
        fine = _r_pass(problem, 2 * cells)
        out["converged"] = rel({k: v.reshape(R, R) for k, v in fine.items()}, out)
        log(f"  {2 * cells} cells: {time.perf_counter() - t0:.1f}s")
        out["albedo_integral"] = check_albedo_integral(problem)
        out["factorisation"] = check_factorisation(problem)
        out["fast_path"] = check_fast_path(problem)
        log(f"  checks: {time.perf_counter() - t0:.1f}s")
    if grid:
        g = _global_pass(problem, grid)
        out["grid2d"] = {"grid": grid, **rel({k: v.reshape(R, R) for k, v in g.items() if k != "cell"}, out)}
        log(f"  2-D {grid}x{grid} grid: {time.perf_counter() - t0:.1f}s")
    out["seconds"] = time.perf_counter() - t0
    _EXACT[key] = out
    return out


# ---------------------------------------------------------------- samplers vs truth
def summarise(albedo: torch.Tensor, roughness: torch.Tensor, exact: dict) -> dict:
    """Samples ``[n, T]`` per map against the exact posterior: median over texels of ``std (ddof 1) / exact std``
    (``ratio_*``, with the 10th / 90th percentiles ``ratio_q10_*``, ``ratio_q90_*``, and the fraction of
    texels whose ratio is above 2 or below 1/2, ``off2_*``: the tails a user looking at one texel meets), of
    ``|mean - exact mean| / exact std`` (``mean_err_*``) and of the particles' median absolute deviation
    over the exact std (``mad_*``: robust to a few stragglers; compare with the ``iid`` row, ~0.6, since
    a std ratio near 1 can also come from most particles collapsed on one point plus a few far away)."""
    out = {}
    for p, x in (("albedo", albedo), ("roughness", roughness)):
        s = x.double().reshape(x.shape[0], -1)
        ex_m, ex_s = exact[f"mean_{p}"].reshape(-1), exact[f"std_{p}"].reshape(-1)
        ratio = s.std(0, unbiased=True) / ex_s
        out[f"ratio_{p}"] = float(ratio.median())
        out[f"ratio_q10_{p}"] = float(ratio.quantile(0.1))
        out[f"ratio_q90_{p}"] = float(ratio.quantile(0.9))
        out[f"off2_{p}"] = float(((ratio > 2) | (ratio < 0.5)).double().mean())
        out[f"mean_err_{p}"] = float(((s.mean(0) - ex_m).abs() / ex_s).median())
        mad = (s - s.median(0).values).abs().median(0).values
        out[f"mad_{p}"] = float((mad / ex_s).median())
    return out


def std_ratios(sampler_name: str = "spos", params: dict | None = None, steps: int | None = None, seed: int = 0, *,
               particles: int = 20, problem: HighDimProblem | None = None, exact: dict | None = None,
               progress: bool = False, trace_every: int = 0, init_margin: float | None = None) -> dict:
    """Run a sampler on the model's Potential from prior draws; compare its particles with the exact posterior.

    Returns :func:`summarise` of the final particles plus ``"seconds"``,
    ``"steps"``, ``"evaluations"`` and ``"params"``; ``"error"`` instead when
    the sampler diverged. NUTS runs ``warmup_steps + particles * thin`` steps
    (one chain, its last draws; ``steps`` is ignored). Two pseudo-samplers:
    ``"iid"`` (exact independent draws from the quadrature posterior: what
    ``particles`` perfect samples give) and ``"prior"`` (the initial particles).
    ``steps`` / ``init_margin`` ``None``: the preset's. ``init_margin > 0`` clamps the initial prior draws to the central ``1 - 2 init_margin`` of each
    parameter's range (prior draws near 0 or 1 sit where the logit transform saturates; with the
    preconditioner shared by the particles they take tens of thousands of steps to come back).
    ``trace_every > 0`` adds ``"trace"``: ``[t, ratio_albedo, ratio_roughness, mean_err_albedo,
    mean_err_roughness]`` of the particles after every ``trace_every`` steps (a run of fewer steps with a
    constant step size, e.g. SGLD, is the same trajectory cut short; with annealing it is not).
    """
    problem = problem or setup()
    exact = exact or exact_std(problem)
    if sampler_name == "iid":
        d = iid_draws(problem, exact, particles, seed)
        return {"sampler": "iid", "params": {}, "steps": 0, "seconds": 0.0, "evaluations": 0,
                **summarise(d["albedo"], d["roughness"], exact)}
    pot = Potential(problem.model, (problem.data,))
    z0 = pot.init(particles, seed=seed)
    if sampler_name not in ("iid", "prior"):
        smp, cfg = make_sampler(sampler_name, params=params)
        steps = cfg.steps if steps is None else steps
        init_margin = cfg.init_margin if init_margin is None else init_margin
    init_margin = init_margin or 0.0
    if init_margin > 0:
        x0 = pot.to_constrained(z0)
        for k, (lo, hi) in (("albedo", (0.0, 1.0)), ("roughness", tuple(problem.model.roughness_range))):
            x0[k] = x0[k].clamp(lo + init_margin * (hi - lo), hi - init_margin * (hi - lo))
        z0 = pot.to_unconstrained(x0)
    if sampler_name == "prior":
        x = pot.to_constrained(z0)
        return {"sampler": "prior", "params": {}, "steps": 0, "seconds": 0.0, "evaluations": 0,
                **summarise(x["albedo"], x["roughness"], exact)}
    n_steps = steps
    if smp.name == "nuts":
        n_steps = smp.warmup_steps + particles * smp.thin
    trace = []

    def record(t, state, info):
        if trace_every and (t + 1) % trace_every == 0:
            with torch.no_grad():
                xs = pot.to_constrained(smp.particles(state))
            v = summarise(xs["albedo"], xs["roughness"], exact)
            trace.append([t + 1, v["ratio_albedo"], v["ratio_roughness"], v["mean_err_albedo"], v["mean_err_roughness"]])

    t0 = time.perf_counter()
    try:
        res = run(smp, pot, particles=particles, steps=n_steps, seed=seed, progress=progress, checkpoint_every=0,
                  callbacks=(record,) if trace_every else (), z0=z0)
    except Exception as e:  # noqa: BLE001  (a benchmark row: report the failure, keep going)
        msg = str(e).splitlines()[0] if str(e) else ""
        if not isinstance(e, SamplerDiverged):
            msg = f"{type(e).__name__}: {msg}"
        return {"sampler": smp.name, "params": smp.params(), "steps": n_steps, "seconds": time.perf_counter() - t0,
                "evaluations": pot.evaluations, "error": msg}
    secs = time.perf_counter() - t0
    x = pot.to_constrained(res.z)
    out = {"sampler": smp.name, "params": smp.params(), "steps": n_steps, "seconds": secs,
           "evaluations": res.evaluations, **summarise(x["albedo"], x["roughness"], exact)}
    if trace_every:
        out["trace"] = trace
    return out


def compare(samplers=("iid", "prior") + SAMPLERS, *, steps: int | None = None, seed: int = 0,
            params: dict | None = None, problem: HighDimProblem | None = None, exact: dict | None = None,
            particles: int = 20, progress: bool = False, init_margin: float | None = None) -> dict:
    """``{sampler: std_ratios(...)}``; ``params`` maps a sampler name to hyper-parameter overrides
    (on top of :data:`DEFAULT_PARAMS`)."""
    problem = problem or setup()
    exact = exact or exact_std(problem)
    out = {}
    for name in samplers:
        p = {**DEFAULT_PARAMS.get(name, {}), **(params or {}).get(name, {})}
        out[name] = std_ratios(name, p, steps, seed, particles=particles, problem=problem, exact=exact,
                               progress=progress, init_margin=init_margin)
    return out


def code_version() -> str:
    """The git commit and a hash of the sampler sources (the samplers change; a table says which it measured)."""
    import hashlib
    import subprocess
    from pathlib import Path

    src = Path(__file__).resolve().parents[1] / "samplers"
    h = hashlib.sha256(b"".join(f.read_bytes() for f in sorted(src.glob("*.py")))).hexdigest()[:12]
    try:
        head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=src, capture_output=True, text=True,
                              timeout=10).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--", "."], cwd=src, capture_output=True, text=True,
                               timeout=10).stdout.strip()
    except Exception:  # noqa: BLE001  (no git: the hash alone)
        head, dirty = "", ""
    return f"samplers sha256 {h}" + (f" (git {head}{', modified' if dirty else ''})" if head else "")


def describe(problem: HighDimProblem, exact: dict) -> str:
    """A paragraph: the problem, the truth's summary and the quadrature checks."""
    s = problem.setup
    y = problem.data.images
    q = lambda t: f"{float(t.median()):.4f} [{float(t.min()):.4f}, {float(t.max()):.4f}]"  # noqa: E731
    lines = [f"per_texel gray, {s.resolution}x{s.resolution} texels (D = {2 * s.resolution ** 2}), {s.views} rectified "
             f"collocated views (radius {s.radius}, power {s.power}), sigma {s.sigma}, Laplace likelihood, "
             f"{'seeded Laplace noise' if s.noise else 'noiseless'} observations "
             f"(pixels: median {float(y.median()):.3f}, 5-95% [{float(y.quantile(0.05)):.3f}, "
             f"{float(y.quantile(0.95)):.3f}]).",
             f"Exact posterior std, median [min, max] over texels: albedo {q(exact['std_albedo'])}, "
             f"roughness {q(exact['std_roughness'])}."]
    if "converged" in exact:
        c, f = exact["converged"], exact["factorisation"]
        lines.append(
            f"Quadrature ({exact['settings']['cells']} roughness cells, albedo in closed form) vs "
            f"{2 * exact['settings']['cells']} cells: max rel. std change {c['max_rel_std_change']:.1e}, max mean "
            f"change {c['max_mean_change_in_std']:.1e} std. Closed-form albedo integral vs an 8000-cell midpoint "
            f"rule: max diff {exact['albedo_integral']:.1e}. Factorised energy vs Potential.energy(jacobian=False): "
            f"spread {f['float64']:.1e} in float64 ({f['sampler_dtype']:.1e} with the samplers' {s.dtype}; energies up "
            f"to {f['energy_scale']:.0f}). Affine-in-albedo renders vs direct: {exact['fast_path']:.1e}.")
    if "grid2d" in exact:
        g = exact["grid2d"]
        lines.append(f"A plain {g['grid']}x{g['grid']} 2-D midpoint grid would be off by {g['median_rel_std_error']:.1%} "
                     f"(median rel. std error; max {g['max_rel_std_change']:.2g}).")
    lines.append(f"Truth: {exact['seconds']:.0f} s. Code: {code_version()}, torch threads {torch.get_num_threads()}.")
    return "\n".join(lines)


def markdown(table: dict) -> str:
    lines = ["| sampler | std ratio albedo (q10-q90) | std ratio roughness (q10-q90) | off by > 2x albedo / roughness | "
             "|mean err| / std albedo | |mean err| / std roughness | MAD / std albedo | MAD / std roughness | steps | "
             "seconds |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for name, v in table.items():
        if "error" in v:
            lines.append(f"| {name} | failed: {v['error']} | | | | | | | {v['steps']} | {v['seconds']:.1f} |")
            continue
        lines.append(f"| {name} | {v['ratio_albedo']:.3g} ({v['ratio_q10_albedo']:.2g}-{v['ratio_q90_albedo']:.2g}) | "
                     f"{v['ratio_roughness']:.3g} ({v['ratio_q10_roughness']:.2g}-{v['ratio_q90_roughness']:.2g}) | "
                     f"{v['off2_albedo']:.1%} / {v['off2_roughness']:.1%} | {v['mean_err_albedo']:.3g} | {v['mean_err_roughness']:.3g} | {v['mad_albedo']:.2g} | "
                     f"{v['mad_roughness']:.2g} | {v['steps']} | {v['seconds']:.1f} |")
    return "\n".join(lines)
