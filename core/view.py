"""The field of view a cloud itself shows, read from the cloud alone (no calibration): used wherever a point's
target must be one the other frame could have seen — the evaluation's view pruning and the rigid polish's object
score (:mod:`evaluation.view_prune`, :mod:`evaluation.rigid_polish`) and the net's hold of the points that leave
the view (``HALFlowConfig.eval_view_hold``).

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
    """The field of view a cloud itself shows (camera frame, degrees and metres): its azimuth range narrowed
    by a margin on each side, its elevation range and its farthest depth — read from the cloud alone, no
    calibration. A point outside it could not have been seen in that frame."""

    az_min: float
    az_max: float
    el_min: float
    el_max: float
    z_max: float

    @classmethod
    def of(cls, cloud: np.ndarray, margin_deg: float = VIEW_MARGIN_DEG) -> "ViewExtent":
        """The extent of ``cloud`` (M ≥ 1, 3), azimuth narrowed by ``margin_deg`` on each side."""
        az, el = view_angles(cloud)
        return cls(float(az.min()) + margin_deg, float(az.max()) - margin_deg, float(el.min()), float(el.max()),
                   float(np.asarray(cloud)[:, 2].max()))

    def contains(self, points: np.ndarray) -> np.ndarray:
        """(N,) bool: which of ``points`` (N, 3), same camera frame, lie inside."""
        az, el = view_angles(points)
        return ((az > self.az_min) & (az < self.az_max) & (el >= self.el_min) & (el <= self.el_max)
                & (np.asarray(points)[:, 2] > 0) & (np.asarray(points)[:, 2] <= self.z_max))
