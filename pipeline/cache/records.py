"""What stage one hands to the cache writer: one block of consecutive pairs of one sequence.

Units and frames (docs/design.md §2): depth is z in metres (camera frame, x right, y down, z forward), after the
scale factor has been applied; 0 marks an invalid pixel (sky, no LiDAR return). Flat pixel index of pixel
(u, v) in an image of width W is ``v * W + u``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class FrameRecord:
    """One frame at the working size.

    frame_id: the frame's index in its sequence.
    depth: (H, W) float32 metric depth in metres after scale; 0 = invalid / sky.
    rgb: (H, W, 3) uint8 colour image.
    """

    frame_id: int
    depth: np.ndarray
    rgb: np.ndarray


@dataclass
class PairRecord:
    """One pair (t, t+1) after the filters.

    frame_t, frame_t1: frame ids of the two frames (both must be in the block's ``frames``).
    idx1: (N1,) int32 flat pixel indices ``v*W + u`` of the kept frame-t points, sorted ascending, unique.
    idx2: (N2,) int32 kept frame-(t+1) pixels, same convention.
    T: (4, 4) float64 ``T_{t→t+1}`` (camera t → camera t+1), metric (translation already scaled).
    scale: the factor applied to the net's depth and translation (1.0 when already metric).
    stats: point counts after each filter (e.g. {"valid": .., "ground": .., ...}), names free-form.
    gt_flow: (N1, 3) float32 ground-truth scene flow of the kept frame-t points (metres, camera-t frame),
        or None.
    moving: (N1,) bool, True where the point belongs to a moving object, or None.
    """

    frame_t: int
    frame_t1: int
    idx1: np.ndarray
    idx2: np.ndarray
    T: np.ndarray
    scale: float
    stats: dict[str, int] = field(default_factory=dict)
    gt_flow: np.ndarray | None = None
    moving: np.ndarray | None = None


@dataclass
class BlockRecord:
    """A block: consecutive pairs of one sequence and the frames they use (each frame stored once).

    sequence: sequence name (e.g. "00"); block_index: the block's number within the sequence (0, 1, ...).
    K: (3, 3) float64 intrinsics at the working size (pixels).
    frames: every frame referenced by ``pairs``, each once, any order (the writer sorts by frame_id).
    pairs: the block's pairs in order.
    """

    sequence: str
    block_index: int
    K: np.ndarray
    frames: list[FrameRecord]
    pairs: list[PairRecord]
