"""Value checks: a value of the wrong kind is one line (:class:`~bayes_brdf.errors.InputError`), said one way.

Each check returns the value converted (a ``float``, an ``int``, a tuple) or raises an
:class:`~bayes_brdf.errors.InputError` naming the value (``name``: ``"light power"``,
``"frames[2].fl_x"``), with the caller's ``where`` (a file, an option) and ``fix``:

* :func:`number` -- a real number; booleans and strings are not numbers (a JSON ``true``, a TOML ``"2"``).
* :func:`finite` -- a finite number.
* :func:`positive` -- a positive finite number.
* :func:`count` -- an integer ``>= least`` (a positive integer for ``least=1``).
* :func:`fraction` -- a number in ``(0, 1]``.
* :func:`vec3` -- three finite numbers (a position).
* :func:`rgb` -- a gray number or three (R, G, B), finite and non-negative (a light's power).

Example:
    >>> vec3([0, 0, 1.5], "camera position")
    (0.0, 0.0, 1.5)
    >>> rgb(1500, "light power")
    (1500.0, 1500.0, 1500.0)
    >>> positive(-1, "sample size", where="parameters.json")
    Traceback (most recent call last):
    ...
    bayes_brdf.errors.InputError: parameters.json: sample size must be a positive number, got -1
"""
from __future__ import annotations

import math
import numbers

from .errors import InputError


def _real(value) -> float | None:
    """``value`` as a float, or ``None`` when it is no number (a bool, a string, ``None``, a list)."""
    if isinstance(value, (bool, str, bytes)):
        return None
    try:
        return float(value)
    except (TypeError, ValueError, RuntimeError):      # RuntimeError: a torch tensor of several values
        return None


def number(value, name: str, *, where=None, fix: str | None = None) -> float:
    """``value`` as a float: any real number (int, float, a NumPy or 0-d torch scalar), not a bool or a string."""
    x = _real(value)
    if x is None:
        raise InputError(f"{name} must be a number, got {value!r}", where=where, fix=fix)
    return x


def finite(value, name: str, *, where=None, fix: str | None = "give finite numbers") -> float:
    """A finite number (:func:`number`, neither NaN nor infinite)."""
    x = number(value, name, where=where, fix=fix)
    if not math.isfinite(x):
        raise InputError(f"{name} is not finite ({value!r})", where=where, fix=fix)
    return x


def positive(value, name: str, *, where=None, fix: str | None = None) -> float:
    """A positive finite number (:func:`number`, ``0 < x < inf``)."""
    x = number(value, name, where=where, fix=fix)
    if not (math.isfinite(x) and x > 0):
        raise InputError(f"{name} must be a positive number, got {value!r}", where=where, fix=fix)
    return x


def count(value, name: str, *, least: int = 0, where=None, fix: str | None = None) -> int:
    """An integer ``>= least`` (a Python or NumPy integer, not a bool or a float): a count, an index, steps."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < least:
        what = "a positive integer" if least == 1 else f"an integer >= {least}"
        raise InputError(f"{name} must be {what}, got {value!r}", where=where, fix=fix)
    return int(value)


def fraction(value, name: str, *, where=None, fix: str | None = None) -> float:
    """A number in ``(0, 1]``: a share of the pixels, of the views."""
    x = _real(value)
    if x is None or not 0 < x <= 1:
        raise InputError(f"{name} must be in (0, 1], got {value!r}", where=where, fix=fix)
    return x


def vec3(value, name: str, *, where=None, fix: str | None = None) -> tuple[float, float, float]:
    """Three finite numbers ``(x, y, z)`` from any sequence of numbers (a list, a tuple, an array)."""
    try:
        t = tuple(_real(x) for x in value)
    except TypeError:
        t = ()
    if len(t) != 3 or None in t:
        raise InputError(f"{name} must be three numbers (x, y, z), got {value!r}", where=where, fix=fix)
    if not all(math.isfinite(x) for x in t):
        raise InputError(f"{name} is not finite: {value!r}", where=where, fix=fix)
    return t


def rgb(value, name: str, *, where=None, fix: str | None = None) -> tuple[float, float, float]:
    """An RGB triple, finite and non-negative, from one number (gray) or a sequence of one or three."""
    seq = [value] if _real(value) is not None else value
    try:
        t = tuple(_real(x) for x in seq)
    except TypeError:
        t = ()
    if len(t) not in (1, 3) or None in t:
        raise InputError(f"{name} must be one number or three (R, G, B), got {value!r}", where=where, fix=fix)
    t = t * 3 if len(t) == 1 else t
    if not all(math.isfinite(x) for x in t):
        raise InputError(f"{name} is not finite: {value!r}", where=where, fix=fix)
    if min(t) < 0:
        raise InputError(f"{name} must be non-negative, got {value!r}", where=where, fix=fix)
    return t
