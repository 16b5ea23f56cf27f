"""benchmarks/mover_bias.py: the share of each moving object's own motion a net's flow takes, per level."""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks.mover_bias import heading_class, main, object_shares, summary
from testkit.flow_checkpoint import tiny_flow_checkpoint
from testkit.rigid_scene import structured_scene


def _objects(n_per: int = 10):
    """Two movers (instances 1, 2) and static points (instance 0); the camera moves 1 m forward."""
    n = 3 * n_per
    rigid = np.tile(np.float32([0.0, 0.0, -1.0]), (n, 1))
    own = np.zeros((n, 3), np.float32)
    own[n_per:2 * n_per] = [2.0, 0.0, 0.0]   # object 1 drives 2 m right
    own[2 * n_per:] = [0.0, 0.0, 1.5]        # object 2 drives 1.5 m forward
    gt = rigid + own
    instance = np.repeat([0, 1, 2], n_per)
    return rigid, gt, instance != 0, instance


def test_half_the_motion_is_a_share_of_one_half_and_an_offset_across_is_metres():
    rigid, gt, moving, instance = _objects()
    half = rigid + 0.5 * (gt - rigid)
    objs = object_shares(half, rigid, gt, moving, instance)
    assert [o.points for o in objs] == [10, 10]
    assert [o.share for o in objs] == pytest.approx([0.5, 0.5], abs=1e-6)
    assert [o.across_m for o in objs] == pytest.approx([0.0, 0.0], abs=1e-6)
    assert objs[0].motion_m == pytest.approx(2.0, abs=1e-6) and objs[0].epe_m == pytest.approx(1.0, abs=1e-6)
    across = gt + np.float32([0.0, 0.3, 0.0])  # the whole motion, plus 0.3 m down
    objs = object_shares(across, rigid, gt, moving, instance)
    assert [o.share for o in objs] == pytest.approx([1.0, 1.0], abs=1e-6)
    assert [o.across_m for o in objs] == pytest.approx([0.3, 0.3], abs=1e-5)
    held = object_shares(rigid, rigid, gt, moving, instance)  # left with the camera
    assert [o.share for o in held] == pytest.approx([0.0, 0.0], abs=1e-6)
    assert [o.heading_deg for o in objs] == pytest.approx([90.0, 0.0])  # right, straight ahead
    assert [heading_class(o.heading_deg) for o in objs] == ["crossing", "away"]
    assert [heading_class(h) for h in (-44.0, 46.0, 134.0, 136.0, -179.0)] == ["away", "crossing", "crossing",
                                                                            "toward", "toward"]
    r = summary(objs)
    assert r["objects"] == 2 and r["points"] == 20 and r["share_median"] == pytest.approx(1.0)


def test_small_objects_and_objects_that_do_not_move_are_left_out():
    rigid, gt, moving, instance = _objects()
    assert len(object_shares(gt, rigid, gt, moving, instance, min_points=11)) == 0
    still = moving.copy()
    objs = object_shares(gt, rigid, rigid.copy(), still, instance)  # labelled moving, no own motion
    assert objs == [] and summary(objs) == {"objects": 0, "points": 0}


def _split(folder, labels: bool, n: int = 300) -> None:
    """Two FlowNet3D-layout scenes of the structured street; a block of points moves 1 m on its own."""
    folder.mkdir(parents=True)
    for i in range(2):
        cam = structured_scene(np.random.default_rng(i), n)
        lidar = np.stack([cam[:, 2], -cam[:, 0], -cam[:, 1]], 1).astype(np.float32)
        flow = np.tile(np.float32([-1.0, 0.0, 0.0]), (n, 1))
        moving = np.zeros(n, bool)
        moving[:40] = True
        flow[:40, 1] += 1.0
        extra = {"moving": moving, "instance": moving.astype(np.int32)} if labels else {}
        np.savez(folder / f"{i:06d}.npz", pos1=lidar, pos2=lidar + flow, gt=flow, **extra)


def test_the_table_has_a_row_per_split_and_level(tmp_path, capsys):
    path = tiny_flow_checkpoint(tmp_path / "net.pt", ego_head=True)
    _split(tmp_path / "split", labels=True)
    assert main(["--checkpoint", str(path), "--split", f"s={tmp_path / 'split'}", "--n-points", "256"]) == 0
    rows = [r for r in capsys.readouterr().out.splitlines() if r.startswith("| s |")]
    assert [r.split("|")[2].strip() for r in rows] == ["L0", "L1", "L2", "L3"]
    epe = float(rows[0].split("|")[8])
    assert np.isfinite(epe) and epe >= 0
    assert main(["--checkpoint", str(path), "--split", f"s={tmp_path / 'split'}", "--n-points", "256", "--by-heading"]) == 0
    rows = [r for r in capsys.readouterr().out.splitlines() if r.startswith("| s |")]
    labels = [r.split("|")[2].strip() for r in rows]
    assert labels[:4] == ["L0", "L0 away", "L0 crossing", "L0 toward"] and len(labels) == 16
    by_class = {r.split("|")[2].strip(): int(r.split("|")[3]) for r in rows}
    assert by_class["L0"] > 0 and by_class["L0 crossing"] == by_class["L0"] and by_class["L0 away"] == by_class["L0 toward"] == 0  # moves along y


def test_a_split_without_labels_or_a_net_without_an_ego_head_is_one_line(tmp_path, capsys):
    plain = tiny_flow_checkpoint(tmp_path / "plain.pt")
    ego = tiny_flow_checkpoint(tmp_path / "ego.pt", ego_head=True)
    _split(tmp_path / "bare", labels=False)
    _split(tmp_path / "labelled", labels=True)
    for ck, split, says in ((ego, "bare", "no moving/instance labels"), (plain, "labelled", "model.ego_head")):
        assert main(["--checkpoint", str(ck), "--split", f"s={tmp_path / split}", "--n-points", "256"]) == 2
        err = capsys.readouterr().err
        assert err.startswith("error: ") and says in err and len(err.strip().splitlines()) == 1
