"""Augmentations that bridge stage one's camera clouds and LiDAR test clouds (``DataConfig``).

Stage one's clouds are back-projected depth pixels: one point per kept pixel, both frames sampled on
the image grid, the ground removed at a fixed height below the camera (``FilterConfig.ground_max_y``). The KITTI scene-flow test clouds are LiDAR scans:
points on the scanner's rings, a density that changes between the two frames, and the ground removed by
a height threshold that leaves a varying rim of low points. A net that only saw the first kind learns
their regularities. Each augmentation picks a subset of a pair's points (frames: camera, x right, y down,
z forward, metres), seeded by the pair's draw, before the ``n_points`` are sampled:

* ``lidar_rings`` (probability per pair): keep the points near horizontal scan rings of the camera
  centre — elevation ``atan2(−y, √(x² + z²))`` within a band of ``ring_band`` of the ring spacing, spacing
  drawn in [0.3°, 0.5°] (HDL-64E: ≈0.4°) and phase at random, the same rings for both frames (the
  sensor moves, so they hit other surface points in frame t+1, as a real scanner's do);
* ``density_drop`` (fraction): frame t+1 loses a random share of up to this fraction of its points;
* ``ground_jitter_m`` (metres): both frames lose the points lower than a cut drawn up to this far
  above the lowest remaining points (the 99th percentile of y in frame t).

Two augmentations change the motion instead of the points kept: ``ego_speed_scale`` (:func:`speed_scaled_view`)
makes a pair look as if the camera had moved a factor faster or slower between t and t+1, so that the
net meets camera speeds beyond the few the training sequences drove at; ``ego_turn_deg`` / ``ego_shift_m``
(:func:`turn_shift_view`) turn and shift frame t's camera at random, so that the motion between the
frames no longer follows the way the sequences drove. ``synthetic_movers`` (:func:`synthetic_mover`) moves one
object-sized cluster of frame t's points, so that it arrives where frame t+1 shows it from somewhere else: a
mover of a speed and heading the world never drove, made from the pair's own points. Another changes the street:
``mirror`` (:func:`mirror_pair`) reflects a whole pair left–right, a street the world never drove (traffic
on the other side, every turn the other way), with the depth map and intrinsics reflected to match.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from core.clusters import object_clusters

RING_SPACING_DEG = (0.3, 0.5)
MOVER_YAW_DEG = 5.0  # the moved cluster also turns about its vertical axis by up to this


def ring_mask(points: np.ndarray, spacing_deg: float, phase: float, band: float) -> np.ndarray:
    """Points (N, 3) whose elevation lies within ``band`` (fraction of a spacing) of a ring."""
    elev = np.degrees(np.arctan2(-points[:, 1], np.hypot(points[:, 0], points[:, 2])))
    frac = np.mod(elev / spacing_deg - phase, 1.0)
    return frac < band


def augment_masks(rng: np.random.Generator, pc1: np.ndarray, pc2: np.ndarray, lidar_rings: float = 0.0,
                  ring_band: float = 0.5, density_drop: float = 0.0, ground_jitter_m: float = 0.0
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Boolean masks of the points of pc1 (N1, 3) and pc2 (N2, 3) that the augmentations keep.

    Draws from ``rng`` only for the augmentations that are on, so a config with all of them off gives
    the same draws as before they existed. A mask never empties a cloud: an augmentation that would leave
    fewer than 64 points of either cloud is skipped for that pair.
    """
    keep1 = np.ones(len(pc1), bool)
    keep2 = np.ones(len(pc2), bool)

    def apply(m1: np.ndarray, m2: np.ndarray) -> None:
        nonlocal keep1, keep2
        if (keep1 & m1).sum() >= 64 and (keep2 & m2).sum() >= 64:
            keep1, keep2 = keep1 & m1, keep2 & m2

    if lidar_rings > 0 and rng.random() < lidar_rings:
        spacing, phase = rng.uniform(*RING_SPACING_DEG), rng.random()
        apply(ring_mask(pc1, spacing, phase, ring_band), ring_mask(pc2, spacing, phase, ring_band))
    if density_drop > 0:
        share = rng.uniform(0.0, density_drop)
        apply(np.ones(len(pc1), bool), rng.random(len(pc2)) >= share)
    if ground_jitter_m > 0 and len(pc1):
        cut = np.percentile(pc1[:, 1], 99.0) - rng.uniform(0.0, ground_jitter_m)
        apply(pc1[:, 1] <= cut, pc2[:, 1] <= cut)
    return keep1, keep2


def speed_scaled_view(T: np.ndarray, scale: float) -> np.ndarray:
    """The 4×4 rigid motion ``A`` that moves frame t's camera so that the pair's ego-motion becomes ``scale``
    times ``T`` (``T_{t→t+1}``: camera-t coordinates to camera-(t+1), metres).

    Scaling a motion: its rotation angle about the same axis and its translation are both multiplied by
    ``scale`` (the same path curvature driven ``scale`` times as far), ``T' = (R^scale, scale · t)``. Frame
    t+1 stays where it is, so its cloud, its depth map and every target in its frame are untouched; frame
    t's points become ``A p`` with ``A = T'⁻¹ T`` (then ``T' A p = T p``: a static point lands where it did),
    and a flow target ``f`` at ``p`` becomes ``p + f − A p``. Only the depth-consistency term's
    back-projection at the source pixel sees the new camera-t position, as it would for a real camera there.
    """
    T = np.asarray(T, dtype=np.float64)
    Ts = np.eye(4)
    Ts[:3, :3] = Rotation.from_rotvec(scale * Rotation.from_matrix(T[:3, :3]).as_rotvec()).as_matrix()
    Ts[:3, 3] = scale * T[:3, 3]
    return np.linalg.inv(Ts) @ T


def turn_shift_view(rng: np.random.Generator, turn_deg: float, shift_m: float) -> np.ndarray:
    """A 4×4 rigid motion of frame t's camera: a turn about its y axis (vertical, camera frame) by an angle
    drawn uniformly in ± ``turn_deg`` degrees, then a shift of (x, 0, z) with each of x, z drawn uniformly in
    ± ``shift_m`` metres. Used like :func:`speed_scaled_view`: frame t's points become ``A p``, frame t+1 and
    every target in its frame stay, so a flow target ``f`` at ``p`` becomes ``p + f − A p``."""
    A = np.eye(4)
    A[:3, :3] = Rotation.from_rotvec([0.0, np.radians(rng.uniform(-turn_deg, turn_deg)), 0.0]).as_matrix()
    A[[0, 2], 3] = rng.uniform(-shift_m, shift_m, size=2)
    return A


def synthetic_mover(rng: np.random.Generator, pc1: np.ndarray, motion_m: tuple[float, float],
                    yaw_deg: float = MOVER_YAW_DEG) -> tuple[np.ndarray, np.ndarray] | None:
    """One object-sized cluster of frame t's points (``pc1`` (N, 3), camera t: x right, y down, z forward,
    metres; :func:`object_clusters`), drawn uniformly, and where it stood at time t had it moved: its points
    (indices, (k, 3)) turned about the cluster's vertical axis through its centroid by an angle uniform in
    ± ``yaw_deg`` degrees, then shifted back along a horizontal (x–z) heading drawn uniformly over the circle
    by a length drawn uniformly in ``motion_m`` (metres per frame). Frame t+1 is not touched, so the points'
    flow targets stay where they are: between the frames the cluster moves on its own by that much (the
    inverse turn and shift), which the Chamfer and depth terms see and stage one's static flow does not. None
    when the cloud has no such cluster."""
    clusters = object_clusters(pc1)
    if not clusters:
        return None
    idx = clusters[rng.integers(len(clusters))]
    yaw = np.radians(rng.uniform(-yaw_deg, yaw_deg))
    heading = rng.uniform(0.0, 2.0 * np.pi)
    length = rng.uniform(*motion_m)
    pts = pc1[idx].astype(np.float64)
    centre = pts.mean(0)
    R = Rotation.from_rotvec([0.0, yaw, 0.0]).as_matrix()
    back = length * np.array([np.sin(heading), 0.0, np.cos(heading)])
    return idx, (pts - centre) @ R.T + centre - back


def draw_speed_scale(rng: np.random.Generator, low: float, high: float) -> float:
    """A factor drawn log-uniformly in [low, high] (so ×2 and ×½ are equally likely); no draw when equal."""
    if low == high:
        return float(low)
    return float(np.exp(rng.uniform(np.log(low), np.log(high))))


def mirror_pair(sample: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The pair reflected left–right (x → −x in both camera frames), in place of ``sample``'s arrays.

    A reflected street is as physical as the original one, so every loss keeps its meaning if the
    frame-(t+1) depth map and the intrinsics are reflected with the points: a point (x, y, z) projects to
    column ``u = fx x / z + cx``; its mirror (−x, y, z) must land on the mirrored column ``W − 1 − u``, so
    ``cx' = W − 1 − cx`` and ``depth2'[:, u] = depth2[:, W − 1 − u]``. Points, static flow and the flow
    target are (N, 3) metres, camera frames (x right, y down, z forward); K (3, 3) pixels; depth2 (H, W).
    """
    out = dict(sample)
    flip = np.array([-1.0, 1.0, 1.0], np.float32)
    for key in ("pc1", "pc2", "static_flow", "gt_flow", "pc2_target"):
        if key in out:
            out[key] = (out[key] * flip).astype(np.float32)
    K = np.array(out["K"], np.float32)
    width = out["depth2"].shape[1]
    K[0, 2] = (width - 1) - K[0, 2]
    K[0, 1] = -K[0, 1]  # a skew term changes sign with x (zero for every camera here)
    out["K"] = K
    out["depth2"] = np.ascontiguousarray(out["depth2"][:, ::-1])
    return out
