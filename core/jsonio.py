"""Atomic JSON files: the one writer behind stage one's cache files and the trainers' run folders.

A file appears complete or not at all: it is written to ``<name>.tmp-<pid>-<host>`` in the same folder,
fsynced and ``os.replace``d into place. Keys are sorted and the text is ASCII, so equal data gives equal
bytes. Each caller chooses its NaN policy: the cache refuses NaN/inf (strict JSON), run folders allow it
(a diverged run's metrics are still worth writing).
"""

from __future__ import annotations

import dataclasses
import json
import os
import re
import socket
from pathlib import Path
from typing import Any


def host_name() -> str:
    """This machine's name, reduced to path-safe characters (it goes into temp-file names)."""
    return re.sub(r"[^A-Za-z0-9_.-]", "_", socket.gethostname()) or "host"


def tmp_suffix() -> str:
    """``.tmp-<pid>-<host>``: marks a directory or file being written by this process."""
    return f".tmp-{os.getpid()}-{host_name()}"


def to_jsonable(obj: Any) -> Any:
    """``obj`` with dataclasses turned into dicts, tuples into lists, paths into strings, keys into strings."""
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {k: to_jsonable(v) for k, v in dataclasses.asdict(obj).items()}
    if isinstance(obj, dict):
        return {str(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_jsonable(v) for v in obj]
    if isinstance(obj, Path):
        return str(obj)
    return obj


def write_json_atomic(path: str | os.PathLike[str], obj: Any, *, allow_nan: bool = False, indent: int = 1) -> None:
    """Write ``obj`` (plain data, dataclasses, paths; see :func:`to_jsonable`) as sorted-key ASCII JSON.

    Atomic and durable: temp file in the same folder + fsync + ``os.replace`` + fsync of the folder.
    ``allow_nan=False`` (the default) raises ValueError on NaN/inf and writes nothing.
    """
    path = Path(path)
    text = json.dumps(to_jsonable(obj), sort_keys=True, indent=indent, ensure_ascii=True, allow_nan=allow_nan) + "\n"
    tmp = path.with_name(path.name + tmp_suffix())
    try:
        with open(tmp, "w", encoding="ascii") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()
    fsync_dir(path.parent)


def fsync_dir(path: Path) -> None:
    """Make a rename or a new entry in ``path`` durable (no-op where directories cannot be opened)."""
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)
