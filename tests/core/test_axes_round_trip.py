"""One axes table for writer and readers: :data:`core.axes.FORMAT_AXES`. The synthetic writer writes a tiny
split in every layout it supports, the readers read it back, and points and flow come back in the camera frame
(x right, y down, z forward, metres) as written."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from evaluation.readers import REGISTRY, FlowNet3DOptions, HPLFlowNetOptions, load_split
from core.axes import FORMAT_AXES, HPLFLOWNET, LIDAR
from pipeline.filters import FAR_LIMIT_M
from pipeline.synth.sceneflow_export import ScanGT, write_pair

WRITTEN = ("flownet3d", "hplflownet")  # the layouts of the synthetic world's sceneflow/ folder


def _scan(rng: np.random.Generator, n: int) -> ScanGT:
    """Camera-frame points 1..50 m ahead, ±2.5 m vertically, ground = more than 1.4 m below the camera."""
    points = np.column_stack([rng.uniform(-10, 10, n), rng.uniform(-2.0, 2.5, n), rng.uniform(1, 50, n)])
    flow = rng.normal(0, 0.5, (n, 3))
    moving = rng.random(n) < 0.3
    return ScanGT(points=points, flow=flow, moving=moving, ground=points[:, 1] > 1.4,
                  classes=moving.astype(np.int32), instance=np.where(moving, 3, -1).astype(np.int32))


@pytest.fixture()
def written(tmp_path: Path) -> tuple[Path, ScanGT, ScanGT]:
    rng = np.random.default_rng(0)
    t0, t1 = _scan(rng, 400), _scan(rng, 380)
    write_pair(tmp_path, 7, t0, t1)
    return tmp_path, t0, t1


def test_every_format_has_its_axes_and_they_are_rotations() -> None:
    assert set(REGISTRY) <= set(FORMAT_AXES) and set(WRITTEN) <= set(REGISTRY)
    for fmt in REGISTRY.values():
        assert fmt.axes is FORMAT_AXES[fmt.name]
    v = np.random.default_rng(1).normal(size=(5, 3))
    for axes in (LIDAR, HPLFLOWNET):
        assert np.allclose(axes.matrix @ axes.matrix.T, np.eye(3)) and np.isclose(np.linalg.det(axes.matrix), 1)
        np.testing.assert_array_equal(axes.to_camera(v), v @ axes.matrix.T)  # exact: only signs and order
        np.testing.assert_array_equal(axes.from_camera(axes.to_camera(v)), v)
        assert axes.to_camera(v.astype(np.float32)).dtype == np.float32
        # a rigid motion in the stored axes is the same motion in camera axes: A (R p + t) = (A R Aᵀ)(A p) + A t
        pose = np.eye(4)
        pose[:3, :3] = np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]])
        pose[:3, 3] = [0.5, -1.0, 2.0]
        cam = axes.pose_to_camera(pose)
        np.testing.assert_allclose(axes.to_camera(v @ pose[:3, :3].T + pose[:3, 3]),
                                   axes.to_camera(v) @ cam[:3, :3].T + cam[:3, 3], atol=1e-12)
    # the conventions in words: LiDAR forward is camera z, LiDAR left is camera −x, LiDAR up is camera −y
    np.testing.assert_array_equal(LIDAR.to_camera(np.eye(3)), [[0, 0, 1], [-1, 0, 0], [0, -1, 0]])
    np.testing.assert_array_equal(HPLFLOWNET.to_camera(np.array([1.0, 2.0, 3.0])), [-1.0, -2.0, 3.0])
    with pytest.raises(ValueError, match="signed permutation"):
        type(LIDAR)("bad", np.diag([1.0, 1.0, -1.0]), "a reflection")


def test_flownet3d_round_trip(written) -> None:
    root, t0, t1 = written
    s = load_split(root / "flownet3d")[0]
    assert s.name == "000007"
    keep1 = ~t0.ground & (t0.points[:, 2] < FAR_LIMIT_M)  # the writer's own filters: ground removed, z < 35 m
    keep2 = ~t1.ground & (t1.points[:, 2] < FAR_LIMIT_M)
    assert 0 < keep1.sum() < len(keep1)
    np.testing.assert_allclose(s.pc1, t0.points[keep1], atol=1e-5)
    np.testing.assert_allclose(s.flow, t0.flow[keep1], atol=1e-6)
    np.testing.assert_allclose(s.pc2, t1.points[keep2], atol=1e-5)  # the next scan, not pc1 + flow
    np.testing.assert_array_equal(s.moving, t0.moving[keep1])
    np.testing.assert_array_equal(s.classes, t0.classes[keep1])
    np.testing.assert_array_equal(s.instance, t0.instance[keep1])
    near = load_split(root / "flownet3d", flownet3d=FlowNet3DOptions(max_depth=20.0))[0]
    np.testing.assert_allclose(near.pc1, t0.points[keep1 & (t0.points[:, 2] < 20)], atol=1e-5)


def test_hplflownet_round_trip(written) -> None:
    root, t0, _ = written
    raw = load_split(root / "hplflownet", hplflownet=HPLFlowNetOptions(remove_ground=False, max_depth=None))[0]
    assert raw.name == "000007" and raw.n1 == len(t0.points)  # every point written, in order
    np.testing.assert_allclose(raw.pc1, t0.points, atol=1e-5)
    np.testing.assert_allclose(raw.flow, t0.flow, atol=1e-5)
    np.testing.assert_allclose(raw.pc2, t0.points + t0.flow, atol=1e-5)
    np.testing.assert_array_equal(raw.moving, t0.moving)
    np.testing.assert_array_equal(raw.instance, t0.instance)
    # HPLFlowNet's default filters, in camera terms: drop a pair when both points are > 1.4 m below the camera,
    # keep it when both are nearer than 35 m
    end = t0.points + t0.flow
    keep = ~((t0.points[:, 1] > 1.4) & (end[:, 1] > 1.4)) & (t0.points[:, 2] < 35) & (end[:, 2] < 35)
    s = load_split(root / "hplflownet")[0]
    np.testing.assert_allclose(s.pc1, t0.points[keep], atol=1e-5)
    np.testing.assert_allclose(s.flow, t0.flow[keep], atol=1e-5)
