"""Shared test fixtures: paths to the real KITTI samples beside the checkout."""

from __future__ import annotations

from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / "shared" / "data"


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """The real KITTI samples (../shared/data); tests that need them skip, saying so, when absent."""
    if not SHARED_DATA.is_dir():
        pytest.skip(f"real KITTI samples not found at {SHARED_DATA}")
    return SHARED_DATA
