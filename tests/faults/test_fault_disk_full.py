"""A full disk (simulated by a per-file size cap, RLIMIT_FSIZE: writes past it fail with EFBIG as they
would with ENOSPC) ends stage one and training with one line naming the file, and leaves no partial
block or checkpoint behind; stage one then resumes to a complete cache once there is room."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from _faults import REPO
from _trainer_fixtures import config_flags, tiny_cache, tiny_config  # noqa: F401

from pipeline.cache import verify
from pipeline.cache.manifest import find_tmp

resource = pytest.importorskip("resource")
CAP_BYTES = 12_000  # bigger than the JSON files, smaller than a block's RGB shard or a checkpoint


def _capped(cap: int):
    def setup() -> None:
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write past the cap then fails with EFBIG
        resource.setrlimit(resource.RLIMIT_FSIZE, (cap, cap))
    return setup


def _run(module: str, args: list[str], cap: int | None) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(REPO), "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1",
           "PYTHONDONTWRITEBYTECODE": "1"}
    return subprocess.run([sys.executable, "-m", module, *map(str, args)], cwd=REPO, env=env, capture_output=True,
                          text=True, timeout=300, preexec_fn=_capped(cap) if cap else None)


def _one_line(proc: subprocess.CompletedProcess) -> str:
    lines = [x for x in proc.stderr.splitlines() if x.strip()]
    assert proc.returncode == 2 and len(lines) == 1, (proc.returncode, proc.stderr[-3000:])
    assert lines[0].startswith("error: ") and "File too large" in lines[0], lines[0]
    return lines[0]


@pytest.mark.parametrize("workers", [1, pytest.param(2, marks=pytest.mark.slow)])
def test_stage_one_disk_full_then_resume(synth_root: Path, tmp_path: Path, workers: int) -> None:
    out = tmp_path / "cache"
    args = ["--root", synth_root, "--depth", "gt", "--pose", "gt", "--block_size", "4", "--workers", workers,
            "--out", out, "--progress", "false"]
    line = _one_line(_run("pipeline", args, CAP_BYTES))
    assert "/blocks/00/" in line  # names the block it could not write
    (root,) = [p.parent for p in out.glob("*/*/cache.json")]
    assert not find_tmp(root) and not (root / "manifest.json").exists()  # nothing half-written stays
    done = _run("pipeline", args, None)
    assert done.returncode == 0, done.stderr[-2000:]
    report = verify(root)
    assert report.ok and report.pairs_checked == 8, report.summary()


def test_training_disk_full_keeps_no_partial_checkpoint(tiny_cache: Path, tmp_path: Path) -> None:  # noqa: F811
    run = tmp_path / "run"
    proc = _run("training", config_flags(tiny_config(tiny_cache, run, steps=2, ckpt_every=1)), CAP_BYTES)
    line = _one_line(proc)
    assert "latest.pt" in line
    assert not (run / "latest.pt").exists() and not list(run.glob("latest.pt.tmp-*"))
