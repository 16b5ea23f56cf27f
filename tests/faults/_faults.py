"""Helpers of the fault-injection tests: a checkpoint that would run code, and running a CLI as a user does."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


class _TouchOnLoad:
    """Unpickling this object would call ``open(marker, "w")``: a stand-in for any shell command."""

    def __init__(self, marker: Path) -> None:
        self.marker = str(marker)

    def __reduce__(self):
        return (open, (self.marker, "w"))


def write_malicious_checkpoint(path: Path, marker: Path, kind: str = "flow") -> Path:
    """A ``torch.save``d file laid out like a monoflow checkpoint whose unpickling would create ``marker``."""
    import torch

    path.parent.mkdir(parents=True, exist_ok=True)
    payload = {"checkpoint_version": 1, "kind": kind, "model": _TouchOnLoad(marker), "step": 1,
               "state_dict": _TouchOnLoad(marker)}
    torch.save(payload, path)
    assert not marker.exists()
    return path


def run_cli(module: str, args: list[str], timeout: float = 240) -> subprocess.CompletedProcess:
    """``python -m <module> args`` from the repository, one thread per process, with a time limit."""
    env = dict(os.environ)
    env["PYTHONPATH"] = str(REPO) + os.pathsep + env.get("PYTHONPATH", "")
    env.update(OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1")
    return subprocess.run([sys.executable, "-m", module, *map(str, args)], cwd=REPO, env=env,
                          capture_output=True, text=True, timeout=timeout)


def assert_one_error_line(proc: subprocess.CompletedProcess, names: str) -> str:
    """Exit code 2 and exactly one stderr line ``error: <names>: ...`` (beside ``WARNING:`` lines about the
    configuration, which are not errors); returns that line."""
    lines = [x for x in proc.stderr.splitlines() if x.strip() and not x.startswith("WARNING: ")]
    assert proc.returncode == 2, (proc.returncode, proc.stderr[-2000:])
    assert len(lines) == 1, proc.stderr[-2000:]
    assert lines[0].startswith(f"error: {names}"), lines[0]
    return lines[0]
