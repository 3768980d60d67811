"""``bayes-brdf infer CAPTURE``: sample a material model's posterior with any sampler, write what it found."""
from __future__ import annotations

import json
import sys
import time
import warnings
from pathlib import Path

from ..errors import ConvergenceWarning

from .common import int_list, key_value, positive_int, steps_arg


def add_sampling_args(f, default_out: str):
    """The options ``infer`` and ``fit`` share: capture, model, sampler, run size, seed, device, output."""
    f.add_argument("capture", help="capture folder (or its parameters.json / optim.json / observations.json)")
    f.add_argument("--model", default="per_texel", help="model preset name or TOML path (default: %(default)s)")
    f.add_argument("--sampler", default=None,
                   help="sampler preset name or TOML path (default: spos, calibrated from 2-D to per-texel maps)")
    f.add_argument("--views", type=int_list, default=None, help="comma-separated view indices to fit (default: all)")
    f.add_argument("--resolution", type=positive_int, default=128,
                   help="resample the photos to this resolution; a per_texel model uses as many texels "
                        "(default: %(default)s)")
    f.add_argument("--particles", type=positive_int, default=None, help="override the preset's particle count")
    f.add_argument("--steps", type=steps_arg, default=None,
                   help="override the preset's step count, or 'auto': run until the convergence checks pass "
                        "(at most 4x the preset's)")
    f.add_argument("--param", type=key_value, action="append", default=[], metavar="KEY=VALUE",
                   help="override a sampler hyper-parameter, e.g. step_size=0.02 (repeatable)")
    f.add_argument("--model-param", type=key_value, action="append", default=[], metavar="KEY=VALUE",
                   help="override a model option, e.g. sigma=0.02 (repeatable)")
    f.add_argument("--seed", type=int, default=0, help="random seed (default: %(default)s)")
    f.add_argument("--device", default="cpu", help="torch device, e.g. cpu or cuda (default: %(default)s)")
    f.add_argument("--out", default=default_out, help="output folder (default: %(default)s)")


def add_parser(sub):
    f = sub.add_parser("infer", help="sample the posterior of a material model given a capture",
                       description="Load a capture (any supported format), sample the posterior of a model preset "
                                   "(models/*.toml or a path) with a sampler preset (samplers/*.toml or a path) and "
                                   "write posterior.safetensors, the mean and MAP maps, per-site std maps (EXR) and "
                                   "summary.json to --out. Rerunning with the same arguments resumes from the "
                                   "checkpoint in --out.")
    add_sampling_args(f, "out/infer")
    f.set_defaults(func=run)


def sample(a, obs, out: Path):
    """Sample the posterior for the parsed arguments ``a`` on ``obs``; checkpoints (and resumes) in ``out``."""
    from ..inference import infer
    from ..presets import load_preset

    table = dict(load_preset("models", a.model))
    table.update(dict(a.model_param))
    if table.get("model") == "per_texel" and "resolution" not in dict(a.model_param):
        table["resolution"] = a.resolution
    sampler = a.sampler or "spos"
    out.mkdir(parents=True, exist_ok=True)
    with warnings.catch_warnings():         # the CLI says it in its own terms (convergence_note)
        warnings.simplefilter("ignore", ConvergenceWarning)
        return infer(table, obs, sampler, seed=a.seed, particles=a.particles, steps=a.steps,
                     params=dict(a.param) or None, checkpoint=out / "checkpoint.pt", progress=sys.stderr.isatty(),
                     device=a.device)


def convergence_note(post) -> str:
    """One line for stderr when the run's convergence checks failed (``""`` when they passed)."""
    from ..samplers.diagnostics import Diagnostics

    d = post.diagnostics
    if not d or d.get("converged", True):
        return ""
    steps = int(d.get("steps") or post.meta.get("steps") or 0)
    return "warning: " + Diagnostics(d["checks"], steps).message(f"rerun with --steps {2 * steps} (and a new --out)")


def write_posterior(post, out: Path) -> dict:
    """``posterior.safetensors``, ``mean/`` and ``map/`` maps, ``std/<site>.exr`` (+ PNG with a colour bar)."""
    from ..io import save_svbrdf
    from ..uncertainty import write_map

    post.save(out / "posterior.safetensors")
    save_svbrdf(post.maps("mean").to("cpu"), out / "mean")
    save_svbrdf(post.maps("map").to("cpu"), out / "map")
    for site, s in post.std().items():
        img = s.float().cpu()
        img = img[:, None, None] if img.dim() == 1 else img
        write_map(out / "std" / site, img, title=f"posterior std of {site} (Eq. 9)")
    return {k: float(v.mean()) for k, v in post.std().items()}


def run(a) -> int:
    import torch

    from ..io import load_capture

    obs = load_capture(a.capture, resolution=a.resolution)
    if a.views is not None:
        obs = obs.subset(a.views)
    out = Path(a.out)
    t = time.perf_counter()
    post = sample(a, obs, out)
    secs = time.perf_counter() - t
    mean_std = write_posterior(post, out)
    summary = {"capture": str(a.capture), "views": a.views, "model": post.meta["model"],
               "sampler": post.meta["sampler"], "params": post.meta["params"], "run": post.meta["run"],
               "seed": a.seed, "seconds": post.meta["seconds"], "wall_seconds": secs,
               "evaluations": post.meta["evaluations"], "mean_std": mean_std,
               "best_energy": float(post.energies.min()), "device": str(torch.device(a.device)),
               "diagnostics": post.diagnostics}
    (out / "summary.json").write_text(json.dumps(summary, indent=2, default=str))
    print(f"{post} from {len(obs)} views in {post.meta['seconds']:.1f} s -> {out}/ "
          f"(posterior.safetensors, mean/, map/, std/, summary.json)")
    note = convergence_note(post)
    if note:
        print(note, file=sys.stderr)
    return 0
