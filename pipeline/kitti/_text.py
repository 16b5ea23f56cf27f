"""Parsing of KITTI's whitespace-separated text files (calibrations, poses, times).

Every problem raises :class:`~core.errors.InputError` naming the file and, where it applies, the
key or the 1-based line number.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from core.errors import InputError

PathLike = str | os.PathLike[str]


def read_text(path: PathLike) -> str:
    """Whole file as text; a missing, unreadable or non-text file raises InputError."""
    p = Path(path)
    if not p.exists():
        raise InputError(p, "file not found")
    if not p.is_file():
        raise InputError(p, "not a file")
    try:
        return p.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(p, f"cannot read as text ({exc.__class__.__name__}: {exc})") from None


def parse_floats(path: PathLike, tokens: list[str], where: str) -> np.ndarray:
    """``tokens`` as float64; a non-number or non-finite value raises InputError naming ``where``."""
    try:
        values = np.array([float(t) for t in tokens], dtype=np.float64)
    except ValueError:
        bad = next(t for t in tokens if not _is_float(t))
        raise InputError(path, f"{where}: {bad!r} is not a number") from None
    if not np.all(np.isfinite(values)):
        raise InputError(path, f"{where}: non-finite value")
    return values


def _is_float(token: str) -> bool:
    try:
        float(token)
    except ValueError:
        return False
    return True


def split_key(line: str) -> tuple[str | None, list[str]]:
    """Split ``"KEY: v1 v2 …"`` (or tracking-style ``"KEY v1 v2 …"``) into (KEY, tokens).

    A line whose first token is a number has no key: (None, tokens).
    """
    head, sep, rest = line.partition(":")
    if sep and head.strip() and " " not in head.strip() and not _is_float(head.strip()):
        return head.strip(), rest.split()
    tokens = line.split()
    if tokens and not _is_float(tokens[0]):
        return tokens[0], tokens[1:]
    return None, tokens


def read_key_values(path: PathLike) -> dict[str, list[str]]:
    """``KEY: tokens`` lines of a calibration file → {KEY: tokens}; '#' comments and blank lines skipped.

    A key-less line or a repeated key raises InputError.
    """
    out: dict[str, list[str]] = {}
    for lineno, raw in enumerate(read_text(path).splitlines(), start=1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        key, tokens = split_key(line)
        if key is None:
            raise InputError(path, f"line {lineno}: expected 'KEY: values', got numbers without a key")
        if key in out:
            raise InputError(path, f"line {lineno}: key {key!r} appears twice")
        out[key] = tokens
    return out


def get_matrix(path: PathLike, table: dict[str, list[str]], key: str, shape: tuple[int, ...]) -> np.ndarray:
    """``table[key]`` parsed as float64 of ``shape`` (row-major); missing key or wrong count → InputError."""
    if key not in table:
        raise InputError(path, f"missing key {key!r}")
    need = int(np.prod(shape))
    tokens = table[key]
    if len(tokens) != need:
        raise InputError(path, f"key {key!r}: expected {need} numbers, got {len(tokens)}")
    return parse_floats(path, tokens, f"key {key!r}").reshape(shape)


def format_row(values: np.ndarray, fmt: str = "%.12e") -> str:
    """Numbers joined by single spaces, each formatted with ``fmt``."""
    return " ".join(fmt % float(v) for v in np.asarray(values, dtype=np.float64).ravel())


def write_text(path: PathLike, text: str) -> None:
    """Write ``text`` to ``path``, creating parent folders."""
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_text(text, encoding="utf-8")
