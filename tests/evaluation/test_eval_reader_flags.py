"""``monoflow-evaluate run --format NAME --NAME.<option>``: each registered format's options are flags with
their field docs as help, and they reach the reader."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from evaluation.cli import build_parser, main
from evaluation.predictions import read_predictions
from evaluation.readers import REGISTRY, FlowNet3DOptions, HPLFlowNetOptions, load_split
from evaluation.readers.flags import open_split, reader_options
from core.errors import ConfigError
from core.options import field_docs


def _fn3d_split(root: Path) -> Path:
    """Two FlowNet3D scenes (LiDAR axes, x forward) of 40 points 5..45 m ahead."""
    root.mkdir()
    rng = np.random.default_rng(0)
    for name in ("a", "b"):
        pos1 = np.column_stack([np.linspace(5, 45, 40), rng.uniform(-3, 3, 40), rng.uniform(-1, 1, 40)])
        gt = rng.normal(0, 0.1, (40, 3))
        np.savez(root / f"{name}.npz", pos1=pos1.astype(np.float32), pos2=(pos1 + gt).astype(np.float32),
                 gt=gt.astype(np.float32))
    return root


def _hpl_split(root: Path) -> Path:
    """One HPLFlowNet scene: stored (−x, −y, z); points 1 and 2 are ground (stored y < −1.4), point 3 is far."""
    (root / "s").mkdir(parents=True)
    pc1 = np.array([[0.0, 0.0, 10.0], [1.0, -1.5, 10.0], [2.0, -1.6, 12.0], [3.0, 0.0, 50.0]], np.float32)
    np.save(root / "s" / "pc1.npy", pc1)
    np.save(root / "s" / "pc2.npy", pc1 + np.float32(0.1))
    return root


def test_every_format_option_is_a_documented_flag() -> None:
    text = build_parser()._subparsers._group_actions[0].choices["run"].format_help()
    for fmt in REGISTRY.values():
        assert f"{fmt.name} reader options" in text
        for field, doc in field_docs(fmt.options).items():
            assert f"--{fmt.name}.{field}" in text and doc.split()[0] in text
    assert "metres" in text


def test_hplflownet_flags_reach_the_reader(tmp_path: Path) -> None:
    split = _hpl_split(tmp_path / "hpl")
    parse = build_parser().parse_args
    assert load_split(split)[0].n1 == 2  # defaults: both ground points (pc2 is ground too) and the far one dropped
    args = parse(["run", "--split", str(split), "--hplflownet.max_depth", "none", "--hplflownet.remove-ground",
                  "false"])
    assert reader_options(args) == {"hplflownet": HPLFlowNetOptions(remove_ground=False, max_depth=None)}
    assert open_split(args)[0].n1 == 4
    args = parse(["run", "--split", str(split), "--format", "hplflownet", "--hplflownet.ground_height", "1.55"])
    assert open_split(args)[0].n1 == 3  # only the point at stored y = −1.6 is ground now
    assert reader_options(parse(["run", "--split", str(split)])) == {}
    with pytest.raises(SystemExit):  # argparse names the choices
        parse(["run", "--split", str(split), "--hplflownet.ground_rule", "neither"])


def test_options_of_another_format_are_refused(tmp_path: Path, capsys) -> None:
    split = _fn3d_split(tmp_path / "fn3d")
    args = build_parser().parse_args(["run", "--split", str(split), "--hplflownet.max_depth", "10"])
    with pytest.raises(ConfigError, match=r"--hplflownet\.\* options were given but .* is read as flownet3d"):
        open_split(args)
    assert main(["run", "--split", str(split), "--baselines", "zero", "--hplflownet.max_depth", "10",
                 "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: --hplflownet.* options") and "--flownet3d.*" in err[0]


def test_flownet3d_max_depth_flag_changes_what_is_scored(tmp_path: Path) -> None:
    """End to end: ``--flownet3d.max_depth 20`` keeps only camera z < 20 m, and the full protocol scores exactly
    the points the reader returns with that option."""
    split = _fn3d_split(tmp_path / "fn3d")
    out = tmp_path / "eval"
    rc = main(["run", "--split", str(split), "--baselines", "zero", "--protocol", "full", "--n-points", "16",
               "--save-predictions", "--no-progress", "--no-warmup", "--device", "cpu", "--out", str(out),
               "--flownet3d.max_depth", "20"])
    assert rc == 0
    expected = load_split(split, flownet3d=FlowNet3DOptions(max_depth=20.0))
    scenes = read_predictions(out / "predictions-zero.h5")
    assert [s.name for s in scenes] == expected.names
    for s, want in zip(scenes, expected):
        assert 0 < len(s.points) == want.n1 < 40 and s.points[:, 2].max() < 20
        np.testing.assert_allclose(s.gt_flow, want.flow)
