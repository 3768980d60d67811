"""Reading JSON metadata files with one-line errors."""
from __future__ import annotations

import json
from pathlib import Path

from ..errors import InputError


def read_json_object(path: Path, fix: str = "fix the JSON syntax") -> dict:
    """The top-level JSON object of ``path``; an :class:`InputError` naming the file otherwise."""
    try:
        d = json.loads(Path(path).read_text())
    except json.JSONDecodeError as e:
        raise InputError(f"malformed JSON at line {e.lineno} column {e.colno} ({e.msg})", where=path, fix=fix) from None
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(f"cannot read file ({e})", where=path) from None
    if not isinstance(d, dict):
        raise InputError("expected a JSON object at the top level", where=path)
    return d
