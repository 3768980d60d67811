"""``bayes-brdf recommend CAPTURE``: rank candidate views by mutual information with the posterior (Eq. 18)."""
from __future__ import annotations

import json
import math
import time
from pathlib import Path

from ..executor import add_ray_args, executor_of_args
from .common import positive_float, positive_int
from .infer import add_sampling_args, load, sample

#: --candidate-light: how generated and held-out candidates are lit
LIGHTINGS = ("capture", "flash", "environment", "both")


def add_parser(sub):
    r = sub.add_parser("recommend", help="rank candidate views by how much they would reduce the uncertainty",
                       description="Fit the posterior on --views of a capture (or load one with --posterior), then "
                                   "score candidate views by mutual information (Eq. 18) and print the best --k, "
                                   "with hypersphere exclusion of --radius degrees between picks. Candidates: the "
                                   "capture's views that were not fitted ('heldout', e.g. to replay a session), or "
                                   "generated views (fibonacci:N, sobol:N) at the capture's camera distance, lit as "
                                   "--candidate-light says (by default as the capture: its environment map and/or "
                                   "its flash), or a JSON file of views. Writes recommend.json and a plot of the "
                                   "candidates.")
    add_sampling_args(r, "out/recommend")
    r.add_argument("--posterior", default=None,
                   help="a posterior.safetensors written by fit/infer (skips fitting; its model must be a preset)")
    r.add_argument("--from", dest="from_run", default=None, metavar="RUN",
                   help="the next view while the user holds the camera: a folder of an earlier fit/infer/recommend "
                        "run on this capture (or its posterior.safetensors), fitted on fewer photos; the sampler "
                        "starts from its particles and runs --warm-steps (no annealing) on --views, the earlier "
                        "photos and the new ones, before scoring the candidates")
    r.add_argument("--warm-steps", type=positive_int, default=None,
                   help="steps of the warm-started run with --from (default: 300; --steps says the same)")
    r.add_argument("--candidates", default="heldout",
                   help="heldout, fibonacci:N, sobol:N or a JSON file of views (default: %(default)s)")
    r.add_argument("--candidate-light", default="capture", choices=LIGHTINGS,
                   help="how generated and held-out candidates are lit: capture (as the capture's views: its "
                        "environment map and/or a flash at the camera), flash (a flash at the camera alone), "
                        "environment (the capture's environment map alone), both (the environment map and a flash "
                        "at the camera); a JSON file's views keep their own lights (default: %(default)s)")
    r.add_argument("--flash-power", type=positive_float, default=None,
                   help="power of the candidates' flash (default: the capture's flash's; needed for "
                        "--candidate-light flash or both when the capture has no flash)")
    r.add_argument("--k", type=positive_int, default=3, help="views to recommend (default: %(default)s)")
    r.add_argument("--radius", type=float, default=10.0,
                   help="exclusion radius between picks, degrees (default: %(default)s)")
    r.add_argument("--method", default="mi", choices=["mi", "std", "sobol", "fibonacci", "random"],
                   help="mi (ours), std (max image-space std), sobol, fibonacci or random baselines "
                        "(default: %(default)s)")
    r.add_argument("--estimator", default="mc", choices=["mc", "quadrature"],
                   help="entropy estimator: mc (Eq. 21) or quadrature (deterministic, slower) (default: %(default)s)")
    add_ray_args(r)
    r.add_argument("--noise-var", default="0",
                   help="noise variance in the score: a number (0, the default, is the paper's noise-free renderer) "
                        "or 'observation' (the model's photo noise; see docs/guidance.md)")
    r.set_defaults(func=run)


def _lighting(full, choice: str, flash_power):
    """``(environment or None, flash (power, falloff) or None)`` that ``--candidate-light choice`` puts on
    generated and held-out candidates; one line if the capture lacks what is asked."""
    from ..errors import InputError

    envs = list(dict.fromkeys(v.environment for v in full.views if v.environment is not None))
    points = [l for v in full.views for l in v.point_lights]
    want_env = choice in ("environment", "both") or (choice == "capture" and bool(envs))
    want_flash = choice in ("flash", "both") or (choice == "capture" and bool(points))
    env = flash = None
    if want_env:
        if not envs:
            raise InputError(f"--candidate-light {choice}: the capture's views have no environment map to light "
                             "the candidates with", fix="use --candidate-light flash, or a capture lit by an "
                                                        "environment (render --env)")
        if len(envs) > 1:
            raise InputError(f"--candidate-light {choice}: the capture's views are lit by {len(envs)} different "
                             "environment maps", fix="give a JSON file of candidate views")
        env = envs[0]
    if want_flash:
        if flash_power is None and not points:
            raise InputError(f"--candidate-light {choice}: the capture's views have no flash to copy onto the "
                             "candidates", fix="give the flash's power with --flash-power")
        flash = (flash_power if flash_power is not None else points[0].power,
                 points[0].falloff if points else True)
    return env, flash


def _lit(camera, name, env, flash):
    from ..render.lights import PointLight
    from ..render.views import View

    lights = () if flash is None else (PointLight(camera.position, flash[0], flash[1]),)
    return View(camera, lights + (() if env is None else (env,)), name)


def _candidates(spec: str, full, fitted, light: str = "capture", flash_power=None):
    from ..errors import InputError
    from ..render.surface import PlanarSample
    from ..render.views import View, collocated_views

    if spec == "heldout":
        idx = [i for i in range(len(full)) if i not in fitted]
        if not idx:
            raise InputError("no held-out views to rank: every view is fitted",
                             fix="fit fewer --views, or use --candidates fibonacci:N")
        views = [full.views[i] for i in idx]
        if light != "capture" or flash_power is not None:        # the held-out cameras, lit as asked
            env, flash = _lighting(full, light, flash_power)
            views = [_lit(v.camera, v.name, env, flash) for v in views]
        return views, idx
    p = Path(spec)
    if p.suffix.lower() == ".json":
        if light != "capture" or flash_power is not None:
            raise InputError("--candidate-light and --flash-power light generated and held-out candidates only: "
                             "a JSON file's views keep their own lights", fix="give the lights in the file")
        if not p.is_file():
            raise InputError("candidate views file not found", where=p)
        try:
            data = json.loads(p.read_text())
        except (OSError, json.JSONDecodeError) as e:
            raise InputError(f"unreadable views JSON ({e})", where=p) from None
        data = data.get("views", data) if isinstance(data, dict) else data
        views = [View.from_dict(d.get("view", d), where=f"{p}[{i}]") for i, d in enumerate(data)]
        return views, list(range(len(views)))
    kind, _, num = spec.partition(":")
    if kind not in ("fibonacci", "sobol") or not num.isdigit() or int(num) < 1:
        raise InputError(f"bad --candidates '{spec}'", fix="use heldout, fibonacci:N, sobol:N or a JSON file of views")
    from ..render.cameras import PerspectiveCamera

    env, flash = _lighting(full, light, flash_power)
    v0 = full.views[0]
    centre = full.surface.center
    dist = sorted(math.dist(v.camera.position, centre) for v in full.views)[len(full.views) // 2]
    if isinstance(v0.camera, PerspectiveCamera):    # like the capture's cameras, around its geometry's centre
        kw = dict(camera="perspective", fov=v0.camera.fov, target=centre,
                  max_zenith=60 if isinstance(full.surface, PlanarSample) else 90)
    else:
        kw = dict(camera="rectified", max_zenith=60)
    cams = collocated_views(int(num), dist, method=kind, resolution=v0.resolution, **kw)
    views = [_lit(v.camera, v.name, env, flash) for v in cams]
    return views, list(range(len(views)))


def run(a) -> int:
    from ..guidance.scores import parse_noise_var

    nv = parse_noise_var(a.noise_var)           # checked before any fitting
    with executor_of_args(a) as ex:             # Ray missing or a cluster out of reach: one line before the fit
        return _run(a, nv, ex)


def _run(a, nv, ex) -> int:
    from ..errors import InputError
    from ..executor import score_candidates
    from ..guidance import recommend
    from ..io.outputs import write_json
    from ..plots import plot_candidates
    from ..posterior import Posterior

    t0 = time.perf_counter()
    prev = _earlier_posterior(a) if a.from_run else None
    obs, full, out = load(a, "recommend", full=True)
    fitted = list(range(len(full))) if a.views is None else list(a.views)
    # a bad --candidates or --candidate-light fails before the fit
    cands, labels = _candidates(a.candidates, full, fitted, a.candidate_light, a.flash_power)
    # the recommendation reads the particles, never the MAP (Eq. 7): it is not refined (2 s of a 64² warm start)
    if prev is not None:
        post = sample(a, obs, out, z0=prev.z, start=_start_label(a.from_run, prev), map_steps=0)
        post.save(out / "posterior.safetensors")
    elif a.posterior:
        post = Posterior.load(a.posterior)
        if post.model is None:
            raise InputError("this posterior's model cannot be rebuilt from its file", where=a.posterior,
                             fix="refit with --views instead of --posterior")
        if post.surface is None:
            post.surface = full.surface
    else:
        post = sample(a, obs, out, map_steps=0)
        post.save(out / "posterior.safetensors")
    t_fit = time.perf_counter() - t0
    scores = None
    if a.method in ("mi", "std"):    # in shards of candidates, in this process or on Ray: the same numbers
        scores = score_candidates(post, cands, full.surface, executor=ex, estimator=a.estimator, seed=a.seed,
                                  noise_var=nv)
    rec = recommend(post, cands, a.k, method=a.method, radius=a.radius, surface=full.surface, seed=a.seed,
                    scores=scores, offset=len(fitted))
    result = {"capture": str(a.capture), "fitted_views": fitted, "candidates": a.candidates, "method": a.method,
              "candidate_light": a.candidate_light, "candidates_lit_by": _describe(cands), "k": a.k,
              "radius_deg": a.radius, "estimator": a.estimator, "noise_var": nv,
              "fit_seconds": t_fit, "warm_start": None if prev is None else {
                  "from": str(a.from_run), "fitted_views_before": _earlier_views(a.from_run),
                  "steps": post.meta.get("steps")},
              "recommended": [labels[i] for i in rec.indices], **rec.to_dict()}
    if scores is not None:
        result["all"] = [{"candidate": labels[i], "mi": float(scores.mi[i]), "mean_std": float(scores.mean_std[i]),
                          "pixels": int(scores.pixels[i])} for i in range(len(cands))]
        plot_candidates(out / "candidates.png", cands,
                        scores.mi.numpy() if a.method == "mi" else scores.mean_std.numpy(),
                        rec.indices, f"{len(cands)} candidates, {a.k} recommended ({a.method})",
                        centre=full.surface.center)
    write_json(out / "recommend.json", result)
    what = "view" if a.candidates == "heldout" else "candidate"
    print(f"recommended ({a.method}, from {len(cands)} candidates lit by {_describe(cands)}): "
          + ", ".join(f"{what} {labels[i]}" + (f" (MI {float(scores.mi[i]):.0f} nats)" if scores is not None else "")
                      for i in rec.indices) + f" -> {out}/recommend.json")
    if scores is not None and a.candidates == "heldout":
        order = sorted(range(len(cands)), key=lambda i: -float(scores.mi[i]))
        print("ranking by mutual information: " + " > ".join(str(labels[i]) for i in order))
    if scores is not None and nv == 0 and bool((scores.mi < 0).any()):
        print("(the noise-free score is a differential entropy, so it can be negative: only the order matters)")
    return 0


def _earlier_posterior(a):
    """The posterior of ``--from RUN`` (a run folder or its ``posterior.safetensors``), checked before any work;
    sets the warm start's run length and switches annealing off in ``a``."""
    from ..errors import InputError
    from ..inference import WARM_STEPS, warm_params
    from ..posterior import Posterior

    if a.posterior:
        raise InputError("--from and --posterior both give a posterior", fix="use --from RUN to warm-start a fit on "
                         "the new photos, or --posterior FILE to score with a posterior as it is")
    p = Path(a.from_run)
    f = p / "posterior.safetensors" if p.is_dir() else p
    if not f.is_file():
        raise InputError("no posterior.safetensors in the run folder given to --from", where=p,
                         fix="give the --out folder of an earlier fit, infer or recommend on this capture")
    prev = Posterior.load(f)
    if prev.z is None:
        raise InputError("this posterior has no particles to start from", where=f,
                         fix="give the folder of a run written by fit, infer or recommend")
    if a.warm_steps is not None and a.steps is not None and a.warm_steps != a.steps:
        raise InputError(f"--warm-steps {a.warm_steps} and --steps {a.steps} disagree", fix="give one of them")
    a.steps = a.steps or a.warm_steps or WARM_STEPS
    a.param = list(warm_params(a.sampler or "spos", dict(a.param)).items())   # as bb.inference.update
    return prev


def _earlier_views(run):
    """The views the ``--from`` run fitted, from its ``run.json`` (``None``: all of them, or not recorded)."""
    import json

    try:
        return json.loads((Path(run) / "run.json").read_text()).get("fingerprint", {}).get("views")
    except (OSError, ValueError, AttributeError):
        return None


def _start_label(run, prev) -> dict:
    """What the warm start starts from, for the run's fingerprint: the earlier particles' digest."""
    from ..identity import digest_tensor

    return {"from": str(Path(run).resolve()), "particles": digest_tensor(prev.z)}


def _describe(views) -> str:
    """What lights the candidates, in words: 'flash', 'environment', 'environment + flash', 'point lights'
    (lights away from the camera), several joined by ' / '."""
    def one(v):
        points = v.point_lights
        flash = "flash" if all(tuple(l.position) == tuple(v.camera.position) for l in points) else "point lights"
        return " + ".join((["environment"] if v.environment is not None else []) + ([flash] if points else []))
    return " / ".join(dict.fromkeys(one(v) for v in views))
