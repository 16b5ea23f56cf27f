"""The field of view a cloud itself shows, read from the cloud alone (no calibration): used wherever a point's
target must be one the other frame could have seen — the evaluation's view pruning and the rigid polish's object
score (:mod:`evaluation.view_prune`, :mod:`evaluation.rigid_polish`) and the net's hold of the points that leave
the view (``HALFlowConfig.eval_view_hold``).

A camera-frustum cloud (KITTI's stereo and LiDAR test sets cut to the camera's view) shows a sector ahead of the
camera; a surround LiDAR sweep (Argoverse 2, Waymo through the OpenSceneFlow reader) shows the whole circle but for
the sectors where it has no return. Both read the same way: the sector seen is the circle less the widest azimuth
gap between the cloud's points.

Camera frame: x right, y down, z forward, metres; angles in degrees.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

VIEW_MARGIN_DEG = 0.5
"""The azimuth band (degrees) at each side of a cloud's extent that counts as outside: the sensor's edge columns
are sparse, so a point just inside the outermost return may still not have been seen."""


def view_angles(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Azimuth ``atan2(x, z)`` and elevation ``atan2(−y, √(x² + z²))`` in degrees of ``points`` (N, 3)."""
    p = np.asarray(points, np.float64)
    return np.degrees(np.arctan2(p[:, 0], p[:, 2])), np.degrees(np.arctan2(-p[:, 1], np.hypot(p[:, 0], p[:, 2])))


@dataclass(frozen=True)
class ViewExtent:
    """The field of view a cloud itself shows (camera frame, degrees and metres), read from the cloud alone: the
    azimuth sector from ``start`` over ``span`` degrees (the circle less the cloud's widest azimuth gap) narrowed by
    a margin at each side, its elevation range, and its reach — its farthest depth ``z`` for a sector ahead of the
    camera (every azimuth within ±90°: a camera frustum, whose far cut is a depth), else its farthest horizontal
    range (a surround sweep). A point outside it could not have been seen in that frame."""

    start: float
    span: float
    el_min: float
    el_max: float
    reach: float
    ahead: bool

    @classmethod
    def of(cls, cloud: np.ndarray, margin_deg: float = VIEW_MARGIN_DEG) -> "ViewExtent":
        """The extent of ``cloud`` (M ≥ 1, 3), its azimuth sector narrowed by ``margin_deg`` on each side."""
        p = np.asarray(cloud, np.float64)
        az, el = view_angles(p)
        ring = np.sort(az)
        gaps = np.append(np.diff(ring), ring[0] + 360.0 - ring[-1])  # gap after each azimuth, the last wrapping round
        widest = int(np.argmax(gaps))
        start = ring[(widest + 1) % len(ring)]
        span = 360.0 - float(gaps[widest])
        ahead = bool(start > -90.0 and start + span < 90.0)
        reach = float(p[:, 2].max()) if ahead else float(np.hypot(p[:, 0], p[:, 2]).max())
        return cls(float(start) + margin_deg, span - 2 * margin_deg, float(el.min()), float(el.max()), reach, ahead)

    def contains(self, points: np.ndarray) -> np.ndarray:
        """(N,) bool: which of ``points`` (N, 3), same camera frame, lie inside."""
        p = np.asarray(points, np.float64)
        az, el = view_angles(p)
        along = np.mod(az - self.start, 360.0)  # degrees past the sector's first edge
        near = (p[:, 2] > 0) & (p[:, 2] <= self.reach) if self.ahead else np.hypot(p[:, 0], p[:, 2]) <= self.reach
        return (along > 0) & (along < self.span) & (el >= self.el_min) & (el <= self.el_max) & near
