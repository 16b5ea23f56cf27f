"""Every file of a finished block is listed, with its size, in the block's own attributes.

zarr reads an absent chunk as the fill value: a deleted ``T`` chunk would silently become zero matrices, a
deleted ``gt_flow`` shard static flow. So the writer records ``chunk_files`` (relative POSIX path → size in
bytes, every file of the block but its top ``zarr.json``, which holds the list) just before the block is
consolidated, and the reader, ``inspect_block`` (``merge``/``finalize``) and ``verify`` compare the files
on disk with it: an absent or short (truncated) chunk is one error naming the block and the chunk.
Pure standard library: no zarr import.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

from core.errors import InputError

CHUNK_FILES_ATTR = "chunk_files"
ROOT_METADATA = "zarr.json"


def list_block_files(path: str | os.PathLike[str]) -> dict[str, int]:
    """Relative POSIX path → size of every file under the block folder ``path`` but its top zarr.json."""
    path = Path(path)
    out: dict[str, int] = {}
    for dirpath, _, files in os.walk(path):
        for name in files:
            full = Path(dirpath) / name
            rel = full.relative_to(path).as_posix()
            if rel != ROOT_METADATA:
                out[rel] = full.stat().st_size
    return dict(sorted(out.items()))


def file_problems(path: str | os.PathLike[str], listed: Any) -> list[str]:
    """What is wrong with the files of block ``path`` against its ``chunk_files`` attribute ([] if all
    present with their sizes). Extra files are not a problem (zarr never reads them)."""
    path = Path(path)
    if not isinstance(listed, dict) or not listed:
        return [f"no {CHUNK_FILES_ATTR} list in its zarr.json (written by an older monoflow? rebuild the cache)"]
    missing, short = [], []
    for rel, size in listed.items():
        try:
            actual = (path / rel).stat().st_size
        except FileNotFoundError:
            missing.append(rel)
            continue
        except OSError as exc:
            missing.append(f"{rel} ({exc.strerror})")
            continue
        if actual != size:
            short.append(f"{rel} ({actual} of {size} bytes)")
    problems = []
    if missing:
        problems.append(f"chunk file(s) missing: {', '.join(missing[:6])}" + (" …" if len(missing) > 6 else ""))
    if short:
        problems.append(f"chunk file(s) of the wrong size: {', '.join(short[:6])}" + (" …" if len(short) > 6 else ""))
    return problems


def read_block_attrs(path: str | os.PathLike[str]) -> dict[str, Any]:
    """The attributes of a finished block, read from its top zarr.json (one small file, no zarr import)."""
    meta = Path(path) / ROOT_METADATA
    try:
        obj = json.loads(meta.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError(Path(path), "block listed in the manifest is missing") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(meta, f"unreadable block metadata ({type(exc).__name__}: {exc})") from None
    attrs = obj.get("attributes") if isinstance(obj, dict) else None
    if not isinstance(attrs, dict):
        raise InputError(meta, "block metadata has no attributes")
    return attrs


def check_block_files(path: str | os.PathLike[str], attrs: dict[str, Any] | None = None) -> None:
    """Raise one InputError naming block ``path`` if a listed file is absent or has another size."""
    attrs = read_block_attrs(path) if attrs is None else attrs
    problems = file_problems(path, attrs.get(CHUNK_FILES_ATTR))
    if problems:
        raise InputError(Path(path), "; ".join(problems))
