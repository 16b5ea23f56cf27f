"""Label-free per-scene optimisation (evaluation/optimise): the NSFP baseline recovers a known motion,
refinement improves a perturbed truth, early stopping stops, a seed makes it deterministic, and the
robust rigid fit ignores a moving object."""

from __future__ import annotations

import dataclasses
import math
import time

import numpy as np
import pytest
import torch

from core.errors import ConfigError
from evaluation.methods import make_baseline, refined
from evaluation.optimise import (LoopConfig, NSFPConfig, NSFPMethod, RefineConfig, RefinedMethod, fit_nsfp,
                                 minimise, refine_flow, robust_rigid_fit)
from evaluation.optimise.rigid import so3_exp

torch.set_num_threads(1)


def rotation_y(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def street(n: int = 300, seed: int = 0, mover: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A small street (camera frame, metres): road 1.6 m below the camera, two façades, a box that moves
    (when ``mover``). The camera drives 0.8 m forward and yaws 0.02 rad; the box drives 0.6 m forward.
    Returns pc1 (n, 3), pc2 (n, 3) (the same surface points seen from frame 2, shuffled), flow (n, 3), moving (n,)."""
    rng = np.random.default_rng(seed)
    k = n // 4
    road = np.c_[rng.uniform(-5, 6, k), np.full(k, 1.6), rng.uniform(4, 25, k)]
    left = np.c_[np.full(k, -5.0), rng.uniform(-3, 1.6, k), rng.uniform(4, 25, k)]
    right = np.c_[np.full(k, 6.0), rng.uniform(-3, 1.6, k), rng.uniform(4, 25, k)]
    box = np.c_[rng.uniform(1, 3, n - 3 * k), rng.uniform(0, 1.6, n - 3 * k), rng.uniform(10, 14, n - 3 * k)]
    pc1 = np.concatenate([road, left, right, box])
    moving = np.zeros(n, bool)
    if mover:
        moving[3 * k:] = True
    world2 = pc1 + moving[:, None] * np.array([0.0, 0.0, 0.6])
    R, t = rotation_y(0.02), np.array([0.05, 0.0, -0.8])
    p2 = world2 @ R.T + t
    flow = (p2 - pc1).astype(np.float32)
    return pc1.astype(np.float32), p2[rng.permutation(n)].astype(np.float32), flow, moving


def epe(pred: np.ndarray, gt: np.ndarray) -> float:
    return float(np.linalg.norm(pred - gt, axis=1).mean())


SMALL_NSFP = dict(layers=3, hidden=32, iterations=100, patience=0)


def test_nsfp_recovers_rigid_flow_far_better_than_zero() -> None:
    pc1, pc2, gt, _ = street(n=200, mover=False)
    method = NSFPMethod(NSFPConfig(**SMALL_NSFP))
    flow = method(pc1, pc2)
    assert flow.shape == pc1.shape and flow.dtype == np.float32
    zero = epe(np.zeros_like(gt), gt)
    assert zero > 0.7
    assert epe(flow, gt) < 0.2 * zero
    assert method.last is not None and method.last.iterations == 100


def test_nsfp_is_deterministic_with_a_seed() -> None:
    pc1, pc2, _, _ = street(n=120)
    cfg = NSFPConfig(layers=3, hidden=32, iterations=25, patience=0, seed=3)
    a, b = fit_nsfp(pc1, pc2, cfg), fit_nsfp(pc1, pc2, cfg)
    torch.manual_seed(123)  # the global RNG does not matter
    c = fit_nsfp(pc1, pc2, cfg)
    assert torch.equal(a.flow, b.flow) and torch.equal(a.flow, c.flow) and a.history == c.history
    d = fit_nsfp(pc1, pc2, NSFPConfig(layers=3, hidden=32, iterations=25, patience=0, seed=4))
    assert not torch.equal(a.flow, d.flow)


def test_nsfp_backward_cycle_runs() -> None:
    pc1, pc2, gt, _ = street(n=120, mover=False)
    res = fit_nsfp(pc1, pc2, NSFPConfig(layers=3, hidden=32, iterations=60, patience=0, backward=True))
    assert epe(res.flow.numpy(), gt) < epe(np.zeros_like(gt), gt)
    assert res.history[-1] < res.history[0]


@pytest.mark.parametrize("parametrisation", ["rigid-mlp", "mlp", "free"])
def test_refinement_from_perturbed_truth_reduces_epe(parametrisation: str) -> None:
    pc1, pc2, gt, moving = street(seed=1)
    rng = np.random.default_rng(5)
    init = gt + rng.normal(0, 0.08, gt.shape).astype(np.float32)  # per-point noise
    init += np.array([0.15, 0.0, 0.1], np.float32)  # and a wrong ego translation
    res = refine_flow(pc1, pc2, init, RefineConfig(parametrisation=parametrisation, iterations=150, patience=0,
                                                   lr=1e-2 if parametrisation == "free" else 3e-3))
    before, after = epe(init, gt), epe(res.flow.numpy(), gt)
    assert after < 0.8 * before, (before, after)
    assert res.loss <= res.history[0]


def test_refinement_keeps_the_truth_and_uses_laplacian() -> None:
    pc1, pc2, gt, _ = street(seed=2)
    res = refine_flow(pc1, pc2, gt, RefineConfig(iterations=30, laplacian_weight=1.0, patience=0))
    assert epe(res.flow.numpy(), gt) < 0.05  # the truth is (near) a minimum of the label-free loss


def test_refined_method_is_its_own_row() -> None:
    pc1, pc2, gt, _ = street(n=120)
    base = make_baseline("zero")
    method = refined(base, RefineConfig(iterations=40, patience=0))
    assert isinstance(method, RefinedMethod) and method.name == "zero + refinement" and base.name == "zero"
    flow = method(pc1, pc2, None, None)
    assert flow.shape == pc1.shape and flow.dtype == np.float32
    assert epe(flow, gt) < epe(np.zeros_like(gt), gt)
    assert make_baseline("nsfp").name == "nsfp"


def test_nsfp_full_is_the_authors_settings() -> None:
    full = make_baseline("nsfp-full")
    cfg = full.config.validate()
    assert full.name == "nsfp-full" and cfg.iterations == 5000 and cfg.patience == 70 and cfg.backward
    assert cfg.cycle_weight == 0.0 and cfg.truncate == pytest.approx(2 ** 0.5) and cfg.lr == 8e-3
    assert NSFPConfig.published(iterations=7).iterations == 7  # overrides win
    assert NSFPConfig().iterations == 60 and not NSFPConfig().backward  # the demo's budget unchanged


def test_early_stopping_stops_and_budget_holds() -> None:
    x = torch.zeros(3, requires_grad=True)

    def flat():  # the loss does not depend on x: no step can improve it
        return (x * 0).sum() + 1.0, x.detach().expand(4, 3)

    res = minimise([x], flat, LoopConfig(iterations=100, patience=5))
    assert res.stopped_early and res.iterations == 6 and res.loss == 1.0
    res = minimise([x], flat, LoopConfig(iterations=40, patience=0))
    assert not res.stopped_early and res.iterations == 40 and len(res.history) == 40

    y = torch.tensor([2.0], requires_grad=True)

    def bowl():
        return (y ** 2).sum(), y.expand(1, 3)

    res = minimise([y], bowl, LoopConfig(iterations=2000, lr=0.05, patience=10, min_delta=1e-6))
    assert res.stopped_early and res.iterations < 2000 and res.loss < 1e-3
    assert res.loss == min(res.history)


def test_time_budget_stops_the_loop() -> None:
    y = torch.tensor([2.0], requires_grad=True)

    def slow_bowl():  # each step takes at least 5 ms: 20 ms of budget end the loop by step 5
        time.sleep(0.005)
        return (y ** 2).sum(), y.expand(1, 3)

    res = minimise([y], slow_bowl, LoopConfig(iterations=10_000, lr=0.05, patience=0, time_budget=0.02))
    assert res.stopped_early and 1 <= res.iterations <= 5 and res.seconds > 0.02  # 5 steps take >= 25 ms
    assert len(res.history) == res.iterations and res.loss == min(res.history)
    res = minimise([y], slow_bowl, LoopConfig(iterations=3, patience=0, time_budget=60.0))
    assert not res.stopped_early and res.iterations == 3  # a budget not reached changes nothing


def test_robust_rigid_fit_ignores_the_mover() -> None:
    pc1, _, gt, moving = street(seed=4)
    assert 0.1 < moving.mean() < 0.4
    p, f = torch.tensor(pc1), torch.tensor(gt)
    R, t, rigid = robust_rigid_fit(p, f, scale=0.2)
    np.testing.assert_allclose(R.numpy(), rotation_y(0.02), atol=1e-3)
    np.testing.assert_allclose(t.numpy(), [0.05, 0.0, -0.8], atol=5e-3)  # GM: movers keep a tiny weight
    assert epe(rigid.numpy()[~moving], gt[~moving]) < 5e-3
    # so3_exp: a rotation about y by 0.3 rad, and the identity at zero
    np.testing.assert_allclose(so3_exp(torch.tensor([0.0, 0.3, 0.0], dtype=torch.float64)).numpy(), rotation_y(0.3),
                               atol=1e-12)
    assert torch.equal(so3_exp(torch.zeros(3)), torch.eye(3))


def test_bad_settings_are_config_errors() -> None:
    from core.errors import ConfigError

    with pytest.raises(ConfigError):
        NSFPConfig(iterations=0).validate()
    with pytest.raises(ConfigError):
        RefineConfig(parametrisation="nope").validate()
    with pytest.raises(ConfigError):
        NSFPConfig(truncate=0).validate()
    with pytest.raises(ConfigError, match="plane"):
        RefineConfig(plane=1.5).validate()
    with pytest.raises(ConfigError, match="time_budget"):
        NSFPConfig(time_budget=-1.0).validate()


def test_refinement_along_the_normals_keeps_a_flow_that_lies_on_frame_two_surfaces() -> None:
    """Frame 2 is another sample of the same surfaces (as two LiDAR sweeps are), so the true flow ends between
    its samples. From the truth, the point-to-point Chamfer pulls the points along the surfaces onto the
    nearest samples; counted along the normals (``plane`` 1, after a registration) the truth stays put."""
    rng = np.random.default_rng(3)

    def surfaces(n: int) -> np.ndarray:  # road, two façades, camera frame (metres)
        k = n // 3
        return np.concatenate([np.c_[rng.uniform(-5, 6, k), np.full(k, 1.6), rng.uniform(4, 25, k)],
                               np.c_[np.full(k, -5.0), rng.uniform(-3, 1.6, k), rng.uniform(4, 25, k)],
                               np.c_[np.full(n - 2 * k, 6.0), rng.uniform(-3, 1.6, n - 2 * k), rng.uniform(4, 25, n - 2 * k)]])

    R, t = rotation_y(0.02), np.array([0.05, 0.0, -0.8])
    pc1 = surfaces(600).astype(np.float32)
    pc2 = (surfaces(600) @ R.T + t).astype(np.float32)
    gt = (pc1 @ R.T + t - pc1).astype(np.float32)
    errors = {}
    for plane in (0.0, 1.0):
        cfg = RefineConfig.after_registration(plane=plane, iterations=60, patience=0, lr=1e-2)
        errors[plane] = epe(refine_flow(pc1, pc2, gt, cfg).flow.numpy(), gt)
    assert RefineConfig.after_registration().plane == 1.0
    assert errors[1.0] < 0.5 * errors[0.0] and errors[1.0] < 0.05, errors


def test_with_frame_one_s_own_points_in_frame_two_point_pairs_follow_what_one_rigid_motion_cannot() -> None:
    """``pairing="points"`` (thirty-fourth round): frame 2 holds frame 1's own points, moved by the camera and
    by a smooth non-rigid part (a depth estimate's bending, say), shuffled. From the registered camera motion,
    the point-to-point term without the rigid pull walks each point onto its counterpart; the surface
    settings (along the normals, pulled to one rigid motion) cannot follow the bending. The opposite case, a
    re-scan, is the test above: there the surface settings win."""
    rng = np.random.default_rng(3)
    k = 200
    pc1 = np.concatenate([np.c_[rng.uniform(-5, 6, k), np.full(k, 1.6), rng.uniform(4, 25, k)],
                          np.c_[np.full(k, -5.0), rng.uniform(-3, 1.6, k), rng.uniform(4, 25, k)],
                          np.c_[np.full(k, 6.0), rng.uniform(-3, 1.6, k), rng.uniform(4, 25, k)]])
    R, t = rotation_y(0.02), np.array([0.05, 0.0, -0.8])
    bend = np.c_[0.1 * np.sin(pc1[:, 2] / 4), 0.05 * np.sin(pc1[:, 0] / 3), 0.1 * np.cos(pc1[:, 0] / 3)]
    moved = pc1 @ R.T + t + bend
    gt = (moved - pc1).astype(np.float32)
    pc2 = moved[rng.permutation(len(moved))].astype(np.float32)
    start = (pc1 @ R.T + t - pc1).astype(np.float32)  # the camera's motion, registered exactly
    errors = {}
    for pairing in ("surface", "points"):
        cfg = dataclasses.replace(RefineConfig.for_start(True, pairing), iterations=60, patience=0)
        errors[pairing] = epe(refine_flow(pc1.astype(np.float32), pc2, start, cfg).flow.numpy(), gt)
    assert errors["points"] < 0.5 * errors["surface"] and errors["points"] < 0.5 * epe(start, gt), errors


def test_the_pairing_names_its_settings_and_its_row() -> None:
    assert RefineConfig.for_start(True) == RefineConfig.after_registration()
    assert RefineConfig.for_start(False) == RefineConfig()
    pairs = RefineConfig.for_start(True, "points")
    assert pairs == dataclasses.replace(RefineConfig.after_registration(), plane=0.0, rigid_weight=0.0)
    assert RefineConfig.for_start(False, "points") == dataclasses.replace(RefineConfig(), rigid_weight=0.0)
    with pytest.raises(ConfigError, match="pairing"):
        RefineConfig.for_start(True, "lidar")
    zero = make_baseline("zero")
    assert refined(zero, pairing="points").name == "zero + refinement (point pairs)"
    assert refined(zero).name == "zero + refinement" and refined(zero).config == RefineConfig()
