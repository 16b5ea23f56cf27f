"""Fault-injection tests (``pytest -m faults``): every test here is marked ``faults``; the shared helpers of
``tests/`` and the helpers of the stage folders' tests (``test_preprocess.tree_bytes``,
``test_eval_cli.save_tiny_checkpoint``) are importable from this folder too."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

TESTS = Path(__file__).resolve().parents[1]
for folder in (TESTS, TESTS / "pipeline", TESTS / "evaluation"):
    if str(folder) not in sys.path:
        sys.path.insert(0, str(folder))


def pytest_collection_modifyitems(config, items) -> None:
    here = Path(__file__).resolve().parent
    for item in items:
        if Path(str(item.fspath)).resolve().parent == here:
            item.add_marker(pytest.mark.faults)
