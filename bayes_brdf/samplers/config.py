"""Sampler hyper-parameters as dataclass fields: built from a table with type checks, one-line errors.

:class:`Configurable` is the mixin every built-in sampler's dataclass derives from (next to the
:class:`~bayes_brdf.samplers.base.Sampler` protocol): :meth:`~Configurable.from_params` turns a preset's
``[params]`` table into the dataclass (an unknown key or a value of the wrong type is an
:class:`~bayes_brdf.errors.InputError`), :meth:`~Configurable.params` gives the table back (it enters a
checkpoint's signature) and :meth:`~Configurable.validate` checks the values. The configuration is
captured once; a run's own numbers (its horizon, its groups) go into the state at ``init``.
"""
from __future__ import annotations

import dataclasses
import math

from ..errors import InputError


class Configurable:
    """Hyper-parameters as dataclass fields: :meth:`from_params`, :meth:`params`, :meth:`validate`."""

    name = "sampler"

    @classmethod
    def from_params(cls, params: dict | None = None):
        """Build from a ``{hyper-parameter: value}`` table; unknown keys and bad values are one-line errors.

        Example:
            >>> from bayes_brdf.samplers import SGLD
            >>> SGLD.from_params({"step_size": 1}).step_size
            1.0
        """
        params = dict(params or {})
        fields = {f.name: f for f in dataclasses.fields(cls)}
        extra = set(params) - set(fields)
        if extra:
            raise InputError(f"unknown {cls.name} parameter(s) {sorted(extra)}", fix=f"allowed: {sorted(fields)}")
        kw = {}
        for k, v in params.items():
            kw[k] = _coerce(cls.name, k, v, fields[k])
        s = cls(**kw)
        s.validate()
        return s

    def params(self) -> dict:
        """``{hyper-parameter: value}`` (part of a checkpoint's signature)."""
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}

    def validate(self):
        """Check hyper-parameter values (one-line :class:`InputError`)."""

    def _positive(self, *names):
        for k in names:
            v = getattr(self, k)
            if not (isinstance(v, (int, float)) and v > 0 and math.isfinite(v)):
                raise InputError(f"{self.name} parameter {k} must be a positive number, got {v!r}")

    def _unit(self, *names):
        """Parameters that must lie strictly inside (0, 1) (decay rates)."""
        for k in names:
            v = getattr(self, k)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0 < v < 1:
                raise InputError(f"{self.name} parameter {k} must be in (0, 1), got {v!r}")

    def _choice(self, name, options):
        v = getattr(self, name)
        if v not in options:
            raise InputError(f"{self.name} parameter {name} must be one of {list(options)}, got {v!r}")


def _coerce(sampler: str, key: str, value, field):
    default = field.default if field.default is not dataclasses.MISSING else None
    if isinstance(default, bool):
        if not isinstance(value, bool):
            raise InputError(f"{sampler} parameter {key} must be true or false, got {value!r}")
        return value
    if isinstance(default, float) and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    if isinstance(default, (int, float)) and not isinstance(default, bool):
        if isinstance(value, bool) or not isinstance(value, (int, float)) or \
                (isinstance(default, int) and not isinstance(default, bool) and not isinstance(value, int)):
            if not (isinstance(field.type, str) and "str" in field.type and isinstance(value, str)):
                what = "an integer" if isinstance(default, int) and isinstance(value, float) else "a number"
                raise InputError(f"{sampler} parameter {key} must be {what}, got {value!r}")
    if isinstance(default, str) and not isinstance(value, str):
        if not (isinstance(field.type, str) and ("float" in field.type or "int" in field.type)
                and isinstance(value, (int, float)) and not isinstance(value, bool)):
            raise InputError(f"{sampler} parameter {key} must be a string, got {value!r}")
    return value
