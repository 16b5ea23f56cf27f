"""Run folders: the resolved config, package versions and git revision saved with every output."""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

from pipeline.runinfo import package_versions  # noqa: F401  (re-exported: the trainers' run info)


def git_revision(start: Path | None = None) -> str | None:
    """``git describe --always --dirty`` of the checkout holding this code, or None outside git."""
    here = Path(start or Path(__file__).resolve().parent)
    try:
        out = subprocess.run(["git", "describe", "--always", "--dirty"], cwd=here, capture_output=True,
                             text=True, timeout=5, check=True)
    except (OSError, subprocess.SubprocessError):
        return None
    return out.stdout.strip() or None


def to_jsonable(obj: Any) -> Any:
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {k: to_jsonable(v) for k, v in dataclasses.asdict(obj).items()}
    if isinstance(obj, dict):
        return {str(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_jsonable(v) for v in obj]
    if isinstance(obj, Path):
        return str(obj)
    return obj


def write_json_atomic(path: Path, data: Any) -> None:
    tmp = path.with_name(f"{path.name}.tmp-{os.getpid()}")
    tmp.write_text(json.dumps(to_jsonable(data), indent=2, sort_keys=True) + "\n")
    os.replace(tmp, path)


def save_run_info(run_dir: Path, config: Any, name: str = "config.json") -> Path:
    """Write ``config.json`` (resolved config + versions + git revision + command line) into ``run_dir``."""
    run_dir.mkdir(parents=True, exist_ok=True)
    path = run_dir / name
    write_json_atomic(path, {"config": config, "versions": package_versions(), "git": git_revision(),
                             "argv": sys.argv})
    return path
