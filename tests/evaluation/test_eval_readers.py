"""Readers of the scene-flow test sets: axis conventions against known motions, filters, bad files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from evaluation.readers import (
    FlowNet3DOptions,
    HPLFlowNetOptions,
    OpenSceneFlowOptions,
    detect_format,
    load_split,
)
from evaluation.sample import SceneFlowSample
from core.errors import InputError

# ------------------------------------------------------------------------------------------------
# SceneFlowSample


def test_sample_checks_shapes() -> None:
    ok = SceneFlowSample("a", np.zeros((4, 3)), np.zeros((5, 3)), np.zeros((4, 3)))
    assert ok.pc1.dtype == np.float32 and ok.n1 == 4 and ok.n2 == 5
    with pytest.raises(ValueError, match=r"flow has 3 rows but pc1 has 4"):
        SceneFlowSample("a", np.zeros((4, 3)), np.zeros((5, 3)), np.zeros((3, 3)))
    with pytest.raises(ValueError, match=r"pc2 must have shape \(N, 3\)"):
        SceneFlowSample("a", np.zeros((4, 3)), np.zeros((5, 2)), np.zeros((4, 3)))
    with pytest.raises(ValueError, match="moving"):
        SceneFlowSample("a", np.zeros((4, 3)), np.zeros((5, 3)), np.zeros((4, 3)), moving=np.zeros(5, bool))
    with pytest.raises(ValueError, match=r"color1 must lie in \[0, 1\]"):
        SceneFlowSample("a", np.zeros((1, 3)), np.zeros((1, 3)), np.zeros((1, 3)), color1=np.full((1, 3), 255.0))
    with pytest.raises(ValueError, match="rotation"):
        SceneFlowSample("a", np.zeros((1, 3)), np.zeros((1, 3)), np.zeros((1, 3)), pose=np.diag([2.0, 1, 1, 1]))
    with pytest.raises(ValueError, match="non-finite"):
        SceneFlowSample("a", np.full((1, 3), np.nan), np.zeros((1, 3)), np.zeros((1, 3)))


# ------------------------------------------------------------------------------------------------
# FlowNet3D kitti_rm_ground (LiDAR-like axes: x forward, y left, z up)


def _write_fn3d(path: Path, pos1: np.ndarray, pos2: np.ndarray, gt: np.ndarray, **extra: np.ndarray) -> None:
    np.savez(path, pos1=pos1.astype(np.float32), pos2=pos2.astype(np.float32), gt=gt.astype(np.float32), **extra)


def test_flownet3d_axes_known_motion(tmp_path: Path) -> None:
    # point 0: 10 m ahead, 2 m to the left, 1 m below the sensor, moving forward by 1 m
    # point 1: 20 m ahead, moving 0.5 m to the left
    # point 2: 5 m ahead, moving 0.25 m up
    pos1 = np.array([[10.0, 2.0, -1.0], [20.0, 0.0, 0.0], [5.0, 0.0, 0.0]])
    gt = np.array([[1.0, 0.0, 0.0], [0.0, 0.5, 0.0], [0.0, 0.0, 0.25]])
    _write_fn3d(tmp_path / "000000.npz", pos1, pos1 + gt, gt, moving=np.array([True, False, True]))
    split = load_split(tmp_path)
    assert split.fmt == "flownet3d" and split.names == ["000000"]
    s = split[0]
    # camera = (−y, −z, x): 2 m left -> x = −2, 1 m below -> y = +1 (down), 10 m ahead -> z = 10
    np.testing.assert_allclose(s.pc1[0], [-2.0, 1.0, 10.0])
    # forward (+x LiDAR) motion is +z in the camera; leftward (+y) is −x; upward (+z) is −y
    np.testing.assert_allclose(s.flow, [[0, 0, 1.0], [-0.5, 0, 0], [0, -0.25, 0]])
    np.testing.assert_allclose(s.pc1 + s.flow, s.pc2, atol=1e-6)
    assert s.moving.tolist() == [True, False, True]
    assert s.pose is None


def test_flownet3d_max_depth(tmp_path: Path) -> None:
    pos1 = np.array([[10.0, 0, 0], [40.0, 0, 0]])
    pos2 = np.array([[11.0, 0, 0], [36.0, 0, 0], [2.0, 0, 0]])
    gt = np.array([[1.0, 0, 0], [-4.0, 0, 0]])
    _write_fn3d(tmp_path / "a.npz", pos1, pos2, gt)
    assert load_split(tmp_path)[0].n1 == 2
    s = load_split(tmp_path, flownet3d=FlowNet3DOptions(max_depth=35.0))[0]
    np.testing.assert_allclose(s.pc1, [[0, 0, 10.0]])
    np.testing.assert_allclose(s.flow, [[0, 0, 1.0]])
    np.testing.assert_allclose(s.pc2, [[0, 0, 11.0], [0, 0, 2.0]])


# ------------------------------------------------------------------------------------------------
# HPLFlowNet KITTI_processed_occ_final (stored = (−x, −y, z) of the camera)


def _write_hpl(folder: Path, pc1: np.ndarray, pc2: np.ndarray, moving: np.ndarray | None = None) -> None:
    folder.mkdir(parents=True)
    np.save(folder / "pc1.npy", pc1.astype(np.float32))
    np.save(folder / "pc2.npy", pc2.astype(np.float32))
    if moving is not None:
        np.save(folder / "moving.npy", moving)


def test_hplflownet_axes_known_motion(tmp_path: Path) -> None:
    # camera-frame truth: point 0 at (1, 1, 10) (1 m right, 1 m below) moves 1 m forward;
    # point 1 at (−2, 0, 8) moves 0.5 m to the right.
    cam1 = np.array([[1.0, 1.0, 10.0], [-2.0, 0.0, 8.0]])
    cam_flow = np.array([[0.0, 0.0, 1.0], [0.5, 0.0, 0.0]])
    stored = np.array([-1.0, -1.0, 1.0])  # stored = (−x, −y, z)
    _write_hpl(tmp_path / "000000", cam1 * stored, (cam1 + cam_flow) * stored, moving=np.array([False, True]))
    split = load_split(tmp_path)
    assert split.fmt == "hplflownet" and split.names == ["000000"]
    s = split[0]
    np.testing.assert_allclose(s.pc1, cam1, atol=1e-6)
    np.testing.assert_allclose(s.flow, cam_flow, atol=1e-6)  # forward stays +z, rightward is +x
    np.testing.assert_allclose(s.pc2, cam1 + cam_flow, atol=1e-6)
    assert s.moving.tolist() == [False, True]


def test_hplflownet_filters_follow_hplflownet(tmp_path: Path) -> None:
    # stored coordinates (y up, z depth); ground is stored y < −1.4
    pc1 = np.array(
        [
            [0.0, -1.5, 10.0],  # 0: ground in both frames -> dropped
            [1.0, -1.5, 10.0],  # 1: ground in pc1 only -> kept by HPLFlowNet's rule ("both")
            [2.0, 0.0, 10.0],  # 2: plain -> kept
            [3.0, 0.0, 34.0],  # 3: pc2 at z = 36 -> dropped (z < 35 needed in both)
            [4.0, 0.0, 36.0],  # 4: pc1 at z = 36 -> dropped
        ]
    )
    pc2 = pc1.copy()
    pc2[1, 1] = -1.0
    pc2[3, 2] = 36.0
    pc2[4, 2] = 34.0
    _write_hpl(tmp_path / "s", pc1, pc2, moving=np.array([0, 1, 0, 1, 1], dtype=bool))
    s = load_split(tmp_path)[0]
    np.testing.assert_allclose(s.pc1[:, 0], [-1.0, -2.0])  # kept points 1, 2 (camera x = −stored x)
    np.testing.assert_allclose(s.flow[0], [0.0, -0.5, 0.0])  # stored y −1.5 -> −1.0 is camera −0.5 (up)
    assert s.moving.tolist() == [True, False]
    either = load_split(tmp_path, hplflownet=HPLFlowNetOptions(ground_rule="either"))[0]
    np.testing.assert_allclose(either.pc1[:, 0], [-2.0])
    raw = load_split(tmp_path, hplflownet=HPLFlowNetOptions(remove_ground=False, max_depth=None))[0]
    assert raw.n1 == 5


# ------------------------------------------------------------------------------------------------
# OpenSceneFlow HDF5


def _write_osf(path: Path, labels: bool = False) -> dict[str, np.ndarray]:
    """Three frames; the ego vehicle drives 1 m forward (+x) between frames; one car drives 2 m left."""
    import h5py

    static = np.array([[10.0, 0.0, 0.0], [5.0, 3.0, 1.0], [8.0, -2.0, 0.5]])
    ground = np.array([[6.0, 0.0, -1.7]])
    car = np.array([[12.0, -1.0, 0.0]])
    pts0 = np.concatenate([static, ground, car])  # frame-0 coordinates
    poses = [np.eye(4) for _ in range(3)]
    for i, p in enumerate(poses):
        p[0, 3] = float(i)  # ego -> world: ego at x = i
    car_world = [car + [0.0, 2.0 * i, 0.0] for i in range(3)]
    with h5py.File(path, "w") as f:
        for i in range(3):
            world = np.concatenate([static, ground, car_world[i]])
            lidar = world - [float(i), 0.0, 0.0]  # into ego frame i
            g = f.create_group(str(1000 + 100 * i))
            g.create_dataset("lidar", data=np.hstack([lidar, np.ones((5, 1))]).astype(np.float32))
            g.create_dataset("pose", data=poses[i].astype(np.float32))
            g.create_dataset("ground_mask", data=np.array([0, 0, 0, 1, 0], bool))
            if i < 2:
                nxt = np.concatenate([static, ground, car_world[i + 1]]) - [float(i + 1), 0.0, 0.0]
                g.create_dataset("flow", data=(nxt - lidar).astype(np.float32))
                g.create_dataset("flow_is_valid", data=np.array([1, 1, 0, 1, 1], bool))
                if labels:  # Argoverse-2 categories (0 = background, 1 = regular vehicle) and instances
                    g.create_dataset("flow_category_indices", data=np.array([0, 0, 0, 0, 1], np.uint8))
                    g.create_dataset("flow_instance_id", data=np.array([-1, -1, -1, -1, 7], np.int16))
    return {"pts0": pts0}


def test_opensceneflow_pairs_axes_and_masks(tmp_path: Path) -> None:
    _write_osf(tmp_path / "scene_a.h5")
    split = load_split(tmp_path)
    assert split.fmt == "opensceneflow"
    assert split.names == ["scene_a/1000", "scene_a/1100"]  # the last frame has no flow
    s = split[0]
    # ground (index 3) removed from both clouds, invalid flow (index 2) removed from pc1
    assert s.n1 == 3 and s.n2 == 4
    # static points move −1 m along LiDAR x (ego drove forward) = −1 m along camera z
    np.testing.assert_allclose(s.flow[:2], [[0, 0, -1.0], [0, 0, -1.0]], atol=1e-6)
    # the car: −1 m forward and +2 m left in LiDAR axes -> camera (−2, 0, −1)
    np.testing.assert_allclose(s.flow[2], [-2.0, 0.0, -1.0], atol=1e-6)
    assert s.moving.tolist() == [False, False, True]
    assert s.classes is None and s.instance is None  # this file has no labels
    # camera-axes pose reproduces the static flow: T(p) − p
    static = s.pc1[:2] @ s.pose[:3, :3].T + s.pose[:3, 3] - s.pc1[:2]
    np.testing.assert_allclose(static, s.flow[:2], atol=1e-6)
    np.testing.assert_allclose(s.pose[:3, 3], [0, 0, -1.0], atol=1e-6)
    keep_all = load_split(
        tmp_path, opensceneflow=OpenSceneFlowOptions(remove_ground=False, valid_only=False, to_camera=False)
    )[0]
    assert keep_all.n1 == 5 and keep_all.n2 == 5
    np.testing.assert_allclose(keep_all.flow[0], [-1.0, 0.0, 0.0], atol=1e-6)


def test_opensceneflow_passes_classes_and_instances_through(tmp_path: Path) -> None:
    _write_osf(tmp_path / "scene_a.h5", labels=True)
    s = load_split(tmp_path)[0]
    # ground (index 3) and invalid flow (index 2) removed, as for every other per-point array
    assert s.classes.tolist() == [0, 0, 1] and s.instance.tolist() == [-1, -1, 7]
    assert s.foreground.tolist() == [False, False, True]


# ------------------------------------------------------------------------------------------------
# detection, sorting, names, bad files


def test_auto_detection_and_sorting(tmp_path: Path) -> None:
    z = np.zeros((2, 3))
    for name in ("000002", "000000", "000001"):
        _write_fn3d(tmp_path / f"{name}.npz", z + 1, z + 1, z)
    assert detect_format(tmp_path) == "flownet3d"
    assert detect_format(tmp_path / "000001.npz") == "flownet3d"
    split = load_split(tmp_path)
    assert split.names == ["000000", "000001", "000002"]
    assert [s.name for s in split] == split.names
    assert len(split[0:2]) == 2
    assert load_split(tmp_path, names=["000001"]).names == ["000001"]
    with pytest.raises(InputError, match="unknown scene names"):
        load_split(tmp_path, names=["nope"])
    single = load_split(tmp_path / "000002.npz")
    assert single.names == ["000002"]


def test_empty_or_mixed_folder(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="no scene-flow data"):
        load_split(tmp_path)
    with pytest.raises(InputError, match="no such file"):
        load_split(tmp_path / "missing")
    _write_fn3d(tmp_path / "a.npz", np.ones((1, 3)), np.ones((1, 3)), np.zeros((1, 3)))
    _write_osf(tmp_path / "b.h5")
    with pytest.raises(InputError, match="mixes several formats"):
        load_split(tmp_path)
    assert load_split(tmp_path, fmt="flownet3d").names == ["a"]


def test_one_bad_file_among_many_is_named(tmp_path: Path) -> None:
    z = np.zeros((3, 3))
    for i in range(5):
        _write_fn3d(tmp_path / f"{i:06d}.npz", z + 1, z + 1, z)
    np.savez(tmp_path / "000003.npz", pos1=z, pos2=z)  # no 'gt'
    (tmp_path / "000004.npz").write_bytes(b"this is not a zip file")
    with pytest.raises(InputError) as info:
        load_split(tmp_path)
    msg = str(info.value)
    assert "2 malformed flownet3d entries" in msg
    assert "000003.npz: missing arrays ['gt']" in msg
    assert "000004.npz: not a readable .npz" in msg
    for good in ("000000.npz", "000001.npz", "000002.npz"):
        assert good not in msg


def test_bad_shapes_are_reported(tmp_path: Path) -> None:
    _write_fn3d(tmp_path / "a.npz", np.ones((4, 3)), np.ones((2, 3)), np.zeros((3, 3)))
    with pytest.raises(InputError, match=r"a\.npz: 'gt' has 3 rows, expected 4"):
        load_split(tmp_path)


def test_hpl_folder_missing_file_is_named(tmp_path: Path) -> None:
    for i in range(3):
        _write_hpl(tmp_path / f"{i:06d}", np.ones((2, 3)), np.ones((2, 3)))
    (tmp_path / "000001" / "pc2.npy").unlink()
    with pytest.raises(InputError, match=r"000001: missing pc2\.npy") as info:
        load_split(tmp_path)
    assert "000000" not in str(info.value).split(": 1 malformed")[1]


def test_bad_values_raise_input_error_on_access(tmp_path: Path) -> None:
    pos = np.array([[1.0, 0, 0], [np.nan, 0, 0]])
    _write_fn3d(tmp_path / "nan.npz", pos, np.ones((2, 3)), np.zeros((2, 3)))
    split = load_split(tmp_path)  # headers are fine
    with pytest.raises(InputError, match=r"nan\.npz: cannot read scene 'nan': pc1 contains non-finite"):
        split[0]


def test_osf_bad_file_named(tmp_path: Path) -> None:
    import h5py

    _write_osf(tmp_path / "good.h5")
    with h5py.File(tmp_path / "bad.h5", "w") as f:
        g = f.create_group("1")
        g.create_dataset("lidar", data=np.zeros((3, 3)))
        f.create_group("2")
    with pytest.raises(InputError, match=r"bad\.h5: group 1: missing \['pose', 'ground_mask'\]"):
        load_split(tmp_path)
