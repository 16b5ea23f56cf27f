"""Check a :class:`BlockRecord` and turn it into the typed arrays and attributes of one block group.

Pure numpy (no zarr): what is stored, independent of how it is compressed. Programming errors in a record
(wrong shapes, unsorted indices, a pair naming a frame the block lacks) raise ValueError naming the block.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from pipeline.cache.layout import FORMAT_NAME, SCHEMA_VERSION, check_block_index, check_name
from pipeline.cache.points import (
    DEPTH_STEPS_PER_METRE,
    dequantize_depth,
    points_from_depth,
    quantize_depth,
)
from pipeline.cache.records import BlockRecord
from core.geometry import static_flow as static_flow_from_pose

DEPTH_ENCODING = {"dtype": "uint16", "steps_per_metre": DEPTH_STEPS_PER_METRE, "invalid": 0}


def gt_flow_to_ulp_offsets(gt_flow: np.ndarray, static_flow: np.ndarray) -> np.ndarray:
    """Ground-truth flow as int32 offsets of its float32 bit patterns from the static flow's.

    Static points' GT flow equals their static flow, so their offsets are 0 (or a few ulps when the source
    computed it slightly differently) and compress to almost nothing; moving points carry the rest.
    Exactly invertible by :func:`gt_flow_from_ulp_offsets` given the same static flow.
    """
    g = np.ascontiguousarray(gt_flow, dtype=np.float32).view(np.uint32)
    s = np.ascontiguousarray(static_flow, dtype=np.float32).view(np.uint32)
    return (g - s).view(np.int32)  # uint32 arithmetic wraps modulo 2**32


def gt_flow_from_ulp_offsets(offsets: np.ndarray, static_flow: np.ndarray) -> np.ndarray:
    """Inverse of :func:`gt_flow_to_ulp_offsets`: (N, 3) float32 ground-truth flow."""
    s = np.ascontiguousarray(static_flow, dtype=np.float32).view(np.uint32)
    return (s + np.ascontiguousarray(offsets, dtype=np.int32).view(np.uint32)).view(np.float32)


@dataclass
class EncodedBlock:
    arrays: dict[str, np.ndarray]
    attrs: dict[str, Any]


def _fail(rec: BlockRecord, problem: str) -> ValueError:
    return ValueError(f"block {rec.sequence!r}/{rec.block_index}: {problem}")


def _indices(rec: BlockRecord, name: str, idx: np.ndarray, n_pixels: int, j: int) -> np.ndarray:
    a = np.asarray(idx)
    if a.ndim != 1 or not (np.issubdtype(a.dtype, np.integer)):
        raise _fail(rec, f"pair {j}: {name} must be a 1-D integer array, got {a.dtype} {a.shape}")
    if a.size and (a.min() < 0 or a.max() >= n_pixels):
        raise _fail(rec, f"pair {j}: {name} outside [0, {n_pixels})")
    if a.size > 1 and not (np.diff(a.astype(np.int64)) > 0).all():
        raise _fail(rec, f"pair {j}: {name} must be strictly ascending")
    return a.astype(np.int32)


def encode_block(rec: BlockRecord, config_hash: str, code_version: dict) -> EncodedBlock:
    """Validate ``rec`` and return its arrays (see docs/cache-format.md for each) and group attributes."""
    check_name(rec.sequence)
    check_block_index(rec.block_index)
    if not rec.frames:
        raise _fail(rec, "no frames")
    if not rec.pairs:
        raise _fail(rec, "no pairs")
    K = np.asarray(rec.K, dtype=np.float64)
    if K.shape != (3, 3) or not np.isfinite(K).all():
        raise _fail(rec, f"K must be a finite (3, 3) matrix, got shape {K.shape}")

    frames = sorted(rec.frames, key=lambda f: int(f.frame_id))
    ids = [int(f.frame_id) for f in frames]
    if len(set(ids)) != len(ids):
        raise _fail(rec, f"duplicate frame ids {ids}")
    H, W = np.asarray(frames[0].depth).shape[:2] if np.asarray(frames[0].depth).ndim == 2 else (0, 0)
    if H == 0 or W == 0:
        raise _fail(rec, f"frame {ids[0]}: depth must be (H, W), got {np.asarray(frames[0].depth).shape}")
    depth = np.empty((len(frames), H, W), np.uint16)
    rgb = np.empty((len(frames), 3, H, W), np.uint8)
    for k, f in enumerate(frames):
        d, c = np.asarray(f.depth), np.asarray(f.rgb)
        if d.shape != (H, W):
            raise _fail(rec, f"frame {f.frame_id}: depth shape {d.shape}, expected {(H, W)}")
        if c.shape != (H, W, 3) or c.dtype != np.uint8:
            raise _fail(rec, f"frame {f.frame_id}: rgb must be ({H}, {W}, 3) uint8, got {c.dtype} {c.shape}")
        try:
            depth[k] = quantize_depth(d)
        except ValueError as exc:
            raise _fail(rec, f"frame {f.frame_id}: {exc}") from None
        rgb[k] = np.moveaxis(c, -1, 0)

    position = {fid: k for k, fid in enumerate(ids)}
    n_pixels = H * W
    P = len(rec.pairs)
    T = np.empty((P, 4, 4), np.float64)
    scale = np.empty((P,), np.float64)
    idx1, idx2, gts, movs, stats, pair_frames = [], [], [], [], [], []
    has_gt = rec.pairs[0].gt_flow is not None
    has_mov = rec.pairs[0].moving is not None
    for j, p in enumerate(rec.pairs):
        for fid in (p.frame_t, p.frame_t1):
            if int(fid) not in position:
                raise _fail(rec, f"pair {j} names frame {fid}, not among the block's frames {ids}")
        pair_frames.append([int(p.frame_t), int(p.frame_t1)])
        Tj = np.asarray(p.T, dtype=np.float64)
        if Tj.shape != (4, 4) or not np.isfinite(Tj).all():
            raise _fail(rec, f"pair {j}: T must be a finite (4, 4) matrix, got shape {Tj.shape}")
        T[j] = Tj
        scale[j] = float(p.scale)
        if not np.isfinite(scale[j]):
            raise _fail(rec, f"pair {j}: scale is not finite")
        a = _indices(rec, "idx1", p.idx1, n_pixels, j)
        idx1.append(a)
        idx2.append(_indices(rec, "idx2", p.idx2, n_pixels, j))
        if (p.gt_flow is not None) != has_gt or (p.moving is not None) != has_mov:
            raise _fail(rec, "gt_flow / moving must be present for every pair of a block or for none")
        if has_gt:
            g = np.asarray(p.gt_flow, dtype=np.float32)
            if g.shape != (a.size, 3):
                raise _fail(rec, f"pair {j}: gt_flow shape {g.shape}, expected {(a.size, 3)}")
            if not np.isfinite(g).all():
                raise _fail(rec, f"pair {j}: gt_flow is not finite")
            # the reader's static flow, bit for bit: from the stored depth, as CacheReader computes it
            pc1 = points_from_depth(dequantize_depth(depth[position[int(p.frame_t)]]), a, K)
            gts.append(gt_flow_to_ulp_offsets(g, static_flow_from_pose(pc1, Tj, as_float32=True)))
        if has_mov:
            m = np.asarray(p.moving)
            if m.shape != (a.size,) or m.dtype != np.bool_:
                raise _fail(rec, f"pair {j}: moving must be ({a.size},) bool, got {m.dtype} {m.shape}")
            movs.append(m)
        st = {str(k): int(v) for k, v in dict(p.stats).items()}
        stats.append(st)

    def ragged(parts: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
        offsets = np.zeros(P + 1, np.int64)
        offsets[1:] = np.cumsum([x.shape[0] for x in parts])
        return np.concatenate(parts).astype(np.int32), offsets

    arrays: dict[str, np.ndarray] = {"K": K, "T": T, "scale": scale, "depth": depth, "rgb": rgb}
    arrays["idx1"], arrays["offsets1"] = ragged(idx1)
    arrays["idx2"], arrays["offsets2"] = ragged(idx2)
    if has_gt:
        arrays["gt_flow"] = np.concatenate(gts).astype(np.int32).reshape(-1, 3)
    if has_mov:
        arrays["moving"] = np.concatenate(movs).astype(np.bool_)

    attrs = {
        "format": FORMAT_NAME,
        "schema_version": SCHEMA_VERSION,
        "config_hash": config_hash,
        "code_version": code_version,
        "sequence": rec.sequence,
        "block_index": int(rec.block_index),
        "height": int(H),
        "width": int(W),
        "depth_encoding": DEPTH_ENCODING,
        "frame_ids": ids,
        "pair_frames": pair_frames,
        "stats": stats,
        "num_pairs": P,
        "num_points1": int(arrays["offsets1"][-1]),
        "num_points2": int(arrays["offsets2"][-1]),
        "has_gt_flow": has_gt,
        "has_moving": has_mov,
    }
    return EncodedBlock(arrays, attrs)
