"""Shared pytest fixtures (keep this small and generic)."""
from __future__ import annotations

from pathlib import Path

import pytest

SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """``../shared/data`` beside the repository (real captures, peer data); skips the test when absent."""
    if not SHARED_DATA.is_dir():
        pytest.skip("../shared/data not found: real captures live beside the repo, see README")
    return SHARED_DATA
