"""Shared checks of the IO tests."""
import pytest

from bayes_brdf.errors import InputError


def raises_one_line(fn, *names) -> str:
    """Call ``fn``; it must raise a one-line InputError mentioning every string in ``names``, re-raised
    cleanly (no chained PIL / json / numpy traceback shown). Returns the message."""
    with pytest.raises(InputError) as ei:
        fn()
    msg = str(ei.value)
    assert "\n" not in msg
    for n in names:
        assert n in msg, f"{n!r} not in {msg!r}"
    assert ei.value.__cause__ is None and (ei.value.__context__ is None or ei.value.__suppress_context__)
    return msg
