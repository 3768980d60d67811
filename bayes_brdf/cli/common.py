"""Argument helpers shared by the CLI commands."""
from __future__ import annotations

import argparse
import tomllib

from .. import checks


def positive_int(s: str) -> int:
    try:
        return checks.count(int(s), "value", least=1)
    except ValueError:          # not an integer, or below 1 (an InputError is a ValueError)
        raise argparse.ArgumentTypeError(f"expected a positive integer, got '{s}'") from None


def positive_float(s: str) -> float:
    try:
        return checks.positive(float(s), "value")
    except ValueError:          # not a number, or not positive and finite
        raise argparse.ArgumentTypeError(f"expected a positive number, got '{s}'") from None


def key_value(s: str) -> tuple[str, object]:
    """``key=value`` with the value read as TOML (``0.1``, ``true``, ``"adam"``); bare words are strings."""
    if "=" not in s:
        raise argparse.ArgumentTypeError(f"expected key=value, got '{s}'")
    k, v = s.split("=", 1)
    try:
        val = tomllib.loads(f"v = {v}")["v"]
    except tomllib.TOMLDecodeError:
        val = v
    return k.strip(), val


def int_list(s: str) -> list[int]:
    try:
        return [int(x) for x in s.split(",") if x.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated integers, got '{s}'") from None


def view_list(s: str) -> list[int]:
    """``--views`` / ``--holdout``: comma-separated view indices, at least one, each from 0 up, none twice."""
    try:
        v = [int(x) for x in s.split(",") if x.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated view indices like 0,2,4, got '{s}'") from None
    if not v:
        raise argparse.ArgumentTypeError("expected at least one view index, like 0,2,4; leave the option out "
                                         "for all views")
    neg = [i for i in v if i < 0]
    if neg:
        raise argparse.ArgumentTypeError(f"view indices count from 0, got {neg[0]}")
    dup = sorted({i for i in v if v.count(i) > 1})
    if dup:
        raise argparse.ArgumentTypeError(f"view {dup[0]} is listed twice in '{s}'")
    return v


def check_views(views, n: int, option: str = "--views") -> None:
    """One line when an index in ``views`` is not one of the capture's ``n`` views."""
    from ..errors import InputError

    bad = [i for i in (views or []) if not 0 <= i < n]
    if bad:
        raise InputError(f"{option} {bad[0]}: the capture has {n} views", fix=f"use indices 0..{n - 1}")


def particles_arg(s: str) -> int:
    """``--particles``: at least 2 (one particle has no spread: its std maps would all be 0)."""
    v = positive_int(s)
    if v < 2:
        raise argparse.ArgumentTypeError(f"expected at least 2 particles (one has no spread, its std would be 0), "
                                         f"got {v}")
    return v


def float_list(s: str) -> list[float]:
    try:
        return [float(x) for x in s.split(",") if x.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers, got '{s}'") from None


def steps_arg(s: str) -> "int | str":
    """``--steps``: a positive integer or ``auto``."""
    if s.strip().lower() == "auto":
        return "auto"
    try:
        return positive_int(s)
    except argparse.ArgumentTypeError:
        raise argparse.ArgumentTypeError(f"expected a positive integer or 'auto', got '{s}'") from None
