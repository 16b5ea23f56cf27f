"""Two-pass view pruning (evaluation/view_prune.py): which points are set aside and what they get."""

from __future__ import annotations

import numpy as np

from evaluation.methods import make_method
from evaluation.view_prune import ViewPruned, inside_extent


def test_inside_extent_reads_the_view_from_pc2():
    rng = np.random.default_rng(0)
    az = np.radians(rng.uniform(-30, 30, 500))
    r = rng.uniform(5, 30, 500)
    pc2 = np.stack([r * np.sin(az), rng.uniform(-1, 1, 500), r * np.cos(az)], 1)
    pts = np.array([[0, 0, 10.0], [10 * np.tan(np.radians(40)), 0, 10.0], [0, 0, 40.0], [0, 0, -5.0], [0, -5, 10.0]])
    assert inside_extent(pts, pc2, 0.5).tolist() == [True, False, False, False, False]


class _Recorder:
    """A toy method that knows the camera drove 3 m forward (every point's flow is (0, 0, −3)) and records
    what it was given."""

    name = "toy"

    def __init__(self):
        self.calls = []

    def __call__(self, pc1, pc2, color1=None, color2=None):
        self.calls.append(pc1.copy())
        return np.repeat(np.array([[0.0, 0.0, -3.0]], np.float32), len(pc1), 0)


def test_second_pass_sees_only_points_in_view_and_the_others_take_the_rigid_flow():
    rng = np.random.default_rng(1)
    n = 400
    az = np.radians(rng.uniform(-35, 35, n))
    r = rng.uniform(4, 30, n)
    pc1 = np.stack([r * np.sin(az), rng.uniform(-1, 0.5, n), r * np.cos(az)], 1)
    moved = pc1 - np.array([0, 0, 3.0])  # the camera drove 3 m forward: static points come 3 m closer
    pc2 = moved[(np.abs(np.degrees(np.arctan2(moved[:, 0], moved[:, 2]))) < 35) & (moved[:, 2] > 0)]  # t+1's view
    # the scan also holds a far wall and points above and below the band, so no pc1 target sits on an edge
    pc2 = np.concatenate([pc2, [[0.0, 0.0, 40.0], [0.0, -3.0, 8.0], [0.0, 3.0, 8.0]]])
    toy = _Recorder()
    method = ViewPruned(toy)
    flow = method(pc1, pc2)
    assert len(toy.calls) == 2 and method.name == "toy + view pruning"
    second_input = toy.calls[1]
    assert len(second_input) == n  # topped up to the input size, from the points in view only
    seen = (pc1[:, None] == second_input[None]).all(-1).any(1)
    expected_in_view = inside_extent(moved, pc2, 0.5)
    assert np.array_equal(seen, expected_in_view)
    assert 0 < (~seen).sum() < n // 2  # the points driving out of the view at the sides, or behind the camera
    assert np.allclose(flow, [0.0, 0.0, -3.0], atol=1e-4)  # rigid flow for those, the second pass for the rest
    assert make_method("view-prune", toy).name == "toy + view pruning"
