"""Metric scale of monocular depth and pose (docs/design.md §3.4).

A monocular depth net and pose net agree on a common but unknown scale. The factor ``s`` found here
multiplies every depth map *and* every translation of the same block, so static flow stays
consistent. Poses read from the dataset are metric already: their translations are left alone unless
``scale_translation`` says otherwise. Modes:

* ``none``: the inputs are already metric (ground truth, LiDAR, stereo disparity); ``s = 1``.
* ``fixed``: a given factor.
* ``lidar``: ``median(D_lidar / D)`` over pixels where both are valid (the released code's recipe).
* ``camera-height``: RANSAC road-plane fit on back-projected points of the lower image part, ``s =
  camera_height / (distance of the camera centre to that plane)`` — purely monocular.

Per block, :func:`combine_factors` takes the median of the per-frame factors (robust to one frame whose
plane fit fails). Camera frame: x right, y down, z forward; depth is z in the net's units.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field

import numpy as np

from core.errors import ConfigError, MonoflowError
from core.geometry import backproject, pixel_grid

SCALE_MODES = ("none", "fixed", "lidar", "camera-height")
SCALE_FALLBACKS = ("carry", "abort")
#: Depth sources whose maps are metric already (no scale factor needed).
METRIC_DEPTH_SOURCES = ("gt", "lidar", "disparity")
#: A block whose median valid depth (after scaling) lies outside this range (metres) does not look metric.
PLAUSIBLE_MEDIAN_DEPTH_M = (1.0, 150.0)


@dataclass
class ScaleConfig:
    """How the block's common depth / translation factor is found."""

    mode: str = field(default="none", metadata={"help": "none | fixed | lidar | camera-height"})
    factor: float = field(default=1.0, metadata={"help": "the factor of mode 'fixed'"})
    camera_height: float = field(default=1.65, metadata={"help": "metres of the camera above the road (KITTI 1.65)"})
    horizon_margin: float = field(
        default=0.15, metadata={"help": "camera-height: skip this fraction of the rows between horizon (cy) and bottom"}
    )
    column_fraction: float = field(default=0.6, metadata={"help": "camera-height: central fraction of columns used"})
    max_tilt_deg: float = field(default=25.0, metadata={"help": "camera-height: largest plane tilt from level"})
    inlier_tolerance: float = field(
        default=0.02, metadata={"help": "camera-height: inlier distance to the plane as a fraction of the camera height"}
    )
    iterations: int = field(default=300, metadata={"help": "camera-height: RANSAC hypotheses"})
    max_points: int = field(default=20000, metadata={"help": "camera-height: points subsampled for the fit"})
    seed: int = field(default=0, metadata={"help": "camera-height: RANSAC seed (results are deterministic)"})
    scale_translation: bool | None = field(
        default=None,
        metadata={"help": "multiply pose translations by the factor too; none = only when the pose comes from the net"},
    )
    fallback: str = field(
        default="carry",
        metadata={"help": "a block where no frame gives a factor (no road plane found): 'carry' = take the last "
                          "good factor of the sequence (the sequence median when there is none yet) and count it; "
                          "'abort' = stop with an error"},
    )
    refuse_non_metric: bool = field(
        default=False,
        metadata={"help": "stop (instead of warning loudly) when the clouds cannot be metric or the depth and "
                          "pose scales disagree (e.g. --depth net with --scale.mode none)"},
    )

    def __post_init__(self) -> None:
        if self.mode not in SCALE_MODES:
            raise ConfigError(f"scale mode must be one of {', '.join(SCALE_MODES)}, got {self.mode!r}")
        if not (np.isfinite(self.factor) and self.factor > 0):
            raise ConfigError(f"scale factor must be a positive number, got {self.factor}")
        if self.camera_height <= 0:
            raise ConfigError(f"camera_height must be positive, got {self.camera_height}")
        if self.fallback not in SCALE_FALLBACKS:
            raise ConfigError(f"scale fallback must be one of {', '.join(SCALE_FALLBACKS)}, got {self.fallback!r}")


class ScaleError(MonoflowError):
    """A frame gives no usable scale (no overlap with LiDAR, no road plane found)."""


def lidar_scale(depth: np.ndarray, lidar_depth: np.ndarray) -> float:
    """``median(lidar_depth / depth)`` over pixels where both maps are valid (> 0, finite); same (H, W)."""
    if depth.shape != lidar_depth.shape:
        raise ValueError(f"depth {depth.shape} and LiDAR depth {lidar_depth.shape} differ in shape")
    ok = np.isfinite(depth) & (depth > 0) & np.isfinite(lidar_depth) & (lidar_depth > 0)
    if not ok.any():
        raise ScaleError("no pixel has both a depth and a LiDAR return")
    return float(np.median(lidar_depth[ok].astype(np.float64) / depth[ok].astype(np.float64)))


@dataclass
class PlaneFit:
    """A plane ``n · p = d`` in camera coordinates (n unit, pointing down: n_y > 0; d = camera height)."""

    normal: np.ndarray
    d: float
    inliers: int
    candidates: int


def road_region_points(depth: np.ndarray, K: np.ndarray, config: ScaleConfig) -> np.ndarray:
    """Back-projected points (N, 3) of the road region: rows below the horizon (v > cy + margin), central columns.

    Only pixels with valid depth; at most ``config.max_points``, taken with a regular stride (deterministic).
    """
    H, W = depth.shape
    cy = float(K[1, 2])
    top = cy + config.horizon_margin * max(H - 1 - cy, 0.0)
    half = 0.5 * config.column_fraction * W
    uv = pixel_grid(H, W)
    region = (uv[..., 1] > top) & (np.abs(uv[..., 0] - 0.5 * (W - 1)) <= half)
    region &= np.isfinite(depth) & (depth > 0)
    d = depth[region].astype(np.float64)
    pix = uv[region]
    if d.size > config.max_points:
        step = int(np.ceil(d.size / config.max_points))
        d, pix = d[::step], pix[::step]
    return backproject(d, np.asarray(K, dtype=np.float64), pix)


def fit_road_plane(points: np.ndarray, config: ScaleConfig) -> PlaneFit:
    """RANSAC plane through ``points`` (N, 3) that is nearly level (tilt ≤ max_tilt_deg) and below the camera.

    A point is an inlier of plane ``n · p = d`` when ``|n · p − d| < inlier_tolerance · d``: a road point
    whose depth is off by a fraction e lies ``e · d`` off the plane, whatever its distance, so the
    tolerance is a relative depth error and the fit is scale-free. The hypothesis with the most inliers
    is refined by least squares (SVD) over its inliers, re-selected each round.
    """
    n_pts = points.shape[0]
    if n_pts < 3:
        raise ScaleError(f"only {n_pts} road-region points")
    unit = float(np.median(points[:, 2]))
    if not unit > 0:
        raise ScaleError("road-region points have no positive depth")
    P = points / unit  # numerically tidy; the result is scaled back
    tol = config.inlier_tolerance
    cos_tilt = np.cos(np.radians(config.max_tilt_deg))
    rng = np.random.default_rng(config.seed)
    picks = rng.integers(0, n_pts, size=(config.iterations, 3))
    a, b, c = P[picks[:, 0]], P[picks[:, 1]], P[picks[:, 2]]
    normals = np.cross(b - a, c - a)
    norms = np.linalg.norm(normals, axis=1)
    good = norms > 1e-12
    normals[good] /= norms[good, None]
    normals *= np.where(normals[:, 1:2] < 0, -1.0, 1.0)  # point down (+y)
    ds = np.einsum("ij,ij->i", normals, a)
    good &= (normals[:, 1] >= cos_tilt) & (ds > 0)
    if not good.any():
        raise ScaleError("no level plane below the camera among the RANSAC hypotheses")
    best_count, best = -1, None
    for n, d in zip(normals[good], ds[good]):
        count = int(np.count_nonzero(np.abs(P @ n - d) < tol * d))
        if count > best_count:
            best_count, best = count, (n, d)
    n, d = best
    inl = np.abs(P @ n - d) < tol * d
    for _ in range(3):  # least-squares refinement, re-selecting the inliers each round
        if np.count_nonzero(inl) < 3:
            raise ScaleError("road-plane refinement lost its inliers")
        Q = P[inl]
        centre = Q.mean(axis=0)
        _, _, vt = np.linalg.svd(Q - centre, full_matrices=False)
        n = vt[-1] * (1.0 if vt[-1][1] >= 0 else -1.0)
        d = float(n @ centre)
        inl = np.abs(P @ n - d) < tol * abs(d)
    if not (n[1] >= cos_tilt and d > 0):
        raise ScaleError("refined road plane is not level or not below the camera")
    return PlaneFit(normal=n, d=d * unit, inliers=int(np.count_nonzero(inl)), candidates=n_pts)


def camera_height_scale(depth: np.ndarray, K: np.ndarray, config: ScaleConfig | None = None) -> float:
    """Factor that puts the camera ``config.camera_height`` metres above the fitted road plane."""
    config = config or ScaleConfig(mode="camera-height")
    plane = fit_road_plane(road_region_points(depth, K, config), config)
    return config.camera_height / plane.d


def frame_factor(config: ScaleConfig, depth: np.ndarray, K: np.ndarray, lidar_depth: np.ndarray | None = None) -> float:
    """This frame's scale factor under ``config.mode``; raises :class:`ScaleError` when it has none."""
    if config.mode == "none":
        return 1.0
    if config.mode == "fixed":
        return float(config.factor)
    if config.mode == "lidar":
        if lidar_depth is None:
            raise ConfigError("scale mode 'lidar' needs projected LiDAR depth (velodyne scans and Tr)")
        return lidar_scale(depth, lidar_depth)
    return camera_height_scale(depth, K, config)


def combine_factors(factors: list[float]) -> float:
    """The block's factor: median of the frames' factors (NaN entries — failed frames — are skipped)."""
    f = np.asarray([x for x in factors if np.isfinite(x) and x > 0], dtype=np.float64)
    if f.size == 0:
        raise ScaleError("no frame of the block gave a scale factor")
    return float(np.median(f))


def scale_consistency_problems(depth: str, pose: str, config: ScaleConfig) -> list[str]:
    """Why clouds made with these sources and this scale config would not be metric, or would mix scales.

    ``depth`` / ``pose``: stage one's source names (``net``, ``gt``, ...). Empty list = consistent.
    """
    problems = []
    metric_depth = depth in METRIC_DEPTH_SOURCES
    scales_t = pose == "net" if config.scale_translation is None else bool(config.scale_translation)
    if depth == "net" and config.mode == "none":
        problems.append("depth comes from the net and --scale.mode is 'none': the clouds are in the net's unknown "
                        "scale, not metres, so the metric filters (ground 1.15 m, far 35 m, LiDAR range) and the "
                        "flow net's units are meaningless; use --scale.mode camera-height (no LiDAR needed), "
                        "lidar or fixed")
    if metric_depth and pose == "net" and config.mode in ("none", "fixed"):
        problems.append(f"depth '{depth}' is metric but the pose net's translations are in its own unknown scale "
                        "(nothing aligns them): the static flow mixes two scales; use --pose gt, or depth and pose "
                        "from the same nets with a scale mode")
    if pose == "gt" and scales_t and config.mode != "none":
        problems.append("the dataset's poses are metric but --scale.scale_translation true multiplies their "
                        "translations by the depth factor: depth and pose scales disagree")
    return problems


def announce_scale_problems(depth: str, pose: str, config: ScaleConfig) -> list[str]:
    """:func:`scale_consistency_problems`, said before any work: with ``refuse_non_metric`` a ConfigError
    naming the first, else one ``WARNING:`` line each on stderr (the run goes on). Returns the problems."""
    problems = scale_consistency_problems(depth, pose, config)
    if problems and config.refuse_non_metric:
        raise ConfigError(problems[0] + " (--scale.refuse_non_metric true)")
    for problem in problems:
        print(f"WARNING: {problem}", file=sys.stderr)
    return problems


def implausible_depth(depths: np.ndarray) -> str | None:
    """A sentence when the median valid depth of ``depths`` (metres, 0 = invalid) is outside
    :data:`PLAUSIBLE_MEDIAN_DEPTH_M` (a street scene's median lies between them), else None."""
    d = depths[np.isfinite(depths) & (depths > 0)]
    if d.size == 0:
        return "no valid depth at all"
    med = float(np.median(d))
    lo, hi = PLAUSIBLE_MEDIAN_DEPTH_M
    if lo <= med <= hi:
        return None
    return f"median depth {med:.3g} m is outside {lo:g}..{hi:g} m: the clouds do not look metric"


__all__ = [
    "METRIC_DEPTH_SOURCES",
    "PLAUSIBLE_MEDIAN_DEPTH_M",
    "SCALE_FALLBACKS",
    "implausible_depth",
    "scale_consistency_problems",
    "PlaneFit",
    "SCALE_MODES",
    "ScaleConfig",
    "ScaleError",
    "camera_height_scale",
    "combine_factors",
    "fit_road_plane",
    "frame_factor",
    "lidar_scale",
    "road_region_points",
]
