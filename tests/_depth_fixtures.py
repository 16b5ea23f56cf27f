"""Shared set-up of the depth/pose trainer tests: one torch thread, and small anti-aliased synthetic worlds."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch


@pytest.fixture(autouse=True)
def one_thread():
    """Tests compare numbers across runs and share two cores: one torch thread each."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


def depth_world(root: Path, frames: int, test_frames: int, seed: int = 0, parked_cars: int = 4) -> Path:
    """A 128×64 anti-aliased world: training sequence 00 of ``frames`` frames, test sequence 01 of ``test_frames``."""
    from pipeline.synth import SynthConfig, generate

    generate(SynthConfig(seed=seed, width=128, height=64, n_sequences=1, frames=frames, test_frames=test_frames,
                         supersample=2, parked_cars=parked_cars, moving_cars=1), root)
    return root
