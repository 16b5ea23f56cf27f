"""``kill -9`` of a multi-worker stage-one parent leaves no process of the run alive 10 s later (the
workers used to go on writing blocks and then hang), and rerunning the same command completes the cache."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from _faults import REPO

from pipeline.cache import verify
from pipeline.cache.manifest import find_tmp

pytestmark = pytest.mark.slow


def _children() -> dict[int, list[int]]:
    """ppid → pids of every process on this machine (from /proc)."""
    out: dict[int, list[int]] = {}
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            stat = Path(f"/proc/{entry}/stat").read_text()
        except OSError:
            continue
        ppid = int(stat.rsplit(")", 1)[1].split()[1])
        out.setdefault(ppid, []).append(int(entry))
    return out


def _descendants(pid: int) -> set[int]:
    tree, found, todo = _children(), set(), [pid]
    while todo:
        for child in tree.get(todo.pop(), []):
            if child not in found:
                found.add(child)
                todo.append(child)
    return found


def _alive(pid: int) -> bool:
    """Running (not a zombie waiting for its reaper)."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


def _stage_one(synth_root: Path, out: Path) -> list[str]:
    return [sys.executable, "-m", "pipeline", "--root", str(synth_root), "--depth", "net", "--random_init", "true",
            "--pose", "gt", "--size", "128x48", "--block_size", "1", "--workers", "2", "--device", "cpu",
            "--progress", "false", "--out", str(out)]


def test_killed_parent_leaves_no_worker_and_the_rerun_completes(synth_root: Path, tmp_path: Path) -> None:
    if not Path("/proc/self/stat").exists():
        pytest.skip("needs /proc to list the run's processes")
    env = {**os.environ, "PYTHONPATH": str(REPO), "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}
    out = tmp_path / "cache"
    parent = subprocess.Popen(_stage_one(synth_root, out), cwd=REPO, env=env, stdout=subprocess.DEVNULL,
                              stderr=subprocess.PIPE, start_new_session=True)
    family: set[int] = set()
    try:
        deadline = time.monotonic() + 240
        while True:  # kill once the workers have finished a block but not the run
            assert parent.poll() is None, f"stage one ended before the kill: {parent.stderr.read().decode()[-2000:]}"
            assert time.monotonic() < deadline, "no block written within 240 s"
            done = list(out.glob("*/*/blocks/*/*/zarr.json"))
            if done:
                family = _descendants(parent.pid)
                break
            time.sleep(0.05)
        assert not list(out.glob("*/*/manifest.json")), "the run finished before the kill"
        assert len(family) >= 2, family  # the two workers (and multiprocessing's resource tracker)
        parent.send_signal(signal.SIGKILL)
        parent.wait(timeout=30)
        killed_at = time.monotonic()
        while any(_alive(p) for p in family) and time.monotonic() < killed_at + 10:
            time.sleep(0.1)
        survivors = [p for p in family if _alive(p)]
        assert not survivors, f"processes of the killed run still alive 10 s later: {survivors}"
    finally:
        if parent.poll() is None:
            parent.kill()
            parent.wait(timeout=30)
        parent.stderr.close()
        for p in family:  # never leave a stray worker behind, even when the test fails
            try:
                os.kill(p, signal.SIGKILL)
            except (ProcessLookupError, PermissionError):
                pass

    rerun = subprocess.run(_stage_one(synth_root, out), cwd=REPO, env=env, capture_output=True, text=True, timeout=600)
    assert rerun.returncode == 0, rerun.stderr[-2000:]
    (root,) = [m.parent for m in out.glob("*/*/manifest.json")]
    report = verify(root)
    assert report.ok and report.pairs_checked == 8, report.summary()
    assert not find_tmp(root)  # the temp block of a killed worker was removed by the rerun
