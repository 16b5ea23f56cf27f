"""Run folders: the resolved config, package versions and git revision saved with every output."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

from core import jsonio
from core.runinfo import git_revision, package_versions


def write_json_atomic(path: Path, data: Any) -> None:
    """A run folder's JSON (dataclasses welcome, NaN allowed: a diverged run's metrics are still written)."""
    jsonio.write_json_atomic(path, data, allow_nan=True, indent=2)


def save_run_info(run_dir: Path, config: Any, name: str = "config.json") -> Path:
    """Write ``config.json`` (resolved config + versions + git revision + command line) into ``run_dir``."""
    run_dir.mkdir(parents=True, exist_ok=True)
    path = run_dir / name
    write_json_atomic(path, {"config": config, "versions": package_versions(), "git": git_revision(describe=True),
                             "argv": sys.argv})
    return path
