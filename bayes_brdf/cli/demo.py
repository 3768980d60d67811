"""``bayes-brdf demo``: fit -> uncertainty -> recommended views -> guided rounds, with an HTML report."""
from __future__ import annotations

import sys

from .common import positive_int


#: what the demo writes into --out (removed by --overwrite)
OWNED = ("capture", "fit", "novel", "recommend", "guided", "real", "mesh", "report.html", "demo.json")


def add_parser(sub):
    d = sub.add_parser("demo", help="the whole story on a synthetic material, with an HTML report",
                       description="Photograph a procedural material (rendered), sample the posterior of its "
                                   "per-texel maps, show parameter- and image-space uncertainty next to the actual "
                                   "error on novel views, recommend the next views by mutual information, run a few "
                                   "guided capture rounds against a low-discrepancy baseline, do the same on an object (a mesh, "
                                   "section 7), and write report.html (self-contained) to --out. About four and a half "
                                   "minutes on 2 CPU cores with --capture (four without).")
    d.add_argument("--material", default="wood", help="procedural material (default: %(default)s)")
    d.add_argument("--resolution", type=positive_int, default=32, help="texels per side (default: %(default)s)")
    d.add_argument("--views", type=positive_int, default=5, help="initial photos (default: %(default)s)")
    d.add_argument("--steps", type=positive_int, default=1500, help="sampler steps of the fits (default: %(default)s); the guided rounds, warm-started from the "
                        "round before, run min(800, this)")
    d.add_argument("--rounds", type=int, default=2, help="guided capture rounds (default: %(default)s)")
    d.add_argument("--k", type=positive_int, default=3, help="views recommended per round (default: %(default)s)")
    d.add_argument("--seeds", type=positive_int, default=3,
                   help="seeds (capture noise, initial views) of the guided-vs-baseline comparison (default: %(default)s)")
    d.add_argument("--capture", default=None,
                   help="also fit a real capture folder (half its photos), check the uncertainty on the other half "
                        "and rank them by mutual information, in section 6 of the report")
    d.add_argument("--mesh", default="bowl",
                   help="the object of section 7: bowl, sphere, block, a mesh file (OBJ/PLY/GLB), or none "
                        "(default: %(default)s)")
    d.add_argument("--mesh-up", choices=["z", "y", "-y", "-z"], default="z",
                   help="up axis of a --mesh file (default: %(default)s; the Stanford bunny: y)")
    d.add_argument("--seed", type=int, default=0, help="random seed (default: %(default)s)")
    d.add_argument("--overwrite", action="store_true",
                   help="start over in --out even if it holds a demo with other settings")
    d.add_argument("--out", default="out/demo/story", help="output folder (default: %(default)s)")
    d.set_defaults(func=run)


def run(a) -> int:
    from ..errors import InputError
    from ..materials import MATERIALS
    from ..demo import run as demo

    if a.material not in MATERIALS:
        raise InputError(f"unknown material '{a.material}'", fix=f"use one of {', '.join(sorted(MATERIALS))}")
    if a.rounds < 0:
        raise InputError(f"--rounds must be >= 0, got {a.rounds}")
    from ..io.outputs import check_folder, claim
    check_folder(a.out)                                  # before minutes of work
    settings = {k: getattr(a, k) for k in ("material", "resolution", "views", "steps", "rounds", "k", "seeds",
                                           "capture", "seed", "mesh", "mesh_up")}
    if a.mesh != "none":
        from ..demo_mesh import load_demo_mesh
        m = load_demo_mesh(a.mesh, a.mesh_up)                # a bad --mesh fails now, not after minutes
        settings["mesh"] = m.digest
    if a.capture:
        from ..identity import observations_digest
        from ..io import load_capture
        from ..demo import DEFAULTS
        res = DEFAULTS["capture_resolution"]
        settings["capture"] = observations_digest(load_capture(a.capture, resolution=res))   # fails now if bad
    from .. import __version__
    from ..runs.fingerprint import sampler_identity
    claim(a.out, {"demo": settings, "sampler": sampler_identity("spos"), "version": __version__},
          f"a demo of {a.material} ({a.resolution} px, seed {a.seed})", overwrite=a.overwrite, owned=OWNED)
    path = demo(a.out, material=a.material, resolution=a.resolution, views=a.views, steps=a.steps, rounds=a.rounds,
                k=a.k, seed=a.seed, seeds=a.seeds, capture=a.capture, mesh=a.mesh, mesh_up=a.mesh_up,
                progress=sys.stderr.isatty())
    print(f"demo: report at {path.resolve()} (open it in a browser)")
    return 0
