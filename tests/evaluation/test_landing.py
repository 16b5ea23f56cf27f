"""Registration on exact landings (evaluation.landing): frame 2 holds frame 1's points moved, sampled thinly."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from evaluation.baselines.base import apply_transform, transform_error
from evaluation.landing import confirmed, landings, register_on_landings
from testkit.rigid_scene import SMALL, motion, structured_scene, thin_pairs


def test_a_motion_centimetres_off_is_taken_onto_the_exact_one():
    pc1, pc2 = thin_pairs()
    off = motion(0.3, (0.0, 1.0, 0.0), (0.03, -0.01, 0.04)) @ SMALL  # 0.3° and 5 cm off
    tree2 = cKDTree(pc2)
    start = landings(off, pc1, tree2, 0.005)
    T, n = register_on_landings(pc1, pc2, off, 0.005, tree2=tree2)
    rot_err, t_err = transform_error(T, SMALL)
    assert rot_err < 1e-6 and t_err < 1e-6, (rot_err, t_err)  # exact, to rounding
    exact = landings(SMALL, pc1, tree2, 0.005)
    assert n == pytest.approx(exact) and 0.15 * len(pc1) < exact < 0.25 * len(pc1)  # the kept counterparts: ~20 %
    assert start < exact / 10


def test_landings_count_each_point_by_how_near_it_lands():
    pc2 = np.zeros((1, 3))
    pts = np.array([[0.0, 0.0, 0.0], [0.0025, 0.0, 0.0], [0.0, 0.006, 0.0]])
    assert landings(np.eye(4), pts, cKDTree(pc2), 0.005) == pytest.approx(1.5)  # 1 + 0.5 + 0


def test_never_lands_fewer_than_its_start_and_keeps_a_start_that_is_already_exact():
    pc1, pc2 = thin_pairs(1)
    tree2 = cKDTree(pc2)
    T, n = register_on_landings(pc1, pc2, SMALL, 0.005, tree2=tree2)
    assert n == pytest.approx(landings(SMALL, pc1, tree2, 0.005))
    assert transform_error(T, SMALL)[1] < 1e-6
    # a re-scan: frame 2 holds no counterparts, so no motion lands more than a chance few; the start is not lost
    rng = np.random.default_rng(2)
    rescan = apply_transform(SMALL, structured_scene(rng, 3000))
    T2, n2 = register_on_landings(pc1, rescan, SMALL, 0.005)
    assert n2 >= landings(SMALL, pc1, cKDTree(rescan), 0.005)


def test_too_few_points_return_the_start():
    pc1, pc2 = thin_pairs()
    T, n = register_on_landings(pc1[:4], pc2, SMALL, 0.005)
    np.testing.assert_array_equal(T, SMALL)
    assert n == landings(SMALL, pc1[:4], cKDTree(pc2), 0.005)


def test_confirmed_where_the_flow_lands_neighbours_and_mostly_not_on_a_mover_left_static():
    """The right flow everywhere but on a car (0.3 m off there, as a mover left with the camera's motion): a fifth of
    the counterparts kept, so the neighbourhood ((1 − s)^k < 1 %) is about 21 points. The rest is confirmed; of the
    car only the points whose neighbourhood reaches the road under it or a chance landing; an empty frame 2
    confirms nothing."""
    pc1, pc2 = thin_pairs(3)
    right = apply_transform(SMALL, pc1) - pc1
    car = (np.abs(pc1[:, 0] + 3) < 1.0) & (np.abs(pc1[:, 2] - 8) < 2.1) & (pc1[:, 1] < 1.59)  # the box at (-3, ·, 8)
    flow = right + car[:, None] * np.array([0.0, 0.0, 0.3])
    sure = confirmed(pc1, flow, pc2, 0.02, static=~car)
    assert car.sum() > 200 and sure[~car].mean() > 0.97 and sure[car].mean() < 0.5
    assert not confirmed(pc1, right, np.zeros((0, 3)), 0.02).any()
