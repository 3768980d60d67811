"""Safe outputs: folders checked before any work, files written atomically, a folder owned by one run.

* :func:`check_folder` / :func:`check_file_target` -- before any compute: the place can be
  created and written, and has room for what will be written (one :class:`InputError` otherwise).
* :func:`atomic_path` -- every result file is written to a temporary name in its folder and
  renamed over the target when complete (a crash never leaves half a file), with mode 0644
  (``0666`` less the umask), whatever the writing library chose.
* :func:`claim` -- an output folder records the fingerprint of the run that owns it
  (``run.json``, :mod:`bayes_brdf.identity`); a command on other data, views, model or
  sampler settings refuses to touch it unless told to start over.

Example:
    >>> import tempfile, pathlib
    >>> d = pathlib.Path(tempfile.mkdtemp())
    >>> write_json(d / "a.json", {"x": 1}).read_text()
    '{\\n  "x": 1\\n}\\n'
    >>> oct((d / "a.json").stat().st_mode & 0o777) == oct(file_mode())
    True
"""
from __future__ import annotations

import contextlib
import json
import os
import shutil
import uuid
from pathlib import Path

from ..errors import InputError

RUN_FILE = "run.json"
_MODE: list[int] = []


def file_mode() -> int:
    """The mode new result files get: ``0o666`` less the process umask (``0o644`` with the usual 022)."""
    if not _MODE:
        um = os.umask(0)
        os.umask(um)
        _MODE.append(0o666 & ~um)
    return _MODE[0]


@contextlib.contextmanager
def atomic_path(path):
    """Yield a temporary path next to ``path`` (same suffix); on success rename it onto ``path`` (mode 0644).

    For libraries that write by file name (safetensors, matplotlib, OpenEXR). On an exception the
    temporary file is removed and ``path`` is left as it was.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.stem}.{uuid.uuid4().hex[:8]}.tmp{path.suffix}")
    try:
        yield tmp
        os.chmod(tmp, file_mode())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise


def write_bytes(path, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically (mode 0644)."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return Path(path)


def write_text(path, text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically (mode 0644)."""
    return write_bytes(path, text.encode("utf-8"))


def write_json(path, obj, **kw) -> Path:
    """``json.dumps(obj, indent=2)`` to ``path`` atomically (mode 0644); non-JSON values via ``str``."""
    return write_text(path, json.dumps(obj, indent=2, default=str, **kw) + "\n")


def _oserror(e: OSError) -> str:
    return e.strerror or type(e).__name__


def check_folder(path, *, need_bytes: int = 0, option: str = "--out", fix: str | None = None) -> Path:
    """Create ``path`` (a folder) if needed and check it can be written and has ``need_bytes`` free.

    Raises one :class:`InputError` naming the folder and the option otherwise. Nothing is left
    behind but the (empty) folder.
    """
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise InputError(f"{option} {p} is a file, not a folder", fix=f"give a folder for {option}")
    try:
        p.mkdir(parents=True, exist_ok=True)
        probe = p / f".write-test-{uuid.uuid4().hex[:8]}"
        probe.write_bytes(b"x")
        probe.unlink()
    except OSError as e:
        raise InputError(f"cannot write to {option} {p} ({_oserror(e)})",
                         fix=fix or f"choose a writable folder for {option}") from None
    if need_bytes:
        free = shutil.disk_usage(p).free
        if free < need_bytes:
            raise InputError(f"{option} {p} has {free / 1e6:.0f} MB free, the results need about "
                             f"{need_bytes / 1e6:.0f} MB", fix="free some space or choose another folder")
    return p


def check_file_target(path, *, option: str) -> Path:
    """Check that the file ``path`` can be written (its folder creatable and writable; not a folder)."""
    p = Path(path)
    if p.is_dir():
        raise InputError(f"{option} {p} is a folder", fix=f"give a file name for {option}")
    check_folder(p.parent if str(p.parent) else ".", option=f"the folder of {option}",
                 fix=f"give {option} a file in a writable folder")
    return p


def clear(out: Path, names) -> None:
    """Remove the entries ``names`` (files or folders a command writes) from ``out``."""
    for n in names:
        q = Path(out) / n
        if q.is_dir() and not q.is_symlink():
            shutil.rmtree(q)
        elif q.exists() or q.is_symlink():
            q.unlink()


def claim(out, fingerprint: dict, label: str, *, overwrite: bool = False, owned=()) -> str:
    """Make ``out`` the folder of the run ``fingerprint`` (described by ``label``); returns ``"new"``,
    ``"same"`` (the same run: resume) or ``"overwritten"``.

    A folder holding another run's ``run.json`` (or results but no ``run.json``) is refused with one
    line unless ``overwrite``; ``overwrite`` removes the ``owned`` entries (and the run file) first,
    so the run starts over.
    """
    from ..identity import differences

    out = Path(out)
    rf = out / RUN_FILE
    old = None
    if rf.is_file():
        try:
            old = json.loads(rf.read_text())
        except (OSError, ValueError):
            old = {}
    stale = [n for n in owned if (out / n).exists()]
    if old is None and not stale:
        status = "new"
    elif old is not None and old.get("fingerprint") == fingerprint and not overwrite:
        return "same"
    elif not overwrite:
        if old is None or "fingerprint" not in old:
            raise InputError(f"{out} holds results of another run ({', '.join(stale[:3])})",
                             fix="use another --out, or --overwrite to start over there")
        diff = differences(old["fingerprint"], fingerprint)
        shown = ", ".join(diff[:4]) + (", ..." if len(diff) > 4 else "")
        raise InputError(f"{out} holds a run of {old.get('label', 'another capture')}, not this one "
                         f"(it differs in {shown})", fix="use another --out, or --overwrite")
    else:
        clear(out, list(owned) + [RUN_FILE])
        status = "overwritten"
    write_json(rf, {"label": label, "fingerprint": fingerprint})
    return status
