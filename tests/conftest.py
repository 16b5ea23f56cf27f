"""Shared test fixtures: paths to the real KITTI samples beside the checkout, and a small synthetic world."""

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


@pytest.fixture(scope="session")
def synth_root(tmp_path_factory) -> Path:
    """A small synthetic world (208×64, one 9-frame sequence, seed 0), written once per test session."""
    from pipeline.synth import SynthConfig, generate

    root = tmp_path_factory.getbasetemp() / "synth_w208_h64_s0_f9"
    generate(SynthConfig(seed=0, width=208, height=64, n_sequences=1, frames=9, test_frames=0), root)
    return root
