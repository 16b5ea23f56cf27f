"""benchmarks/sensor_gap.py's ego-motion check: the rigid motion of a method's static flow against the truth,
with its signed per-axis errors."""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks.sensor_gap import ego_errors
from core.geometry import pose_vec_to_mat
from evaluation.protocols import ProtocolConfig
from evaluation.sample import SceneFlowSample


def _split(n: int = 600):
    rng = np.random.default_rng(0)
    pc1 = (rng.random((n, 3)) * [20.0, 3.0, 30.0] + [-10.0, -2.0, 5.0]).astype(np.float32)
    T = pose_vec_to_mat(np.array([0.05, 0.0, -1.2, 0.0, 0.01, 0.0]))
    flow = (pc1 @ T[:3, :3].T + T[:3, 3] - pc1).astype(np.float32)
    moving = np.zeros(n, bool)
    moving[:40] = True
    flow[:40] += 3.0  # movers: not part of the fit
    return [SceneFlowSample("a", pc1, pc1 + flow, flow, moving=moving)], T


def test_truth_has_no_error_and_a_known_bias_shows_on_its_axis():
    split, T = _split()
    cfg = ProtocolConfig(protocol="fps", n_points=512, n_score=128, seeds=(0,), warmup=False).validate()

    def exact(pc1, pc2, *_):
        rows = {tuple(p): i for i, p in enumerate(map(tuple, split[0].pc1))}
        return split[0].flow[[rows[tuple(p)] for p in map(tuple, pc1)]]

    e = ego_errors(exact, split, cfg)
    assert e["t_err"] < 1e-4 and e["rot_err_deg"] < 1e-3
    assert e["t_true"] == pytest.approx(np.linalg.norm(T[:3, 3]), abs=1e-4)

    def short_and_down(pc1, pc2, *_):  # every point 0.3 m short forward and 0.1 m down
        return exact(pc1, pc2) + np.array([0.0, 0.1, 0.3], dtype=np.float32)

    e = ego_errors(short_and_down, split, cfg)
    assert e["dt_x"] == pytest.approx(0.0, abs=1e-4)
    assert e["dt_y"] == pytest.approx(0.1, abs=1e-4) and e["dt_z"] == pytest.approx(0.3, abs=1e-4)
    assert e["t_net"] == pytest.approx(np.linalg.norm(T[:3, 3] + [0.0, 0.1, 0.3]), abs=1e-3)
    assert max(abs(e[k]) for k in ("dr_pitch", "dr_yaw", "dr_roll")) < 1e-3


def test_per_level_report_has_one_line_per_level_coarsest_first(tmp_path, capsys):
    from benchmarks.sensor_gap import print_levels
    from evaluation.methods import NetMethod
    from testkit.flow_checkpoint import tiny_flow_checkpoint

    split, _ = _split(400)
    net = NetMethod(tiny_flow_checkpoint(tmp_path / "net.pt"), device="cpu", name="tiny")
    cfg = ProtocolConfig(protocol="fps", n_points=256, n_score=128, seeds=(0,), warmup=False).validate()
    print_levels(net, "own", split, cfg)
    lines = capsys.readouterr().out.strip().splitlines()
    assert [line.split()[2] for line in lines] == ["L3:", "L2:", "L1:", "L0:"]
    assert all("|t|" in line and "static EPE3D" in line and "nan" not in line for line in lines)


def test_gate_shares_count_open_gates_on_static_and_moving_points_per_level():
    """A stand-in net whose ego gate opens on the points with x < 0 at L0 and on none at L1: the shares are
    those points' fractions among the static and the moving points the protocol sampled."""
    from types import SimpleNamespace

    import torch

    from benchmarks.sensor_gap import gate_shares
    from evaluation.protocols import prepare_scene

    split, _ = _split(400)
    cfg = ProtocolConfig(protocol="fps", n_points=256, n_score=128, seeds=(0,), warmup=False).validate()

    def net(pc1, pc2):
        idx = torch.arange(pc1.shape[1])[None]
        return SimpleNamespace(indices=[idx, idx[:, ::2]], gates=[(pc1[..., 0] < 0).float(), torch.zeros(1, 128)])

    shares = gate_shares(SimpleNamespace(net=net, device="cpu"), split, cfg)
    scene = prepare_scene(split[0], cfg, 0)
    left, moving = scene.pc1[:, 0] < 0, split[0].moving[scene.index1]
    assert moving.any() and (~moving).any()
    want = ((left & ~moving).sum() / (~moving).sum(), (left & moving).sum() / moving.sum())
    assert shares[0] == pytest.approx(want)
    assert shares[1] == (0.0, 0.0)


def test_speed_scaled_camera_pairs_keep_the_targets_and_scale_the_motion():
    from types import SimpleNamespace

    from benchmarks.sensor_gap import cache_samples, static_motion

    (sample,), T = _split(300)
    pair = SimpleNamespace(pc1=sample.pc1, pc2=sample.pc2, gt_flow=sample.flow, moving=sample.moving, T=T)
    plain, = cache_samples([pair], None, "c")
    doubled, = cache_samples([pair], None, "c", speed_scale=2.0)
    assert np.array_equal(plain.pc1, sample.pc1) and np.array_equal(plain.flow, sample.flow)
    # every point still lands where it did in frame t+1 (movers included), frame t+1 untouched
    assert np.allclose(doubled.pc1 + doubled.flow, sample.pc1 + sample.flow, atol=1e-4)
    assert np.array_equal(doubled.pc2, sample.pc2)
    static = ~sample.moving
    _, tr = static_motion(doubled.pc1[static].astype(np.float64), doubled.flow[static].astype(np.float64))
    assert np.allclose(tr, 2.0 * T[:3, 3], atol=1e-3)  # the static motion is twice the pair's
