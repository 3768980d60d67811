"""``bayes-brdf compare``: the paper's Table 1 (samplers on a 2-D posterior with an exact answer)."""
from __future__ import annotations

from ..executor import add_ray_args
from .common import float_list, key_value, positive_float, positive_int


def add_parser(sub):
    c = sub.add_parser("compare", help="the sampler comparison table (the paper's Table 1)",
                       description="Sample a 2-D posterior (gray albedo, roughness; one pixel under one collocated "
                                   "flash, or under a known environment) with each sampler, compare with dense quadrature, print a markdown table "
                                   "of MSE of the mean / variance and seconds; --json writes the numbers. --ray runs the samplers' runs as "
                                   "tasks of a local Ray (--ray-address: a cluster), with the same numbers.")
    c.add_argument("--angle", type=float, default=0.0, help="zenith of camera+flash in degrees (default: %(default)s)")
    c.add_argument("--albedo", type=float, default=0.5, help="true albedo of the observed pixel (default: %(default)s)")
    c.add_argument("--roughness", type=float, default=0.5, help="true roughness (default: %(default)s)")
    c.add_argument("--sigma", type=positive_float, default=0.01, help="sigma_err of the L1 likelihood (default: %(default)s)")
    c.add_argument("--observations", type=float_list, default=[],
                   help="extra configurations as comma-separated angles, one pixel each (default: none)")
    c.add_argument("--lighting", choices=("collocated", "environment", "environment+flash"), default="collocated",
                   help="how the pixel is lit: the collocated flash, a known environment alone, or both "
                        "(default: %(default)s)")
    c.add_argument("--env", metavar="MAP", default=None,
                   help="HDR map (EXR or .hdr, read z-up) for the environment lightings (default: the built-in "
                        "studio, a softbox mirrored by a camera at --angle 20)")
    c.add_argument("--env-scale", type=positive_float, default=1.0, help="radiance scale of the map (default: %(default)s)")
    c.add_argument("--runs", type=positive_int, default=20, help="independent runs per sampler (default: %(default)s)")
    c.add_argument("--particles", type=positive_int, default=16, help="samples per run (default: %(default)s)")
    c.add_argument("--steps", type=positive_int, default=None,
                   help="steps per run for every sampler (default: each sampler's preset)")
    c.add_argument("--samplers", default="spos,svgd,sgld,emcee,multistart_sgd,nuts",
                   help="comma-separated names or preset paths (default: %(default)s)")
    c.add_argument("--param", type=key_value, action="append", default=[], metavar="SAMPLER.KEY=VALUE",
                   help="override a hyper-parameter, e.g. spos.beta=10 (repeatable)")
    c.add_argument("--grid", type=positive_int, default=1000, help="quadrature cells per axis (default: %(default)s)")
    c.add_argument("--seed", type=int, default=0, help="base seed (default: %(default)s)")
    c.add_argument("--json", help="also write the numbers to this JSON file")
    add_ray_args(c)
    c.set_defaults(func=run)


def run(a) -> int:
    from ..errors import InputError
    from ..experiments.table1 import Table1Setup, compare, markdown
    from ..io.outputs import check_file_target, write_json

    if a.json:
        check_file_target(a.json, option="--json")        # before the minutes of sampling

    if not 0 <= a.albedo <= 1 or not 0.05 <= a.roughness <= 1:
        raise InputError(f"--albedo must be in [0, 1] and --roughness in [0.05, 1], got {a.albedo}, {a.roughness}")
    for ang in [a.angle, *a.observations]:
        if not 0 <= ang < 89:
            raise InputError(f"angles must be in [0, 89) degrees, got {ang}")
    if a.env is not None and a.lighting == "collocated":
        raise InputError("--env needs an environment lighting", fix="add --lighting environment "
                                                                    "(or environment+flash)")
    params = {}
    for k, v in a.param:
        if "." not in k:
            raise InputError(f"--param {k}=...: name the sampler, e.g. spos.{k}")
        s, key = k.split(".", 1)
        params.setdefault(s, {})[key] = v
    setup = Table1Setup(angle=a.angle, albedo=a.albedo, roughness=a.roughness, sigma=a.sigma,
                        observations=a.observations, grid=a.grid, lighting=a.lighting, env=a.env,
                        env_scale=a.env_scale)
    from ..experiments.table1 import environment_of
    environment_of(setup)                                  # a bad map fails here, before any sampling
    names = [s for s in a.samplers.split(",") if s]
    from ..executor import executor_of_args
    with executor_of_args(a) as ex:                        # the samplers' runs: in this process, or Ray tasks
        table = compare(setup, names, runs=a.runs, particles=a.particles, steps=a.steps, seed=a.seed,
                        params=params, progress=False, executor=ex)
    print(markdown(table))
    if a.json:
        rows = {k: v for k, v in table.items() if not k.startswith("_")}
        p = write_json(a.json, {**rows, "_truth": table["_truth"]})
        print(f"wrote {p}")
    return 0
