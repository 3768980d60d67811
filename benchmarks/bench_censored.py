"""Clipped highlights on a synthetic capture with known maps: censored vs dropped vs fitted as exact.

Usage:
    python benchmarks/bench_censored.py                     # 32^2, power 40 (2.8 % of pixels clip at 1)
    python benchmarks/bench_censored.py --resolution 64 --power 60
    python benchmarks/bench_censored.py --captures card_blue bath_tile yellow_box --out out/censored

The problem is :mod:`bayes_brdf.experiments.highdim`'s per-texel gray material
(5 rectified collocated flash views, Laplace noise sigma 0.01) with a brighter
flash, clipped at 1 as a camera would: ``saturated`` marks every pixel with a
channel at the clip. Each treatment is fit with the package defaults
(``spos``, ``sigma = "auto"``), seed 0:

* ``censored`` -- the default: a clipped pixel contributes ``log P(R + noise >= 1)``;
* ``drop``     -- ``saturated = "drop"``: clipped pixels left out;
* ``exact``    -- the clipped values fitted as if they were the radiance (no saturation mask).

Printed per treatment, over the texels seen clipped in at least one view and over
all texels: the roughness and albedo error of the posterior mean, the posterior
std, and the coverage of the *true* value by the central 50 % / 90 % intervals
(mean +- 0.674 / 1.645 std: a calibrated posterior covers about 0.50 / 0.90 of
the texels). Numbers only, no asserts.

``--captures``: the real captures in ``../shared/data/captures`` (no truth), each
fit with ``bayes-brdf fit NAME --views 0,2,4,6,8 --resolution 64`` censored and
with ``--model-param saturated=drop`` (into ``OUT/NAME_censored`` and
``OUT/NAME_drop``; a finished fit there is reused). Printed: the inferred sigma,
the held-out 50 % / 90 % coverage and Spearman(std, |error|), and, on the texels
clipped in a fit view, the posterior mean and std of roughness under both, and
the held-out |error| of the posterior-mean render on the pixels of those texels
(the highlights' neighbourhood, where roughness shows).
"""
from __future__ import annotations

import argparse
import json
import time
import warnings
from dataclasses import replace

import torch

import bayes_brdf as bb
from bayes_brdf.experiments import highdim as H


def problem(resolution: int, power: float, clip: float, seed: int):
    prob = H.setup(H.HighDimSetup(noise=True, resolution=resolution, power=power, seed=seed))
    obs = prob.data.observations
    sat = (obs.images >= clip).any(-1)
    clipped = replace(obs, images=obs.images.clamp(max=clip), saturated=sat)
    return prob, clipped, sat


def summarise(post, truth: dict, texels: torch.Tensor) -> dict:
    out = {}
    for site in ("roughness", "albedo"):
        mean, std = post.mean(site)[0].double(), post.std(site)[0].double()
        t = truth[site]
        z = (t - mean).abs() / std.clamp_min(1e-12)
        for name, sel in (("clipped", texels), ("all", torch.ones_like(texels))):
            out[f"{site}_{name}"] = {"mae": float((mean - t).abs()[sel].mean()), "std": float(std[sel].median()),
                                     "cov50": float((z[sel] <= 0.674).double().mean()),
                                     "cov90": float((z[sel] <= 1.645).double().mean())}
    return out


def real_captures(names, out, data="../shared/data/captures"):
    from pathlib import Path

    from bayes_brdf.cli.main import main as cli
    from bayes_brdf.io import load_capture
    from bayes_brdf.posterior import Posterior
    from bayes_brdf.uncertainty import predictive_cdf

    print(f"{'capture':11s} {'treatment':9s} {'sigma':>6s} {'c50':>5s} {'c90':>5s} {'spear':>5s}  "
          f"{'clipped texels':>14s} {'rough mean':>10s} {'rough std':>9s} {'|err| near clip':>15s} {'|err| all':>9s}")
    for name in names:
        cap = Path(data) / name
        full = load_capture(cap, resolution=64)
        fit_views, held = [0, 2, 4, 6, 8], [1, 3, 5, 7]
        texels = full.saturated[fit_views].any(0)                       # rectified 64^2 captures: pixel = texel
        for tr in ("censored", "drop"):
            d = Path(out) / f"{name}_{tr}"
            if not (d / "summary.json").is_file():
                extra = ["--model-param", "saturated=drop"] if tr == "drop" else []
                cli(["fit", str(cap), "--views", "0,2,4,6,8", "--resolution", "64", "--out", str(d), *extra])
            s = json.loads((d / "summary.json").read_text())
            post = Posterior.load(d / "posterior.safetensors")
            rm, rs = post.mean("roughness")[0], post.std("roughness")[0]
            ho = full.subset(held)
            _, _, mean = predictive_cdf(post, ho.views, ho.images, ho.surface)
            err = (mean - ho.images).abs().mean(-1)                          # [V, H, W]
            ok = ~ho.saturated & ho.mask if ho.mask is not None else ~ho.saturated
            near = ok & texels[None]
            h = s["heldout"]
            print(f"{name:11s} {tr:9s} {s['noise_sigma']:6.4f} {h['coverage']['50']:5.2f} {h['coverage']['90']:5.2f} "
                  f"{h['spearman']:5.2f}  {int(texels.sum()):14d} {float(rm[texels].mean()):10.4f} "
                  f"{float(rs[texels].mean()):9.4f} {float(err[near].mean()):15.4f} {float(err[ok].mean()):9.4f}")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--resolution", type=int, default=32)
    ap.add_argument("--power", type=float, default=40.0)
    ap.add_argument("--clip", type=float, default=1.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--treatments", nargs="+", default=["censored", "drop", "exact"])
    ap.add_argument("--json", default=None, help="also write the rows here")
    ap.add_argument("--captures", nargs="+", default=None, help="real captures instead (see above)")
    ap.add_argument("--out", default="out/censored", help="where --captures fits go")
    a = ap.parse_args()
    if a.captures:
        return real_captures(a.captures, a.out)
    prob, obs, sat = problem(a.resolution, a.power, a.clip, a.seed)
    texels = sat.any(0)
    print(f"{a.resolution}^2 texels, power {a.power:g}: {100 * float(sat.float().mean()):.2f} % of pixels clipped "
          f"at {a.clip:g}, {int(texels.sum())} texels clipped in some view")
    rows = {}
    for tr in a.treatments:
        model = bb.models.per_texel(a.resolution, albedo="gray", specular=0.04,
                                    saturated="drop" if tr == "drop" else "censored")
        data = replace(obs, saturated=None) if tr == "exact" else obs
        t = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            post = bb.infer(model, data, seed=a.seed, progress=False)
        rows[tr] = {"seconds": time.perf_counter() - t, "noise_sigma": post.noise_sigma,
                    "converged": post.diagnostics.get("converged"), **summarise(post, prob.truth, texels)}
    print(f"{'treatment':10s} {'sigma':>6s} {'s':>5s}  " + "  ".join(
        f"{k:>30s}" for k in ("roughness clipped: mae std c50 c90", "roughness all", "albedo clipped", "albedo all")))
    for tr, r in rows.items():
        cells = [r[k] for k in ("roughness_clipped", "roughness_all", "albedo_clipped", "albedo_all")]
        print(f"{tr:10s} {r['noise_sigma']:6.4f} {r['seconds']:5.0f}  " + "  ".join(
            f"{c['mae']:8.4f} {c['std']:7.4f} {c['cov50']:5.2f} {c['cov90']:5.2f}" for c in cells))
    if a.json:
        with open(a.json, "w") as f:
            json.dump(rows, f, indent=2)


if __name__ == "__main__":
    main()
