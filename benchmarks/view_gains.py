"""Per-view brightness of a fit's photos against its MAP: is a held-out view's error an exposure offset?

Usage:
    python benchmarks/view_gains.py FIT_FOLDER CAPTURE --resolution 128

For every view of ``CAPTURE`` (fitted and held out, as ``FIT_FOLDER/summary.json`` says), over the pixels
on the sample that are lit (MAP render above 0.03, channel mean) and not clipped: the median and
quartiles of ``photo / MAP render`` (sums over channels) and the mean absolute error. A view whose median
is far from the fitted views' is darker or brighter as a whole (a flash or exposure other than the stated
one), which no noise level that grows with the radiance predicts (docs/calibration.md). Numbers only.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import torch

from bayes_brdf.io import load_capture
from bayes_brdf.posterior import Posterior
from bayes_brdf.runs.heldout import predict


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("fit", type=Path, help="a `bayes-brdf fit` output folder")
    ap.add_argument("capture", type=Path)
    ap.add_argument("--resolution", type=int, required=True, help="the fit's resolution")
    a = ap.parse_args()
    post = Posterior.load(a.fit / "posterior.safetensors")
    fitted = set(json.loads((a.fit / "summary.json").read_text())["fit_views"])
    obs = load_capture(a.capture, resolution=a.resolution)
    p = predict(post, obs.views, obs.images, obs.surface)
    ok = p.inside.clone()
    if obs.saturated is not None:
        ok &= ~obs.saturated.to(ok.device)
    print(f"{'view':>4s} {'':5s} {'median':>7s} {'q25':>6s} {'q75':>6s} {'mean|err|':>9s}")
    for v in range(len(obs.views)):
        m = ok[v] & (p.map_render[v].mean(-1) > 0.03)
        ratio = p.photos[v][m].sum(-1) / p.map_render[v][m].sum(-1)
        q = torch.quantile(ratio.double(), torch.tensor([0.25, 0.5, 0.75], dtype=torch.float64))
        err = float((p.photos[v][m] - p.map_render[v][m]).abs().mean())
        print(f"{v:4d} {'fit' if v in fitted else 'held':5s} {q[1]:7.3f} {q[0]:6.3f} {q[2]:6.3f} {err:9.4f}")


if __name__ == "__main__":
    main()
