"""Where things live in a cache root, how it is named, and how its JSON files are written.

A cache root is ``<out>/<dataset>/<config-hash>/`` (:func:`cache_root`) holding

* ``cache.json``    — header: schema version, config, config hash, source (written by the first writer);
* ``manifest.json`` — the index a reader needs (written last, by finalize or merge);
* ``blocks/<sequence>/<block:05d>/`` — one finished zarr group per block; a block being written lives in
  ``blocks/<sequence>/<block:05d>.tmp-<pid>-<host>/`` until it is complete and renamed into place.

JSON is written canonically (sorted keys, fixed separators, no NaN/inf) and atomically (temp file +
``os.replace``, :func:`core.jsonio.write_json_atomic`), so a resumed run produces byte-identical files.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
from pathlib import Path
from typing import Any

from core.errors import ConfigError
# re-exported for the cache modules: temp names, fsync, and the JSON writer, whose defaults (no NaN/inf,
# indent 1) are the cache's canonical form
from core.jsonio import fsync_dir, host_name, tmp_suffix, write_json_atomic  # noqa: F401
from core.runinfo import git_revision

SCHEMA_VERSION = 2  # 2: blocks list their chunk files and sizes (integrity.py)
FORMAT_NAME = "monoflow-stage-one-cache"
HEADER_NAME = "cache.json"
MANIFEST_NAME = "manifest.json"
BLOCKS_DIR = "blocks"
MAX_BLOCKS_PER_SEQUENCE = 100_000  # block directories are named with 5 digits

_SEQUENCE_RE = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.-]*$")
_BLOCK_RE = re.compile(r"^\d{5}$")
_TMP_RE = re.compile(r"^(?P<stem>.+)\.tmp-(?P<pid>\d+)-(?P<host>.+)$")


def canonical_json(obj: Any) -> str:
    """The canonical JSON text of ``obj``: sorted keys, no whitespace, no NaN/inf."""
    try:
        return json.dumps(obj, sort_keys=True, separators=(",", ":"), ensure_ascii=True, allow_nan=False)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"cache config/source must be plain JSON data: {exc}") from None


def config_hash(config: dict) -> str:
    """Short (12 hex digits) sha256 of the canonical JSON of ``config``; names the cache directory."""
    return hashlib.sha256(canonical_json(config).encode("ascii")).hexdigest()[:12]


def cache_root(out: str | os.PathLike[str], dataset: str, config: dict) -> Path:
    """``<out>/<dataset>/<config-hash>/`` for a stage-one config."""
    check_name(dataset, "dataset")
    return Path(out) / dataset / config_hash(config)


def check_name(name: str, what: str = "sequence") -> str:
    """A sequence or dataset name that is safe as one path component (letters, digits, ``_ . -``)."""
    if not isinstance(name, str) or not _SEQUENCE_RE.match(name) or ".tmp-" in name:
        raise ValueError(f"{what} name {name!r} must be letters, digits, '_', '.', '-' (not starting with '.')")
    return name


def check_block_index(block_index: int) -> int:
    if isinstance(block_index, bool) or not isinstance(block_index, int) or not 0 <= block_index < MAX_BLOCKS_PER_SEQUENCE:
        raise ValueError(f"block index {block_index!r} must be an int in [0, {MAX_BLOCKS_PER_SEQUENCE})")
    return block_index


def block_relpath(sequence: str, block_index: int) -> str:
    """``blocks/<sequence>/<block:05d>`` (POSIX separators, as stored in the manifest)."""
    return f"{BLOCKS_DIR}/{check_name(sequence)}/{check_block_index(block_index):05d}"


def block_dir(root: Path, sequence: str, block_index: int) -> Path:
    return Path(root) / block_relpath(sequence, block_index)


def parse_tmp_name(name: str) -> tuple[str, int, str] | None:
    """(stem, pid, host) of a temp name made with :func:`core.jsonio.tmp_suffix`, or None for any other name."""
    m = _TMP_RE.match(name)
    return (m["stem"], int(m["pid"]), m["host"]) if m else None


def is_block_name(name: str) -> bool:
    return bool(_BLOCK_RE.match(name))


def code_version() -> dict[str, str | None]:
    """``{"monoflow": package version, "git": HEAD revision (full hash) of the source checkout or None}``."""
    import pipeline

    return {"monoflow": pipeline.__version__, "git": git_revision()}
