"""Registration on exact landings, for splits whose frame 2 holds frame 1's own points moved (``--pairing points``).

In a split written from correspondences (HPLFlowNet's stereoKITTI, FlowNet3D's ``kitti_rm_ground``, the image-grid
splits of :mod:`benchmarks.synth_stereo`) frame 2's points are frame 1's points moved by their flow, and the protocol
draws each frame's sample independently, so about ``n_points / N₂`` of frame 1's sampled points find their own
counterpart in frame 2's sample (:mod:`evaluation.pairing`). Under the right camera motion every static point whose
counterpart was kept lands *on* a frame-2 point — to the split's rounding, not to a sampling spacing — while a motion a
few centimetres off lands almost none within a few millimetres. So the number of frame-1 points that land within
``tight`` metres of a frame-2 point, each counted by how near it lands (:func:`landings`), scores a camera motion far
more sharply than any nearest-distance mean, and least squares on the pairs that land within a shrinking radius
(:func:`register_on_landings`) walks a motion that is centimetres off onto the exact one: the rigid polish's step 7
(:attr:`evaluation.rigid_polish.RigidPolishConfig.pairs_exact`, forty-fifth round). The same landings tell where a
flow is right (:func:`confirmed`): around a point whose neighbours it lands on frame-2 points, which the refinement
then keeps (:attr:`evaluation.optimise.RefineConfig.confirm_radius`).

No labels: only the two clouds and a start motion. Points in metres, camera frames (x right, y down, z forward);
transforms are 4×4 and map camera 1 to camera 2.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from evaluation.baselines.base import apply_transform, kabsch

#: the radii (metres) of the pairs each round of :func:`register_on_landings` refits on, widest first: the first
#: reaches a start a few centimetres off, the last pairs only points that already land
RADII_M = (0.1, 0.05, 0.02, 0.01, 0.005, 0.002, 0.001, 0.001)
MIN_PAIRS = 6  #: fewer pairs than this within a round's radius: the round is skipped (too few to fix a motion)

__all__ = ["landed", "landings", "register_on_landings", "confirmed", "RADII_M"]


def landed(moved: np.ndarray, pc2: np.ndarray, radius: float) -> np.ndarray:
    """(N,) bool: whether each of ``moved`` (N, 3, frame-1 points carried into camera 2) lies within ``radius`` metres
    of a point of ``pc2`` (M, 3); all false when either cloud is empty."""
    moved = np.asarray(moved, np.float64)
    if len(moved) == 0 or len(pc2) == 0:
        return np.zeros(len(moved), bool)
    return np.isfinite(cKDTree(np.asarray(pc2, np.float64)).query(moved, distance_upper_bound=radius)[0])


def landings(T: np.ndarray, points: np.ndarray, tree2: cKDTree, tight: float) -> float:
    """How many of ``points`` (N, 3, camera 1) moved by ``T`` (4, 4) land on a frame-2 point (``tree2``, the search
    tree of frame 2's points), each counted by how near: ``Σ max(0, 1 − d / tight)`` over the points' distances ``d``
    (metres) to their nearest frame-2 point. An exact landing counts 1 and one ``tight`` away or farther 0, so a motion
    a millimetre off scores below the exact one even where both land the same points within ``tight``."""
    if len(points) == 0:
        return 0.0
    dist = tree2.query(apply_transform(T, points), distance_upper_bound=tight)[0]
    near = np.isfinite(dist)
    return float((1.0 - dist[near] / tight).sum())


def register_on_landings(points: np.ndarray, pc2: np.ndarray, T: np.ndarray, tight: float,
                         radii: tuple[float, ...] = RADII_M, tree2: cKDTree | None = None) -> tuple[np.ndarray, float]:
    """``(T', n)``: the camera motion (4, 4) that lands the most of ``points`` (N, 3, camera 1; the points taken to
    move with the camera) within ``tight`` metres of a frame-2 point of ``pc2`` (M, 3), and that number ``n``
    (:func:`landings`).

    From the start ``T``, each round pairs every point with its nearest frame-2 point under the current motion,
    keeps the pairs closer than that round's radius (``radii``, metres, widest first and down to below ``tight``)
    and refits the motion to them by least squares (:func:`evaluation.baselines.base.kabsch`). The motion with the
    most landings among the start and the rounds is returned, so the answer never lands fewer points than the start:
    where frame 2 holds no counterparts (a re-scan) the start stands, up to a motion that lands a few more points by
    chance."""
    pts = np.asarray(points, np.float64)
    tree2 = cKDTree(np.asarray(pc2, np.float64)) if tree2 is None else tree2
    best, best_n = np.asarray(T, np.float64), landings(T, pts, tree2, tight)
    if len(pts) < MIN_PAIRS or tree2.n < MIN_PAIRS:
        return best, best_n
    current = best
    for radius in radii:
        dist, near = tree2.query(apply_transform(current, pts), distance_upper_bound=radius)
        paired = np.isfinite(dist)
        if paired.sum() < MIN_PAIRS:
            continue
        current = kabsch(pts[paired], tree2.data[near[paired]])
        n = landings(current, pts, tree2, tight)
        if n > best_n:
            best, best_n = current, n
    return best, best_n


def confirmed(pc1: np.ndarray, flow: np.ndarray, pc2: np.ndarray, radius: float, miss: float = 0.01,
              most: int = 64, least: int = 8, static: np.ndarray | None = None) -> np.ndarray:
    """(N,) bool: whether any of each point's k nearest frame-1 points (itself included) lands within ``radius``
    metres of a frame-2 point of ``pc2`` (M, 3) under ``flow`` (N, 3) at ``pc1`` (N, 3).

    Where frame 2 holds frame 1's points, a flow that is right around a point lands those of its neighbours whose
    counterparts the sampling kept on frame-2 points; one wrong by more than ``radius`` lands them only by chance. The
    share ``s`` of the points that land (of the ``static`` ones, (N,) bool, when given: the start's own guess of
    what moves with the camera) estimates how many counterparts the sampling kept, and k is the smallest
    neighbourhood in which a right flow lands none with a chance below ``miss``: ``(1 − s)^k < miss``, within
    [``least``, ``most``] (a fifth kept: 21 points; a twentieth: 64). With fewer points than k, all of them."""
    p1 = np.asarray(pc1, np.float64)
    lands = landed(p1 + np.asarray(flow, np.float64), pc2, radius)
    if not lands.any():
        return lands
    pool = lands if static is None or not np.any(static) else lands[np.asarray(static, bool)]
    share = float(pool.mean())
    k = most if share <= 0 else int(np.clip(np.ceil(np.log(miss) / np.log1p(-min(share, 1 - 1e-12))), least, most))
    k = min(k, len(p1))
    near = cKDTree(p1).query(p1, k)[1].reshape(len(p1), k)
    return lands[near].any(axis=1)
