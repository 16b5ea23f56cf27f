"""The cache's header and manifest: reading them, inspecting finished blocks, building the manifest.

``merge(root)`` builds ``manifest.json`` from the blocks present (the end of a multi-machine array job);
``CacheWriter.finalize`` does the same for the blocks it was told to expect. The manifest holds no
timestamps, so the same blocks always give a byte-identical manifest.
"""

from __future__ import annotations

import json
import os
import shutil
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pipeline.cache.layout import (
    BLOCKS_DIR,
    FORMAT_NAME,
    HEADER_NAME,
    MANIFEST_NAME,
    SCHEMA_VERSION,
    block_dir,
    block_relpath,
    canonical_json,
    check_block_index,
    check_name,
    code_version,
    host_name,
    is_block_name,
    parse_tmp_name,
    write_json_atomic,
)
from pipeline.cache.integrity import CHUNK_FILES_ATTR, file_problems, read_block_attrs
from core.errors import InputError
from core.processes import writer_gone

ExpectedBlocks = Mapping[str, int] | Iterable[tuple[str, int]]


# --------------------------------------------------------------------------- JSON files


def load_json(path: Path, what: str, required: tuple[str, ...]) -> dict[str, Any]:
    """Load a cache JSON file, checking format name, schema version and ``required`` keys (InputError)."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InputError(path, f"no {what} (not a finished cache? run the preprocess step, or `merge`)") from None
    except OSError as exc:
        raise InputError(path, f"cannot read {what}: {exc.strerror}") from None
    try:
        obj = json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputError(path, f"{what} is not valid JSON ({exc.msg} at line {exc.lineno})") from None
    if not isinstance(obj, dict) or obj.get("format") != FORMAT_NAME:
        raise InputError(path, f"not a monoflow cache {what} (format is not {FORMAT_NAME!r})")
    if obj.get("schema_version") != SCHEMA_VERSION:
        raise InputError(
            path,
            f"cache schema version {obj.get('schema_version')!r}, this code reads {SCHEMA_VERSION}; rebuild the cache",
        )
    missing = [k for k in required if k not in obj]
    if missing:
        raise InputError(path, f"{what} lacks {', '.join(missing)}")
    return obj


def read_header(root: Path) -> dict[str, Any]:
    return load_json(Path(root) / HEADER_NAME, "cache header", ("config", "config_hash", "source"))


def read_manifest(root: Path) -> dict[str, Any]:
    return load_json(
        Path(root) / MANIFEST_NAME, "manifest", ("config_hash", "image_size", "num_pairs", "sequences")
    )


def make_header(config: dict, source: dict, config_hash: str) -> dict[str, Any]:
    return {
        "format": FORMAT_NAME,
        "schema_version": SCHEMA_VERSION,
        "config": json.loads(canonical_json(config)),
        "config_hash": config_hash,
        "source": json.loads(canonical_json(source)),
    }


# --------------------------------------------------------------------------- blocks on disk


@dataclass(frozen=True)
class BlockInfo:
    """What a finished block's metadata says about it (checked against its offsets arrays)."""

    sequence: str
    block_index: int
    path: str  # relative to the root, POSIX
    num_pairs: int
    num_points1: int
    num_points2: int
    frame_ids: tuple[int, ...]
    height: int
    width: int
    has_gt_flow: bool
    has_moving: bool
    config_hash: str
    code_version: str  # canonical JSON of the writer's code version


def scan_blocks(root: Path) -> dict[str, list[int]]:
    """Finished blocks present under ``root/blocks``: sequence → sorted block indices (temp dirs ignored)."""
    out: dict[str, list[int]] = {}
    base = Path(root) / BLOCKS_DIR
    if not base.is_dir():
        return out
    for seq_dir in sorted(base.iterdir()):
        if not seq_dir.is_dir() or parse_tmp_name(seq_dir.name):
            continue
        found = sorted(int(d.name) for d in seq_dir.iterdir() if is_block_name(d.name) and (d / "zarr.json").is_file())
        if found:
            out[seq_dir.name] = found
    return out


def inspect_block(root: Path, sequence: str, block_index: int, config_hash: str | None = None) -> BlockInfo:
    """Open a finished block and check its metadata and offsets (cheap: no pixel data is read).

    Raises InputError naming the block directory when it is missing, unreadable or inconsistent.
    """
    from pipeline.cache.block_format import OPTIONAL_ARRAYS, REQUIRED_ARRAYS, open_block_group

    path = block_dir(root, sequence, block_index)
    if not (path / "zarr.json").is_file():
        raise InputError(path, "block missing")
    head = read_block_attrs(path)  # schema and chunk files first: a lost chunk would otherwise read as zeros
    if head.get("format") != FORMAT_NAME or head.get("schema_version") != SCHEMA_VERSION:
        raise InputError(path, f"block format/schema {head.get('format')!r}/{head.get('schema_version')!r}, this "
                               f"code reads {FORMAT_NAME!r}/{SCHEMA_VERSION}; rebuild the cache")
    lost = file_problems(path, head.get(CHUNK_FILES_ATTR))
    if lost:
        raise InputError(path, "; ".join(lost))
    try:
        g = open_block_group(path)
        a = dict(g.attrs)
        names = set(g.array_keys())
        lacking = [n for n in REQUIRED_ARRAYS if n not in names]
        if lacking:
            raise InputError(path, f"block lacks arrays {lacking}")
        P = int(a["num_pairs"])
        off1, off2 = g["offsets1"][...], g["offsets2"][...]
        shapes = {n: tuple(g[n].shape) for n in names}
    except InputError:
        raise
    except Exception as exc:  # zarr/codec errors on damaged files
        raise InputError(path, f"unreadable block ({type(exc).__name__}: {exc})") from None
    problems = []
    if a.get("sequence") != sequence or a.get("block_index") != block_index:
        problems.append(f"attributes name block {a.get('sequence')!r}/{a.get('block_index')!r}")
    if config_hash is not None and a.get("config_hash") != config_hash:
        problems.append(f"written for config {a.get('config_hash')!r}, cache is {config_hash!r}")
    if off1.shape != (P + 1,) or off2.shape != (P + 1,):
        problems.append(f"offsets shapes {off1.shape} {off2.shape} for {P} pairs")
    elif off1[-1] != a["num_points1"] or off2[-1] != a["num_points2"]:
        problems.append("offsets disagree with the point counts")
    if shapes.get("idx1") != (a["num_points1"],) or shapes.get("idx2") != (a["num_points2"],):
        problems.append("idx arrays disagree with the point counts")
    H, W, F = a["height"], a["width"], len(a["frame_ids"])
    if shapes.get("depth") != (F, H, W) or shapes.get("rgb") != (F, 3, H, W):
        problems.append(f"frame arrays {shapes.get('depth')} {shapes.get('rgb')} for {F} frames of {H}x{W}")
    if shapes.get("T") != (P, 4, 4) or shapes.get("scale") != (P,) or len(a["pair_frames"]) != P:
        problems.append("per-pair arrays disagree with the pair count")
    for name, flag, shape in (("gt_flow", "has_gt_flow", (a["num_points1"], 3)), ("moving", "has_moving", (a["num_points1"],))):
        if bool(a[flag]) != (name in names) or (name in names and shapes[name] != shape):
            problems.append(f"{name} inconsistent with {flag}")
    unknown = names - set(REQUIRED_ARRAYS) - set(OPTIONAL_ARRAYS)
    if unknown:
        problems.append(f"unknown arrays {sorted(unknown)}")
    if problems:
        raise InputError(path, "; ".join(problems))
    return BlockInfo(
        sequence=sequence,
        block_index=block_index,
        path=block_relpath(sequence, block_index),
        num_pairs=P,
        num_points1=int(a["num_points1"]),
        num_points2=int(a["num_points2"]),
        frame_ids=tuple(int(f) for f in a["frame_ids"]),
        height=int(H),
        width=int(W),
        has_gt_flow=bool(a["has_gt_flow"]),
        has_moving=bool(a["has_moving"]),
        config_hash=str(a["config_hash"]),
        code_version=canonical_json(a.get("code_version")),
    )


def find_tmp(root: Path) -> list[Path]:
    """Every temp directory/file of a writer under ``root`` (blocks and JSON files)."""
    root = Path(root)
    found = [p for p in root.iterdir() if parse_tmp_name(p.name)] if root.is_dir() else []
    base = root / BLOCKS_DIR
    if base.is_dir():
        for seq_dir in base.iterdir():
            if seq_dir.is_dir():
                found += [p for p in seq_dir.iterdir() if parse_tmp_name(p.name)]
    return sorted(found)


def remove_stale_tmp(root: Path, all_hosts: bool = False) -> list[Path]:
    """Remove temp dirs/files left by dead writers; return what was removed.

    A temp name carries its writer's pid and host. By default only this host's entries whose writer is
    gone (:func:`core.processes.writer_gone`: no such process, or one that reuses the id) are removed
    (another host's writer may be alive on a shared file system); ``all_hosts=True`` removes every temp
    entry but this process's own, for when no writer can be running.
    """
    removed = []
    me = host_name()
    for p in find_tmp(root):
        _, pid, host = parse_tmp_name(p.name)
        if host == me:  # a live writer's entry stays; with all_hosts only this process's own does
            keep = not writer_gone(pid, p) and (not all_hosts or pid == os.getpid())
        else:  # another host's writer cannot be judged from here
            keep = not all_hosts
        if keep:
            continue
        if p.is_dir() and not p.is_symlink():
            shutil.rmtree(p, ignore_errors=True)
        else:
            p.unlink(missing_ok=True)
        removed.append(p)
    return removed


# --------------------------------------------------------------------------- manifest


def normalize_expected(expected: ExpectedBlocks) -> dict[str, list[int]]:
    """``{"00": 3}`` (blocks 0..2) or ``[("00", 0), ("00", 1)]`` → sequence → sorted block indices."""
    out: dict[str, set[int]] = {}
    if isinstance(expected, Mapping):
        for seq, n in expected.items():
            out.setdefault(check_name(seq), set()).update(range(int(n)))
    else:
        for seq, b in expected:
            out.setdefault(check_name(seq), set()).add(check_block_index(int(b)))
    return {s: sorted(v) for s, v in sorted(out.items()) if v}


def build_manifest(root: Path, blocks: dict[str, list[int]]) -> dict[str, Any]:
    """Inspect ``blocks`` (sequence → indices) and return the manifest dict; InputError on a bad block."""
    root = Path(root)
    header = read_header(root)
    if not blocks:
        raise InputError(root, "no blocks to put in the manifest")
    infos = [inspect_block(root, s, b, header["config_hash"]) for s in sorted(blocks) for b in sorted(blocks[s])]
    sizes = {(i.height, i.width) for i in infos}
    if len(sizes) != 1:
        raise InputError(root, f"blocks have different image sizes {sorted(sizes)}")
    (H, W), = sizes
    sequences: dict[str, Any] = {}
    first = 0
    for info in infos:
        seq = sequences.setdefault(info.sequence, {"first_pair": first, "num_pairs": 0, "num_blocks": 0, "blocks": []})
        seq["blocks"].append(
            {
                "block": info.block_index,
                "path": info.path,
                "first_pair": first,
                "num_pairs": info.num_pairs,
                "frames": [min(info.frame_ids), max(info.frame_ids)],
                "num_points1": info.num_points1,
                "num_points2": info.num_points2,
                "has_gt_flow": info.has_gt_flow,
                "has_moving": info.has_moving,
            }
        )
        seq["num_pairs"] += info.num_pairs
        seq["num_blocks"] += 1
        first += info.num_pairs
    from pipeline.cache.encode import DEPTH_ENCODING

    return {
        "format": FORMAT_NAME,
        "schema_version": SCHEMA_VERSION,
        "config": header["config"],
        "config_hash": header["config_hash"],
        "source": header["source"],
        "code_version": code_version(),
        "block_code_versions": [json.loads(v) for v in sorted({i.code_version for i in infos})],
        "image_size": {"height": H, "width": W},
        "depth_encoding": DEPTH_ENCODING,
        "num_pairs": first,
        "num_blocks": len(infos),
        "sequences": sequences,
    }


def merge(root: str | os.PathLike[str], expected_blocks: ExpectedBlocks | None = None) -> dict[str, Any]:
    """Build and write ``manifest.json`` from the finished blocks; return the manifest.

    With ``expected_blocks`` every expected block must be present (InputError listing the missing ones)
    and only those enter the manifest. Without it, the blocks present are used, and a sequence whose block
    indices are not 0..n−1 is an error (a missing *last* block cannot be seen this way: pass the plan).
    Temp directories are ignored (never removed here: a writer elsewhere may still be running).
    """
    root = Path(root)
    present = scan_blocks(root)
    if expected_blocks is not None:
        want = normalize_expected(expected_blocks)
        missing = [f"{s}/{b:05d}" for s in want for b in want[s] if b not in set(present.get(s, ()))]
        if missing:
            more = f" (+{len(missing) - 8} more)" if len(missing) > 8 else ""
            raise InputError(root, f"{len(missing)} expected block(s) missing: {', '.join(missing[:8])}{more}")
        blocks = want
    else:
        gaps = [f"{s}: {sorted(set(range(max(b) + 1)) - set(b))}" for s, b in present.items() if b != list(range(len(b)))]
        if gaps:
            raise InputError(root, f"blocks missing inside sequences ({'; '.join(gaps)}); write them first")
        blocks = present
    manifest = build_manifest(root, blocks)
    write_json_atomic(root / MANIFEST_NAME, manifest)
    return manifest
