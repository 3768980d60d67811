"""User-facing errors.

Anything a user can cause (a malformed capture, a bad option, a shape that does
not fit) raises :class:`InputError` with ONE line saying what is wrong, where
(file or option), and how to fix it. The CLI prints that line and exits with
code 2; Python callers can catch it like any ``ValueError``.
"""
from __future__ import annotations

from pathlib import Path


class InputError(ValueError):
    """Bad input: a one-line message naming what, where and how to fix.

    Example:
        >>> raise InputError("image is not square", where="cap/00.png", fix="crop it")
        Traceback (most recent call last):
        ...
        bayes_brdf.errors.InputError: cap/00.png: image is not square; crop it
    """

    def __init__(self, problem: str, where: str | Path | None = None, fix: str | None = None):
        msg = problem if where is None else f"{where}: {problem}"
        if fix:
            msg = f"{msg}; {fix}"
        super().__init__(" ".join(msg.split()))  # one line, always
        self.problem, self.where, self.fix = problem, where, fix


class ConvergenceWarning(UserWarning):
    """A sampler run whose convergence checks failed (:mod:`bayes_brdf.samplers.diagnostics`): the
    posterior may not be trustworthy yet; the message names the checks and the remedy."""
