"""``bayes-brdf infer CAPTURE``: sample a material model's posterior with any sampler, write what it found."""
from __future__ import annotations

import sys
import time
import warnings
from pathlib import Path

from .common import check_views, key_value, particles_arg, positive_int, steps_arg, view_list
from .run_folder import claim_folder, log_run, output_folder


def add_sampling_args(f, default_out: str, many: bool = False):
    """The options ``infer`` and ``fit`` share: capture, model, sampler, run size, seed, device, output
    (``many``: ``CAPTURE...``, one or more, each fitted into its own sub-folder of ``--out``, as ``fit-many``)."""
    if many:
        f.add_argument("captures", nargs="+", metavar="CAPTURE",
                       help="capture folders (or their parameters.json / optim.json / observations.json)")
    else:
        f.add_argument("capture", help="capture folder (or its parameters.json / optim.json / observations.json)")
    f.add_argument("--model", default="per_texel", help="model preset name or TOML path (default: %(default)s)")
    f.add_argument("--sampler", default=None,
                   help="sampler preset name or TOML path (default: spos, calibrated from 2-D to per-texel maps)")
    f.add_argument("--views", type=view_list, default=None, help="comma-separated view indices to fit (default: all)")
    f.add_argument("--resolution", type=positive_int, default=None,
                   help="resample the photos to this resolution, at most their own; a per_texel model uses as "
                        "many texels (default: the photos' own, at most 128)")
    f.add_argument("--particles", type=particles_arg, default=None,
                   help="override the preset's particle count (at least 2)")
    f.add_argument("--steps", type=steps_arg, default=None,
                   help="a fixed step count, or 'auto': a quarter of the preset's steps, then more until the "
                        "convergence checks pass, at most 4x the preset's (default: the preset's choice; spos: auto)")
    f.add_argument("--param", type=key_value, action="append", default=[], metavar="KEY=VALUE",
                   help="override a sampler hyper-parameter, e.g. step_size=0.02 (repeatable)")
    f.add_argument("--model-param", type=key_value, action="append", default=[], metavar="KEY=VALUE",
                   help="override a model option, e.g. sigma=0.02 (repeatable)")
    f.add_argument("--seed", type=int, default=0, help="random seed (default: %(default)s)")
    f.add_argument("--device", default="cpu", help="torch device, e.g. cpu or cuda (default: %(default)s)")
    if many:
        f.add_argument("--out", default=default_out, metavar="DIR",
                       help="output folder: each capture in DIR/<capture name> (a second capture of the same name "
                            "in DIR/<name>-2 ...), as its own run (default: %(default)s, so each capture's folder is "
                            "the one a plain fit of it uses); a rerun resumes each, another run is refused")
    else:
        f.add_argument("--out", default=None,
                       help=f"output folder (default: {default_out}/CAPTURE, named after the capture); a rerun of "
                            "the same command resumes there, another run is refused")
    f.add_argument("--overwrite", action="store_true",
                   help="start over in --out even if it holds another (or the same) run")


def add_parser(sub):
    f = sub.add_parser("infer", help="sample the posterior of a material model given a capture",
                       description="Load a capture (any supported format), sample the posterior of a model preset "
                                   "(models/*.toml or a path) with a sampler preset (samplers/*.toml or a path) and "
                                   "write posterior.safetensors, the mean and MAP maps, per-site std maps (EXR) and "
                                   "summary.json to --out. Rerunning with the same arguments resumes from the "
                                   "checkpoint in --out.")
    add_sampling_args(f, "out/infer")
    f.set_defaults(func=run)


def load(a, command: str, full: bool = False):
    """Check the output folder, load the capture (``--resolution``: at most the photos' own), check ``--views``.

    Returns the observations of the fitted views (and, with ``full``, all of them too).
    """
    from ..io import load_capture

    out = output_folder(a, command)                  # before any work: one line if it cannot be written
    cap = load_capture(a.capture, resolution=a.resolution, max_resolution=128)
    check_views(a.views, len(cap))
    obs = cap if a.views is None else cap.subset(a.views)
    return (obs, cap, out) if full else (obs, out)


def sample(a, obs, out: Path, *, z0=None, start: dict | None = None, map_steps: int | None = None):
    """Sample the posterior for the parsed arguments ``a`` on ``obs``; checkpoints (and resumes) in ``out``.

    ``out`` must hold this run or nothing (:func:`~bayes_brdf.cli.run_folder.claim_folder`); the
    invocation is appended to ``out/run_log.jsonl``. ``z0``: start from these particles (a warm start,
    ``recommend --from``), described by ``start`` in the run's fingerprint. ``map_steps``: as
    :func:`bayes_brdf.inference.infer` (0: the best particle is the MAP, not refined).
    """
    from ..errors import ConvergenceWarning
    from ..identity import observations_digest
    from ..inference import infer
    from ..runs.fingerprint import model_table
    from ..samplers.driver import Interrupted

    table = model_table(a.model, dict(a.model_param), obs.resolution[0])
    digest = observations_digest(obs)       # once per run: the folder's fingerprint and the checkpoint's
    status = claim_folder(a, obs, table, digest, start=start)
    if status == "overwritten":
        print(f"bayes-brdf: --overwrite: starting over in {out}", file=sys.stderr)
    t = time.perf_counter()
    try:
        with warnings.catch_warnings():         # the CLI says it in its own terms (convergence_note)
            warnings.simplefilter("ignore", ConvergenceWarning)
            post = infer(table, obs, a.sampler or "spos", seed=a.seed, particles=a.particles, steps=a.steps,
                         params=dict(a.param) or None, checkpoint=out / "checkpoint.pt",
                         progress=sys.stderr.isatty(), device=a.device, observations_digest=digest, z0=z0,
                         map_steps=map_steps)
    except Interrupted as e:
        log_run(out, {"status": f"interrupted at step {e.step}", "wall_seconds": time.perf_counter() - t})
        raise
    lg = post.log
    if lg.get("resumed_from") and lg["resumed_from"] >= lg.get("steps", 0):
        print(f"bayes-brdf: {out} holds this run, finished ({lg['steps']} steps): rewriting its results",
              file=sys.stderr)
    log_run(out, {"status": "finished", "resumed_from": lg.get("resumed_from", 0), "steps": lg.get("steps"),
                  "sampling_seconds": lg.get("seconds"), "wall_seconds": time.perf_counter() - t})
    return post


def timing(post) -> str:
    """``"in 41.2 s"``, or for a resumed run ``"in 41.2 s of sampling (resumed at step 600)"``."""
    lg = post.log
    secs = lg.get("seconds", 0.0)
    if lg.get("resumed_from"):
        if lg["resumed_from"] >= lg.get("steps", 0):
            return f"sampled earlier in {secs:.1f} s"
        return f"in {secs:.1f} s of sampling (resumed at step {lg['resumed_from']})"
    return f"in {secs:.1f} s"


def convergence_note(post) -> str:
    """One line for stderr when the run's convergence checks failed (``""`` when they passed)."""
    from ..samplers.diagnostics import Diagnostics

    d = post.diagnostics
    if not d or d.get("converged", True):
        return ""
    diag = Diagnostics.from_dict({**d, "steps": int(d.get("steps") or post.meta.get("steps") or 0)})
    return "warning: " + diag.message(cli=True)


def write_posterior(post, out: Path) -> dict:
    """``posterior.safetensors``, ``mean/`` and ``map/`` maps, ``std/<site>.exr`` (+ PNG with a colour bar)."""
    from ..io import save_svbrdf
    from ..plots import write_map

    post.save(out / "posterior.safetensors")
    save_svbrdf(post.maps("mean").to("cpu"), out / "mean")
    save_svbrdf(post.maps("map").to("cpu"), out / "map")
    std = post.std()
    for site, s in std.items():
        img = s.float().cpu()
        img = img[:, None, None] if img.dim() == 1 else img
        write_map(out / "std" / site, img, title=f"posterior std of {site} (Eq. 9)")
    return {k: float(v.mean()) for k, v in std.items()}


def run(a) -> int:
    import torch

    from ..io.outputs import write_json

    obs, out = load(a, "infer")
    t = time.perf_counter()
    post = sample(a, obs, out)
    secs = time.perf_counter() - t
    mean_std = write_posterior(post, out)
    summary = {"capture": str(a.capture), "views": a.views, "resolution": obs.resolution[0],
               "model": post.meta["model"], "sampler": post.meta["sampler"], "params": post.meta["params"],
               "run": post.meta["run"], "seed": a.seed, "sampling_seconds": post.log.get("seconds"),
               "resumed_from": post.log.get("resumed_from", 0), "wall_seconds": secs,
               "evaluations": post.meta["evaluations"], "mean_std": mean_std,
               "best_energy": float(post.energies.min()), "device": str(torch.device(a.device)),
               "diagnostics": post.diagnostics}
    write_json(out / "summary.json", summary)
    print(f"{post} from {len(obs)} views {timing(post)} -> {out}/ "
          f"(posterior.safetensors, mean/, map/, std/, summary.json)")
    note = convergence_note(post)
    if note:
        print(note, file=sys.stderr)
    return 0
