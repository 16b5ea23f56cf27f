"""The four point filters of stage one (docs/design.md §3.6): ground, sky/far, LiDAR range, occlusion.

Each filter is a *keep* mask over camera-frame points (x right, y down, z forward, metres); thresholds
are options of :class:`FilterConfig` and every filter can be switched off. The masks are pure functions
of their inputs (no I/O), so :mod:`pipeline.pairs` can apply them in a fixed order and count what each
one removes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from core.errors import ConfigError


#: The order in which :mod:`pipeline.pairs` applies the filters (and names them in its stats).
FILTER_NAMES = ("ground", "far", "lidar", "occlusion")

FAR_LIMIT_M = 35.0
"""The far limit, metres of camera z (x right, y down, z forward): points with ``z >= 35`` are dropped.

One idea used in two places: stage one's sky/far filter (the default of :attr:`FilterConfig.far_max_z` and
:func:`far_keep`, the paper's value) and the KITTI scene-flow test protocols' depth limit (FlowNet3D / FLOT
keep camera z < 35 m, HPLFlowNet's ``DEPTH_THRESHOLD = 35``; ``docs/evaluation-protocols.md``) — the paper
trains on the range the benchmark scores. The evaluation's distance bands split there too
(:data:`evaluation.metrics.BANDS`)."""

#: Velodyne → image_2 camera of KITTI's standard mount, used when a calibration has no ``Tr``:
#: velodyne x forward / y left / z up → camera x right / y down / z forward; the scanner sits
#: ≈ 0.08 m above and 0.27 m behind cam0, and a cam0 point has x ≈ +0.06 m in image_2
#: (``P2[0,3] / P2[0,0]``), so the scanner's origin is ≈ (+0.06, −0.08, −0.27) in image_2's frame.
KITTI_DEFAULT_VELO_TO_CAM = np.array(
    [
        [0.0, -1.0, 0.0, 0.06],
        [0.0, 0.0, -1.0, -0.08],
        [1.0, 0.0, 0.0, -0.27],
        [0.0, 0.0, 0.0, 1.0],
    ]
)


def transform_columns(T: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(x, y, z) float64 columns of ``R p + t`` for points (N, 3) and a 4×4 (or 3×4) T.

    Column arithmetic: numpy's ``(N, 3) @ (3, 3)`` matmul is 10–20× slower for clouds this size.
    """
    T = np.asarray(T, dtype=np.float64)
    x = points[:, 0].astype(np.float64)
    y = points[:, 1].astype(np.float64)
    z = points[:, 2].astype(np.float64)
    return tuple(T[i, 0] * x + T[i, 1] * y + T[i, 2] * z + T[i, 3] for i in range(3))


@dataclass
class FilterConfig:
    """Switches and thresholds of the four filters (docs/design.md §3.6; the paper's values are the defaults)."""

    ground: bool = field(default=True, metadata={"help": "remove ground points (y >= ground_max_y)"})
    ground_max_y: float = field(default=1.15, metadata={"help": "metres below the camera centre (y down)"})
    far: bool = field(default=True, metadata={"help": "remove sky / far points (z >= far_max_z)"})
    far_max_z: float = field(default=FAR_LIMIT_M, metadata={"help": "metres along the optical axis"})
    lidar: bool = field(default=True, metadata={"help": "remove what an HDL-64E at the velodyne pose cannot see"})
    lidar_max_elevation_deg: float = field(default=2.0, metadata={"help": "upper edge of the scanner's fan"})
    lidar_min_elevation_deg: float = field(default=-24.8, metadata={"help": "lower edge of the scanner's fan"})
    lidar_max_range: float = field(default=120.0, metadata={"help": "metres from the scanner"})
    occlusion: bool = field(default=True, metadata={"help": "remove points failing the depth-consistency check"})
    occlusion_threshold: float = field(
        default=0.5, metadata={"help": "remove where |D_proj - D_next| / (D_proj + D_next) >= this"}
    )

    def check(self) -> "FilterConfig":
        """Raise ConfigError for thresholds that would silently drop every point (or are not numbers)."""
        import math

        values = {f: float(getattr(self, f)) for f in ("ground_max_y", "far_max_z", "lidar_max_elevation_deg",
                                                       "lidar_min_elevation_deg", "lidar_max_range", "occlusion_threshold")}
        bad = [f"{k} = {v}" for k, v in values.items() if not math.isfinite(v)]
        if self.far and not values["far_max_z"] > 0:
            bad.append(f"far_max_z = {values['far_max_z']} (must be > 0 m: nothing lies nearer)")
        if self.lidar and not values["lidar_max_range"] > 0:
            bad.append(f"lidar_max_range = {values['lidar_max_range']} (must be > 0 m)")
        if self.lidar and not values["lidar_min_elevation_deg"] < values["lidar_max_elevation_deg"]:
            bad.append("lidar_min_elevation_deg must be < lidar_max_elevation_deg")
        if self.occlusion and not values["occlusion_threshold"] > 0:
            bad.append(f"occlusion_threshold = {values['occlusion_threshold']} (must be > 0)")
        if bad:
            raise ConfigError(f"filters: {'; '.join(bad)}")
        return self

    def enabled(self) -> tuple[str, ...]:
        """Names of the switched-on filters, in application order."""
        return tuple(name for name in FILTER_NAMES if getattr(self, name))


def ground_keep(points: np.ndarray, max_y: float = 1.15) -> np.ndarray:
    """Keep points above the ground: ``y < max_y`` (metres, y down). points (…, 3) → (…,) bool."""
    return points[..., 1] < max_y


def far_keep(points: np.ndarray, max_z: float = FAR_LIMIT_M) -> np.ndarray:
    """Keep points nearer than ``max_z`` metres along the optical axis: ``z < max_z``."""
    return points[..., 2] < max_z


def lidar_keep(
    points: np.ndarray,
    T_velo_to_cam: np.ndarray | None = None,
    min_elevation_deg: float = -24.8,
    max_elevation_deg: float = 2.0,
    max_range: float = 120.0,
) -> np.ndarray:
    """Keep points an HDL-64E at the velodyne pose could see.

    The points (…, 3), camera frame, are moved into the velodyne frame (x forward, y left, z up) with
    ``inv(T_velo_to_cam)`` (4×4; :data:`KITTI_DEFAULT_VELO_TO_CAM` when None); a point is kept when its
    elevation ``atan2(z, hypot(x, y))`` lies in [min, max] degrees and its range is at most ``max_range``.
    """
    T = KITTI_DEFAULT_VELO_TO_CAM if T_velo_to_cam is None else np.asarray(T_velo_to_cam, dtype=np.float64)
    shape = points.shape[:-1]
    x, y, z = transform_columns(np.linalg.inv(T), points.reshape(-1, 3))
    horizontal = np.hypot(x, y)
    elevation = np.arctan2(z, horizontal)
    rng = np.hypot(horizontal, z)
    lo, hi = math.radians(min_elevation_deg), math.radians(max_elevation_deg)
    return ((elevation >= lo) & (elevation <= hi) & (rng <= max_range)).reshape(shape)


def sample_depth(depth: np.ndarray, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Bilinear sample of a depth map (H, W) at pixel coordinates uv (N, 2) → (values (N,), ok (N,)).

    Only valid neighbours (depth > 0, finite) take part; their weights are renormalised, so sparse or
    holed depth maps do not pull values towards 0. ``ok`` is False where no neighbour is valid or uv is
    outside the image. Values where not ok are 0.
    """
    H, W = depth.shape
    u = uv[:, 0].astype(np.float64)
    v = uv[:, 1].astype(np.float64)
    inside = (u >= 0) & (u <= W - 1) & (v >= 0) & (v <= H - 1)
    u = np.where(inside, u, 0.0)
    v = np.where(inside, v, 0.0)
    u0 = np.minimum(np.floor(u).astype(np.int64), W - 1)
    v0 = np.minimum(np.floor(v).astype(np.int64), H - 1)
    u1 = np.minimum(u0 + 1, W - 1)
    v1 = np.minimum(v0 + 1, H - 1)
    fu = u - u0
    fv = v - v0
    flat = depth.reshape(-1)
    acc = np.zeros(u.shape, dtype=np.float64)
    wsum = np.zeros(u.shape, dtype=np.float64)
    for vv, uu, w in ((v0, u0, (1 - fu) * (1 - fv)), (v0, u1, fu * (1 - fv)), (v1, u0, (1 - fu) * fv), (v1, u1, fu * fv)):
        d = flat[vv * W + uu].astype(np.float64)
        good = (d > 0) & np.isfinite(d) & (w > 0)
        acc += np.where(good, w * np.where(good, d, 0.0), 0.0)
        wsum += np.where(good, w, 0.0)
    ok = inside & (wsum > 1e-9)
    values = np.where(ok, acc / np.where(ok, wsum, 1.0), 0.0)
    return values, ok


def occlusion_keep(
    points: np.ndarray,
    T_src_to_dst: np.ndarray,
    depth_dst: np.ndarray,
    K: np.ndarray,
    threshold: float = 0.5,
) -> np.ndarray:
    """SC-SfMLearner depth-consistency check of source-frame points against the destination depth map.

    points (N, 3): source-camera frame, metres. ``T_src_to_dst`` (4, 4) moves them into the destination
    camera; they are projected with K (3, 3) to (u', v'), and ``D_dst`` is sampled there bilinearly
    (:func:`sample_depth`). A point is kept when it lands inside the image, in front of the camera
    (z > 0), on valid depth, and ``|D_proj − D_dst(u', v')| / (D_proj + D_dst(u', v')) < threshold``.
    Returns (N,) bool.
    """
    H, W = depth_dst.shape
    x, y, z = transform_columns(T_src_to_dst, points)
    K = np.asarray(K, dtype=np.float64)
    front = z > 1e-6
    zs = np.where(front, z, 1.0)
    u = K[0, 0] * x / zs + K[0, 1] * y / zs + K[0, 2]
    v = K[1, 1] * y / zs + K[1, 2]
    d_dst, ok = sample_depth(depth_dst, np.stack([u, v], axis=-1))  # ok implies inside the image
    with np.errstate(divide="ignore", invalid="ignore"):
        diff = np.abs(z - d_dst) / (z + d_dst)
    return front & ok & (diff < threshold)


__all__ = [
    "FAR_LIMIT_M",
    "FILTER_NAMES",
    "FilterConfig",
    "KITTI_DEFAULT_VELO_TO_CAM",
    "far_keep",
    "ground_keep",
    "lidar_keep",
    "occlusion_keep",
    "sample_depth",
    "transform_columns",
]
