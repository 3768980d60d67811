"""One sampling run of a capture, below the CLI: what identifies it and how it is checked against photos.

* :mod:`~bayes_brdf.runs.fingerprint` -- the model table a run samples (a preset with its overrides)
  and the run's fingerprint (:mod:`bayes_brdf.identity`), from plain values.
* :mod:`~bayes_brdf.runs.heldout` -- a fitted posterior against held-out photos: image-space std,
  the MAP's error, correlation and predictive coverage, and the noise level the fitted photos show.

The CLI (``infer``, ``fit``, ``recommend``), the demo and the experiments call down into these;
nothing here knows of argparse.
"""
from __future__ import annotations

from .fingerprint import model_table, run_fingerprint
from .heldout import Predicted, fitted_noise, heldout_report, predict

__all__ = ["model_table", "run_fingerprint", "Predicted", "predict", "fitted_noise", "heldout_report"]
