"""Loading ``torch.save``d files without running code from them.

Every checkpoint monoflow reads goes through :func:`load_weights_only`: ``torch.load(weights_only=True)``
rebuilds tensors and plain Python data only, so a file whose pickle names a function (``os.system``,
``open``, ...) is refused before anything in it runs. Any problem is one :class:`InputError` naming the file.
"""

from __future__ import annotations

import os
import pickle
import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from core.errors import InputError

_GLOBAL = re.compile(r"Unsupported global: GLOBAL (\S+)")
_ANSI = re.compile(r"\x1b\[[0-9;]*m")


def _first_line(exc: BaseException) -> str:
    text = _ANSI.sub("", str(exc)).strip()
    return (text.splitlines() or [""])[0][:160]


def load_weights_only(path: str | os.PathLike[str], safe_globals: Sequence[Any] = ()) -> Any:
    """``torch.load(path, map_location="cpu", weights_only=True)``; ``safe_globals`` are extra types the
    file may name (plain data types only). InputError naming the file for a missing, unreadable or refused
    file (the message says which global a refused file named)."""
    import torch

    path = Path(path)
    if not path.is_file():
        raise InputError(path, "checkpoint not found")
    try:
        with torch.serialization.safe_globals(list(safe_globals)):
            return torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as exc:
        found = _GLOBAL.search(str(exc))
        what = f"it names {found.group(1)}" if found else _first_line(exc)
        raise InputError(path, f"refused: not plain tensors and data ({what}); nothing in it was run") from None
    except Exception as exc:  # torch raises many types on damaged files (RuntimeError, EOFError, ...)
        raise InputError(path, f"not a readable checkpoint ({type(exc).__name__}: {_first_line(exc)})") from None
