"""Checking a finished cache end to end: every listed block decodes and agrees with the manifest.

``verify(root)`` reads every array of every block (so every chunk's CRC32C is checked) and checks the
invariants the reader relies on. It never raises for a damaged cache: it reports.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pipeline.cache.encode import gt_flow_from_ulp_offsets
from pipeline.cache.layout import MANIFEST_NAME, block_relpath
from pipeline.cache.manifest import find_tmp, inspect_block, read_manifest, scan_blocks
from pipeline.cache.points import dequantize_depth, points_from_depth
from core.errors import InputError
from core.geometry import static_flow


@dataclass
class VerifyReport:
    """Outcome of :func:`verify`. ``errors`` make the cache unusable; ``warnings`` do not."""

    root: Path
    blocks_checked: int = 0
    pairs_checked: int = 0
    bytes_on_disk: int = 0
    errors: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.errors

    def summary(self) -> str:
        state = "OK" if self.ok else f"{len(self.errors)} error(s)"
        lines = [
            f"{self.root}: {state}; {self.blocks_checked} blocks, {self.pairs_checked} pairs, "
            f"{self.bytes_on_disk / 2**20:.1f} MiB"
            + (f" ({self.bytes_on_disk / self.pairs_checked / 2**10:.0f} KiB/pair)" if self.pairs_checked else "")
        ]
        lines += [f"error: {e}" for e in self.errors] + [f"warning: {w}" for w in self.warnings]
        return "\n".join(lines)


def _check_block_data(root: Path, entry: dict, height: int, width: int) -> tuple[list[str], int]:
    """Decode every array of one block and check its invariants; (problems, bytes on disk)."""
    from pipeline.cache.block_format import open_block_group

    path = root / entry["path"]
    g = open_block_group(path)
    a = dict(g.attrs)
    data = {name: g[name][...] for name in g.array_keys()}  # full decode: checks every CRC
    P = int(a["num_pairs"])
    n_pix = height * width
    problems = []
    if (int(a["height"]), int(a["width"])) != (height, width):
        problems.append(f"image size {a['height']}x{a['width']}, manifest says {height}x{width}")
    for key in ("num_pairs", "num_points1", "num_points2", "has_gt_flow", "has_moving"):
        if a[key] != entry[key]:
            problems.append(f"{key} = {a[key]}, manifest says {entry[key]}")
    for s in ("1", "2"):
        off, idx = data["offsets" + s], data["idx" + s]
        if off[0] != 0 or off[-1] != idx.shape[0] or (np.diff(off) < 0).any():
            problems.append(f"offsets{s} not monotone from 0 to {idx.shape[0]}")
            continue
        if idx.size and (idx.min() < 0 or idx.max() >= n_pix):
            problems.append(f"idx{s} outside the image [0, {n_pix})")
        steps = np.diff(idx.astype(np.int64))
        inner = np.ones(steps.shape, bool)
        inner[off[1:-1][(off[1:-1] > 0) & (off[1:-1] < idx.size)] - 1] = False  # pair boundaries may step down
        if (steps[inner] <= 0).any():
            problems.append(f"idx{s} not strictly ascending within a pair")
    frames = set(int(f) for f in a["frame_ids"])
    if any(int(f) not in frames for pf in a["pair_frames"] for f in pf):
        problems.append("a pair names a frame the block lacks")
    T = data["T"]
    if not np.isfinite(T).all() or not np.allclose(T[:, 3], [0, 0, 0, 1]):
        problems.append("T not finite rigid transforms")
    if not np.isfinite(data["K"]).all() or not np.isfinite(data["scale"]).all():
        problems.append("K or scale not finite")
    if "gt_flow" in data and not problems:
        pos = {int(f): k for k, f in enumerate(a["frame_ids"])}
        off = data["offsets1"]
        for j, (ft, _) in enumerate(a["pair_frames"]):
            idx = data["idx1"][off[j] : off[j + 1]]
            pc1 = points_from_depth(dequantize_depth(data["depth"][pos[int(ft)]]), idx, data["K"])
            sf = static_flow(pc1, data["T"][j], as_float32=True)
            gt = gt_flow_from_ulp_offsets(data["gt_flow"][off[j] : off[j + 1]], sf)
            if not np.isfinite(gt).all():
                problems.append(f"pair {j}: gt_flow not finite")
    if int(a["num_pairs"]) != P:
        problems.append("pair count mismatch")
    size = sum(os.path.getsize(os.path.join(d, f)) for d, _, fs in os.walk(path) for f in fs)
    return problems, size


def verify(root: str | os.PathLike[str]) -> VerifyReport:
    """Check the cache at ``root``: manifest readable and consistent; every listed block present, fully
    decodable (CRC-checked) and agreeing with the manifest; offsets monotone; indices inside the image and
    ascending; frames referenced exist. Blocks present but not listed and writers' temp entries are warnings.
    """
    root = Path(root)
    report = VerifyReport(root=root)
    try:
        m = read_manifest(root)
    except InputError as exc:
        report.errors.append(str(exc))
        return report
    H, W = int(m["image_size"]["height"]), int(m["image_size"]["width"])
    listed: set[tuple[str, int]] = set()
    expected_first = 0
    for seq in sorted(m["sequences"]):
        sinfo = m["sequences"][seq]
        if int(sinfo["first_pair"]) != expected_first:
            report.errors.append(f"{MANIFEST_NAME}: sequence {seq} first_pair {sinfo['first_pair']}, expected {expected_first}")
        for entry in sinfo["blocks"]:
            b = int(entry["block"])
            listed.add((seq, b))
            where = root / block_relpath(seq, b)
            if entry["path"] != block_relpath(seq, b):
                report.errors.append(f"{MANIFEST_NAME}: block {seq}/{b} has path {entry['path']!r}")
                continue
            if int(entry["first_pair"]) != expected_first:
                report.errors.append(f"{MANIFEST_NAME}: block {seq}/{b} first_pair {entry['first_pair']}, expected {expected_first}")
            expected_first += int(entry["num_pairs"])
            try:
                inspect_block(root, seq, b, m["config_hash"])
                problems, size = _check_block_data(root, entry, H, W)
            except InputError as exc:
                report.errors.append(str(exc))
                continue
            except Exception as exc:  # damaged chunk: codec / CRC error
                report.errors.append(f"{where}: unreadable data ({type(exc).__name__}: {exc})")
                continue
            report.errors += [f"{where}: {p}" for p in problems]
            report.blocks_checked += 1
            report.pairs_checked += int(entry["num_pairs"])
            report.bytes_on_disk += size
    if expected_first != int(m["num_pairs"]):
        report.errors.append(f"{MANIFEST_NAME}: num_pairs {m['num_pairs']}, blocks hold {expected_first}")
    for seq, blocks in scan_blocks(root).items():
        for b in blocks:
            if (seq, b) not in listed:
                report.warnings.append(f"{root / block_relpath(seq, b)}: block present but not in the manifest")
    for p in find_tmp(root):
        report.warnings.append(f"{p}: a writer's temp entry (running elsewhere, or left by a killed run)")
    return report
