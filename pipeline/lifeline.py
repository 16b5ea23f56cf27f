"""Worker processes that die with their parent.

A stage-one worker is a spawned process; if its parent is killed (``kill -9``, OOM killer) nothing tells
it, so before this it went on writing blocks and then hung. :func:`die_with_parent` ties a worker's life
to its parent's: on Linux the kernel sends it SIGKILL when the parent dies (``PR_SET_PDEATHSIG``), and on
every system a daemon thread checks the parent's pid twice a second and kills the worker once the parent
is gone. A block the worker was writing stays a temp directory, which the next writer removes.
"""

from __future__ import annotations

import os
import signal
import sys
import threading

POLL_S = 0.5
_PR_SET_PDEATHSIG = 1


def _kernel_lifeline() -> None:
    """Ask Linux to SIGKILL this process when its parent exits (best effort: silently absent elsewhere)."""
    if not sys.platform.startswith("linux"):
        return
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(_PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0)
    except (OSError, AttributeError):
        pass


def _die() -> None:
    os.kill(os.getpid(), signal.SIGKILL)


def _watch(parent_pid: int, poll_s: float) -> None:
    stop = threading.Event()
    while not stop.wait(poll_s):
        if os.getppid() != parent_pid:
            _die()


def die_with_parent(parent_pid: int, poll_s: float = POLL_S) -> None:
    """Make this process die (SIGKILL) when ``parent_pid``, its parent, is gone; call it first thing in a
    worker. If the parent is already gone, die now."""
    _kernel_lifeline()
    if os.getppid() != parent_pid:  # the parent died before the lifeline was in place
        _die()
    threading.Thread(target=_watch, args=(parent_pid, poll_s), name="monoflow-lifeline", daemon=True).start()
