"""Every CUDA path of the library against the CPU, within float32 tolerances, with timings.

Usage (on a machine with a GPU, a CUDA build of torch and Mitsuba's ``cuda_ad_rgb``):

    python benchmarks/gpu_check.py                    # --device cuda, the benchmark's sizes
    python benchmarks/gpu_check.py --quick            # small sizes, a minute or two
    python benchmarks/gpu_check.py --device cpu --quick   # no GPU: exercise the script itself (see below)

Checks, each computed on the CPU (the reference) and on the device, compared element by element:

* ``shade eager``     -- plain-torch shading of the plane (rectified views): images and the gradients w.r.t.
  every per-particle map, against float64 on the CPU;
* ``fused images``    -- ``backend="compiled"`` images and gradients (on CUDA: the ``torch.compile`` kernels of
  :mod:`bayes_brdf.render.fused`), against the native C kernel in float64;
* ``fused loss``      -- the sampler's hot path ``shade_loss`` (shading fused with the L1 likelihood) and its
  gradients, against the native C kernel in float64;
* ``mesh G-buffer``   -- Mitsuba ray casting (camera rays and shadow rays) of a mesh, ``cuda_ad_rgb`` against
  ``llvm_ad_rgb``: two float32 ray tracers, so pixels on silhouettes and atlas seams may differ; it compares
  the fraction of pixels that agree (mask, shadows, and position, normal and uv within tolerance);
* ``texels auto`` / ``texels compiled`` -- a mesh's shading through bilinear texel taps (its loss, with the
  G-buffer of the CPU moved to the device so that only shading differs): loss and gradients against the native
  texel kernel in float64;
* ``guidance``        -- ``score_views`` (mutual information, MC estimator) of 200 candidate views: per-candidate
  MI and mean std against the CPU in float32 (the estimator's common random numbers are drawn per dtype, so a
  float64 reference would differ by Monte Carlo noise, not rounding);
* ``censored``        -- the clipped highlights' censored Laplace terms and their gradients in the renders and the
  noise scale (the likelihood's ``_CensoredSum``): the torch expressions on the device, the native pass on the CPU,
  against float64;
* ``fit``             -- a short ``bb.infer`` (SPOS, per-texel model, tiny synthetic plane): both runs start from
  the same particles (prior draws made on the CPU) and the samplers draw their noise from a CPU generator (the
  texel moves on torch's path in both, ``texel_moves.reference_moves``), so they see the same random numbers and differ only by float32 rounding, which the dynamics amplify over the
  steps (at 100 steps of the full size, per-texel means already differed by 0.03 between two CPU runs that
  differ only in their kernels); compared are the posterior mean and std maps and the MAP, against the CPU in
  float32, with a loose tolerance (a tenth of the largest value).

Each row: the largest absolute error, the largest relative one (``|d - r| / (|r| + atol)``), the tolerance
(``|d - r| <= atol + rtol |r|`` for every element, ``atol`` a fraction of the quantity's largest ``|r|``), the
result, and the median ms of the same computation in float32 on the CPU (library defaults: native kernels)
and on the device, after a warm-up call (which compiles). ``note`` names the worst quantity, the error of the
CPU's own float32 run against the reference (what the device's error should be close to), and the routes the
device run took (``native``, ``torch.compile``, ``eager``, tap ``gather``, torch or native KDE): a check whose
device run did not take the route it is meant to test fails. A check that raises fails with its one-line error;
the exit status is 1 when any check fails, 2 when the device is not there.

``--device cpu``: no GPU here. The "device" run is then float32 on the CPU with the native C kernels switched
off (``BAYES_BRDF_NO_NATIVE``), so it goes the way CUDA goes (``torch.compile``, eager torch, sparse tap
gathers, the torch KDE), and the G-buffer check compares ``llvm_ad_rgb`` with itself. It shows that the script
and those code paths work, not that CUDA does.
"""
from __future__ import annotations

import argparse
import collections
import contextlib
import datetime
import functools
import os
import platform
import statistics
import sys
import time
import traceback
import types
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import torch

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

BUNNY = ROOT.parent / "shared" / "data" / "psdr_assets" / "bunny_low.obj"
F32, F64 = torch.float32, torch.float64


# ------------------------------------------------------------------ sizes
def sizes(quick: bool) -> dict:
    """Problem sizes: the benchmarks' (``bench_render.py``, ``bench_mesh_step.py``, ``bench_guidance.py``) or small."""
    if quick:
        return dict(n=4, V=4, res=32, mesh="sphere", mviews=2, mres=48, tex=32, lights=2, cand=200, cres=16,
                    cn=8, fit_tex=8, fit_views=3, fit_n=8, fit_steps=30, repeats=3)
    return dict(n=20, V=20, res=128, mesh="bunny", mviews=8, mres=128, tex=128, lights=2, cand=200, cres=64,
                cn=20, fit_tex=16, fit_views=4, fit_n=16, fit_steps=50, repeats=10)


# ------------------------------------------------------------------ device helpers
def sync(device: str) -> None:
    if torch.device(device).type == "cuda":
        torch.cuda.synchronize()


@contextlib.contextmanager
def cuda_routes(on: bool):
    """With ``on``: the native C kernels off (``BAYES_BRDF_NO_NATIVE=1``), so a CPU run goes CUDA's way."""
    if not on:
        yield
        return
    before = os.environ.get("BAYES_BRDF_NO_NATIVE")
    os.environ["BAYES_BRDF_NO_NATIVE"] = "1"
    try:
        yield
    finally:
        if before is None:
            os.environ.pop("BAYES_BRDF_NO_NATIVE", None)
        else:
            os.environ["BAYES_BRDF_NO_NATIVE"] = before


@contextlib.contextmanager
def mitsuba_variant_env(variant: str | None):
    """``BAYES_BRDF_MITSUBA_VARIANT=variant`` for the block (the ray caster reads it at every call)."""
    key = "BAYES_BRDF_MITSUBA_VARIANT"
    before = os.environ.get(key)
    if variant is not None:
        os.environ[key] = variant
    try:
        yield
    finally:
        if before is None:
            os.environ.pop(key, None)
        else:
            os.environ[key] = before


@contextlib.contextmanager
def probe_routes():
    """Count which shading implementations run inside the block: yields a Counter of route names."""
    from bayes_brdf.guidance import entropy, scores
    from bayes_brdf.render import fused, native, texels

    hits: collections.Counter = collections.Counter()
    saved = []

    def wrap(obj, attr, label):
        orig = getattr(obj, attr)
        if isinstance(orig, type):                        # an autograd.Function: count its .apply
            def apply(*a, _o=orig, **k):
                hits[label] += 1
                return _o.apply(*a, **k)
            new = types.SimpleNamespace(apply=apply)
        else:
            @functools.wraps(orig)
            def new(*a, _o=orig, **k):
                hits[label(*a, **k) if callable(label) else label] += 1
                return _o(*a, **k)
        saved.append((obj, attr, orig))
        setattr(obj, attr, new)

    def kde_label(x, *a, backend="auto", **k):
        native_ok = backend != "torch" and x.device.type == "cpu" and entropy._lib(x.dtype) is not None
        return "native KDE" if native_ok else "torch KDE"

    wrap(native, "NativeShade", "native")
    wrap(native, "NativeLoss", "native")
    wrap(fused, "_FusedShade", "torch.compile")
    wrap(fused, "_FusedLoss", "torch.compile")
    wrap(fused, "eager_kernel", "eager")
    wrap(fused, "eager_loss", "eager")
    wrap(texels, "gather", "gather")
    wrap(scores, "kde_entropy", kde_label)
    failed = set(fused._failed)
    try:
        yield hits
    finally:
        for obj, attr, orig in reversed(saved):
            setattr(obj, attr, orig)
        if set(fused._failed) - failed:
            hits["torch.compile FAILED"] += 1


def timed(fn: Callable[[], dict], device: str, repeats: int) -> tuple[dict, float]:
    """``(outputs of the first call, median ms over repeats)``: one warm-up call (compiles), then ``repeats``."""
    out = fn()
    sync(device)
    ts = []
    for _ in range(repeats):
        sync(device)
        t = time.perf_counter()
        fn()
        sync(device)
        ts.append(time.perf_counter() - t)
    return out, statistics.median(ts) * 1e3 if ts else float("nan")


def host(out: dict) -> dict:
    """Outputs as float64 CPU tensors (bool tensors stay bool)."""
    res = {}
    for k, v in out.items():
        v = torch.as_tensor(v).detach().cpu()
        res[k] = v if v.dtype == torch.bool else v.to(F64)
    return res


# ------------------------------------------------------------------ comparisons
@dataclass
class Tol:
    rtol: float
    atol: float          # a fraction of the quantity's largest |reference|

    def __str__(self) -> str:
        return f"rtol {self.rtol:.0e}, atol {self.atol:.0e} max(abs r)"


@dataclass
class Compared:
    max_abs: float
    max_rel: float
    ok: bool
    worst: str
    note: str = ""


def allclose(dev: dict, ref: dict, tol: Tol) -> Compared:
    """``|d - r| <= atol + rtol |r|`` for every element of every quantity; the worst quantity named."""
    max_abs = max_rel = 0.0
    worst, worst_ratio, ok = "", -1.0, True
    for k, r in ref.items():
        d = dev[k]
        if tuple(d.shape) != tuple(r.shape):
            return Compared(float("nan"), float("nan"), False, k, f"{k}: shape {tuple(d.shape)} != {tuple(r.shape)}")
        if not bool(torch.isfinite(d).all()):
            return Compared(float("nan"), float("nan"), False, k, f"{k}: not finite on the device")
        atol = tol.atol * max(float(r.abs().max()) if r.numel() else 0.0, 1e-30)
        err = (d - r).abs()
        ratio = float((err / (atol + tol.rtol * r.abs())).max()) if r.numel() else 0.0
        ok &= ratio <= 1.0
        max_abs = max(max_abs, float(err.max()) if r.numel() else 0.0)
        max_rel = max(max_rel, float((err / (r.abs() + atol)).max()) if r.numel() else 0.0)
        if ratio > worst_ratio:
            worst, worst_ratio = k, ratio
    return Compared(max_abs, max_rel, ok, f"{worst} ({worst_ratio:.2f} of tol)")


# ------------------------------------------------------------------ the checks
@dataclass
class Check:
    """``prepare(device, dtype)`` builds inputs and returns a function that computes the outputs ``{name: tensor}``
    (timed: called once to warm up, then ``repeats`` times)."""

    name: str
    prepare: Callable[[str, torch.dtype], Callable[[], dict]]
    tol: Tol
    ref_dtype: torch.dtype = F64
    expect: tuple = ()                    # routes the device run must take (any of them)
    compare: Callable | None = None       # (dev, ref, tol) -> Compared; default allclose
    tol_text: str | None = None
    repeats: int | None = None            # timed calls after the warm-up (default: the size's)
    ref_same_as_cpu: bool = field(init=False, default=False)

    def __post_init__(self):
        self.ref_same_as_cpu = self.ref_dtype == F32


def _planar_setup(S, dtype, device):
    from bayes_brdf.render import SVBRDF, PlanarSample, collocated_views
    from bayes_brdf.render.gbuffer import GBuffer
    from bayes_brdf.render.shade import shade

    views = collocated_views(S["V"], radius=15.0, camera="rectified", resolution=S["res"], power=1500.0,
                             method="sobol")
    g64 = GBuffer.build(views, PlanarSample(10.0), dtype=F64)
    gen = torch.Generator().manual_seed(0)
    n, R = S["n"], S["res"]
    maps = [torch.rand(n, c, R, R, generator=gen, dtype=F64) for c in (3, 1, 3)]
    maps[1] = MIN_ROUGHNESS + (1 - MIN_ROUGHNESS) * maps[1]
    maps[2] = 0.5 * maps[2]
    gout = torch.rand(n, S["V"], 3, R, R, generator=gen, dtype=F64)
    target = torch.rand(S["V"], R, R, 3, generator=gen, dtype=F64)
    normal = torch.tensor([0.0, 0.0, 1.0], dtype=F64)[:, None, None].expand(3, R, R)
    weight = 100.0 * untied(shade(SVBRDF(*maps, normal), g64, backend="eager"), target)
    mv = lambda t: t.to(device=device, dtype=dtype)  # noqa: E731
    return g64.to(dtype=dtype, device=device), [mv(m).requires_grad_() for m in maps], mv(normal), mv(gout), \
        mv(target), mv(weight)


#: the least roughness of the checks' maps: below about 0.1 the GGX denominator (n.h)^2 (alpha^2 - 1) + 1 loses
#: most of float32's digits at a highlight's centre (1 - (n.h)^2 against alpha^2 = r^4), on any device: the CPU's
#: own float32 gradients w.r.t. roughness are then off by percents, which says nothing about the device
MIN_ROUGHNESS = 0.15


def untied(images, target):
    """``[V, H, W]`` 1 where no particle's pixel (any channel) is within float32 rounding of ``target``, else 0:
    the L1 loss's gradient is ``sign(R - y)``, which rounding flips where ``R = y`` (a difference of a whole
    pixel's gradient, not an error), so those pixels are weighted out of the loss checks."""
    d = (images - target).abs() <= 1e-4 * (images.abs() + 1)          # [n, V, H, W, 3]
    return (~d.any(-1).any(0)).to(F64)


def check_shade(S, backend: str, path: str) -> Callable:
    from bayes_brdf.render import SVBRDF
    from bayes_brdf.render.shade import shade, shade_loss

    def prepare(device, dtype):
        g, leaves, normal, gout, target, weight = _planar_setup(S, dtype, device)

        def run():
            x = SVBRDF(*leaves, normal)
            if path == "loss":
                loss = shade_loss(x, g, target, weight, backend=backend)
                grads = torch.autograd.grad(loss.sum(), leaves)
                return {"loss": loss, **dict(zip(("d/d albedo", "d/d roughness", "d/d specular"), grads))}
            img = shade(x, g, backend=backend, channels_last=False)
            grads = torch.autograd.grad(img, leaves, gout)
            return {"images": img, **dict(zip(("d/d albedo", "d/d roughness", "d/d specular"), grads))}
        return run
    return prepare


def _mesh(S):
    from bayes_brdf.render.mesh import Mesh
    if S["mesh"] == "bunny" and BUNNY.exists():
        return Mesh.load(BUNNY, up="y")
    return Mesh.sphere()


def _mesh_views(mesh, S, res=None):
    from bayes_brdf.render import PointLight, View, collocated_views
    r = mesh.radius
    cams = [v.camera for v in collocated_views(S["mviews"], 2.6 * r, resolution=res or S["mres"], target=mesh.center,
                                                fov=45, method="sobol")]
    ring = collocated_views(S["lights"], 4 * r, target=mesh.center, method="fibonacci", resolution=4)
    flash = lambda c: PointLight(c.position, (2.6 * r) ** 2)  # noqa: E731
    lamps = tuple(PointLight(v.camera.position, (4 * r) ** 2) for v in ring[1:])
    return [View(c, (flash(c), *lamps)) for c in cams]


def check_gbuffer(S, device_variant: str) -> tuple[Callable, Callable]:
    """Mesh G-buffer by ray casting in the reference variant (``llvm_ad_rgb``) and the device's."""
    from bayes_brdf.render.gbuffer import GBuffer

    mesh = _mesh(S)
    views = _mesh_views(mesh, S)

    def prepare(device, dtype):
        variant = "llvm_ad_rgb" if torch.device(device).type == "cpu" else device_variant

        def run():
            with mitsuba_variant_env(variant):
                g = GBuffer.build(views, mesh, dtype=dtype, device=device)
            sync(device)
            lit = g.light_scale.abs().amax(2) > 0                     # [V, L, H, W]: light reaches the pixel
            return {"mask": g.mask, "lit": lit, "position": g.position, "normal": g.normal,
                    "uv": g.uv.permute(0, 3, 1, 2)}
        return run

    def compare(dev, ref, tol):
        m_agree = dev["mask"] == ref["mask"]
        both = dev["mask"] & ref["mask"]
        px = both.numel()
        ok_px = m_agree.clone()
        ok_px &= (dev["lit"] == ref["lit"]).all(1) | ~both
        max_abs = max_rel = 0.0
        worst = "mask"
        limits = {"position": tol.atol * mesh.radius, "normal": tol.rtol, "uv": tol.rtol}
        for k, lim in limits.items():
            err = (dev[k] - ref[k]).abs().amax(1)                     # [V, H, W]
            err = torch.where(both, err, torch.zeros_like(err))
            ok_px &= err <= lim
            agreeing = err[both & ok_px]
            if agreeing.numel():
                a = float(agreeing.max())
                scale = {"position": mesh.radius, "normal": 1.0, "uv": 2.0}[k]
                if a / scale > max_rel:
                    worst = k
                max_abs, max_rel = max(max_abs, a), max(max_rel, a / scale)
        frac = float(ok_px.float().mean())
        bad = int((~ok_px).sum())
        return Compared(max_abs, max_rel, frac >= MIN_AGREE, worst,
                        f"{100 * frac:.3f}% of {px} px agree ({bad} differ: silhouettes, seams, shadow edges); "
                        f"errors over agreeing pixels, rel to mesh radius / 1 / uv range")
    return prepare, compare


#: mesh G-buffers: the fraction of pixels that must agree between two ray tracers
MIN_AGREE = 0.995


def check_texels(S, backend: str, full_specular: bool) -> Callable:
    """A mesh's loss and gradients through bilinear texel taps; the G-buffer is the CPU's (float64), moved.
    ``full_specular``: a per-particle specular map (else the constant 0.04 of ``per_texel``): the maps looked up
    at the pixels are then all of one size, which the ``torch.compile`` kernel needs."""
    from bayes_brdf.render import SVBRDF
    from bayes_brdf.render.gbuffer import GBuffer
    from bayes_brdf.render.shade import shade, shade_loss

    mesh = _mesh(S)
    views = _mesh_views(mesh, S)
    with mitsuba_variant_env("llvm_ad_rgb"):
        g64 = GBuffer.build(views, mesh, dtype=F64)
    gen = torch.Generator().manual_seed(1)
    n, T = S["n"], S["tex"]
    maps = [torch.rand(n, 3, T, T, generator=gen, dtype=F64),
            MIN_ROUGHNESS + (0.9 - MIN_ROUGHNESS) * torch.rand(n, 1, T, T, generator=gen, dtype=F64),
            0.1 * torch.rand(n, 3, T, T, generator=gen, dtype=F64) if full_specular
            else torch.full((3, 1, 1), 0.04, dtype=F64)]
    nrm64 = torch.tensor([0.0, 0.0, 1.0], dtype=F64).view(3, 1, 1)
    V, (h, w) = g64.num_views, g64.resolution
    target = torch.rand(V, h, w, 3, generator=gen, dtype=F64) * 0.5
    weight = g64.mask.to(F64) * untied(shade(SVBRDF(*maps, nrm64), g64, backend="eager"), target)

    def prepare(device, dtype):
        g = g64.to(dtype=dtype, device=device)
        mv = lambda t: t.to(device=device, dtype=dtype)  # noqa: E731
        leaves = [mv(m).requires_grad_() for m in maps[:3 if full_specular else 2]]
        ks, nrm = leaves[2] if full_specular else mv(maps[2]), mv(nrm64)
        y, wt = mv(target), mv(weight)

        def run():
            loss = shade_loss(SVBRDF(leaves[0], leaves[1], ks, nrm), g, y, wt, backend=backend)
            grads = torch.autograd.grad(loss.sum(), leaves)
            return {"loss": loss, **dict(zip(("d/d albedo", "d/d roughness", "d/d specular"), grads))}
        return run
    return prepare


def check_guidance(S) -> Callable:
    from bayes_brdf.guidance.scores import score_views
    from bayes_brdf.render import SVBRDF, PlanarSample, collocated_views

    R, n = S["cres"], S["cn"]
    views = collocated_views(S["cand"], 3.0, method="sobol", camera="rectified", resolution=R, power=10.0,
                             max_zenith=60)
    gen = torch.Generator().manual_seed(0)
    kd, r = torch.rand(n, 3, R, R, generator=gen), 0.2 + 0.6 * torch.rand(n, 1, R, R, generator=gen)

    def prepare(device, dtype):
        mv = lambda t: t.to(device=device, dtype=dtype)  # noqa: E731
        maps = SVBRDF(mv(kd), mv(r), mv(torch.full((3, 1, 1), 0.04)),
                      mv(torch.tensor([0.0, 0, 1]).view(3, 1, 1).expand(3, R, R).contiguous()))

        def run():
            s = score_views(maps, views, PlanarSample(2.0), estimator="mc", seed=0)
            return {"mi": s.mi, "mean_std": s.mean_std, "pixels": s.pixels}
        return run
    return prepare


def check_censored(S) -> Callable:
    """The saturated pixels' censored Laplace terms as a step calls them (``_CensoredSum``): on the CPU the native
    pass (models/censored_kernel.py), on CUDA the torch expressions; the sum per particle and its gradients."""
    from bayes_brdf.models.likelihood import _CensoredSum

    n, K = S["n"], S["res"] ** 2
    gen = torch.Generator().manual_seed(4)
    r = torch.rand(n, K, 3, generator=gen, dtype=F64) * 1.2
    level = torch.full((K, 3), 0.95, dtype=F64)
    sigma = torch.rand(n, generator=gen, dtype=F64) * 0.04 + 0.01
    w = torch.rand(K, generator=gen, dtype=F64) + 0.5
    g = torch.rand(K, generator=gen, dtype=F64) + 0.5

    def prepare(device, dtype):
        mv = lambda t: t.to(device=device, dtype=dtype)  # noqa: E731
        rr, ss = mv(r).requires_grad_(), mv(sigma).requires_grad_()

        def run():
            out = _CensoredSum.apply(rr, mv(level), ss, mv(w), "laplace", mv(g))
            d_r, d_s = torch.autograd.grad(out.sum(), (rr, ss))
            return {"sum": out, "d/d render": d_r, "d/d sigma": d_s}
        return run
    return prepare


def check_fit(S) -> Callable:
    import bayes_brdf as bb
    from bayes_brdf.models import ModelData
    from bayes_brdf.potential import Potential
    from bayes_brdf.render import SVBRDF, PlanarSample, collocated_views
    from bayes_brdf.render.shade import render
    from bayes_brdf.samplers.texel_moves import reference_moves

    T = S["fit_tex"]
    views = collocated_views(S["fit_views"], 3.0, camera="rectified", resolution=T, method="sobol", power=10.0)
    gen = torch.Generator().manual_seed(3)
    truth = SVBRDF(torch.rand(3, T, T, generator=gen) * 0.6 + 0.2, torch.rand(1, T, T, generator=gen) * 0.5 + 0.2,
                   torch.full((3, 1, 1), 0.04), torch.tensor([0.0, 0, 1]).view(3, 1, 1))
    surface = PlanarSample(2.0)
    img = render(truth, views, surface, backend="eager")[0]
    img = img + 0.01 * torch.randn(img.shape, generator=gen)
    obs = bb.Observations(views, img, surface)
    model = bb.models.per_texel(T)
    z0 = Potential(model, (ModelData.from_observations(obs),)).init(S["fit_n"], seed=0)   # prior draws, CPU

    def prepare(device, dtype):
        def run():
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")                  # a 30-step run does not converge: expected
                # the texel moves' torch path on the CPU too: the one CUDA runs, with the same random draws
                with reference_moves():
                    post = bb.infer(model, obs, "spos", seed=0, steps=S["fit_steps"], dtype=dtype, device=device,
                                    z0=z0.to(device=device, dtype=dtype), map_steps=10, progress=False)
            mean, std, mp = post.mean(), post.map_std(), post.map()
            out = {f"mean {k}": v for k, v in mean.items()}
            out.update({f"std {k}": v for k, v in std.items()})
            out.update({f"MAP {k}": v for k, v in mp.items()})
            return out
        return run
    return prepare


def checks(S, device: str, variant: str) -> list[Check]:
    """The checks, built lazily: a failing set-up fails its own row only."""
    grad_tol = Tol(2e-3, 1e-4)

    def lazy(factory):
        state = {}

        def prepare(dev, dt):
            if "p" not in state:
                state["p"] = factory()
            return state["p"](dev, dt)
        return prepare

    gb = {}

    def gb_prepare(dev, dt):
        if "p" not in gb:
            gb["p"], gb["c"] = check_gbuffer(S, variant)
        return gb["p"](dev, dt)

    return [
        Check("shade eager", lazy(lambda: check_shade(S, "eager", "images")), grad_tol, expect=("eager",)),
        Check("fused images", lazy(lambda: check_shade(S, "compiled", "images")), grad_tol,
              expect=("torch.compile",)),
        Check("fused loss", lazy(lambda: check_shade(S, "compiled", "loss")), grad_tol, expect=("torch.compile",)),
        Check("mesh G-buffer", gb_prepare, Tol(1e-3, 1e-4), ref_dtype=F32,
              compare=lambda d, r, t: gb["c"](d, r, t),
              tol_text=f">= {100 * MIN_AGREE:g}% px agree (dp <= 1e-4 R; dn, duv <= 1e-3)"),
        Check("texels auto", lazy(lambda: check_texels(S, "auto", False)), grad_tol, expect=("gather",)),
        Check("texels compiled", lazy(lambda: check_texels(S, "compiled", True)), grad_tol, expect=("torch.compile",)),
        Check("guidance", lazy(lambda: check_guidance(S)), Tol(1e-3, 1e-4), ref_dtype=F32, expect=("torch KDE",)),
        Check("censored", lazy(lambda: check_censored(S)), Tol(1e-4, 1e-5)),
        Check("fit", lazy(lambda: check_fit(S)), Tol(0.0, 0.1), ref_dtype=F32, repeats=1,
              tol_text="abs(d - r) <= 0.1 max(abs r)"),
    ]


# ------------------------------------------------------------------ running
@dataclass
class Row:
    name: str
    max_abs: float = float("nan")
    max_rel: float = float("nan")
    tol: str = ""
    ok: bool = False
    cpu_ms: float = float("nan")
    dev_ms: float = float("nan")
    note: str = ""


def one_line(e: BaseException) -> str:
    msg = " ".join(str(e).split())
    frames = traceback.extract_tb(e.__traceback__)
    ours = [f for f in frames if Path(f.filename).resolve().is_relative_to(ROOT) and "site-packages" not in f.filename]
    f = ours[-1] if ours else (frames[-1] if frames else None)
    here = ""
    if f is not None:
        p = Path(f.filename).resolve()
        here = f" [{p.relative_to(ROOT) if p.is_relative_to(ROOT) else p.name}:{f.lineno}]"
    return f"{type(e).__name__}: {msg[:200]}{here}"


def run_check(c: Check, device: str, repeats: int) -> Row:
    row = Row(c.name, tol=c.tol_text or str(c.tol))
    emulate = torch.device(device).type == "cpu"
    reps = c.repeats or repeats
    phase = "CPU"
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            # the CPU's own float32 run, library defaults (native kernels): timed
            cpu_fn = c.prepare("cpu", F32)
            cpu_out, row.cpu_ms = timed(cpu_fn, "cpu", reps)
            cpu_out = host(cpu_out)
            ref = cpu_out if c.ref_same_as_cpu else host(c.prepare("cpu", c.ref_dtype)())
        # the device's run (on a CPU: the way CUDA goes, native kernels off)
        phase = "device"
        with warnings.catch_warnings(record=True) as caught, cuda_routes(emulate):
            warnings.simplefilter("always")
            dev_fn = c.prepare(device, F32)
            with probe_routes() as routes:
                dev_out, row.dev_ms = timed(dev_fn, device, reps)
        dev_out = host(dev_out)
        phase = "comparison"
        cmp = (c.compare or allclose)(dev_out, ref, c.tol)
        row.max_abs, row.max_rel, row.ok = cmp.max_abs, cmp.max_rel, cmp.ok
        notes = [cmp.note] if cmp.note else [f"worst: {cmp.worst}"]
        if not c.ref_same_as_cpu:
            own = (c.compare or allclose)(cpu_out, ref, c.tol)
            notes.append(f"CPU f32: {own.max_abs:.1e} abs, {own.max_rel:.1e} rel, {own.worst}")
        if routes:
            notes.append("routes: " + ", ".join(sorted(routes)))
        if c.expect and not any(r in routes for r in c.expect):
            row.ok = False
            notes.append(f"FAIL: expected route {' or '.join(c.expect)}")
        if "torch.compile FAILED" in routes:
            row.ok = False
        lib_warn = [str(w.message) for w in caught
                    if str(w.message).startswith(("bayes_brdf", "torch.compile unavailable"))]
        if lib_warn:
            notes.append("warning: " + " ".join(lib_warn[0].split())[:120])
        row.note = "; ".join(notes)
    except Exception as e:  # noqa: BLE001  (a failing check is a row, not the end of the script)
        row.ok = False
        row.note = f"{phase}: {one_line(e)}"
    return row


def fmt(x: float, spec: str = ".1e") -> str:
    return "-" if x != x else format(x, spec)


def header(device: str, quick: bool, S: dict) -> list[str]:
    lines = [f"# gpu_check: device={device}{' (quick)' if quick else ''}, {datetime.date.today().isoformat()}",
             f"# torch {torch.__version__}, {torch.get_num_threads()} CPU threads, {platform.machine()}, "
             f"python {platform.python_version()}"]
    if torch.device(device).type == "cuda":
        lines.append(f"# GPU: {torch.cuda.get_device_name(device)}, CUDA {torch.version.cuda}")
    else:
        lines.append("# device=cpu: the device run is float32 on the CPU with the native kernels off (CUDA's routes); "
                     "the G-buffer check compares llvm_ad_rgb with itself. This is not a CUDA test.")
    try:
        import mitsuba
        built = [v for v in ("llvm_ad_rgb", "cuda_ad_rgb") if v in mitsuba.variants()]
        built = ", ".join(built) or "neither llvm_ad_rgb nor cuda_ad_rgb"
        lines.append(f"# mitsuba {mitsuba.__version__} (built with {built})")
    except Exception as e:  # noqa: BLE001
        lines.append(f"# mitsuba unavailable ({type(e).__name__})")
    lines.append(f"# sizes: {S}")
    return lines


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                 epilog="See the module docstring (python -m pydoc benchmarks/gpu_check.py) for "
                                        "what each check compares.")
    ap.add_argument("--device", default="cuda", help="torch device to check against the CPU (default: cuda; "
                                                     "cpu: exercise the script on a machine without a GPU)")
    ap.add_argument("--quick", action="store_true", help="small problem sizes (a minute or two)")
    ap.add_argument("--only", nargs="+", metavar="NAME", help="run only the checks whose names start with these")
    ap.add_argument("--variant", default="cuda_ad_rgb", help="Mitsuba variant of the device (default: %(default)s)")
    a = ap.parse_args(argv)
    try:
        dev = torch.device(a.device)
    except RuntimeError:
        print(f"gpu_check: --device {a.device!r} is not a torch device", file=sys.stderr)
        return 2
    if dev.type == "cuda" and not torch.cuda.is_available():
        print(f"gpu_check: no CUDA device here (torch {torch.__version__}, cuda available: False); nothing checked. "
              "Run it on a GPU machine, or with --device cpu to exercise the script.")
        return 2
    S = sizes(a.quick)
    for line in header(a.device, a.quick, S):
        print(line)
    print("| check | max abs | max rel | tolerance | result | CPU ms | device ms | note |")
    print("|---|---|---|---|---|---|---|---|")
    rows = []
    for c in checks(S, a.device, a.variant):
        if a.only and not any(c.name.startswith(o) for o in a.only):
            continue
        r = run_check(c, a.device, S["repeats"])
        rows.append(r)
        print(f"| {r.name} | {fmt(r.max_abs)} | {fmt(r.max_rel)} | {r.tol} | {'PASS' if r.ok else 'FAIL'} | "
              f"{fmt(r.cpu_ms, '.1f')} | {fmt(r.dev_ms, '.1f')} | {r.note.replace('|', '/')} |", flush=True)
    bad = [r.name for r in rows if not r.ok]
    print(f"# {len(rows) - len(bad)} of {len(rows)} checks passed" + (f"; FAILED: {', '.join(bad)}" if bad else ""))
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
