"""The paper's Table 1: samplers on a 2-D posterior with an exact answer.

Homogeneous gray albedo ``rho in [0, 1]`` and roughness ``r in [0.05, 1]``,
uniform prior, ONE pixel observed under ONE collocated flash configuration
(camera and light at zenith ``angle``, distance ``distance``, looking at the
sample's centre), L1 likelihood (Eq. 2; the pixel's three equal channels all
count). The observation is the noiseless render of ``(albedo, roughness)``.
The posterior is a curved ridge: many (rho, r) pairs explain one pixel.

``lighting="environment"``: the same pixel seen under a known environment alone (``env``, default the
built-in :func:`~bayes_brdf.render.environment.studio`: a dim sky and a softbox 20 degrees from the
zenith, opposite the cameras, so that at ``angle = 20`` the pixel mirrors its centre), shaded through its precomputed transfer (:mod:`bayes_brdf.render.transfer`);
``"environment+flash"``: the environment and the collocated flash together. The quadrature runs the
same model's potential, so it is the exact posterior of what the samplers sample.

Truth: posterior mean and variance of both parameters by dense 2-D
quadrature of the same model (midpoint rule on ``grid x grid`` cells; the
density comes from the model's own potential, run on every cell centre in one
batch). Each sampler draws ``particles`` samples with the same budget of
``particles * steps`` potential evaluations (NUTS, which is sequential:
one chain after warm-up cut into ``runs`` consecutive blocks of ``particles``
draws; its evaluations per block are reported); ``runs`` independent runs (batched as independent groups of one
call where the sampler allows it: same statistics, a fraction of the time); we report the MSE of the estimated
mean and of the estimated variance (ddof = 1), each summed over both
parameters, and seconds per run. The row ``iid`` is ``particles`` exact
independent draws from the quadrature posterior: the floor that independent
sampling reaches (averaged over ``IID_RUNS`` runs so that the floor itself
is precise; the samplers' rows average ``runs`` runs).
"""
from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, field

import torch

from ..models.data import ModelData
from ..models.material import homogeneous
from ..observations import Observations
from ..potential import Potential
from ..render.cameras import PerspectiveCamera
from ..render.maps import SVBRDF
from ..render.shade import render
from ..render.surface import PlanarSample
from ..render.views import View
from ..samplers import make_sampler
from ..samplers.driver import run
from .common import say

SAMPLERS = ("spos", "svgd", "sgld", "emcee", "multistart_sgd", "nuts")
#: the i.i.d. floor is averaged over this many runs (it is cheap), so that it is the floor, not a noisy estimate
IID_RUNS = 2000
#: NUTS in the table: one chain cut into ``runs`` blocks (it is sequential and ~10x dearer per evaluation)
NUTS_TABLE1 = {"warmup_steps": 100, "thin": 1, "max_tree_depth": 6}
PAPER = {"spos": (0.0023, 0.0002), "sgld": (0.0078, 0.0010), "multistart_sgd": (0.0045, 0.0039)}


@dataclass
class Table1Setup:
    """The 2-D problem. Defaults chosen so both marginal variances are >= 0.002 (see docs/samplers.md)."""

    angle: float = 0.0              # zenith of the collocated camera + light, degrees
    distance: float = 2.0           # from the sample centre
    power: float = 2.0              # light power (RGB equal)
    albedo: float = 0.5             # the true parameters that made the observed pixel
    roughness: float = 0.5
    sigma: float = 0.01             # sigma_err of Eq. (2)
    observations: list = field(default_factory=list)   # extra [angle, ...] configurations (several pixels)
    grid: int = 1000                # quadrature cells per axis
    dtype: str = "float64"
    lighting: str = "collocated"    # "collocated", "environment" (the built-in studio alone) or "environment+flash"
    env: str | None = None          # an HDR map for the environment lightings (default: render.environment.studio)
    env_scale: float = 1.0

    def angles(self) -> list[float]:
        return [float(self.angle)] + [float(a) for a in self.observations]


LIGHTINGS = ("collocated", "environment", "environment+flash")


def environment_of(setup: Table1Setup):
    """The setup's environment light (``None`` for ``lighting="collocated"``): ``setup.env`` read z-up, or the
    built-in :func:`~bayes_brdf.render.environment.studio` with its softbox 20 degrees from the zenith towards
    ``-x``: the mirror direction of a camera at ``angle = 20`` (the cameras stand on the ``+x`` side)."""
    from ..errors import InputError
    from ..render.environment import EnvironmentLight, studio, z_up

    if setup.lighting not in LIGHTINGS:
        raise InputError(f"unknown lighting '{setup.lighting}'", fix=f"use one of {', '.join(LIGHTINGS)}")
    if setup.lighting == "collocated":
        return None
    if setup.env is None:
        env = studio(azimuth_deg=180.0)
        return EnvironmentLight(env.radiance, setup.env_scale, env.to_world, "studio")
    return EnvironmentLight.from_file(setup.env, setup.env_scale, z_up())


def _view(angle: float, distance: float, power: float, name: str, env=None, flash: bool = True) -> View:
    a = math.radians(angle)
    pos = (distance * math.sin(a), 0.0, distance * math.cos(a))
    cam = PerspectiveCamera(position=pos, target=(0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0) if angle < 89 else (0, 0, 1),
                            fov=1.0, resolution=(1, 1))
    v = View.collocated(cam, power=power, name=name)
    if env is None:
        return v
    return View(cam, (*v.lights, env) if flash else (env,), name)


def problem(setup: Table1Setup) -> tuple:
    """``(model, ModelData)`` of the 2-D posterior."""
    dt = getattr(torch, setup.dtype)
    env = environment_of(setup)
    views = [_view(a, setup.distance, setup.power, f"angle{a:g}", env, setup.lighting != "environment")
             for a in setup.angles()]
    surf = PlanarSample(1.0)
    truth = SVBRDF.constant(setup.albedo, setup.roughness, dtype=dt)
    y = render(truth, views, surf)[0]
    obs = Observations(views, y.float(), surf, meta={"problem": "table1", **asdict(setup)})
    model = homogeneous(albedo="gray", sigma=setup.sigma, specular=0.04)
    return model, ModelData.from_observations(obs, dtype=dt)


def quadrature(setup: Table1Setup, refine: int = 6) -> dict:
    """Exact posterior moments by midpoint quadrature: ``{"mean": [2], "var": [2], "x", "weights", "cell"}``.

    A ``grid x grid`` midpoint rule over the prior's box, then (up to ``refine`` times) over the box that holds
    the mass (every cell within ``e^-30`` of the largest weight, two cells of margin) whenever that box is under
    half the current one along an axis: a posterior narrower than a cell of the prior's box (two views, a sharp
    highlight: a roughness std of 1e-5 against cells of 1e-3) is resolved instead of put into one cell.
    """
    model, data = problem(setup)
    pot = Potential(model, (data,))
    lo, hi = model.roughness_range
    box = torch.tensor([[0.0, 1.0], [float(lo), float(hi)]], dtype=data.dtype)    # albedo, roughness
    for _ in range(refine + 1):
        x, w, cell = _grid(pot, box, setup.grid, data.dtype)
        keep = x[w > w.max() * math.exp(-30)]
        new = torch.stack([keep.min(0).values - 2 * cell, keep.max(0).values + 2 * cell], 1)
        new = torch.stack([torch.maximum(new[:, 0], box[:, 0]), torch.minimum(new[:, 1], box[:, 1])], 1)
        if not bool(((new[:, 1] - new[:, 0]) < 0.5 * (box[:, 1] - box[:, 0])).any()):
            break
        box = new
    mean = (w[:, None] * x).sum(0)
    var = (w[:, None] * (x - mean) ** 2).sum(0)
    return {"mean": mean, "var": var, "x": x, "weights": w, "cell": cell, "box": box}


def _grid(pot: Potential, box, N: int, dtype) -> tuple:
    """Cell centres ``x [N^2, 2]`` (albedo, roughness) of the box, their normalised weights and the cell size."""
    cell = (box[:, 1] - box[:, 0]) / N
    t = (torch.arange(N, dtype=dtype) + 0.5)
    R, P = torch.meshgrid(box[1, 0] + cell[1] * t, box[0, 0] + cell[0] * t, indexing="ij")
    vals = {"albedo": P.reshape(-1, 1), "roughness": R.reshape(-1, 1)}
    with torch.no_grad():
        z = pot.to_unconstrained(vals)
        u = torch.cat([pot.energy(zc, jacobian=False) for zc in z.split(250_000)])
    w = torch.exp(-(u - u.min()))
    return torch.stack([P.reshape(-1), R.reshape(-1)], 1), w / w.sum(), cell


def iid_draws(q: dict, n: int, gen: torch.Generator) -> torch.Tensor:
    """``n`` exact independent draws from the quadrature posterior (cell by weight, uniform within the cell)."""
    idx = torch.multinomial(q["weights"].float(), n, replacement=True, generator=gen)
    jitter = (torch.rand(n, 2, generator=gen, dtype=q["x"].dtype) - 0.5) * q["cell"].to(q["x"].dtype)
    return q["x"][idx] + jitter


def _errors(samples: torch.Tensor, q: dict) -> tuple[float, float]:
    m, v = samples.mean(0), samples.var(0, unbiased=True)
    return float(((m - q["mean"]) ** 2).sum()), float(((v - q["var"]) ** 2).sum())


def compare(setup: Table1Setup | None = None, samplers=SAMPLERS, *, runs: int = 20, particles: int = 16,
            steps: "int | dict | None" = None, seed: int = 0, progress: bool = False, params: dict | None = None,
            executor=None) -> dict:
    """The table: ``{row: {"mse_mean", "mse_var", "seconds", "evaluations"}}`` plus ``"_truth"``.

    ``params`` maps a sampler name to hyper-parameter overrides of its preset. ``steps=None``: each sampler
    runs its preset's steps (what a user gets; the budget is in the ``evaluations`` column); a number gives
    every sampler the same budget; ``{sampler: steps}`` overrides some.

    The samplers' runs are independent pieces of work run through ``executor`` (:mod:`bayes_brdf.executor`:
    ``None`` in this process, ``True`` a local Ray, an address a Ray cluster, or an executor): a batched
    sampler's runs are one piece, an unbatched one's each run, NUTS's chain one; the truth is computed once
    here and its moments sent along. The errors do not depend on the executor; the seconds are each piece's own.
    """
    from ..executor import using

    made = []
    for name in samplers:             # every sampler resolved (a bad name fails) before any work
        over = dict(NUTS_TABLE1) if str(name) == "nuts" else {}
        over.update((params or {}).get(name, {}))
        made.append((name, over, *make_sampler(name, params=over)))
    setup = setup or Table1Setup()
    q = quadrature(setup)
    out = {"_truth": {"mean": q["mean"].tolist(), "var": q["var"].tolist(), "setup": asdict(setup),
                      "runs": runs, "particles": particles, "steps": steps if isinstance(steps, int) else "preset"}}
    gen = torch.Generator().manual_seed(seed)
    n_iid = max(runs, IID_RUNS)
    errs = [_errors(iid_draws(q, particles, gen), q) for _ in range(n_iid)]
    out["iid"] = {"mse_mean": sum(e[0] for e in errs) / n_iid, "mse_var": sum(e[1] for e in errs) / n_iid,
                  "seconds": 0.0, "evaluations": 0, "runs": n_iid}
    jobs = []                         # (sampler's row, name, overrides, steps, run k | "chain" | "batched")
    for i_s, (name, over, smp, cfg) in enumerate(made):
        n_steps = (steps.get(smp.name, cfg.steps) if isinstance(steps, dict) else
                   cfg.steps if steps is None else steps)
        if smp.name == "nuts":        # one chain (batch means), cut into `runs` blocks
            jobs.append((i_s, name, over, n_steps, "chain"))
        elif smp.supports_groups:     # all runs as independent groups of one batched run
            jobs.append((i_s, name, over, n_steps, "batched"))
        else:
            jobs += [(i_s, name, over, n_steps, k) for k in range(runs)]
    shared = {"setup": setup, "truth": {"mean": q["mean"], "var": q["var"]}, "runs": runs, "particles": particles,
              "seed": seed, "progress": progress}
    with using(executor) as ex:
        done = ex.map(_compare_job, jobs, shared=shared,
                      seeds=[seed * 1000 + (j[4] if isinstance(j[4], int) else 0) for j in jobs])
    for i_s, (name, over, smp, cfg) in enumerate(made):
        mine = [(j, d) for j, d in zip(jobs, done) if j[0] == i_s]
        errs = [e for _, d in mine for e in d["errors"]]
        secs, evals = sum(d["seconds"] for _, d in mine), sum(d["evaluations"] for _, d in mine)
        n_steps, batched = mine[0][0][3], mine[0][0][4] == "batched"
        say("compare: %s done in %.1f s (MSE of the mean %.2g)", smp.name, secs, sum(e[0] for e in errs) / runs)
        out[smp.name] = {"mse_mean": sum(e[0] for e in errs) / runs, "mse_var": sum(e[1] for e in errs) / runs,
                         "seconds": secs / runs, "evaluations": evals // runs, "batched": batched,
                         "steps": n_steps if smp.name != "nuts" else None}
    return out


def _compare_job(job: tuple, shared: dict) -> dict:
    """One piece of :func:`compare`: ``{"errors": [(mse_mean, mse_var) per run], "seconds", "evaluations"}``."""
    _, name, over, n_steps, what = job
    runs, particles, seed, progress = shared["runs"], shared["particles"], shared["seed"], shared["progress"]
    q = shared["truth"]
    smp, cfg = make_sampler(name, params=over)
    model, data = problem(shared["setup"])
    pot = Potential(model, (data,))
    t0 = time.perf_counter()
    if what == "chain":               # warm-up, then `runs` consecutive blocks of `particles` thinned draws
        say("compare: %s, one chain of %d runs ...", smp.name, runs)
        res = run(smp, pot, particles=particles * runs, steps=smp.warmup_steps + particles * runs * smp.thin,
                  seed=seed * 1000, progress=progress, checkpoint_every=0)
    else:
        k = 0 if what == "batched" else what
        res = run(smp, pot, particles=particles, steps=n_steps, seed=seed * 1000 + k, progress=progress,
                  checkpoint_every=0, groups=runs if what == "batched" else 1, init_margin=cfg.init_margin)
        if what != "batched":
            say("compare: %s run %d of %d done", smp.name, k + 1, runs)
    secs = time.perf_counter() - t0
    x = pot.to_constrained(res.z)
    xs = torch.cat([x["albedo"], x["roughness"]], 1).reshape(-1, particles, 2)
    return {"errors": [_errors(xi, q) for xi in xs], "seconds": secs, "evaluations": pot.evaluations}


def markdown(table: dict) -> str:
    """The table as markdown, the paper's values beside ours."""
    t = table["_truth"]
    lines = [f"Truth (quadrature): mean albedo {t['mean'][0]:.4f}, roughness {t['mean'][1]:.4f}; "
             f"variance albedo {t['var'][0]:.4f}, roughness {t['var'][1]:.4f}. "
             f"{t['particles']} samples, {t['runs']} runs.", "",
             "| sampler | MSE (mean) | MSE (variance) | seconds / run | evaluations / run | paper (mean / var) |",
             "|---|---|---|---|---|---|"]
    for k, v in table.items():
        if k.startswith("_"):
            continue
        p = PAPER.get(k)
        ps = f"{p[0]:.4f} / {p[1]:.4f}" if p else ""
        label = f"{t['particles']} exact i.i.d. draws" if k == "iid" else k
        lines.append(f"| {label} | {v['mse_mean']:.4f} | {v['mse_var']:.5f} | {v['seconds']:.2f} | "
                     f"{v['evaluations']} | {ps} |")
    return "\n".join(lines)
