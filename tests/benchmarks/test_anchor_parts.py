"""benchmarks/anchor_parts.py: a trained net scored with each subset of the inference anchor's switches."""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks.anchor_parts import PARTS, main, with_parts
from core.errors import ConfigError
from evaluation.methods import NetMethod
from testkit.flow_checkpoint import tiny_flow_checkpoint
from testkit.rigid_scene import structured_scene

ANCHORABLE = dict(translation_vote=True, ego_head=True, l0_cost_volume=True, norm="layer")


def _split(folder, n: int = 400) -> None:
    """Two FlowNet3D-layout scenes of the structured street moved 1 m forward (LiDAR axes: x forward)."""
    folder.mkdir(parents=True)
    for i in range(2):
        cam = structured_scene(np.random.default_rng(i), n)  # camera axes
        lidar = np.stack([cam[:, 2], -cam[:, 0], -cam[:, 1]], 1).astype(np.float32)
        flow = np.tile(np.float32([-1.0, 0.0, 0.0]), (n, 1))
        np.savez(folder / f"{i:06d}.npz", pos1=lidar, pos2=lidar + flow, gt=flow)


def test_all_parts_is_the_anchor_and_none_is_the_net_without_it(tmp_path):
    path = tiny_flow_checkpoint(tmp_path / "run" / "net.pt", **ANCHORABLE)
    rng = np.random.default_rng(0)
    pc1 = structured_scene(rng, 300).astype(np.float32)
    a = np.radians(3.0)  # a turn about y, which the rigid vote measures and the translation vote does not
    R = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    pc2 = (pc1 @ R.T + [0.1, 0.0, 1.0]).astype(np.float32)
    flows = {p: with_parts(NetMethod(path, device="cpu"), p)(pc1, pc2) for p in PARTS}
    np.testing.assert_array_equal(flows["all"], NetMethod(path, device="cpu", eval_anchor=True)(pc1, pc2))
    np.testing.assert_array_equal(flows["none"], NetMethod(path, device="cpu", eval_anchor=False)(pc1, pc2))
    assert np.abs(flows["rv"] - flows["none"]).max() > 1e-4  # the parts change the flow
    assert with_parts(NetMethod(path, device="cpu"), "rvh").name.endswith("[rvh]")


def test_unknown_parts_and_nets_without_the_anchors_parts_are_one_line(tmp_path, capsys):
    paper = tiny_flow_checkpoint(tmp_path / "paper.pt")
    with pytest.raises(ConfigError, match="unknown part"):
        with_parts(NetMethod(paper, device="cpu"), "x")
    _split(tmp_path / "split")
    assert main(["--checkpoint", str(paper), "--split", f"s={tmp_path / 'split'}", "--parts", "rv"]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"error: {paper}: cannot run the anchor's parts") and len(err.strip().splitlines()) == 1


def test_the_table_has_a_row_per_net_and_part(tmp_path, capsys):
    path = tiny_flow_checkpoint(tmp_path / "net.pt", **ANCHORABLE)
    _split(tmp_path / "split")
    assert main(["--checkpoint", str(path), "--split", f"s={tmp_path / 'split'}", "--parts", "none,all",
                 "--n-points", "256", "--n-score", "128"]) == 0
    rows = [r for r in capsys.readouterr().out.splitlines() if r.startswith(f"| {path}")]
    assert [r.split("]")[0].split("[")[1] for r in rows] == ["none", "all"]
    for r in rows:
        epe = float(r.split("|")[2].split("/")[0])
        assert np.isfinite(epe) and epe >= 0


@pytest.mark.parametrize("dense, gap, forward, density, own, view, level, surface, anchor", [
    (False, 0.0, False, 0.0, False, False, False, 0.0, "alldfk"),
    (True, 0.0, False, 0.0, False, False, False, 0.0, "alldfkx"),
    (True, 0.3, False, 0.0, False, False, False, 0.0, "alldfkxg"),
    (True, 0.3, True, 0.0, False, False, False, 0.0, "alldfkxgf"),
    (True, 0.3, True, 0.62, False, False, False, 0.0, "alldfkxgfd"),
    (True, 0.3, True, 0.62, True, False, False, 0.0, "alldfkxgfdo"),
    (True, 0.3, True, 0.62, True, True, False, 0.0, "alldfkxgfdov"),
    (True, 0.3, True, 0.62, True, True, True, 0.0, "alldfkxgfdovl"),
    (True, 0.3, True, 0.62, True, True, True, 1.5, "alldfkxgfdovls")])
def test_each_part_of_the_chain_is_the_anchor_its_switches_make(tmp_path, dense, gap, forward, density, own, view,
                                                                level, surface, anchor):
    """A net saved with the preset's anchor but its turn scan (the chain's last part adds that: the test below)
    (dense, range-weighted vote chosen by its gap with forward starts and rounds weighed by density, the gate over
    16 neighbours, the evidence read against frame 2's whole input, the departures measured from the net's own motion, the points leaving the view given their in-view neighbours'
    departure, the departures kept along the ground, a departure taken only off frame 2's surface; without the
    evidence and what follows it, the twenty-second round's): every part applies to it (its own inference options are
    dropped first), and ``alldfkxgfdovls`` (``alldfkxgfdovl``, ``alldfkxgfdov``, ``alldfkxgfdo``, ``alldfkxgfd``, ``alldfkxgf``, ``alldfkxg``, ``alldfkx``, ``alldfk``) is its
    anchor."""
    preset = dict(ANCHORABLE, eval_anchor=True, rigid_vote_dense=True, rigid_vote_far=True, eval_gate_k=16,
                  eval_evidence_dense=dense, rigid_vote_gap_m=gap, rigid_vote_forward=forward,
                  rigid_vote_density_m=density, eval_own_departure=own, eval_view_hold=view,
                  eval_level_departure=level, eval_evidence_surface=surface)
    path = tiny_flow_checkpoint(tmp_path / "run" / "net.pt", **preset)
    pc1 = structured_scene(np.random.default_rng(0), 300).astype(np.float32)
    pc2 = (pc1 + [0.1, 0.0, 1.0]).astype(np.float32)
    flows = {p: with_parts(NetMethod(path, device="cpu"), p)(pc1, pc2) for p in PARTS}
    np.testing.assert_array_equal(flows[anchor], NetMethod(path, device="cpu")(pc1, pc2))
    np.testing.assert_array_equal(flows["none"], NetMethod(path, device="cpu", eval_anchor=False)(pc1, pc2))


def test_leave_one_out_turns_each_switch_off_alone(tmp_path):
    from dataclasses import fields

    from benchmarks.anchor_parts import LEAVE_ONE_OUT, leave_one_out, without_switch

    path = tiny_flow_checkpoint(tmp_path / "net.pt", **ANCHORABLE, eval_anchor=True, eval_gate_k=8,
                                rigid_vote_yaw_deg=6.0, eval_view_hold=True)
    methods = leave_one_out(str(path))
    trained = methods[0].net.config
    assert methods[0].name.endswith("[as trained]")
    # one row per switch the net has on, named for it, and nothing else changed
    assert [m.name.split("[-")[1].rstrip("]") for m in methods[1:]] == ["eval_anchor", "eval_gate_k",
                                                                       "rigid_vote_yaw_deg", "eval_view_hold"]
    defaults = {f.name: f.default for f in fields(trained)}
    for m in methods[2:]:
        field = m.name.split("[-")[1].rstrip("]")
        changed = {f.name for f in fields(trained) if getattr(m.net.config, f.name) != getattr(trained, f.name)}
        assert changed == {field} and getattr(m.net.config, field) == defaults[field]
    assert methods[1].net.config == trained.without_anchor()
    rng = np.random.default_rng(0)
    pc1 = structured_scene(rng, 300).astype(np.float32)
    a = np.radians(3.0)
    R = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    pc2 = (pc1 @ R.T + [0.1, 0.0, 1.0]).astype(np.float32)
    np.testing.assert_array_equal(methods[0](pc1, pc2), NetMethod(path, device="cpu")(pc1, pc2))
    np.testing.assert_array_equal(methods[1](pc1, pc2), NetMethod(path, device="cpu", eval_anchor=False)(pc1, pc2))
    np.testing.assert_array_equal(methods[3](pc1, pc2), NetMethod(path, device="cpu", turn_scan=0)(pc1, pc2))
    assert without_switch(NetMethod(path, device="cpu"), "eval_level_departure") is None  # off already
    with pytest.raises(ConfigError, match="unknown switch"):
        without_switch(NetMethod(path, device="cpu"), "lr")
    assert set(LEAVE_ONE_OUT) <= set(defaults)


def test_leave_one_out_table_under_another_protocol(tmp_path, capsys):
    path = tiny_flow_checkpoint(tmp_path / "net.pt", **ANCHORABLE, eval_anchor=True)
    _split(tmp_path / "split")
    assert main(["--checkpoint", str(path), "--split", f"s={tmp_path / 'split'}", "--leave-one-out",
                 "--protocol", "full", "--n-points", "256"]) == 0
    rows = [r for r in capsys.readouterr().out.splitlines() if r.startswith(f"| {path}")]
    assert [r.split("]")[0].split("[")[1] for r in rows] == ["as trained", "-eval_anchor"]


def test_parts_and_leave_one_out_are_one_choice(tmp_path, capsys):
    with pytest.raises(SystemExit) as stop:
        main(["--checkpoint", "net.pt", "--split", f"s={tmp_path}", "--leave-one-out", "--parts", "all"])
    assert stop.value.code == 2
    assert "not allowed with argument" in capsys.readouterr().err


def test_the_last_part_of_the_chain_is_the_demo_presets_anchor(tmp_path):
    from benchmarks.anchor_parts import LEAVE_ONE_OUT, _preset_chain
    from training.presets import demo_train_config

    preset = demo_train_config("cache", "run").model
    switches = {f: getattr(preset, f) for f in LEAVE_ONE_OUT}  # every inference-only switch, as the preset sets it
    path = tiny_flow_checkpoint(tmp_path / "net.pt", **ANCHORABLE, **switches)
    rng = np.random.default_rng(1)
    pc1 = structured_scene(rng, 300).astype(np.float32)
    a = np.radians(4.0)  # a turn the scan finds
    R = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    pc2 = (pc1 @ R.T + [0.1, 0.0, 1.0]).astype(np.float32)
    last = list(_preset_chain())[-1]
    trained, parts = NetMethod(path, device="cpu"), with_parts(NetMethod(path, device="cpu"), last)
    # the inference pass runs with the same switches (the part sets directly what eval_anchor turns on)
    run_as_trained = trained.net.config.at_inference()
    for field in [*switches, "rigid_vote", "ego_l0_hold", "ego_l0_hold_from", "ego_gate_evidence", "ego_gate_k"]:
        if field not in ("eval_anchor", "eval_gate_k"):  # what they set, ego_gate_k and the rest, is compared
            assert getattr(parts.net.config, field) == getattr(run_as_trained, field), field
    np.testing.assert_array_equal(parts(pc1, pc2), trained(pc1, pc2))
