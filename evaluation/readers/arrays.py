"""Shape and dtype checks of ``.npy`` / ``.npz`` arrays from their headers, without reading the data.

Each ``check_*`` returns one problem in words (naming the array) or None when the array is fine.
"""

from __future__ import annotations

import zipfile
from pathlib import Path
from typing import Any

import numpy as np

#: optional per-point integer labels every format may carry: class (0 = background) and instance.
LABELS = ("classes", "instance")

Spec = tuple[tuple[int, ...], np.dtype]


def _npy_header(fp: Any) -> Spec:
    version = np.lib.format.read_magic(fp)
    if version == (1, 0):
        shape, _, dtype = np.lib.format.read_array_header_1_0(fp)
    elif version == (2, 0):
        shape, _, dtype = np.lib.format.read_array_header_2_0(fp)
    else:  # pragma: no cover - version 3 headers are rare
        shape, _, dtype = np.lib.format._read_array_header(fp, version)  # type: ignore[attr-defined]
    return tuple(shape), np.dtype(dtype)


def npz_headers(path: Path) -> dict[str, Spec]:
    """Shape and dtype of every array in an ``.npz`` without loading the data."""
    out: dict[str, Spec] = {}
    with zipfile.ZipFile(path) as zf:
        for info in zf.infolist():
            if not info.filename.endswith(".npy"):
                continue
            with zf.open(info) as fp:
                out[info.filename[: -len(".npy")]] = _npy_header(fp)
    return out


def npy_header(path: Path) -> Spec:
    """Shape and dtype of an ``.npy`` file without loading the data."""
    with open(path, "rb") as fp:
        return _npy_header(fp)


def check_points(name: str, shape: tuple[int, ...], dtype: np.dtype, rows: int | None = None) -> str | None:
    """An (N, 3) numeric array, with ``rows`` rows when given."""
    if len(shape) != 2 or shape[1] != 3:
        return f"'{name}' must have shape (N, 3), got {shape}"
    if dtype.kind not in "fiu":
        return f"'{name}' must be numeric, got dtype {dtype}"
    if rows is not None and shape[0] != rows:
        return f"'{name}' has {shape[0]} rows, expected {rows}"
    return None


def _check_vector(name: str, shape: tuple[int, ...], dtype: np.dtype, rows: int, what: str) -> str | None:
    if shape != (rows,):
        return f"'{name}' must have shape ({rows},), got {shape}"
    if dtype.kind not in "biu":
        return f"'{name}' must be {what}, got dtype {dtype}"
    return None


def check_mask(name: str, shape: tuple[int, ...], dtype: np.dtype, rows: int) -> str | None:
    """A (rows,) boolean (or 0/1 integer) mask."""
    return _check_vector(name, shape, dtype, rows, "boolean")


def check_labels(name: str, shape: tuple[int, ...], dtype: np.dtype, rows: int) -> str | None:
    """(rows,) integer labels."""
    return _check_vector(name, shape, dtype, rows, "integer")


def raise_problems(problems: list[str | None]) -> None:
    """Raise one ValueError joining every problem found (none: return)."""
    found = [p for p in problems if p]
    if found:
        raise ValueError("; ".join(found))
