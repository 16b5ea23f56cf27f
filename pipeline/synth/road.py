"""The road: a circular arc (or a straight line) of constant curvature in the map frame.

Map frame: like a camera frame — x right, y down, z forward at the road's start — so the road surface
is the plane y = 0 and everything above it has y < 0. Road coordinates: arclength ``s`` along the
centre line (metres, 0 at the map origin, heading +z there) and lateral offset ``l`` (metres, positive
to the right of the direction of travel). Curvature κ > 0 turns right.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# Cross-section (|l|, metres): lanes of 3.2 m (two per direction), a parking strip, kerb, pavement.
LANE_WIDTH = 3.2
PARKING_EDGE = 6.4  # |l| where the parking strip starts (solid edge line)
ROAD_HALF_WIDTH = 8.6  # kerb line
KERB_HEIGHT = 0.15
PAVEMENT_WIDTH = 4.0


@dataclass(frozen=True)
class Road:
    """Constant-curvature road between arclengths ``s_min`` and ``s_max`` (metres)."""

    curvature: float
    s_min: float
    s_max: float
    ground_half_width: float = 60.0  # the ground ends (sky beyond) at |l| > this

    @property
    def straight(self) -> bool:
        return abs(self.curvature) < 1e-9

    def point(self, s, l):
        """Map (x, z) of road coordinates (s, l)."""
        s, l = np.asarray(s, dtype=np.float64), np.asarray(l, dtype=np.float64)
        if self.straight:
            return l + 0.0 * s, s + 0.0 * l
        R = 1.0 / self.curvature
        th = s * self.curvature
        return R - (R - l) * np.cos(th), (R - l) * np.sin(th)

    def heading(self, s):
        """Yaw (radians) of the direction of travel at arclength s (0 = +z, positive turns to +x)."""
        return np.asarray(s, dtype=np.float64) * self.curvature

    def to_road(self, x, z):
        """Road coordinates (s, l) of map points (x, z)."""
        if self.straight:
            return np.asarray(z, dtype=np.float64), np.asarray(x, dtype=np.float64)
        R = 1.0 / self.curvature
        dx, dz = np.asarray(x) - R, np.asarray(z)
        rho = np.sign(R) * np.hypot(dx, dz)
        th = np.arctan2(dz / rho, -dx / rho)
        return th * R, R - rho

    def lateral_hits(self, O: np.ndarray, D: np.ndarray, l: float) -> tuple[np.ndarray, np.ndarray]:
        """Ray parameters t where rays ``O + t D`` (O (3,), D (3, N) component-major) meet the vertical
        surface of constant lateral offset ``l`` (a plane for a straight road, a cylinder otherwise);
        NaN = none."""
        if self.straight:
            with np.errstate(divide="ignore", invalid="ignore"):
                t = (l - O[0]) / D[0]
            return t, np.full_like(t, np.nan)
        R = 1.0 / self.curvature
        r = abs(R - l)
        ox, oz = O[0] - R, O[2]
        a = D[0] ** 2 + D[2] ** 2
        b = 2.0 * (ox * D[0] + oz * D[2])
        c = ox * ox + oz * oz - r * r
        disc = b * b - 4.0 * a * c
        with np.errstate(invalid="ignore", divide="ignore"):
            sq = np.sqrt(disc)
            t1 = (-b - sq) / (2.0 * a)
            t2 = (-b + sq) / (2.0 * a)
        return t1, t2

    def right(self, s):
        """Unit vector (x, z) pointing to increasing l at arclength s."""
        th = self.heading(s)
        return np.cos(th), -np.sin(th)
