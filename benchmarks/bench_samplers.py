"""Time per step of every sampler on the per-texel model, with Pyro's own SVGD as a reference row.

Usage:
    python benchmarks/bench_samplers.py                         # 64^2 x 10 views and 128^2 x 20 views
    python benchmarks/bench_samplers.py --cases 128x20 --samplers potential spos --steps 20 --repeats 3
    OMP_WAIT_POLICY=passive python benchmarks/bench_samplers.py    # on a busy shared machine

Setting: a synthetic RGB material (``bayes_brdf.materials.make_material``,
"tiles" by default) rendered under rectified collocated views (Sobol
directions, flash of power 1500 at 15 units from a sample of side 10) at image
resolution = texture resolution, so each pixel is one texel and the fused
native shading + loss kernel applies. The model is ``per_texel(R, albedo="rgb")``
(latent sites: albedo ``[3, R, R]`` and roughness ``[1, R, R]``; specular and
normals fixed), the likelihood the Laplace of Eq. 2, 20 particles.

Rows:

* ``potential``: one ``Potential.value_and_grad`` call (energies + gradients of all particles).
* ``spos`` ``svgd`` ``sgld`` ``emcee`` ``multistart_sgd`` ``nuts``: one ``sampler.step`` with the
  sampler's default hyper-parameters (``make_sampler(name)``). emcee is gradient-free (two half-ensemble
  energy calls per step); NUTS is one transition of one chain (up to ``2^max_tree_depth - 1``
  single-particle gradients per step): the last column gives particle evaluations of ``U`` per step.
  emcee's stretch move refuses fewer walkers than twice the dimension unless told to "live
  dangerously", which this benchmark does (the cost of a step does not depend on it).
* ``spos_stein``: the SPOS step without the preset's texel sweep (``texel_moves = 0``): one Stein update, what
  ``pyro_svgd`` does per step (like with like).
* ``spos_eager``: the same SPOS step on ``per_texel(..., backend="eager")`` (plain torch shading,
  autograd gradients): the naive baseline.
* ``pyro_svgd``: Pyro's own ``SVGD(model, RBFSteinKernel(), Adam({"lr": 0.01}),
  num_particles, max_plate_nesting)`` on the same model function and the same ``ModelData``. It runs
  (the model is vectorisable under Pyro's particle plate), but note that Pyro 1.9.2 mixes particles
  for models with two or more latent sites (its guide packs the latent vector site by site, its step
  reshapes it to ``(num_particles, -1)``; see tests/samplers/test_pyro_svgd_packing.py): timing only.

Each row is timed after ``--warmup`` untimed steps, one step at a time, ``--steps`` steps per repeat,
``--repeats`` repeats; the table gives the median and the mean wall-clock ms per step over all timed steps and, in
parentheses, the median process CPU ms (all threads: the work, less sensitive to other processes). The two differ
where some steps do more: the SPOS preset's texel sweep (every ``texel_moves`` steps, on models that offer texel
energies; every step since 2026-12-07, when both include it) is in the mean and, with a sweep less often than every
other step, not in the median; the mean is what a run pays per step. A
row stops early once it has used ``--max-seconds`` (after at least 2 timed steps, and one warm-up step when that
alone took a third of the budget) so that slow rows
(Pyro SVGD, the eager baseline, NUTS) keep the default run to a few minutes.

By default every step of our samplers starts from the same state (``sampler.init`` on prior draws):
the cost of a step then does not depend on where the dynamics go. ``--chain`` advances the chains
instead, as a run would; a sampler whose particles run off to ``|z| > 20`` (saturated sigmoids, maps
at their bounds, denormal floats) gets slower shading, and the benchmark warns about it. Pyro's SVGD
always advances (its state lives in the param store).

On a shared machine other processes inflate the wall times, badly so with OpenMP's default spinning
waits: compare rows of one run, look at the load average in the header, and set
``OMP_WAIT_POLICY=passive`` (measured 10x less inflation under load) or ``--threads 1``.
"""
from __future__ import annotations

import argparse
import os
import statistics
import time
import warnings

import pyro
import torch

from bayes_brdf.materials import make_material
from bayes_brdf.models import ModelData, per_texel
from bayes_brdf.observations import Observations
from bayes_brdf.potential import Potential
from bayes_brdf.render import PlanarSample, collocated_views
from bayes_brdf.render.shade import render
from bayes_brdf.samplers import make_sampler
from bayes_brdf.memory import keep_freed_memory

SAMPLERS = ("spos", "svgd", "sgld", "emcee", "multistart_sgd", "nuts")
ROWS = ("potential", *SAMPLERS, "spos_stein", "spos_eager", "pyro_svgd")
LABELS = {"potential": "potential only (value_and_grad)", "spos_eager": "spos, eager backend (naive)",
          "spos_stein": "spos without texel sweeps (texel_moves = 0)", "pyro_svgd": "pyro.infer.SVGD (reference)"}


def make_data(res: int, views: int, material: str = "tiles", noise: float = 0.01, seed: int = 0) -> ModelData:
    """Observations of a synthetic material under ``views`` rectified collocated views at ``res x res``."""
    vs = collocated_views(views, radius=15.0, camera="rectified", resolution=(res, res), power=1500.0,
                          method="sobol", seed=seed)
    surface = PlanarSample(10.0)
    maps = make_material(material, resolution=res, seed=seed)
    with torch.no_grad():
        img = render(maps, vs, surface)[0]
    gen = torch.Generator().manual_seed(seed)
    img = img + noise * (torch.rand(img.shape, generator=gen) - 0.5)
    return ModelData.from_observations(Observations(vs, img.contiguous(), surface))


class Timer:
    """Times ``fn()`` one call at a time: warm-up, then up to ``steps * repeats`` calls within a time budget.

    Returns the median wall-clock ms, the median process CPU ms (all threads) and the number of timed calls;
    ``calls`` is the number of calls including the warm-up, ``mean`` the mean wall-clock ms of the timed calls
    (where some steps do more than others: SPOS's texel sweep every few steps).
    """

    def __init__(self, warmup: int, steps: int, repeats: int, max_seconds: float):
        self.warmup, self.steps, self.repeats, self.max_seconds = warmup, steps, repeats, max_seconds

    def __call__(self, fn) -> tuple[float, float, int]:
        t_start, self.calls = time.perf_counter(), 0
        for _ in range(self.warmup):
            fn()
            self.calls += 1
            if time.perf_counter() - t_start > self.max_seconds / 3:   # a slow row: one warm-up step is enough
                break
        wall, cpu, t_start = [], [], time.perf_counter()
        for _ in range(self.repeats):
            for _ in range(self.steps):
                t, c = time.perf_counter(), time.process_time()
                fn()
                self.calls += 1
                wall.append(time.perf_counter() - t)
                cpu.append(time.process_time() - c)
                if len(wall) >= 2 and time.perf_counter() - t_start > self.max_seconds:
                    break
            else:
                continue
            break
        self.mean = statistics.fmean(wall) * 1e3
        return statistics.median(wall) * 1e3, statistics.median(cpu) * 1e3, len(wall)


def _saturated(z: torch.Tensor, limit: float = 20.0) -> float:
    """Fraction of unconstrained coordinates beyond ``+-limit`` (where the sigmoid bijections saturate)."""
    return float((z.abs() > limit).float().mean())


def sampler_row(name: str, model, data: ModelData, particles: int, timer: Timer, *, chain: bool = False,
                seed: int = 0, params: dict | None = None) -> dict:
    """Timings of one of our samplers (or ``"potential"``: one ``value_and_grad``) on ``model``.

    ``chain=False`` times every step from the same state (the sampler's ``init`` on prior draws), so the
    cost does not depend on where the dynamics go; ``chain=True`` advances the chain as a run would.
    Returns ``{"wall", "cpu", "steps", "evals", "saturated"}`` (ms per step, timed steps, particle
    evaluations of ``U`` per step, and the fraction of saturated coordinates at the end).
    """
    pot = Potential(model, (data,))
    z0 = pot.init(particles, seed=seed)
    if name == "potential":
        e0 = pot.evaluations
        wall, cpu, k = timer(lambda: pot.value_and_grad(z0))
        return {"wall": wall, "cpu": cpu, "mean": timer.mean, "steps": k, "evals": (pot.evaluations - e0) / timer.calls,
                "saturated": _saturated(z0)}
    sampler, _ = make_sampler(name, params=params)
    rng = torch.Generator().manual_seed(seed)
    torch.manual_seed(seed)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")   # emcee: fewer walkers than 2 D (it then steps anyway)
        state0 = sampler.init(z0, pot, rng, steps=10**6)   # a long horizon (annealing, NUTS' warm-up check)
    box = {"state": state0, "t": 0}

    def step():
        new, _ = sampler.step(box["state"] if chain else state0, box["t"], pot, rng)
        box["t"] += 1
        if chain:
            box["state"] = new
        box["last"] = new

    e0 = pot.evaluations
    wall, cpu, k = timer(step)
    return {"wall": wall, "cpu": cpu, "mean": timer.mean, "steps": k, "evals": (pot.evaluations - e0) / timer.calls,
            "saturated": _saturated(sampler.particles(box["last"]))}


def pyro_svgd_row(model, data: ModelData, particles: int, timer: Timer, lr: float = 0.01, seed: int = 0) -> dict:
    """The same numbers for Pyro's own ``pyro.infer.SVGD`` on the same model and data (its chain advances)."""
    from pyro.infer import SVGD, RBFSteinKernel
    from pyro.optim import Adam

    pyro.clear_param_store()
    pyro.set_rng_seed(seed)
    nesting = Potential(model, (data,)).plate_nesting
    svgd = SVGD(model, RBFSteinKernel(), Adam({"lr": lr}), num_particles=particles, max_plate_nesting=nesting)
    wall, cpu, k = timer(lambda: svgd.step(data))
    sat = _saturated(pyro.param("svgd_particles").unconstrained().detach())
    pyro.clear_param_store()
    return {"wall": wall, "cpu": cpu, "mean": timer.mean, "steps": k, "evals": float(particles), "saturated": sat}


def parse_case(s: str) -> tuple[int, int]:
    try:
        r, v = s.lower().split("x")
        return int(r), int(v)
    except ValueError:
        raise argparse.ArgumentTypeError(f"a case is RESxVIEWS, e.g. 128x20, got {s!r}") from None


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cases", type=parse_case, nargs="+", default=[(64, 10), (128, 20)],
                    help="RESxVIEWS: texels per side (= image pixels per side) and views (default: 64x10 128x20)")
    ap.add_argument("--samplers", nargs="+", default=list(ROWS), choices=ROWS, metavar="ROW",
                    help=f"rows to time (default: all of {', '.join(ROWS)})")
    ap.add_argument("--particles", type=int, default=20)
    ap.add_argument("--steps", type=int, default=10, help="timed steps per repeat (default 10)")
    ap.add_argument("--repeats", type=int, default=2, help="repeats of --steps timed steps (default 2)")
    ap.add_argument("--warmup", type=int, default=2, help="untimed steps first (default 2)")
    ap.add_argument("--max-seconds", type=float, default=15.0,
                    help="stop a row's timing after this many seconds (at least 2 timed steps; default 15)")
    ap.add_argument("--material", default="tiles")
    ap.add_argument("--chain", action="store_true",
                    help="advance each sampler's chain while timing (default: every step from the initial state)")
    ap.add_argument("--threads", type=int, default=None, help="torch.set_num_threads (default: torch's choice)")
    a = ap.parse_args(argv)
    keep_freed_memory()   # as the sampling driver does in a run (bayes_brdf.memory; BAYES_BRDF_KEEP_MEMORY=0: off)
    if a.threads:
        torch.set_num_threads(a.threads)
    timer = Timer(a.warmup, a.steps, a.repeats, a.max_seconds)

    load = ", ".join(f"{x:.1f}" for x in os.getloadavg()) if hasattr(os, "getloadavg") else "?"
    print(f"# sampler step time, per_texel (RGB albedo + roughness), {a.particles} particles, "
          f"torch {torch.__version__}, pyro {pyro.__version__}, {torch.get_num_threads()} threads, "
          f"{os.cpu_count()} CPUs, OMP_WAIT_POLICY={os.environ.get('OMP_WAIT_POLICY', '(unset)')}, "
          f"load average {load}")
    print(f"# median ms per step over up to {a.steps} x {a.repeats} timed steps after {a.warmup} warm-up steps "
          f"(at most {a.max_seconds:g} s per row); "
          + ("chains advance" if a.chain else "every step from the initial state (--chain: advance)"), flush=True)

    results: dict = {}
    for res, views in a.cases:
        data = make_data(res, views, a.material)
        for row in a.samplers:
            if row == "pyro_svgd":
                out = pyro_svgd_row(per_texel(res, albedo="rgb"), data, a.particles, timer)
            elif row == "spos_stein":
                out = sampler_row("spos", per_texel(res, albedo="rgb"), data, a.particles, timer, chain=a.chain,
                                  params={"texel_moves": 0})
            elif row == "spos_eager":
                out = sampler_row("spos", per_texel(res, albedo="rgb", backend="eager"), data, a.particles, timer,
                                  chain=a.chain)
            else:
                out = sampler_row(row, per_texel(res, albedo="rgb"), data, a.particles, timer, chain=a.chain)
            results[(row, res, views)] = out
            print(f"#   {res}^2 x {views}: {row}: {out['wall']:.1f} ms/step wall (mean {out['mean']:.1f}), "
                  f"{out['cpu']:.1f} ms CPU "
                  f"({out['steps']} timed steps; {100 * out['saturated']:.0f}% of coordinates saturated |z| > 20)",
                  flush=True)

    heads = [f"{r}² × {v} views" for r, v in a.cases]
    print()
    print("Median wall ms per step / mean wall ms per step (in parentheses: median process CPU ms, all threads). "
          "The mean counts the steps that do more than the others: SPOS's texel sweep, every texel_moves steps "
          "of the preset (every step: in both), is in the mean; spos_stein is the step without it.")
    print()
    print("| sampler | " + " | ".join(heads) + " | particle evals of U / step |")
    print("|---|" + "---|" * len(heads) + "---|")
    for row in a.samplers:
        cells = [f"{results[(row, r, v)]['wall']:.1f} / {results[(row, r, v)]['mean']:.1f} "
                 f"({results[(row, r, v)]['cpu']:.0f})" for r, v in a.cases]
        evals = sorted({f"{results[(row, r, v)]['evals']:.4g}" for r, v in a.cases})
        print(f"| {LABELS.get(row, row)} | " + " | ".join(cells) + f" | {' / '.join(evals)} |")
    sat = sorted({row for (row, _, _), o in results.items() if o["saturated"] > 0.5})
    if sat:
        print(f"\nWarning: more than half the coordinates of {', '.join(sat)} ended beyond |z| = 20 (saturated "
              "sigmoids: the maps sit at their bounds, denormal values slow the shading kernel).")


if __name__ == "__main__":
    main()
