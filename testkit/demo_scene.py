"""An analytic street scene, rendered by ray casting, for the cache's tests and benchmark.

Not the project's synthetic dataset generator (that is :mod:`pipeline.synth`); this is just enough
realism to measure the cache honestly: a road 1.65 m below the camera, building façades with windows on
both sides (with gaps for cross streets), parked boxes and one moving box, sky beyond 80 m (depth 0), and
sensor-like noise on the colours. The camera drives forward with a slight yaw.

Frames: camera x right, y down, z forward, metres. ``T_{t→t+1}`` maps camera-t to camera-(t+1) points.
Every frame is a pure function of (frame id, size, seed), so frames shared by two blocks are identical.
"""

from __future__ import annotations

import numpy as np

from pipeline.cache.points import canonical_depth, points_from_depth
from pipeline.cache.records import BlockRecord, FrameRecord, PairRecord
from pipeline.filters import FilterConfig, far_keep, ground_keep
from core.geometry import se3_inverse, static_flow

CAMERA_HEIGHT = 1.65
SPEED = 1.0  # metres per frame along the road
YAW_RATE = 0.004  # radians per frame
MOVER_SPEED = np.array([0.0, 0.0, 0.6])  # world metres per frame
SKY_DEPTH = 80.0

# axis-aligned boxes (world frame): (min xyz, max xyz, base colour); index 0 moves with MOVER_SPEED
_BOXES = [
    (np.array([1.2, 0.15, 14.0]), np.array([3.0, 1.65, 18.5]), (160, 30, 30)),
    (np.array([-4.6, 0.2, 9.0]), np.array([-2.9, 1.65, 13.3]), (40, 60, 150)),
    (np.array([2.9, 0.2, 30.0]), np.array([4.6, 1.65, 34.5]), (200, 200, 210)),
    (np.array([-4.5, 0.1, 40.0]), np.array([-2.8, 1.65, 44.4]), (30, 30, 35)),
]
_WALLS = [(-6.0, (150, 120, 100)), (7.0, (180, 170, 150))]  # x of the façade plane, colour
_GAPS = [(22.0, 27.0), (55.0, 62.0)]  # z ranges without buildings (cross streets)


def street_intrinsics(height: int = 256, width: int = 832) -> np.ndarray:
    """KITTI-like K (fx ≈ fy ≈ 0.58 · width) for an image of the given size, pixels."""
    f = 721.5377 * width / 1242.0
    return np.array([[f, 0.0, 0.49 * width], [0.0, 721.5377 * height / 375.0, 0.46 * height], [0.0, 0.0, 1.0]])


def camera_pose(frame_id: int) -> np.ndarray:
    """Camera-to-world 4×4 of frame ``frame_id`` (driving along +z with a slow yaw)."""
    a = YAW_RATE * frame_id
    T = np.eye(4)
    T[:3, :3] = [[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]]
    T[:3, 3] = [0.3 * np.sin(0.05 * frame_id), 0.0, SPEED * frame_id]
    return T


def relative_pose(frame_t: int, frame_t1: int) -> np.ndarray:
    """``T_{t→t1} = inv(Pose_t1) · Pose_t``."""
    return se3_inverse(camera_pose(frame_t1)) @ camera_pose(frame_t)


DEPTH_NOISE = 0.002
"""Relative white noise on depth, like a depth net's pixel-level texture: with it, a frame's stored depth
compresses to about what a real monocular prediction does (≈175 KB at 832×256, measured against
Self-Mono-SF's disparity of KITTI 2015 scene 000139); noise-free analytic planes would compress ~20× better."""


def render(
    frame_id: int, K: np.ndarray, height: int, width: int, seed: int = 0, depth_noise: float = DEPTH_NOISE
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(depth (H, W) float32 metres, 0 = sky; rgb (H, W, 3) uint8; moving (H, W) bool) of one frame."""
    pose = camera_pose(frame_id)
    v, u = np.meshgrid(np.arange(height, dtype=np.float64), np.arange(width, dtype=np.float64), indexing="ij")
    d_cam = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], -1)  # z = 1
    d = d_cam @ pose[:3, :3].T
    o = pose[:3, 3]
    best = np.full(u.shape, np.inf)
    colour = np.zeros(u.shape + (3,))
    moving = np.zeros(u.shape, bool)

    def hit(t: np.ndarray, ok: np.ndarray, col: np.ndarray, mov: bool = False) -> None:
        take = ok & (t > 0.1) & (t < best)
        best[take] = t[take]
        colour[take] = col[take] if col.ndim == 3 else col
        moving[take] = mov

    with np.errstate(divide="ignore", invalid="ignore"):
        # road: world y = CAMERA_HEIGHT
        t = (CAMERA_HEIGHT - o[1]) / d[..., 1]
        p = o + t[..., None] * d
        lane = (np.abs(p[..., 0] - 0.5) < 0.08) & (np.mod(p[..., 2], 6.0) < 3.0)
        g = 80 + 12 * np.sin(0.9 * p[..., 0]) * np.cos(0.4 * p[..., 2])
        road = np.where(lane[..., None], 220.0, g[..., None] * np.array([1.0, 1.0, 1.05]))
        hit(t, d[..., 1] > 0, road)
        # façades: planes x = const, 0.5 .. 14 m tall, except the cross-street gaps
        for x0, base in _WALLS:
            t = (x0 - o[0]) / d[..., 0]
            p = o + t[..., None] * d
            ok = (p[..., 1] > -12.0) & (p[..., 1] < CAMERA_HEIGHT)
            for z0, z1 in _GAPS:
                ok &= ~((p[..., 2] > z0) & (p[..., 2] < z1))
            window = (np.mod(p[..., 2], 3.2) > 1.0) & (np.mod(p[..., 1], 3.0) > 1.2) & (p[..., 1] < -0.5)
            shade = 1.0 + 0.08 * np.sin(1.7 * p[..., 2] + x0)
            col = np.where(window[..., None], np.array([60.0, 70.0, 85.0]), shade[..., None] * np.array(base, float))
            hit(t, ok, col)
        # boxes (slab test); box 0 is displaced by its motion
        for k, (lo, hi, base) in enumerate(_BOXES):
            shift = MOVER_SPEED * frame_id if k == 0 else 0.0
            t0 = (lo + shift - o) / d
            t1 = (hi + shift - o) / d
            tn = np.max(np.minimum(t0, t1), axis=-1)
            tf = np.min(np.maximum(t0, t1), axis=-1)
            p = o + tn[..., None] * d
            stripe = 1.0 + 0.15 * (np.mod(p[..., 1] * 4.0, 2.0) > 1.0)
            hit(tn, tn <= tf, stripe[..., None] * np.array(base, float), mov=(k == 0))
    sky = best > SKY_DEPTH
    rng = np.random.default_rng([seed, frame_id])
    best = best * (1.0 + depth_noise * rng.standard_normal(best.shape))
    depth = np.where(sky, 0.0, best).astype(np.float32)  # t along d with d_z(camera) = 1 is the depth z
    sky_col = np.stack([120 + 60 * v / height, 160 + 40 * v / height, 230 + 0 * v], -1)
    colour[sky] = sky_col[sky]
    colour += rng.normal(0.0, 3.0, colour.shape)  # sensor noise
    rgb = np.clip(np.rint(colour), 0, 255).astype(np.uint8)
    return depth, rgb, moving & ~sky


def keep_mask(depth: np.ndarray, K: np.ndarray) -> np.ndarray:
    """The cache tests' stand-in for stage one's filters: valid depth, then stage one's ground and far filters
    (:mod:`pipeline.filters`) at their defaults (y < 1.15 m, z < 35 m); no LiDAR-range or occlusion check."""
    H, W = depth.shape
    idx = np.arange(H * W)
    p = points_from_depth(depth, idx, K)
    filters = FilterConfig()
    return ((p[:, 2] > 0) & ground_keep(p, filters.ground_max_y) & far_keep(p, filters.far_max_z)).reshape(H, W)


def street_block(
    sequence: str,
    block_index: int,
    pairs_per_block: int = 4,
    height: int = 256,
    width: int = 832,
    seed: int = 0,
    with_truth: bool = True,
) -> BlockRecord:
    """Block ``block_index`` of a street sequence: pairs (t, t+1) for t = block_index·P … block_index·P + P − 1."""
    K = street_intrinsics(height, width)
    first = block_index * pairs_per_block
    ids = list(range(first, first + pairs_per_block + 1))
    frames, masks, movers = [], {}, {}
    for fid in ids:
        depth, rgb, moving = render(fid, K, height, width, seed)
        depth = canonical_depth(depth)
        frames.append(FrameRecord(frame_id=fid, depth=depth, rgb=rgb))
        masks[fid] = keep_mask(depth, K)
        movers[fid] = moving
    by_id = {f.frame_id: f for f in frames}
    pair_records = []
    for t in ids[:-1]:
        idx1 = np.flatnonzero(masks[t]).astype(np.int32)
        idx2 = np.flatnonzero(masks[t + 1]).astype(np.int32)
        T = relative_pose(t, t + 1)
        gt = mov = None
        if with_truth:
            pc1 = points_from_depth(by_id[t].depth, idx1, K)
            mov = movers[t].reshape(-1)[idx1]
            # a moving point's world displacement, seen in camera t+1, added to the static motion
            m_cam = camera_pose(t + 1)[:3, :3].T @ MOVER_SPEED
            gt = (static_flow(pc1, T, as_float32=True) + mov[:, None] * m_cam.astype(np.float32)).astype(np.float32)
        stats = {"pixels": height * width, "valid": int((by_id[t].depth > 0).sum()), "kept": int(idx1.size)}
        pair_records.append(PairRecord(t, t + 1, idx1, idx2, T, 1.0, stats, gt, mov))
    return BlockRecord(sequence=sequence, block_index=block_index, K=K, frames=frames, pairs=pair_records)


__all__ = ["camera_pose", "keep_mask", "relative_pose", "render", "street_block", "street_intrinsics"]
