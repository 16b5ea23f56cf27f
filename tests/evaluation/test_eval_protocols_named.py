"""The named protocols pin the exact points they score (released, fps, hplflownet, flownet3d), the scene
selections (HPLFlowNet's mapping, first/last/kitti_t) and the trained-on guard, and the newer metrics
(three-way EPE, dynamic normalised EPE, distance bands) are checked against hand-computed values."""

from __future__ import annotations

import json
import math
import zlib
from pathlib import Path

import numpy as np
import pytest
import torch

from evaluation.cli import main
from evaluation.metrics import aggregate, scene_metrics
from evaluation.protocols import ProtocolConfig, prepare_scene, run_protocol, scored_points, summary_rows
from evaluation.sample import SceneFlowSample
from evaluation.scenes import check_not_trained_on, mapped_scenes, select_scenes, trained_scenes
from core.errors import ConfigError, InputError

torch.set_num_threads(1)
MAPPING = Path(__file__).resolve().parents[3] / "shared" / "data" / "kitti_sceneflow2015_train_mapping" / \
    "train_mapping.txt"


def indexed_scene(name: str, n1: int, n2: int | None = None) -> SceneFlowSample:
    """A scene whose pc1 row i is (i, 0, 5 + i·1e-3) and whose true flow is (0, 0, i): a point's row can be
    read back from its coordinates (camera frame, metres)."""
    n2 = n1 if n2 is None else n2
    i1, i2 = np.arange(n1, dtype=np.float32), np.arange(n2, dtype=np.float32)
    pc1 = np.stack([i1, np.zeros_like(i1), 5 + i1 * 1e-3], axis=1)
    pc2 = np.stack([-i2, np.ones_like(i2), 5 + i2 * 1e-3], axis=1)
    flow = np.stack([np.zeros_like(i1), np.zeros_like(i1), i1], axis=1)
    return SceneFlowSample(name, pc1, pc2, flow)


def seeded(seed: int, name: str) -> np.random.Generator:
    return np.random.default_rng([seed, zlib.crc32(name.encode())])


def rows_of(points: np.ndarray) -> np.ndarray:
    return np.rint(points[:, 0]).astype(int)


# ---------------------------------------------------------------------------------------------- released


def test_released_scores_exactly_the_first_2048_of_the_seeded_8192_sample() -> None:
    scene = indexed_scene("000007", 20_000, 19_000)
    prepared = prepare_scene(scene, ProtocolConfig("released", n_points=8192, n_score=2048), seed=3)
    rng = seeded(3, "000007")
    want1 = rng.choice(20_000, size=8192, replace=False)
    want2 = rng.choice(19_000, size=8192, replace=False)  # pc2: the next draw of the same generator
    np.testing.assert_array_equal(prepared.index1, want1)
    np.testing.assert_array_equal(prepared.index2, want2)
    np.testing.assert_array_equal(prepared.score_index, np.arange(2048))
    np.testing.assert_array_equal(rows_of(prepared.points), want1[:2048])  # the first 2048, in sample order
    np.testing.assert_array_equal(prepared.gt[:, 2], want1[:2048].astype(np.float32))
    assert len(set(want1.tolist())) == 8192  # without replacement
    # the same seed gives the same points; another seed other points
    again = prepare_scene(scene, ProtocolConfig("released"), seed=3)
    np.testing.assert_array_equal(again.points, prepared.points)
    other = prepare_scene(scene, ProtocolConfig("released"), seed=4)
    assert not np.array_equal(other.index1, prepared.index1)


def test_released_padding_on_a_5000_point_cloud_is_arange_then_repeats_unshuffled() -> None:
    scene = indexed_scene("000001", 5000, 9000)
    prepared = prepare_scene(scene, ProtocolConfig("released", n_points=8192, n_score=2048), seed=0)
    s1 = prepared.index1
    np.testing.assert_array_equal(s1[:5000], np.arange(5000))  # every point once, in file order
    rng = seeded(0, "000001")
    np.testing.assert_array_equal(s1[5000:], rng.choice(5000, size=3192, replace=True))  # then random repeats
    assert len(prepared.index2) == 8192 and len(set(prepared.index2.tolist())) == 8192  # pc2 has enough points
    # so the scored points are the file's first 2048 points, in file order
    np.testing.assert_array_equal(rows_of(prepared.points), np.arange(2048))
    np.testing.assert_array_equal(prepared.points, scene.pc1[:2048])


def test_fps_and_its_old_name_paper_score_the_farthest_point_samples() -> None:
    scene = indexed_scene("s", 600)
    fps = prepare_scene(scene, ProtocolConfig("fps", n_points=256, n_score=32), seed=1)
    paper = prepare_scene(scene, ProtocolConfig("paper", n_points=256, n_score=32), seed=1)
    np.testing.assert_array_equal(fps.points, paper.points)
    np.testing.assert_array_equal(fps.score_index, scored_points(fps.pc1, 32))
    assert ProtocolConfig("paper").validate().protocol == "fps"
    released = prepare_scene(scene, ProtocolConfig("released", n_points=256, n_score=32), seed=1)
    assert not np.array_equal(np.sort(rows_of(released.points)), np.sort(rows_of(fps.points)))
    with pytest.raises(ConfigError, match="unknown protocol"):
        ProtocolConfig("kitti").validate()


# ---------------------------------------------------------------------------------------------- hplflownet


def test_hplflownet_samples_pc2_independently_and_scores_every_sampled_point() -> None:
    scene = indexed_scene("000010", 300)
    prepared = prepare_scene(scene, ProtocolConfig("hplflownet", n_points=128), seed=2)
    rng = seeded(2, "000010")
    np.testing.assert_array_equal(prepared.index1, rng.choice(300, 128, replace=False))
    np.testing.assert_array_equal(prepared.index2, rng.choice(300, 128, replace=False))
    assert not np.array_equal(prepared.index1, prepared.index2)
    np.testing.assert_array_equal(prepared.score_index, np.arange(128))  # all scored
    np.testing.assert_array_equal(rows_of(prepared.points), prepared.index1)
    # a cloud with fewer points is used whole, in file order, without padding
    small = prepare_scene(indexed_scene("000011", 100), ProtocolConfig("hplflownet", n_points=128), seed=2)
    np.testing.assert_array_equal(small.index1, np.arange(100))
    np.testing.assert_array_equal(small.index2, np.arange(100))
    assert len(small.points) == 100


def test_flownet3d_scores_every_sampled_row_repeats_included() -> None:
    scene = indexed_scene("x", 100)
    prepared = prepare_scene(scene, ProtocolConfig("flownet3d", n_points=160), seed=0)
    np.testing.assert_array_equal(prepared.index1[:100], np.arange(100))
    np.testing.assert_array_equal(rows_of(prepared.points), prepared.index1)
    assert len(prepared.points) == 160 and len(set(rows_of(prepared.points).tolist())) == 100


def test_mapping_drops_exactly_the_scenes_with_an_empty_line(tmp_path: Path) -> None:
    mapping = tmp_path / "train_mapping.txt"
    mapping.write_text("\n2011_09_26 2011_09_26_drive_0001_sync 0000000001\n\n  \nx y 3\n")
    kept, dropped = mapped_scenes(["000000", "000001", "000002", "000003", "000004"], mapping)
    assert kept == ["000001", "000004"] and dropped == ["000000", "000002", "000003"]
    with pytest.raises(InputError, match=str(mapping)):
        mapped_scenes(["000009"], mapping)  # past the file's end
    with pytest.raises(InputError, match="not found"):
        mapped_scenes(["000000"], tmp_path / "missing.txt")


@pytest.mark.skipif(not MAPPING.is_file(), reason=f"KITTI devkit mapping not found at {MAPPING}")
def test_devkit_mapping_keeps_the_142_scenes() -> None:
    names = [f"{i:06d}" for i in range(200)]
    kept, dropped = mapped_scenes(names, MAPPING)
    assert len(kept) == 142 and len(dropped) == 58
    assert dropped[:2] == ["000000", "000001"] and kept[-1] == "000199"


def _hpl_split(root: Path) -> Path:
    """Four HPLFlowNet scenes of 40 pairs (stored axes (−x, −y, z), above the ground, z < 35 m)."""
    rng = np.random.default_rng(0)
    for i in range(4):
        d = root / f"{i:06d}"
        d.mkdir(parents=True)
        pc1 = np.stack([rng.uniform(-5, 5, 40), rng.uniform(-1, 1, 40), rng.uniform(5, 30, 40)], 1)
        np.save(d / "pc1.npy", pc1.astype(np.float32))
        np.save(d / "pc2.npy", (pc1 + [0, 0, 0.5 * i]).astype(np.float32))
    return root


def test_cli_hplflownet_needs_the_mapping_and_scores_the_mapped_scenes(tmp_path: Path, capsys) -> None:
    split = _hpl_split(tmp_path / "KITTI_processed_occ_final")
    mapping = tmp_path / "map.txt"
    mapping.write_text("a b 1\n\nc d 2\ne f 3\n")
    out = tmp_path / "eval"
    assert main(["run", "--split", str(split), "--protocol", "hplflownet", "--baselines", "zero",
                 "--out", str(out), "--no-progress"]) == 2
    assert "needs --mapping" in capsys.readouterr().err
    assert main(["run", "--split", str(split), "--protocol", "hplflownet", "--mapping", str(mapping),
                 "--baselines", "zero", "--out", str(out), "--no-progress"]) == 0
    printed = capsys.readouterr().out
    report = json.loads((out / "results.json").read_text())
    assert report["scenes"] == ["000000", "000002", "000003"]
    assert report["selection"]["dropped_by_mapping"] == ["000001"]
    assert "3 scenes (3 of 4 have a raw-data mapping)" in printed and "protocol hplflownet" in printed
    # every point scored: 40 < 8192, so each cloud is used whole; zero flow's EPE is the mean |flow|
    assert report["per_scene"]["zero"][1]["n_points"] == 40
    assert report["rows"][0]["EPE3D"] == pytest.approx((0 + 1.0 + 1.5) / 3, abs=1e-6)


# ---------------------------------------------------------------------------------------------- scenes, guard


def test_scene_selections() -> None:
    names = [f"{i:06d}" for i in range(150)]
    assert select_scenes(names, "first:100") == names[:100]
    assert select_scenes(names, "last:50") == names[100:] == select_scenes(names, "kitti_t")
    assert not set(select_scenes(names, "first:100")) & set(select_scenes(names, "kitti_t"))
    assert select_scenes(names, "all") == names
    for bad in ("last:0", "first:151", "middle:3", "first:x"):
        with pytest.raises(ConfigError):
            select_scenes(names, bad)
    with pytest.raises(ConfigError, match="kitti_t"):
        select_scenes(names[:142], "kitti_t")


def test_guard_refuses_scenes_the_run_records(tmp_path: Path) -> None:
    ckpt = tmp_path / "run" / "latest.pt"
    ckpt.parent.mkdir()
    check_not_trained_on(ckpt, {}, tmp_path, ["000120"])  # nothing recorded: allowed
    (ckpt.parent / "train_scenes.txt").write_text("\n".join(f"{i:06d}" for i in range(100)) + "\n")
    check_not_trained_on(ckpt, {}, tmp_path, ["000120", "000149"])  # disjoint: allowed
    with pytest.raises(ConfigError, match="trained on 1 of the scenes"):
        check_not_trained_on(ckpt, {}, tmp_path, ["000099", "000120"])
    seen, where = trained_scenes(ckpt, {"data": {"train_scenes": ["000003"]}})
    assert seen == {"000003"} and "config.data.train_scenes" in where


def test_guard_refuses_a_synthetic_test_split_whose_sequence_the_cache_holds(tmp_path: Path) -> None:
    world = tmp_path / "world"
    (world / "sceneflow" / "flownet3d").mkdir(parents=True)
    (world / "synth.json").write_text(json.dumps({"test_sequence": "02"}))
    cache = tmp_path / "cache"
    cache.mkdir()
    source = {"root": str(world.resolve()), "sequences": {"00": {}, "01": {}}}
    (cache / "cache.json").write_text(json.dumps({"source": source}))
    split = world / "sceneflow" / "flownet3d"
    check_not_trained_on(tmp_path / "latest.pt", {"cache": str(cache)}, split, ["000000"])
    source["sequences"]["02"] = {}
    (cache / "cache.json").write_text(json.dumps({"source": source}))
    with pytest.raises(ConfigError, match="sequence 02"):
        check_not_trained_on(tmp_path / "latest.pt", {"cache": str(cache)}, split, ["000000"])


# ---------------------------------------------------------------------------------------------- metrics


def test_threeway_and_dynamic_normalised_epe_by_hand() -> None:
    # six points, camera frame, metres; classes 0 = background, 1 = car
    gt = np.array([[0, 0, 1.0], [0, 0, 1.0], [0, 0, 1.0], [0, 0, 2.0], [0, 0, 4.0], [0, 0, 2.0]])
    pred = gt.copy()
    pred[0, 2] += 0.1   # bg static: EPE 0.1
    pred[1, 2] += 0.3   # bg static: EPE 0.3
    pred[2, 2] += 0.5   # fg static (a parked car): EPE 0.5
    pred[3, 2] -= 2.0   # fg dynamic: EPE 2.0 (predicted zero), |g| 2
    pred[4, 2] -= 1.0   # fg dynamic: EPE 1.0, |g| 4
    moving = np.array([0, 0, 0, 1, 1, 0], bool)
    fg = np.array([0, 0, 1, 1, 1, 0], bool)  # point 5: background, static, exact
    depth = np.array([5.0, 25.0, 10.0, 40.0, 19.9, 20.0])
    m = scene_metrics(pred, gt, moving=moving, foreground=fg, depth=depth)
    assert m["bg_static"]["EPE3D"] == pytest.approx((0.1 + 0.3 + 0.0) / 3)
    assert m["fg_static"]["EPE3D"] == pytest.approx(0.5)
    assert m["fg_dynamic"]["EPE3D"] == pytest.approx(1.5)
    # dynamic normalised EPE: mean EPE of the movers / their mean |g| = 1.5 / 3
    assert m["moving"]["EPE3D_norm"] == pytest.approx(0.5)
    assert m["z0-20"]["EPE3D"] == pytest.approx((0.1 + 0.5 + 1.0) / 3)  # z 5, 10, 19.9
    assert m["z20-35"]["EPE3D"] == pytest.approx((0.3 + 0.0) / 2)  # z 25, 20 (lower edge included)
    assert m["z35+"]["EPE3D"] == pytest.approx(2.0)
    agg = aggregate([m])
    assert agg["EPE3D_threeway"] == pytest.approx((0.4 / 3 + 0.5 + 1.5) / 3)
    # a second scene without movers or cars: three-way subsets average over the scenes that have them
    m2 = scene_metrics(np.zeros((2, 3)), np.array([[0, 0, 0.2], [0, 0, 0.4]]), moving=np.zeros(2, bool),
                       foreground=np.zeros(2, bool), depth=np.array([1.0, 2.0]))
    agg2 = aggregate([m, m2])
    assert agg2["bg_static"]["EPE3D"] == pytest.approx((0.4 / 3 + 0.3) / 2)
    assert agg2["fg_dynamic"]["EPE3D"] == pytest.approx(1.5) and agg2["fg_dynamic"]["n_scenes"] == 1
    assert agg2["EPE3D_threeway"] == pytest.approx(((0.4 / 3 + 0.3) / 2 + 0.5 + 1.5) / 3)
    assert agg2["moving"]["EPE3D_norm"] == pytest.approx(0.5)


def test_summary_rows_carry_the_new_metrics_through_the_protocol() -> None:
    pc1 = np.array([[0, 0, 5.0], [1, 0, 10.0], [2, 0, 25.0], [3, 0, 40.0]], np.float32)
    flow = np.array([[0, 0, 1.0], [0, 0, 2.0], [0, 0, 0.5], [0, 0, 0.0]], np.float32)
    scene = SceneFlowSample("a", pc1, pc1 + flow, flow, moving=np.array([1, 0, 0, 0], bool),
                            classes=np.array([1, 1, 0, 0]))
    res = run_protocol([scene], [_Zero()], ProtocolConfig("released", n_points=4, n_score=4), progress=False)
    row = summary_rows(res)[0]
    assert row["EPE3D_fg_dynamic"] == pytest.approx(1.0) and row["EPE3D_fg_static"] == pytest.approx(2.0)
    assert row["EPE3D_bg_static"] == pytest.approx(0.25)
    assert row["EPE3D_threeway"] == pytest.approx((1.0 + 2.0 + 0.25) / 3)
    assert row["EPE3D_norm_dynamic"] == pytest.approx(1.0)  # zero flow leaves all the motion undescribed
    assert row["EPE3D_z0-20"] == pytest.approx(1.5) and row["EPE3D_z20-35"] == pytest.approx(0.5)
    assert row["EPE3D_z35+"] == pytest.approx(0.0)
    assert math.isclose(row["EPE3D"], 3.5 / 4)


class _Zero:
    name = "zero"

    def __call__(self, pc1, pc2, color1=None, color2=None):
        return np.zeros_like(pc1)
