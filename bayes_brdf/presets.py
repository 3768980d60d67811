"""Preset files (TOML) for models and samplers.

Presets live in the repository's top-level ``models/`` and ``samplers/``
folders; a wheel carries them as ``bayes_brdf/presets/<kind>/``. A name
(``"spos"``) resolves to ``<kind>/spos.toml``; a path to an existing file is
used as it is (a user's own preset).
"""
from __future__ import annotations

import tomllib
from pathlib import Path

from .errors import InputError

KINDS = ("models", "samplers")
_PKG = Path(__file__).resolve().parent


def preset_dirs(kind: str) -> list[Path]:
    """Folders searched for ``kind`` presets: the installed copy, then the source tree's."""
    if kind not in KINDS:
        raise InputError(f"unknown preset kind '{kind}'", fix=f"use one of {', '.join(KINDS)}")
    return [d for d in (_PKG / "presets" / kind, _PKG.parent / kind) if d.is_dir()]


def list_presets(kind: str) -> list[str]:
    """Names of the built-in ``kind`` presets.

    Example:
        >>> isinstance(list_presets("samplers"), list)
        True
    """
    return sorted({p.stem for d in preset_dirs(kind) for p in d.glob("*.toml")})


def load_preset(kind: str, name_or_path) -> dict:
    """The TOML table of a preset name or file path; a one-line :class:`InputError` when missing or malformed."""
    p = Path(name_or_path)
    if not p.is_file():
        hits = [d / f"{name_or_path}.toml" for d in preset_dirs(kind) if (d / f"{name_or_path}.toml").is_file()]
        if not hits:
            known = ", ".join(list_presets(kind)) or "none yet"
            raise InputError(f"no {kind[:-1]} preset '{name_or_path}'", fix=f"use a TOML file path or one of: {known}")
        p = hits[0]
    try:
        return tomllib.loads(p.read_text())
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as e:
        raise InputError(f"unreadable preset ({e})", where=p) from None
