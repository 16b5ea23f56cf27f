"""Error types shared by every stage.

Bad input must surface as *one clear line* naming the file and what is wrong, never as a traceback
from deep inside numpy. Code that reads a file raises :class:`InputError`; the CLIs catch
:class:`MonoflowError` and print ``error: <message>`` with exit code 2.
"""

from __future__ import annotations

import os
from pathlib import Path


class MonoflowError(Exception):
    """Base class of every error monoflow reports to a user as one line."""


class InputError(MonoflowError):
    """A file or folder given to monoflow is missing, malformed or inconsistent.

    >>> str(InputError("calib.txt", "missing key 'P2'"))
    "calib.txt: missing key 'P2'"
    """

    def __init__(self, path: str | os.PathLike[str], problem: str) -> None:
        self.path = Path(path)
        self.problem = problem
        super().__init__(f"{path}: {problem}")


class ConfigError(MonoflowError):
    """An option or combination of options makes no sense."""


class TrainingDiverged(MonoflowError):
    """A training run's loss or gradient became NaN or infinite (either trainer stops with this, keeping its
    last good checkpoint)."""


def run_cli(main_body, argv=None) -> int:
    """Run a CLI body, turning :class:`MonoflowError` into ``error: ...`` on stderr and exit code 2; an
    ``OSError`` that escaped (disk full, permission denied) likewise, as ``error: <file>: <reason>``."""
    import sys

    try:
        rc = main_body(argv)
    except MonoflowError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except OSError as exc:  # disk full, permissions, a vanished folder: the file and the system's reason
        where = exc.filename if exc.filename is not None else "?"
        reason = exc.strerror or " ".join(str(exc).split())
        print(f"error: {where}: {reason}", file=sys.stderr)
        return 2
    return int(rc or 0)
