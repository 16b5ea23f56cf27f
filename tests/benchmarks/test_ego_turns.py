"""benchmarks/ego_turns.py: frame 2 turned about camera 2's vertical axis, the ground truth turned with it."""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks.ego_turns import main, turned_frame2
from evaluation.sample import SceneFlowSample
from pipeline.synth.world import rot_y
from testkit.rigid_scene import motion, structured_scene


def _sample(seed: int = 0, n: int = 400) -> SceneFlowSample:
    """The structured street seen from a camera that moved 1 m forward and turned 1°; a block of points moves
    0.5 m to the right on its own."""
    pc1 = structured_scene(np.random.default_rng(seed), n).astype(np.float32)
    T = motion(1.0, (0.0, 1.0, 0.0), (0.0, 0.0, -1.0))
    flow = (pc1 @ T[:3, :3].T + T[:3, 3] - pc1).astype(np.float32)
    moving = np.zeros(n, bool)
    moving[:30] = True
    flow[:30, 0] += 0.5
    pc2 = (pc1 + flow)[np.random.default_rng(seed + 1).permutation(n)]
    return SceneFlowSample(name=f"{seed:06d}", pc1=pc1, pc2=pc2, flow=flow, moving=moving, pose=T)


def test_the_turn_rotates_frame_2_and_the_truth_alike_and_composes_the_pose():
    s = _sample()
    t = turned_frame2(s, 3.0)
    A = rot_y(np.deg2rad(3.0))
    assert np.allclose(A @ A.T, np.eye(3)) and np.isclose(np.linalg.det(A), 1.0) and np.allclose(A[1], [0, 1, 0])
    assert np.allclose(t.pc2, s.pc2 @ A.T, atol=1e-5)
    assert np.allclose(t.pc1 + t.flow, (s.pc1 + s.flow) @ A.T, atol=1e-4)  # movers too
    static = ~s.moving
    want = s.pc1[static] @ t.pose[:3, :3].T + t.pose[:3, 3]  # the composed camera motion A·T
    assert np.allclose(t.pc1[static] + t.flow[static], want, atol=1e-4)
    assert t.pc1 is s.pc1 and t.moving is s.moving
    assert turned_frame2(s, 0.0) is s


def test_the_table_scores_every_method_at_every_turn(tmp_path, capsys):
    split = tmp_path / "split"
    split.mkdir()
    for i in range(2):
        s = _sample(i)
        lidar = lambda p: np.stack([p[:, 2], -p[:, 0], -p[:, 1]], 1).astype(np.float32)  # noqa: E731
        np.savez(split / f"{i:06d}.npz", pos1=lidar(s.pc1), pos2=lidar(s.pc2), gt=lidar(s.flow), moving=s.moving)
    assert main(["--split", f"s={split}", "--turns", "0,3", "--scan", "0,6", "--baselines", "zero,rvote",
                 "--n-points", "256"]) == 0
    rows = [r.split("|") for r in capsys.readouterr().out.splitlines() if r.startswith("| s |")]
    assert [(r[2].strip(), r[3].strip()) for r in rows] == [
        (turn, m) for turn in ("+0°", "+3°") for m in ("zero", "rvote, scan ±0°", "rvote, scan ±6°")]
    epe = {(r[2].strip(), r[3].strip()): float(r[4]) for r in rows}
    assert all(np.isfinite(v) and v >= 0 for v in epe.values())
    # the zero flow is off by the camera's whole motion, more so when it turns more
    assert epe[("+3°", "zero")] > epe[("+0°", "zero")] > 0.5


def test_a_malformed_turn_list_is_one_usage_line(capsys):
    with pytest.raises(SystemExit) as e:
        main(["--split", "s=x", "--turns", "two"])
    assert e.value.code == 2 and "--turns" in capsys.readouterr().err
