"""Whether the process named in a temporary entry (``<name>.tmp-<pid>…``) can still be writing it.

Every writer of this project (cache blocks, JSON files, checkpoints, synthetic worlds) first writes into a
temporary name that carries its process id and renames it when complete, so an interrupted run leaves
only such entries behind, and the next run removes the ones whose writer is gone. A process id alone
is not proof of life: ids are reused (Linux's default ``pid_max`` is 32768, so a busy machine wraps
around within minutes), and a stranger holding a dead writer's id would keep its debris forever; nor is a
killed writer that lingers as an unreaped zombie alive. Where ``/proc`` tells when a process started, a
process that started after the entry was last modified cannot be its writer (a writer creates its entry
after it starts).
"""

from __future__ import annotations

import os
import time
from pathlib import Path

# A process counts as started after an entry only when it started this many seconds later than the
# entry's last change: the start time's resolution is one clock tick (10 ms) and the boot time is derived
# from two clocks read one after the other.
START_MARGIN_S = 0.5


def pid_alive(pid: int) -> bool:
    """Whether a running process with this id exists on this machine (permission denied counts as alive).

    A zombie — killed, but not yet reaped by its parent — does not count: it can write nothing, and where
    the process that adopts orphans does not reap them (some container init processes) a killed
    worker stays a zombie for good, so its id alone would keep its temporary entry forever.
    """
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # PermissionError included: someone's process exists
        return True
    return process_state(pid) not in ("Z", "X")


def _stat_fields(pid: int) -> list[str] | None:
    """The fields of ``/proc/<pid>/stat`` after the command name (field 3, the state, first); None where
    that cannot be read (no such process, no ``/proc``)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
        return stat[stat.rindex(")") + 2:].split()
    except (OSError, ValueError):
        return None


def process_state(pid: int) -> str | None:
    """The one-letter state of process ``pid`` (``R``, ``S``, ``Z`` for a zombie, …); None where unknown."""
    fields = _stat_fields(pid)
    return fields[0] if fields else None


def process_start_time(pid: int) -> float | None:
    """When process ``pid`` started, seconds since the epoch, from ``/proc/<pid>/stat``; None where that
    cannot be read (no such process, no ``/proc``)."""
    fields = _stat_fields(pid)
    try:
        ticks = int(fields[19])  # field 22: start time in clock ticks since boot
        boot = time.time() - time.clock_gettime(time.CLOCK_BOOTTIME)
        return boot + ticks / os.sysconf("SC_CLK_TCK")
    except (TypeError, ValueError, IndexError, AttributeError, OSError):
        return None


def writer_gone(pid: int, entry: str | os.PathLike[str]) -> bool:
    """True when no running process can be the writer of temporary ``entry`` named with ``pid``: no process
    has that id, or the one that has it (this process included) started more than :data:`START_MARGIN_S`
    after ``entry`` was last modified, i.e. it reuses a dead writer's id. False when in doubt."""
    if not pid_alive(pid):
        return True
    started = process_start_time(pid)
    try:
        changed = os.lstat(entry).st_mtime
    except OSError:
        return False  # already gone or unreadable: nothing to decide
    return started is not None and started > changed + START_MARGIN_S


__all__ = ["pid_alive", "process_state", "process_start_time", "writer_gone", "START_MARGIN_S"]
