"""Scoring protocols: hand-computed golden values on a hand-written FlowNet3D split, identical points for
every method, seeds, and the ``full`` protocol scoring every input point."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch

from evaluation.methods import BaselineMethod, make_baseline
from evaluation.protocols import (
    ProtocolConfig,
    choose_points,
    prepare_scene,
    run_protocol,
    scored_points,
    summary_rows,
)
from evaluation.readers import load_split
from evaluation.report import markdown_table
from evaluation.sample import SceneFlowSample
from core.errors import ConfigError, InputError

torch.set_num_threads(1)

# Scene "a": four points in FlowNet3D's LiDAR axes (x fwd, y left, z up); camera = (−y, −z, x).
A_POS1 = np.array([[10, 0, 0], [12, 2, 0.5], [14, -2, 1], [16, 1, -0.5]], np.float32)
A_GT = np.array([[0.3, 0.4, 0], [0, 0, 0.2], [0.12, 0, 0], [0, 0, 0]], np.float32)
# in camera axes: (−0.4, 0, 0.3) |0.5|, (0, −0.2, 0) |0.2|, (0, 0, 0.12) |0.12|, 0
# Scene "b": two static points.
B_POS1 = np.array([[8, 1, 0], [9, -1, 0.2]], np.float32)
OFFSET = np.array([-0.4, 0.0, 0.3], np.float32)  # camera frame; equals scene a's first true flow


@pytest.fixture()
def golden_split(tmp_path: Path) -> Path:
    root = tmp_path / "kitti_rm_ground"
    root.mkdir()
    np.savez(root / "a.npz", pos1=A_POS1, pos2=A_POS1 + A_GT, gt=A_GT)
    np.savez(root / "b.npz", pos1=B_POS1, pos2=B_POS1 + 0.0, gt=np.zeros_like(B_POS1))
    return root


class ConstantFlow:
    """Predicts the same flow (camera frame, metres) for every point."""

    def __init__(self, flow: np.ndarray, name: str = "constant") -> None:
        self.flow, self.name = np.asarray(flow, np.float32), name

    def __call__(self, pc1, pc2, color1=None, color2=None):
        return np.tile(self.flow, (len(pc1), 1))


class Recorder:
    """Records every input it is given; predicts ``scale · pc1`` (so its error depends on the points)."""

    def __init__(self, name: str, scale: float = 0.01) -> None:
        self.name, self.scale, self.calls = name, scale, []

    def __call__(self, pc1, pc2, color1=None, color2=None):
        self.calls.append({"pc1": pc1.copy(), "pc2": pc2.copy(), "color1": None if color1 is None else color1.copy(),
                           "color2": None if color2 is None else color2.copy(),
                           "writeable": [a.flags.writeable for a in (pc1, pc2) if a is not None]})
        return (self.scale * pc1).astype(np.float32)


def _expected_zero() -> dict[str, float]:
    a = {"EPE3D": (0.5 + 0.2 + 0.12 + 0.0) / 4, "Acc3DS": 0.25, "Acc3DR": 0.25, "Outliers3D": 0.75}
    b = {"EPE3D": 0.0, "Acc3DS": 1.0, "Acc3DR": 1.0, "Outliers3D": 0.0}
    return {k: (a[k] + b[k]) / 2 for k in a}


def _expected_offset() -> dict[str, float]:
    # scene a: errors 0, |(−0.4, 0.2, 0.3)| = √0.29, |(−0.4, 0, 0.18)| = √0.1924, |OFFSET| = 0.5;
    # only the first point is accurate; the other three are outliers (rel > 0.1).
    a = {"EPE3D": (0.0 + math.sqrt(0.29) + math.sqrt(0.1924) + 0.5) / 4, "Acc3DS": 0.25, "Acc3DR": 0.25,
         "Outliers3D": 0.75}
    b = {"EPE3D": 0.5, "Acc3DS": 0.0, "Acc3DR": 0.0, "Outliers3D": 1.0}  # EPE 0.5 > 0.3 on static points
    return {k: (a[k] + b[k]) / 2 for k in a}


@pytest.mark.parametrize("protocol", ["paper", "full"])
def test_golden_zero_and_constant_offset(golden_split: Path, protocol: str) -> None:
    split = load_split(golden_split)
    assert split.names == ["a", "b"]
    cfg = ProtocolConfig(protocol=protocol, n_points=4, n_score=4, seeds=(0,))
    results = run_protocol(split, [make_baseline("zero"), ConstantFlow(OFFSET)], cfg, progress=False)
    for result, expected in zip(results, (_expected_zero(), _expected_offset())):
        for key, value in expected.items():
            assert result.metrics[key] == pytest.approx(value, abs=1e-6), (result.name, key)
        assert result.metrics["n_scenes"] == 2
        assert [s["name"] for s in result.per_scene] == ["a", "b"]
    # scene a alone, by hand: the offset method's EPE
    assert results[1].per_scene[0]["EPE3D"] == pytest.approx((math.sqrt(0.29) + math.sqrt(0.1924) + 0.5) / 4, abs=1e-6)
    rows = summary_rows(results)
    assert rows[0]["method"] == "zero" and rows[0]["EPE3D"] == pytest.approx(0.1025, abs=1e-6)
    table = markdown_table(rows)
    assert "| zero | 0.1025 |" in table


def test_every_method_sees_and_is_scored_on_the_same_points() -> None:
    rng = np.random.default_rng(3)
    pc1 = rng.uniform(-10, 10, size=(300, 3)).astype(np.float32)
    scene = SceneFlowSample("s", pc1, pc1[::-1] + 0.5, rng.normal(size=(300, 3)) * 0.1,
                            color1=rng.uniform(size=(300, 3)), color2=rng.uniform(size=(300, 3)))
    first, second = Recorder("first"), Recorder("second", scale=-0.02)
    scored: dict[str, list] = {"first": [], "second": []}
    cfg = ProtocolConfig(n_points=64, n_score=16, seeds=(5,), warmup=False)
    run_protocol([scene], [first, second], cfg, on_prediction=lambda n, p: scored[n].append(p), progress=False)
    a, b = first.calls[0], second.calls[0]
    for key in ("pc1", "pc2", "color1", "color2"):
        np.testing.assert_array_equal(a[key], b[key])
    assert a["writeable"] == [False, False]  # a method cannot change what the next one sees
    # the sample is a subset of the scene's points (distinct rows), colours follow their points
    rows = {tuple(p) for p in scene.pc1}
    assert len({tuple(p) for p in a["pc1"]}) == 64 and all(tuple(p) in rows for p in a["pc1"])
    prepared = prepare_scene(scene, cfg, 5)
    np.testing.assert_array_equal(a["color1"], scene.color1[prepared.index1])
    np.testing.assert_array_equal(a["pc2"], scene.pc2[prepared.index2])
    # scored points: the farthest-point sample of the sampled pc1, the same for both methods
    want = a["pc1"][scored_points(a["pc1"], 16)]
    for name in ("first", "second"):
        (pred,) = scored[name]
        np.testing.assert_array_equal(pred.points, want)
        np.testing.assert_array_equal(pred.gt_flow, scene.flow[prepared.index1][prepared.score_index])
    np.testing.assert_allclose(scored["first"][0].pred_flow, 0.01 * want, rtol=1e-6)


def test_warmup_call_is_not_scored() -> None:
    rng = np.random.default_rng(0)
    pc = rng.normal(size=(40, 3)).astype(np.float32)
    scene = SceneFlowSample("s", pc, pc, np.zeros_like(pc))
    rec = Recorder("r")
    res = run_protocol([scene], [rec], ProtocolConfig(n_points=32, n_score=8, warmup=True), progress=False)
    assert len(rec.calls) == 2  # one untimed warm-up, one scored call
    np.testing.assert_array_equal(rec.calls[0]["pc1"], rec.calls[1]["pc1"])
    assert res[0].metrics["n_scenes"] == 1


def test_seeds_change_the_sample_and_std_is_over_seeds() -> None:
    rng = np.random.default_rng(1)
    scenes = []
    for i in range(3):
        pc1 = rng.uniform(-20, 20, size=(500, 3)).astype(np.float32)
        scenes.append(SceneFlowSample(f"scene{i}", pc1, pc1 + 1.0, rng.normal(size=(500, 3)) * 0.3))
    single = []
    for seed in (0, 1, 2):
        rec = Recorder("r")
        (res,) = run_protocol(scenes, [rec], ProtocolConfig(n_points=100, n_score=20, seeds=(seed,), warmup=False),
                              progress=False)
        single.append((res.metrics["EPE3D"], res.metrics["Acc3DR"], rec.calls[0]["pc1"]))
    # different seeds sample different points; the same seed the same points
    assert not np.array_equal(single[0][2], single[1][2])
    rec = Recorder("r")
    (res,) = run_protocol(scenes, [rec], ProtocolConfig(n_points=100, n_score=20, seeds=(0, 1, 2), warmup=False),
                          progress=False)
    np.testing.assert_array_equal(rec.calls[0]["pc1"], single[0][2])
    np.testing.assert_array_equal(rec.calls[3]["pc1"], single[1][2])
    epes = np.array([s[0] for s in single])
    assert len(set(epes.round(12))) == 3
    assert res.metrics["EPE3D"] == pytest.approx(epes.mean(), abs=1e-12)
    assert res.metrics["EPE3D_std"] == pytest.approx(epes.std(), abs=1e-12)
    assert res.metrics["Acc3DR_std"] == pytest.approx(np.std([s[1] for s in single]), abs=1e-12)
    assert [r["seed"] for r in res.per_seed] == [0, 1, 2]
    assert [r["EPE3D"] for r in res.per_seed] == pytest.approx(list(epes), abs=1e-12)
    row = summary_rows([res])[0]
    assert row["EPE3D_std"] == pytest.approx(epes.std()) and row["n_seeds"] == 3
    assert f"{epes.mean():.4f} ± {epes.std():.4f}" in markdown_table([row])


def _oracle(scene: SceneFlowSample):
    """A method that knows the true flow of every point of ``scene`` (looked up by coordinates)."""
    table = {p.tobytes(): f for p, f in zip(scene.pc1, scene.flow)}

    class Oracle:
        name = "oracle"

        def __call__(self, pc1, pc2, color1=None, color2=None):
            return np.stack([table[p.tobytes()] for p in pc1])

    return Oracle()


def test_full_protocol_scores_every_input_point() -> None:
    rng = np.random.default_rng(2)
    pc1 = rng.uniform(-10, 10, size=(120, 3)).astype(np.float32)
    flow = (np.sin(pc1) * 0.5).astype(np.float32)  # smooth but not linear: interpolation is not exact
    scene = SceneFlowSample("s", pc1, pc1 + flow, flow)
    seen = []
    full = ProtocolConfig(protocol="full", n_points=40, seeds=(0,))
    (res,) = run_protocol([scene], [_oracle(scene)], full, on_prediction=lambda n, p: seen.append(p), progress=False)
    assert res.per_scene[0]["n_points"] == 120
    np.testing.assert_array_equal(seen[0].points, scene.pc1)
    np.testing.assert_array_equal(seen[0].gt_flow, scene.flow)
    # exact at the 40 sampled points (3-NN weights of a coincident point), interpolated elsewhere
    sampled = prepare_scene(scene, full, 0).index1
    err = np.linalg.norm(seen[0].pred_flow - scene.flow, axis=1)
    assert err[sampled].max() < 1e-5
    assert res.metrics["EPE3D"] > 0.01
    # the paper protocol scores sampled points only: the oracle is exact there
    (paper,) = run_protocol([scene], [_oracle(scene)], ProtocolConfig(n_points=40, n_score=10), progress=False)
    assert paper.metrics["EPE3D"] == 0.0 and paper.per_scene[0]["n_points"] == 10
    # every point sampled (n_points >= N, with repeats): full scoring is exact everywhere
    (every,) = run_protocol([scene], [_oracle(scene)], ProtocolConfig(protocol="full", n_points=150), progress=False)
    assert every.metrics["EPE3D"] < 1e-5 and every.per_scene[0]["n_points"] == 120


def test_choose_points() -> None:
    rng = np.random.default_rng(0)
    idx = choose_points(rng, 100, 30)
    assert len(set(idx.tolist())) == 30 and idx.max() < 100
    assert not np.all(np.diff(idx) > 0)  # random order, not sorted (nets taking the first N need that)
    pad = choose_points(rng, 10, 25)
    assert len(pad) == 25 and set(pad.tolist()) == set(range(10))
    with pytest.raises(ValueError):
        choose_points(rng, 0, 5)
    empty = SceneFlowSample("empty", np.zeros((0, 3)), np.ones((4, 3)), np.zeros((0, 3)))
    with pytest.raises(InputError, match="scene empty: empty cloud"):
        prepare_scene(empty, ProtocolConfig(n_points=4, n_score=2), 0)


def test_config_and_name_errors() -> None:
    pc = np.zeros((5, 3), np.float32) + np.arange(5, dtype=np.float32)[:, None]
    scene = SceneFlowSample("s", pc, pc, np.zeros_like(pc))
    zero = make_baseline("zero")
    for bad in (ProtocolConfig(protocol="nope"), ProtocolConfig(n_points=8, n_score=16), ProtocolConfig(seeds=())):
        with pytest.raises(ConfigError):
            run_protocol([scene], [zero], bad, progress=False)
    with pytest.raises(ConfigError, match="distinct names"):
        run_protocol([scene], [zero, BaselineMethod(zero.baseline)], ProtocolConfig(n_points=5, n_score=2),
                     progress=False)
    with pytest.raises(ConfigError, match="unknown baseline"):
        make_baseline("icp")
    with pytest.raises(ConfigError, match="poses"):
        run_protocol([scene], [make_baseline("static")], ProtocolConfig(n_points=5, n_score=2), progress=False)


def test_static_pose_baseline_uses_the_scene_pose() -> None:
    rng = np.random.default_rng(4)
    pc1 = rng.uniform(-5, 5, size=(50, 3)).astype(np.float32)
    pose = np.eye(4)
    pose[:3, 3] = (0.1, 0.0, -0.8)  # camera moves 0.8 m forward: static points come 0.8 m nearer
    flow = np.tile(np.float32([0.1, 0.0, -0.8]), (50, 1))
    scene = SceneFlowSample("s", pc1, pc1 + flow, flow, pose=pose)
    (res,) = run_protocol([scene], [make_baseline("static")], ProtocolConfig(n_points=50, n_score=10), progress=False)
    assert res.metrics["EPE3D"] == pytest.approx(0.0, abs=1e-6)
