"""Capture guidance: which views to take next (Sec. 3.4).

* :func:`score_views` -- mutual information of each candidate view with the posterior (Eqs. 13-21),
  batched over candidates, per-pixel KDE entropies by a native kernel.
* :func:`recommend` -- greedy / batched top-K picks with hypersphere exclusion, and the baselines
  (low-discrepancy directions, max image-space std, random).
* :func:`guided_acquisition` -- Algorithm 1 with a ``capture(views)`` callback
  (:class:`SyntheticCapture`, :class:`PoolCapture`), per-round files and resume.
"""
from .acquisition import AcquisitionResult, Evaluation, PoolCapture, SyntheticCapture, guided_acquisition
from .entropy import kde_entropy, noise_entropy
from .recommend import Recommendation, configuration, distances, low_discrepancy, recommend, top_k
from .scores import CandidateScores, score_views

__all__ = ["score_views", "CandidateScores", "recommend", "Recommendation", "top_k", "low_discrepancy",
           "configuration", "distances", "guided_acquisition", "AcquisitionResult", "Evaluation",
           "SyntheticCapture", "PoolCapture", "kde_entropy", "noise_entropy"]
