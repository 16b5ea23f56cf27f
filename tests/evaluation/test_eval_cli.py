"""``monoflow-evaluate`` end to end on a tiny synthetic world with a tiny checkpoint in the trainer's layout:
the table, the reports, saved predictions re-scored to the same EPE3D, malformed inputs, plots."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from dataclasses import asdict
from pathlib import Path

import numpy as np
import pytest
import torch

from evaluation.cli import main
from evaluation.methods import NetMethod, make_method
from evaluation.predictions import read_predictions, score_predictions
from evaluation.protocols import ProtocolConfig, prepare_scene
from evaluation.readers import load_split

torch.set_num_threads(1)
REPO = Path(__file__).resolve().parents[2]


def save_tiny_checkpoint(path: Path, seed: int = 0, **model_overrides) -> Path:
    """An untrained tiny HALFlowNet saved as the trainer saves one (kind 'flow', config = asdict(TrainConfig))."""
    from training.config import DataConfig, TrainConfig
    from training.model.halflownet import HALFlowConfig, HALFlowNet
    from training.runtime.checkpoints import save_checkpoint

    torch.manual_seed(seed)
    model = HALFlowConfig(n_points=256, level_points=(64, 32, 16, 8, 4), width_scale=0.25, **model_overrides)
    cfg = TrainConfig(model=model, data=DataConfig(n_points=256))
    net = HALFlowNet(model)
    return save_checkpoint(path, {"kind": "flow", "model": net.state_dict(), "step": 3, "config": asdict(cfg)})


ANCHORED = dict(translation_vote=True, ego_head=True, l0_cost_volume=True, norm="layer", feature_dim=0,
                eval_anchor=True, rigid_vote_dense=True, rigid_vote_far=True)
"""A tiny net's model parts for an anchored net (the vote dense and weighed by range), as the inference switches
need it."""


@pytest.fixture(scope="module")
def world(tmp_path_factory) -> Path:
    from pipeline.synth.config import SynthConfig
    from pipeline.synth.generator import generate

    root = tmp_path_factory.mktemp("eval_cli") / "world"
    generate(SynthConfig(width=160, height=48, frames=2, test_frames=3, n_sequences=1), root)
    return root


@pytest.fixture(scope="module")
def checkpoint(world: Path) -> Path:
    return save_tiny_checkpoint(world.parent / "run" / "latest.pt")


def test_run_end_to_end_and_rescore(world: Path, checkpoint: Path, tmp_path: Path, capsys) -> None:
    split = world / "sceneflow" / "flownet3d"
    out = tmp_path / "eval"
    rc = main(["run", "--split", str(split), "--checkpoint", str(checkpoint), "--baselines", "zero,icp-p2p",
               "--out", str(out), "--save-predictions", "--no-progress", "--device", "cpu"])
    printed = capsys.readouterr().out
    assert rc == 0
    assert "| Method | EPE3D (m)↓" in printed and "| ours (run, step 3) |" in printed and "| icp-p2p |" in printed
    # the header names the protocol, the scored-point rule (the net's own sizes), the seeds and the scenes
    assert ("2 scenes of " in printed and "protocol fps: scored 64 farthest-point samples (from row 0) of 256 "
            "random points per cloud; seeds [0]" in printed)
    assert (out / "results.md").read_text().strip() in printed
    report = json.loads((out / "results.json").read_text())
    assert [r["method"] for r in report["rows"]] == ["ours (run, step 3)", "zero", "icp-p2p"]
    assert report["protocol"]["n_points"] == 256 and report["protocol"]["n_score"] == 64
    assert report["scenes"] == ["000000", "000001"] and "versions" in report and "git" in report
    csv_lines = (out / "results.csv").read_text().splitlines()
    assert csv_lines[0].startswith("method,EPE3D,") and len(csv_lines) == 4
    files = sorted(p.name for p in out.glob("predictions-*.h5"))
    assert files == ["predictions-icp-p2p.h5", "predictions-ours_run_step_3.h5", "predictions-zero.h5"]
    for row in report["rows"]:
        slug = {"ours (run, step 3)": "ours_run_step_3"}.get(row["method"], row["method"])
        scored = score_predictions(out / f"predictions-{slug}.h5")
        assert scored["method"] == row["method"]
        assert scored["EPE3D"] == pytest.approx(row["EPE3D"], rel=1e-12)
        assert scored["Acc3DS"] == pytest.approx(row["Acc3DS"], rel=1e-12)
        bands = [k for k in row if k.startswith("EPE3D_z") and not k.endswith("_std")]
        assert bands  # the distance bands are in the run's rows and recomputed from the saved points
        for key in bands:
            assert scored[key[len("EPE3D_"):]]["EPE3D"] == pytest.approx(row[key], rel=1e-12)
        assert scored["n_scenes"] == 2
    # zero flow: the saved predicted flow is zero and its EPE is the mean |gt| (by hand from the file)
    zero = read_predictions(out / "predictions-zero.h5")
    assert all(np.all(s.pred_flow == 0) for s in zero) and all(len(s.points) == 64 for s in zero)
    by_hand = np.mean([np.linalg.norm(s.gt_flow, axis=1).mean() for s in zero])
    assert report["rows"][1]["EPE3D"] == pytest.approx(by_hand, rel=1e-6)
    # every method was scored on the same points
    pts = [[s.points for s in read_predictions(p)] for p in sorted(out.glob("predictions-*.h5"))]
    for other in pts[1:]:
        for a, b in zip(pts[0], other):
            np.testing.assert_array_equal(a, b)
    # `score` prints the same EPE3D
    assert main(["score", *map(str, sorted(out.glob("predictions-*.h5")))]) == 0
    rescored = capsys.readouterr().out
    for row in report["rows"]:
        assert f"| {row['method']} | {row['EPE3D']:.4f} |" in rescored


def test_net_scores_its_own_level0_points(world: Path, checkpoint: Path) -> None:
    """Paper protocol: the scored points are the net's level-0 points, so its flow there is not interpolated."""
    net = NetMethod(checkpoint, device="cpu")
    assert (net.n_points, net.n_score, net.step) == (256, 64, 3)
    scene = prepare_scene(load_split(world / "sceneflow" / "flownet3d")[0], ProtocolConfig(n_points=256, n_score=64), 0)
    with torch.no_grad():
        out = net.net(torch.tensor(scene.pc1)[None], torch.tensor(scene.pc2)[None])
    idx = out.indices[0][0].numpy()
    np.testing.assert_array_equal(np.sort(idx), np.sort(scene.score_index))
    flow = net(scene.pc1, scene.pc2)
    np.testing.assert_allclose(flow[idx], out.flows[0][0].numpy(), atol=1e-5)


def test_synthetic_test_split_marks_class_and_instance_per_point(world: Path) -> None:
    """The writer labels every pc1 point: class 1 (car) on movers and parked cars, 0 elsewhere; the readers
    of both layouts pass the labels through their own filters."""
    for fmt in ("flownet3d", "hplflownet"):
        split = load_split(world / "sceneflow" / fmt)
        for s in split:
            assert s.classes is not None and s.instance is not None and len(s.classes) == s.n1
            assert set(np.unique(s.classes).tolist()) <= {0, 1}
            assert np.all(s.classes[s.moving] == 1)  # every mover is a car
            for inst in np.unique(s.instance[s.classes == 1]):  # one class and one motion per instance
                on = s.instance == inst
                assert np.all(s.classes[on] == 1) and len(np.unique(s.moving[on])) == 1


def test_guard_refuses_scenes_the_checkpoint_trained_on(world: Path, checkpoint: Path, tmp_path: Path,
                                                        capsys) -> None:
    run = tmp_path / "ft"
    run.mkdir()
    ckpt = run / "latest.pt"
    shutil.copy(checkpoint, ckpt)
    (run / "train_scenes.txt").write_text("000001\n")
    split = world / "sceneflow" / "flownet3d"
    args = ["run", "--split", str(split), "--checkpoint", str(ckpt), "--baselines", "", "--out",
            str(tmp_path / "e"), "--no-progress", "--device", "cpu"]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "trained on 1 of the scenes" in err and "train_scenes.txt" in err
    assert main([*args, "--scenes", "first:1"]) == 0  # disjoint scenes are scored
    report = json.loads((tmp_path / "e" / "results.json").read_text())
    assert report["scenes"] == ["000000"] and report["selection"]["scenes"] == "first:1"


def test_malformed_split_is_one_error_line(world: Path, checkpoint: Path, tmp_path: Path, capsys) -> None:
    split = tmp_path / "split"
    shutil.copytree(world / "sceneflow" / "flownet3d", split)
    bad = split / "000002.npz"
    np.savez(bad, pos1=np.zeros((5, 3)), pos2=np.zeros((5, 3)))  # no 'gt'
    rc = main(["run", "--split", str(split), "--baselines", "zero", "--out", str(tmp_path / "o"), "--no-progress"])
    err = capsys.readouterr().err
    assert rc == 2
    assert err.startswith("error: ") and err.count("\n") == 1
    assert f"{bad}: missing arrays ['gt']" in err
    # the file itself as the split: "error: <file>: ..."
    assert main(["run", "--split", str(bad), "--baselines", "zero", "--out", str(tmp_path / "o")]) == 2
    assert capsys.readouterr().err.startswith(f"error: {bad}: ")
    # a file whose header is fine but whose values are not: named when read
    nan = split / "000002.npz"
    pts = np.ones((5, 3))
    pts[0, 0] = np.nan
    np.savez(nan, pos1=pts, pos2=np.ones((5, 3)), gt=np.zeros((5, 3)))
    assert main(["run", "--split", str(nan), "--baselines", "zero", "--out", str(tmp_path / "o"), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"error: {nan}: ") and "non-finite" in err


def test_bad_options_and_checkpoints(world: Path, checkpoint: Path, tmp_path: Path, capsys) -> None:
    split = str(world / "sceneflow" / "flownet3d")
    o = str(tmp_path / "o")
    cases = [
        (["--baselines", "zero", "--seeds", "0,x"], "--seeds must be a comma list of integers"),
        (["--baselines", "nope"], "unknown baseline 'nope'"),
        (["--baselines", ""], "nothing to evaluate"),
        (["--baselines", "static"], "needs T_1→2"),
        (["--checkpoint", str(checkpoint), "--baselines", "", "--n-points", "32", "--n-score", "16"],
         "needs at least 64 points"),
        (["--checkpoint", str(tmp_path / "missing.pt")], "checkpoint not found"),
        (["--checkpoint", str(checkpoint), "--eval-anchor", "on"], f"{checkpoint}: model.eval_anchor"),
        (["--checkpoint", str(checkpoint), "--turn-scan", "6"], f"{checkpoint}: model.rigid_vote_yaw_deg"),
        (["--checkpoint", str(checkpoint), "--turn-scan", "six"], "--turn-scan must be 'as-trained' or a number"),
    ]
    for extra, message in cases:
        assert main(["run", "--split", split, "--out", o, "--no-progress", *extra]) == 2, extra
        err = capsys.readouterr().err
        assert err.startswith("error: ") and message in err, (extra, err)
    # weights that do not fit the checkpoint's own model config
    from training.runtime.checkpoints import load_checkpoint, save_checkpoint

    ck = load_checkpoint(checkpoint, kind="flow")
    ck["config"]["model"]["width_scale"] = 0.5
    broken = save_checkpoint(tmp_path / "broken.pt", {k: v for k, v in ck.items() if k != "checkpoint_version"})
    assert main(["run", "--split", split, "--checkpoint", str(broken), "--out", o]) == 2
    assert capsys.readouterr().err.startswith(f"error: {broken}: weights do not match")


def test_two_checkpoints_of_same_named_runs_get_distinct_names(world: Path, checkpoint: Path, tmp_path: Path,
                                                               capsys) -> None:
    other = save_tiny_checkpoint(tmp_path / "run" / "latest.pt", seed=1)
    out = tmp_path / "eval"
    rc = main(["run", "--split", str(world / "sceneflow" / "flownet3d"), "--checkpoint", str(checkpoint),
               "--checkpoint", str(other), "--baselines", "", "--out", str(out), "--no-progress", "--max-scenes", "1",
               "--protocol", "full", "--seeds", "0,1"])
    assert rc == 0
    rows = json.loads((out / "results.json").read_text())["rows"]
    assert [r["method"] for r in rows] == ["ours (run, step 3)", "ours (run, step 3) #2"]
    assert rows[0]["EPE3D"] != rows[1]["EPE3D"]  # different weights, scored separately
    assert rows[0]["n_scenes"] == 1 and rows[0]["n_seeds"] == 2 and "EPE3D_std" in rows[0]
    assert "protocol full: scored every input point of pc1" in capsys.readouterr().out


def test_the_inference_anchor_can_be_forced_either_way_and_names_the_row(world: Path, tmp_path: Path) -> None:
    """``--eval-anchor``: one trained net scored as trained, anchored and not anchored; only a forced setting
    that differs from the checkpoint's is named, and the anchored row is a different flow."""
    parts = dict(translation_vote=True, ego_head=True, l0_cost_volume=True, norm="layer", feature_dim=0)
    path = save_tiny_checkpoint(tmp_path / "run" / "latest.pt", **parts)
    nets = {a: NetMethod(path, device="cpu", eval_anchor=a) for a in (None, True, False)}
    assert [nets[a].name for a in (None, True, False)] == ["ours (run, step 3)", "ours (run, step 3, anchored)",
                                                           "ours (run, step 3)"]
    assert nets[True].net.config.eval_anchor and not nets[None].net.config.eval_anchor
    scene = prepare_scene(load_split(world / "sceneflow" / "flownet3d")[0], ProtocolConfig(n_points=256, n_score=64), 0)
    plain, anchored = nets[None](scene.pc1, scene.pc2), nets[True](scene.pc1, scene.pc2)
    np.testing.assert_array_equal(plain, nets[False](scene.pc1, scene.pc2))
    assert np.abs(plain - anchored).max() > 1e-4
    out = tmp_path / "eval"
    assert main(["run", "--split", str(world / "sceneflow" / "flownet3d"), "--checkpoint", str(path), "--baselines", "",
                 "--eval-anchor", "on", "--out", str(out), "--no-progress", "--max-scenes", "1"]) == 0
    rows = json.loads((out / "results.json").read_text())["rows"]
    assert [r["method"] for r in rows] == ["ours (run, step 3, anchored)"]


def test_a_net_anchored_with_the_dense_vote_can_be_scored_without_the_anchor(tmp_path: Path) -> None:
    """The demo preset's net (``eval_anchor``, ``rigid_vote_dense``, ``rigid_vote_far``, ``eval_gate_k``)
    forced off runs without the vote, so the anchor's options go with it instead of refusing the config."""
    parts = dict(ANCHORED, eval_gate_k=16)
    path = save_tiny_checkpoint(tmp_path / "run" / "latest.pt", **parts)
    off = NetMethod(path, device="cpu", eval_anchor=False)
    assert off.name == "ours (run, step 3, not anchored)"
    cfg = off.net.config
    assert not (cfg.eval_anchor or cfg.rigid_vote_dense or cfg.rigid_vote_far or cfg.eval_gate_k)
    cfg = NetMethod(path, device="cpu").net.config  # as trained: untouched
    assert cfg.rigid_vote_dense and cfg.rigid_vote_far and cfg.eval_gate_k == 16


def test_plots_without_matplotlib_say_how_to_install(world: Path, tmp_path: Path, monkeypatch, capsys) -> None:
    monkeypatch.setitem(sys.modules, "matplotlib", None)  # import matplotlib -> ImportError
    rc = main(["run", "--split", str(world / "sceneflow" / "flownet3d"), "--baselines", "zero", "--plots",
               "--out", str(tmp_path / "o")])
    assert rc == 2
    assert "pip install matplotlib" in capsys.readouterr().err  # monoflow is not on a package index
    assert not (tmp_path / "o").exists()  # reported before any work
    from evaluation.plots import write_plots
    from core.errors import ConfigError

    with pytest.raises(ConfigError, match=r"pip install matplotlib"):
        write_plots(tmp_path, [], [], [], ProtocolConfig())


def test_plots(world: Path, checkpoint: Path, tmp_path: Path, capsys) -> None:
    pytest.importorskip("matplotlib")
    out = tmp_path / "eval"
    rc = main(["run", "--split", str(world / "sceneflow" / "flownet3d"), "--checkpoint", str(checkpoint),
               "--baselines", "zero", "--out", str(out), "--plots", "--no-progress", "--seeds", "0,1"])
    assert rc == 0
    for name in ("metrics.png", "scene-000000.png"):
        data = (out / name).read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 5000
    # without collected predictions, write_plots recomputes the scene on the protocol's own points
    from evaluation.methods import make_baseline
    from evaluation.plots import write_plots

    split = load_split(world / "sceneflow" / "flownet3d")
    rows = [{"method": "zero", "EPE3D": 0.5, "EPE3D_std": 0.1, "Acc3DS": 0.2}]
    paths = write_plots(tmp_path / "p", rows, split, [make_baseline("zero")], ProtocolConfig(n_points=256, n_score=64),
                        scene_index=1)
    assert [p.name for p in paths] == ["metrics.png", "scene-000001.png"] and all(p.stat().st_size > 0 for p in paths)


def test_python_dash_m_and_help_are_quick() -> None:
    res = subprocess.run([sys.executable, "-m", "evaluation", "--help"], cwd=REPO, capture_output=True, text=True,
                         timeout=60)
    assert res.returncode == 0 and "run" in res.stdout and "ablations" in res.stdout
    res = subprocess.run([sys.executable, "-c", "import sys, evaluation.cli; "
                          "print(sorted(m for m in ('torch', 'zarr', 'h5py', 'matplotlib') if m in sys.modules))"],
                         cwd=REPO, capture_output=True, text=True, timeout=60)
    assert res.stdout.strip() == "[]"


def test_nsfp_baseline_and_refine_rows(world: Path, checkpoint: Path, tmp_path: Path, capsys) -> None:
    """``--baselines nsfp --refine``: an NSFP row and an 'ours + refinement' row beside (never instead of)
    the net's own row, scored on the same points; the net's row is what it is without --refine."""
    split = str(world / "sceneflow" / "flownet3d")
    common = ["run", "--split", split, "--checkpoint", str(checkpoint), "--no-progress", "--device", "cpu"]
    assert main([*common, "--baselines", "zero", "--out", str(tmp_path / "plain")]) == 0
    assert main([*common, "--baselines", "zero,nsfp", "--refine", "--out", str(tmp_path / "ref"), "--no-warmup",
                 "--save-predictions"]) == 0
    printed = capsys.readouterr().out
    assert "| nsfp |" in printed and "| ours (run, step 3) + refinement |" in printed
    rows = json.loads((tmp_path / "ref" / "results.json").read_text())["rows"]
    assert [r["method"] for r in rows] == ["ours (run, step 3)", "ours (run, step 3) + refinement", "zero", "nsfp"]
    plain = json.loads((tmp_path / "plain" / "results.json").read_text())["rows"]
    assert rows[0]["EPE3D"] == plain[0]["EPE3D"]
    by = {r["method"]: r for r in rows}
    assert by["nsfp"]["EPE3D"] < by["zero"]["EPE3D"]  # an untrained net may be anything; NSFP beats zero flow
    assert all(np.isfinite(r["EPE3D"]) and r["seconds_per_scene"] > 0 for r in rows)
    pts = [[s.points for s in read_predictions(p)] for p in sorted((tmp_path / "ref").glob("predictions-*.h5"))]
    assert len(pts) == 4
    for other in pts[1:]:
        for a, b in zip(pts[0], other):
            np.testing.assert_array_equal(a, b)
    # --refine needs a net to refine
    assert main(["run", "--split", split, "--baselines", "zero", "--refine", "--out", str(tmp_path / "x"),
                 "--no-progress"]) == 2
    assert "--refine, --view-prune and --rigid-polish wrap a net" in capsys.readouterr().err


def test_wrappers_stack_view_prune_then_rigid_polish_then_refine() -> None:
    """``--view-prune --rigid-polish --refine``: each wrapper starts from the row before, each its own row."""
    from evaluation.cli import _stacked
    from evaluation.rigid_polish import RigidPolished
    from evaluation.optimise import RefineConfig, RefinedMethod
    from evaluation.view_prune import ViewPruned

    net = make_method("zero")
    rows = _stacked(net, ["view-prune", "rigid-polish", "refine"])
    assert [r.name for r in rows] == ["zero", "zero + view pruning", "zero + view pruning + rigid polish",
                                      "zero + view pruning + rigid polish + refinement"]
    assert isinstance(rows[1], ViewPruned) and rows[1].inner is net
    assert isinstance(rows[2], RigidPolished) and rows[2].inner is rows[1]
    assert isinstance(rows[3], RefinedMethod) and rows[3].base is rows[2]
    # after the rigid polish the refinement holds the registered ego-motion; elsewhere it optimises it
    assert rows[3].config == RefineConfig.after_registration() and rows[3].config.rigid_lr == 0.0
    assert _stacked(net, ["view-prune", "refine"])[2].config == RefineConfig()
    assert [r.name for r in _stacked(net, ["refine"])] == ["zero", "zero + refinement"]
    # --rigid-objects off: the polish without its step 6, named so; on (the default) keeps it
    assert rows[2].config.rigid_objects
    plain = _stacked(net, ["rigid-polish", "refine"], ("rigid_objects",))
    assert not plain[1].config.rigid_objects and plain[1].name == "zero + rigid polish (no object step)"
    assert plain[2].base is plain[1] and plain[2].name == "zero + rigid polish (no object step) + refinement"
    assert plain[1].config.ego_check and rows[2].config.ego_check
    # --ego-check off (with --rigid-objects off too): both switches named
    both = _stacked(net, ["rigid-polish"], ("rigid_objects", "ego_check"))[1]
    assert not both.config.ego_check and not both.config.rigid_objects
    assert both.name == "zero + rigid polish (no object step, no ego check)"
    # --object-search off: step 6 from the median motion alone (object_search 0 m), named so
    flat = _stacked(net, ["rigid-polish"], ("object_search",))[1]
    assert flat.config.object_search == 0.0 and rows[2].config.object_search > 0 and flat.config.rigid_objects
    assert flat.name == "zero + rigid polish (no object search)"
    # --score-in-view off: the object score counts every point, named so
    plain_score = _stacked(net, ["rigid-polish"], ("score_in_view",))[1]
    assert not plain_score.config.score_in_view and rows[2].config.score_in_view
    assert plain_score.name == "zero + rigid polish (all points scored)"
    # --object-whole-extent off: 6 m for every cluster (object_whole_extent 0), named so
    short = _stacked(net, ["rigid-polish"], ("object_whole_extent",))[1]
    assert short.config.object_whole_extent == 0.0 and rows[2].config.object_whole_extent == 12.0
    assert short.name == "zero + rigid polish (extent rule alone)"
    # --level-starts off: the object fits start from the method's whole departure, named so
    whole = _stacked(net, ["rigid-polish"], ("level_starts",))[1]
    assert not whole.config.level_starts and rows[2].config.level_starts
    assert whole.name == "zero + rigid polish (whole departures)"
    # --hold-vertical off: the registration fits all six degrees of freedom (hold_vertical 0), named so
    six = _stacked(net, ["rigid-polish"], ("hold_vertical",))[1]
    assert six.config.hold_vertical == 0.0 and rows[2].config.hold_vertical == 0.03
    assert six.name == "zero + rigid polish (six-degree registration)"


def test_a_net_trained_without_the_turn_scan_can_be_scored_with_it(world: Path, tmp_path: Path) -> None:
    """``--turn-scan``: an anchored net trained before the scan existed (``rigid_vote_yaw_deg`` 0) scored with it;
    the row is named, the config changed for inference only, and ``as-trained`` leaves it alone."""
    path = save_tiny_checkpoint(tmp_path / "run" / "latest.pt", **ANCHORED)
    plain, scanned = NetMethod(path, device="cpu"), NetMethod(path, device="cpu", turn_scan=6.0)
    assert plain.net.config.rigid_vote_yaw_deg == 0.0 and scanned.net.config.rigid_vote_yaw_deg == 6.0
    assert scanned.name == "ours (run, step 3, turn scan ±6°)" and plain.name == "ours (run, step 3)"
    assert NetMethod(path, device="cpu", turn_scan=0.0).name == plain.name  # no change, no name
    scene = prepare_scene(load_split(world / "sceneflow" / "flownet3d")[0], ProtocolConfig(n_points=256, n_score=64), 0)
    assert np.isfinite(scanned(scene.pc1, scene.pc2)).all()
    out = tmp_path / "eval"
    assert main(["run", "--split", str(world / "sceneflow" / "flownet3d"), "--checkpoint", str(path), "--baselines", "",
                 "--turn-scan", "6", "--out", str(out), "--no-progress", "--max-scenes", "1"]) == 0
    rows = json.loads((out / "results.json").read_text())["rows"]
    assert [r["method"] for r in rows] == ["ours (run, step 3, turn scan ±6°)"]


@pytest.mark.parametrize("kwarg, field, on, off, suffix, flag, negative", [
    ("vote_gap", "rigid_vote_gap_m", 0.3, 0.0, "vote by gap 0.3 m", ("--vote-gap", "0.3"), None),
    ("vote_forward", "rigid_vote_forward", True, False, "forward starts", ("--vote-forward", "on"), None),
    ("vote_density", "rigid_vote_density_m", 0.62, 0.0, "density rounds 0.62 m", ("--vote-density", "0.62"), -1.0),
    ("own_departure", "eval_own_departure", True, False, "own departures", ("--own-departure", "on"), None),
    ("view_hold", "eval_view_hold", True, False, "view hold", ("--view-hold", "on"), None),
    ("level_departure", "eval_level_departure", True, False, "level departures", ("--level-departure", "on"), None),
    ("evidence_surface", "eval_evidence_surface", 1.5, 0.0, "off-surface evidence 1.5", ("--evidence-surface", "1.5"),
     -1.0),
    ("neighbourhood_scale", "eval_neighbourhood_scale", True, False, "neighbourhood scale", ("--neighbourhood-scale", "on"),
     None)])
def test_an_inference_option_of_the_rigid_vote_can_be_set_for_a_trained_net_and_names_the_row(
        world: Path, tmp_path: Path, kwarg, field, on, off, suffix, flag, negative) -> None:
    """``--vote-gap`` / ``--vote-forward`` / ``--vote-density`` / ``--own-departure`` / ``--view-hold`` /
    ``--level-departure`` / ``--evidence-surface`` / ``--neighbourhood-scale`` and ``NetMethod(vote_gap | vote_forward |
    vote_density | own_departure | view_hold | level_departure | evidence_surface | neighbourhood_scale=…)``: an anchored net trained before the option
    existed scored with the rigid vote choosing by its gap, starting along the optical axis or weighing its rounds by
    density, with the anchor's departures measured from the net's own motion, with the points leaving the view given
    their neighbours' departure, with departures kept along the ground, taken only off frame 2's surface or gated at the
    scale of the neighbourhood medians (named, for inference only); the option's off value leaves it as trained; a net without a rigid vote (or anchor), or a radius
    or κ below zero: one error naming the option."""
    from core.errors import ConfigError

    path = save_tiny_checkpoint(tmp_path / "run" / "latest.pt", **ANCHORED)
    plain, changed = NetMethod(path, device="cpu"), NetMethod(path, device="cpu", **{kwarg: on})
    assert getattr(plain.net.config, field) == off and getattr(changed.net.config, field) == on
    assert changed.name == f"ours (run, step 3, {suffix})"
    assert NetMethod(path, device="cpu", **{kwarg: off}).name == plain.name
    scene = prepare_scene(load_split(world / "sceneflow" / "flownet3d")[0], ProtocolConfig(n_points=256, n_score=64), 0)
    assert np.isfinite(changed(scene.pc1, scene.pc2)).all()
    bare = save_tiny_checkpoint(tmp_path / "bare" / "latest.pt")
    with pytest.raises(ConfigError, match=field):
        NetMethod(bare, device="cpu", **{kwarg: on})
    if negative is not None:
        with pytest.raises(ConfigError, match=field):
            NetMethod(path, device="cpu", **{kwarg: negative})
    out = tmp_path / "eval"
    assert main(["run", "--split", str(world / "sceneflow" / "flownet3d"), "--checkpoint", str(path), "--baselines", "",
                 *flag, "--out", str(out), "--no-progress", "--max-scenes", "1"]) == 0
    rows = json.loads((out / "results.json").read_text())["rows"]
    assert [r["method"] for r in rows] == [f"ours (run, step 3, {suffix})"]


def test_the_anchors_dense_evidence_can_be_forced_either_way_and_names_the_row(world: Path, tmp_path: Path) -> None:
    """``--evidence-dense`` / ``NetMethod(evidence_dense=…)``: an anchored net trained before the switch existed
    scored with it (named, the config changed for inference only); a net whose anchor is forced off has no
    evidence test to change: one error naming the checkpoint."""
    from core.errors import ConfigError

    path = save_tiny_checkpoint(tmp_path / "run" / "latest.pt", **ANCHORED)
    plain, dense = NetMethod(path, device="cpu"), NetMethod(path, device="cpu", evidence_dense=True)
    assert not plain.net.config.eval_evidence_dense and dense.net.config.eval_evidence_dense
    assert dense.name == "ours (run, step 3, dense evidence)" and plain.name == "ours (run, step 3)"
    assert NetMethod(path, device="cpu", evidence_dense=False).name == plain.name  # no change, no name
    with pytest.raises(ConfigError, match=f"{path}: .*eval_evidence_dense"):
        NetMethod(path, device="cpu", eval_anchor=False, evidence_dense=True)
    out = tmp_path / "eval"
    assert main(["run", "--split", str(world / "sceneflow" / "flownet3d"), "--checkpoint", str(path), "--baselines", "",
                 "--evidence-dense", "on", "--out", str(out), "--no-progress", "--max-scenes", "1"]) == 0
    rows = json.loads((out / "results.json").read_text())["rows"]
    assert [r["method"] for r in rows] == ["ours (run, step 3, dense evidence)"]
    assert np.isfinite(rows[0]["EPE3D"])


def test_pairing_points_names_the_rows_and_needs_a_wrapper(world: Path, tmp_path: Path, capsys) -> None:
    path = save_tiny_checkpoint(tmp_path / "run" / "latest.pt")
    split = str(world / "sceneflow" / "flownet3d")
    assert main(["run", "--split", split, "--checkpoint", str(path), "--baselines", "", "--pairing", "points",
                 "--out", str(tmp_path / "x"), "--no-progress", "--max-scenes", "1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--pairing" in err[0] and not (tmp_path / "x").exists()
    out = tmp_path / "eval"  # every point sampled (the clouds are smaller): each keeps its counterpart
    assert main(["run", "--split", split, "--checkpoint", str(path), "--baselines", "", "--refine", "--pairing",
                 "points", "--n-points", "8192", "--out", str(out), "--no-progress", "--max-scenes", "1"]) == 0
    rows = json.loads((out / "results.json").read_text())["rows"]
    assert [r["method"] for r in rows] == ["ours (run, step 3)", "ours (run, step 3) + refinement (point pairs)"]
    capsys.readouterr()
    out = tmp_path / "stack"  # the tiny net's 256 points of each ~4000-point cloud: few counterparts kept
    assert main(["run", "--split", split, "--checkpoint", str(path), "--baselines", "", "--view-prune", "--rigid-polish",
                 "--refine", "--pairing", "points", "--out", str(out), "--no-progress", "--max-scenes", "1"]) == 0
    rows = json.loads((out / "results.json").read_text())["rows"]
    assert [r["method"] for r in rows] == [  # no view pruning: frame 2 holds frame 1's points, none left the view
        "ours (run, step 3)", "ours (run, step 3) + rigid polish (point pairs)",
        "ours (run, step 3) + rigid polish (point pairs) + refinement (point pairs)"]
    err = capsys.readouterr().err
    assert "--view-prune is left out" in err and "counterparts" not in err  # however few are kept (forty-fifth round)


@pytest.mark.parametrize("fmt, pairing, suffix", [("flownet3d", "auto", ""), ("hplflownet", "auto", " (point pairs)"),
                                                   ("hplflownet", "surface", "")])
def test_the_refinement_pairs_points_by_itself_where_the_layout_stores_frame_one_s_points(
        world: Path, tmp_path: Path, fmt: str, pairing: str, suffix: str) -> None:
    """``--pairing auto`` (the default): the HPLFlowNet layout stores frame 2 as frame 1's points moved (its
    flow is pc2 − pc1 row by row), so the refinement pairs points there; the FlowNet3D layout may hold a re-scan,
    so it keeps the surface settings; ``surface`` forces them."""
    from evaluation.readers.registry import REGISTRY

    assert REGISTRY["hplflownet"].frame2_holds_frame1 and not REGISTRY["flownet3d"].frame2_holds_frame1
    path = save_tiny_checkpoint(tmp_path / "run" / "latest.pt")
    split = world / "sceneflow" / fmt
    names = sorted(p.name for p in split.iterdir() if p.is_dir()) if fmt == "hplflownet" else []
    mapping = tmp_path / "mapping.txt"
    mapping.write_text("".join(f"{n}\n" for n in names) or "x\n")
    out = tmp_path / "eval"
    extra = ["--protocol", "hplflownet", "--mapping", str(mapping)] if fmt == "hplflownet" else []
    assert main(["run", "--split", str(split), "--checkpoint", str(path), "--baselines", "", "--refine",
                 "--refine-pairing", pairing, *extra,  # the flag's former name still works
                 "--out", str(out), "--no-progress", "--max-scenes", "1"]) == 0
    rows = json.loads((out / "results.json").read_text())["rows"]
    assert [r["method"] for r in rows][-1] == f"ours (run, step 3) + refinement{suffix}"


def test_the_refinement_pairs_points_where_a_flownet3d_split_was_written_from_correspondences(
        world: Path, tmp_path: Path, capsys) -> None:
    """The FlowNet3D layout holds both kinds (the synthetic world's re-scans, FlowNet3D's KITTI written from
    correspondences): ``auto`` reads which from the files (evaluation.pairing) — the world's own split keeps the
    surface settings (previous test), the same scenes rewritten with ``pos2`` = ``pos1 + gt`` shuffled and
    thinned pair points, saying why in one note."""
    split = tmp_path / "moved"
    split.mkdir()
    rng = np.random.default_rng(0)
    for f in sorted((world / "sceneflow" / "flownet3d").glob("*.npz")):
        with np.load(f) as d:
            arrays = {k: d[k] for k in d.files}
        moved = (arrays["pos1"] + arrays["gt"])[rng.permutation(len(arrays["pos1"]))]
        arrays["pos2"] = moved[: int(0.8 * len(moved))]
        arrays.pop("color2", None)
        np.savez(split / f.name, **arrays)
    path = save_tiny_checkpoint(tmp_path / "run" / "latest.pt")
    out = tmp_path / "eval"
    assert main(["run", "--split", str(split), "--checkpoint", str(path), "--baselines", "", "--refine",
                 "--n-points", "8192", "--out", str(out), "--no-progress", "--max-scenes", "1"]) == 0
    rows = json.loads((out / "results.json").read_text())["rows"]
    assert [r["method"] for r in rows][-1] == "ours (run, step 3) + refinement (point pairs)"
    notes = [line for line in capsys.readouterr().err.splitlines() if "pairs points" in line]
    assert len(notes) == 1 and "80% of frame 1's points land" in notes[0]
