"""A structured synthetic scene for the registration tests (road, two walls, four boxes; camera axes x right,
y down, z forward, metres) and the rigid motions they recover."""

from __future__ import annotations

import numpy as np

from evaluation.baselines.base import rotation_from_vector


def box_surface(rng: np.random.Generator, centre: tuple, size: tuple, n: int) -> np.ndarray:
    c, s = np.asarray(centre, float), np.asarray(size, float)
    faces, areas = [], []
    for ax in range(3):
        others = [a for a in range(3) if a != ax]
        for sign in (-1.0, 1.0):
            faces.append((ax, sign, others))
            areas.append(s[others[0]] * s[others[1]])
    counts = rng.multinomial(n, np.asarray(areas) / sum(areas))
    out = []
    for (ax, sign, others), k in zip(faces, counts):
        p = np.empty((k, 3))
        p[:, ax] = c[ax] + sign * s[ax] / 2
        for a in others:
            p[:, a] = c[a] + (rng.random(k) - 0.5) * s[a]
        out.append(p)
    return np.concatenate(out)


def structured_scene(rng: np.random.Generator, n: int) -> np.ndarray:
    k = n // 4
    road = np.stack([rng.uniform(-8, 8, k), np.full(k, 1.6), rng.uniform(2, 20, k)], 1)
    k2 = n // 8
    left_wall = np.stack([np.full(k2, -7.0), rng.uniform(-2, 1.6, k2), rng.uniform(2, 20, k2)], 1)
    back_wall = np.stack([rng.uniform(-7, 8, k2), rng.uniform(-2, 1.6, k2), np.full(k2, 20.0)], 1)
    boxes = [((-3, 0.9, 8), (1.8, 1.4, 4.0)), ((3, 0.6, 12), (2.0, 2.0, 2.0)),
             ((0.5, 1.1, 15), (1.0, 1.0, 3.0)), ((5, 0.0, 6), (1.0, 3.2, 1.0))]
    rest = n - len(road) - len(left_wall) - len(back_wall)
    sizes = [rest // 4] * 3 + [rest - 3 * (rest // 4)]
    parts = [road, left_wall, back_wall] + [box_surface(rng, c, s, m) for (c, s), m in zip(boxes, sizes)]
    return np.concatenate(parts)


def motion(deg: float, axis: tuple, t: tuple) -> np.ndarray:
    a = np.asarray(axis, float)
    out = np.eye(4)
    out[:3, :3] = rotation_from_vector(np.radians(deg) * a / np.linalg.norm(a))
    out[:3, 3] = t
    return out


def scene_pair(seed: int, n: int, transform: np.ndarray, noise: float = 0.002) -> tuple[np.ndarray, np.ndarray]:
    """pc1 and pc2 = T(scene) sampled independently (90 % of a common pool each) plus 2 mm noise."""
    rng = np.random.default_rng(seed)
    pool = structured_scene(rng, int(n / 0.9) + 1)
    a = rng.permutation(len(pool))[:n]
    b = rng.permutation(len(pool))[:n]
    pc1 = pool[a] + rng.normal(0, noise, (n, 3))
    pc2 = pool[b] @ transform[:3, :3].T + transform[:3, 3] + rng.normal(0, noise, (n, 3))
    return pc1, pc2


SMALL = motion(5.0, (0.1, 1.0, 0.05), (0.3, 0.05, 1.0))  # a typical frame-to-frame ego motion
YAW30 = motion(30.0, (0.0, 1.0, 0.0), (0.5, 0.0, 1.5))  # a 30° misalignment


def thin_pairs(seed: int = 0, pool: int = 15000, n: int = 3000) -> tuple[np.ndarray, np.ndarray]:
    """A point-pair split's scene as the protocols sample it: frame 1 ``n`` points of a ``pool``-point street, frame 2
    ``n`` of the same street moved by SMALL, drawn independently — about ``n / pool`` (a fifth) of frame 1's points
    keep their counterpart. No noise: a kept counterpart lies exactly where SMALL carries its point."""
    rng = np.random.default_rng(seed)
    scene = structured_scene(rng, pool)
    moved = scene @ SMALL[:3, :3].T + SMALL[:3, 3]
    return scene[rng.permutation(pool)[:n]], moved[rng.permutation(pool)[:n]]
