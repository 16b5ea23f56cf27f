"""Stale temporary entries: a process id alone is not proof that the entry's writer is alive."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from core.processes import START_MARGIN_S, pid_alive, process_start_time, process_state, writer_gone

needs_proc = pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs /proc for start times")


def _sleeper() -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])


def test_a_finished_process_is_gone(tmp_path: Path) -> None:
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait(timeout=60)
    entry = tmp_path / f"x.tmp-{proc.pid}"
    entry.mkdir()
    assert not pid_alive(proc.pid) and writer_gone(proc.pid, entry)


@needs_proc
def test_a_killed_writer_not_yet_reaped_is_gone(tmp_path: Path) -> None:
    """A zombie answers signal 0 but writes nothing (and may never be reaped where init does not)."""
    proc = _sleeper()
    try:
        entry = tmp_path / f"x.tmp-{proc.pid}"
        entry.mkdir()
        assert pid_alive(proc.pid) and not writer_gone(proc.pid, entry)
        proc.kill()  # not waited for: it stays a zombie child of this process
        deadline = time.monotonic() + 30
        while process_state(proc.pid) != "Z":
            assert time.monotonic() < deadline, "the killed child never became a zombie"
            time.sleep(0.01)
        assert not pid_alive(proc.pid) and writer_gone(proc.pid, entry)
    finally:
        proc.kill()
        proc.wait(timeout=60)


@needs_proc
def test_a_live_writer_is_kept_and_a_reused_id_is_not(tmp_path: Path) -> None:
    proc = _sleeper()
    try:
        started = process_start_time(proc.pid)
        assert started is not None and abs(started - time.time()) < 60
        entry = tmp_path / f"x.tmp-{proc.pid}"
        entry.mkdir()  # created after its "writer" started: that process may be writing it
        assert not writer_gone(proc.pid, entry)
        old = started - 3600  # last changed an hour before the process with this id started: a reused id
        os.utime(entry, (old, old))
        assert writer_gone(proc.pid, entry)
        just = started - START_MARGIN_S / 2  # within the margin: in doubt, kept
        os.utime(entry, (just, just))
        assert not writer_gone(proc.pid, entry)
    finally:
        proc.kill()
        proc.wait(timeout=60)


@needs_proc
def test_the_cache_writer_removes_a_block_temp_whose_id_was_reused(tmp_path: Path) -> None:
    from core.jsonio import host_name
    from pipeline.cache.manifest import remove_stale_tmp

    (tmp_path / "blocks" / "00").mkdir(parents=True)
    proc = _sleeper()
    try:
        reused = tmp_path / "blocks" / "00" / f"00000.tmp-{proc.pid}-{host_name()}"
        live = tmp_path / "blocks" / "00" / f"00001.tmp-{proc.pid}-{host_name()}"
        reused.mkdir()
        live.mkdir()
        old = time.time() - 3600
        os.utime(reused, (old, old))
        assert remove_stale_tmp(tmp_path) == [reused]
        assert not reused.exists() and live.exists()
    finally:
        proc.kill()
        proc.wait(timeout=60)


@needs_proc
def test_all_hosts_clears_every_temp_but_this_process_own(tmp_path: Path) -> None:
    from core.jsonio import host_name
    from pipeline.cache.manifest import remove_stale_tmp

    seq = tmp_path / "blocks" / "00"
    seq.mkdir(parents=True)
    proc = _sleeper()
    try:
        other_host = seq / "00000.tmp-1-otherhost"
        live_other = seq / f"00001.tmp-{proc.pid}-{host_name()}"
        own = seq / f"00002.tmp-{os.getpid()}-{host_name()}"
        for p in (other_host, live_other, own):
            p.mkdir()
        assert remove_stale_tmp(tmp_path) == []  # another host's and two live writers' entries stay
        assert remove_stale_tmp(tmp_path, all_hosts=True) == [other_host, live_other]
        assert own.exists()
    finally:
        proc.kill()
        proc.wait(timeout=60)
