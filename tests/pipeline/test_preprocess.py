"""Stage one end to end on the synthetic world: static flow vs ground truth, filters, scale modes, net calls,
workers and shards, the CLI (config file, merge, verify, one-line errors that leave nothing half-written)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from pipeline.cli import main
from pipeline.preprocess import PreprocessConfig, plan_blocks, run_preprocess, sequence_pairs
from pipeline.scale import ScaleConfig



@pytest.fixture(scope="session")
def scaled_root(synth_root, tmp_path_factory):
    """The same world as a monocular net would see it: depth and pose translations × 0.5 (LiDAR stays metric)."""
    from pipeline.kitti.png16 import read_depth_png, write_depth_png
    from pipeline.kitti.poses import read_poses, write_poses

    root = tmp_path_factory.getbasetemp() / "synth_scaled_half"
    if not root.exists():
        shutil.copytree(synth_root, root)
        for png in sorted((root / "sequences/00/depth_2").glob("*.png")):
            write_depth_png(png, read_depth_png(png) * 0.5)
        poses = read_poses(root / "poses/00.txt")
        poses[:, :3, 3] *= 0.5
        write_poses(root / "poses/00.txt", poses)
    return root


def gt_config(root, out, **kw) -> PreprocessConfig:
    base = dict(root=str(root), depth="gt", pose="gt", size="native", block_size=3, out=str(out), progress=False)
    base.update(kw)
    return PreprocessConfig(**base)


def tree_bytes(root: Path, skip=("preprocess_run.json",)) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file() and p.name not in skip}


# --------------------------------------------------------------------------- planning


def test_plan_blocks_of_consecutive_pairs():
    assert sequence_pairs([0, 1, 2, 4, 5]) == [(0, 1), (1, 2), (3, 4)]  # frame 3 missing: no pair across it
    plans = plan_blocks({"01": list(range(4)), "00": list(range(9))}, 3)
    assert [(p.sequence, p.index, p.global_index, len(p.pairs)) for p in plans] == [
        ("00", 0, 0, 3), ("00", 1, 1, 3), ("00", 2, 2, 2), ("01", 0, 3, 3)]
    assert plans[1].pairs == ((3, 4), (4, 5), (5, 6))


def test_cache_name_depends_on_content_options_only(tmp_path):
    from pipeline.preprocess import cache_config

    base = cache_config(gt_config("/data/a", tmp_path), ["00"])
    same = cache_config(gt_config("/elsewhere/b", tmp_path / "x", seed=7, device="cuda", workers=4, amp=True,
                                  shard="1/3", batch_size=2), ["00"])
    assert same == base  # paths, speed knobs and net options that gt sources ignore do not rename the cache
    assert cache_config(gt_config("/data/a", tmp_path, block_size=8), ["00"]) != base
    assert cache_config(gt_config("/data/a", tmp_path), ["00", "01"]) != base
    a, b = tmp_path / "a.pth", tmp_path / "b.pth"
    a.write_bytes(b"weights")
    b.write_bytes(b"weights")
    net_a = cache_config(gt_config("/d", tmp_path, depth="net", depth_checkpoint=str(a)), ["00"])
    net_b = cache_config(gt_config("/d", tmp_path, depth="net", depth_checkpoint=str(b)), ["00"])
    assert net_a == net_b and net_a["depth_checkpoint_sha256"] and net_a["pose_checkpoint_sha256"] is None
    b.write_bytes(b"other weights")
    assert cache_config(gt_config("/d", tmp_path, depth="net", depth_checkpoint=str(b)), ["00"]) != net_a


# --------------------------------------------------------------------------- ground-truth sources


def test_gt_sources_give_ground_truth_static_flow(synth_root, tmp_path):
    from pipeline.cache import CacheReader, verify

    summary = run_preprocess(gt_config(synth_root, tmp_path))
    assert summary.pairs == 8 and summary.blocks_written == 3 and summary.manifest_written
    assert summary.depth_net_images == 0 and summary.pose_net_pairs == 0
    assert list(summary.mean_points) == ["valid", "ground", "far", "lidar", "occlusion"]
    pts = list(summary.mean_points.values())
    assert all(a > b for a, b in zip(pts[:-1], pts[1:]))
    assert 0 < summary.bytes_per_pair < 1e6
    assert "depth gt, pose gt, scale none" in summary.text()

    reader = CacheReader(summary.cache_root)
    assert len(reader) == 8
    n_static = 0
    for i in range(len(reader)):
        s = reader[i]
        assert s.pc1[:, 1].max() < 1.15 and s.pc1[:, 2].max() < 35.0
        assert s.pc2[:, 1].max() < 1.15 and s.pc2[:, 2].max() < 35.0
        static = ~s.moving & np.isfinite(s.gt_flow).all(axis=1)
        err = np.linalg.norm(s.static_flow[static] - s.gt_flow[static], axis=1)
        assert err.max() < 1e-3, (i, err.max())
        n_static += static.sum()
        assert s.scale == 1.0 and s.frame_t1 == s.frame_t + 1
    assert n_static > 5000
    assert verify(summary.cache_root).ok

    run = json.loads((summary.cache_root / "preprocess_run.json").read_text())
    assert run["config"]["depth"] == "gt" and run["versions"]["numpy"] == np.__version__
    assert "git" in run["code_version"]

    again = run_preprocess(gt_config(synth_root, tmp_path))  # resume: nothing left to do
    assert again.blocks_written == 0 and again.blocks_skipped == 3 and again.cache_root == summary.cache_root


@pytest.mark.parametrize("mode", ["camera-height", "lidar"])
def test_scale_modes_recover_an_unknown_scale(scaled_root, tmp_path, mode):
    from pipeline.cache import CacheReader

    results = []
    # The rescaled poses stand in for a pose net's: their translation shares the depth's unknown scale.
    cfg = gt_config(scaled_root, tmp_path, scale=ScaleConfig(mode=mode, scale_translation=True))
    summary = run_preprocess(cfg, on_block=results.append)
    for r in results:
        assert r.scale == pytest.approx(2.0, rel=0.05)
    reader = CacheReader(summary.cache_root)
    for i in (0, 5):
        s = reader[i]
        static = ~s.moving
        g = s.gt_flow[static]  # metric ground truth: the world was only rescaled on disk
        err = np.linalg.norm(s.static_flow[static] - g, axis=1)
        assert np.median(err / np.linalg.norm(g, axis=1)) < 0.05


# --------------------------------------------------------------------------- the command line


def test_cli_config_file_flags_merge_and_verify(synth_root, tmp_path, capsys):
    toml = tmp_path / "run.toml"
    toml.write_text(
        f'root = "{synth_root}"\ndepth = "gt"\npose = "gt"\nsize = "native"\nblock_size = 4\nprogress = false\n'
        "[filters]\nlidar = false\n[scale]\nmode = \"fixed\"\nfactor = 1.0\n"
    )
    out = tmp_path / "cache"
    rc = main(["--config", str(toml), "--out", str(out), "--filters.occlusion", "false", "--shard", "0/2"])
    assert rc == 0
    text = capsys.readouterr().out
    assert "stage one: 4 pairs in 1 blocks" in text and "valid" in text and "occlusion" not in text
    (root,) = list((out / synth_root.name).iterdir())
    run = json.loads((root / "preprocess_run.json").read_text())
    assert run["config"]["filters"]["lidar"] is False and run["config"]["filters"]["occlusion"] is False
    assert run["config"]["block_size"] == 4 and run["config"]["scale"]["mode"] == "fixed"
    assert not (root / "manifest.json").exists()
    assert main(["run", "--config", str(toml), "--out", str(out), "--filters.occlusion", "false",
                 "--shard", "1/2"]) == 0
    (root / "manifest.json").unlink()
    assert main(["merge", str(root)]) == 0
    assert "8 pairs in 2 blocks" in capsys.readouterr().out
    assert main(["verify", str(root)]) == 0
    assert ": OK;" in capsys.readouterr().out


def test_cli_bad_options_are_one_line_errors(synth_root, tmp_path, capsys):
    assert main(["--root", str(synth_root), "--depth", "stereo", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and "depth source" in err and "\n" not in err
    assert main(["--root", str(tmp_path / "nowhere"), "--depth", "gt", "--pose", "gt", "--out", str(tmp_path)]) == 2
    assert "nowhere" in capsys.readouterr().err
    assert main(["--root", str(synth_root), "--depth", "net", "--out", str(tmp_path)]) == 2
    assert "depth_checkpoint" in capsys.readouterr().err
    assert main(["verify", str(tmp_path / "nocache")]) == 1


def test_corrupt_png_mid_sequence_stops_cleanly(synth_root, tmp_path, capsys):
    check_corrupt_png_stops_cleanly(synth_root, tmp_path, capsys, workers=1)


def check_corrupt_png_stops_cleanly(synth_root, tmp_path, capsys, workers):
    from pipeline.cache import CacheReader
    from pipeline.cache.manifest import find_tmp
    from core.errors import InputError

    root = tmp_path / "world"
    shutil.copytree(synth_root, root)
    bad = root / "sequences/00/image_2/000005.png"
    good = bad.read_bytes()
    bad.write_bytes(good[: len(good) // 2])  # truncated
    out = tmp_path / "cache"
    args = ["--root", str(root), "--depth", "gt", "--pose", "gt", "--size", "native", "--block_size", "2",
            "--progress", "false", "--out", str(out), "--workers", str(workers)]
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"error: {bad}: ") and "\n" not in err
    (cache,) = list((out / "world").iterdir())
    done = sorted(p.name for p in (cache / "blocks/00").iterdir())
    assert "00002" not in done  # the block holding frame 5 (pairs 4-5, 5-6)
    if workers == 1:
        assert done == ["00000", "00001"]  # finished blocks stay; nothing after the error was started
    assert find_tmp(cache) == [] and not (cache / "manifest.json").exists()
    with pytest.raises(InputError):
        CacheReader(cache)
    bad.write_bytes(good)
    assert main(args) == 0
    assert len(CacheReader(cache)) == 8


def test_missing_frame_mid_sequence_is_named(synth_root, tmp_path, capsys):
    root = tmp_path / "world"
    shutil.copytree(synth_root, root)
    (root / "sequences/00/image_2/000004.png").unlink()
    args = ["--root", str(root), "--depth", "gt", "--pose", "gt", "--size", "native", "--progress", "false",
            "--out", str(tmp_path / "cache")]
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"error: {root / 'sequences/00/image_2/000004.png'}: missing") and "\n" not in err
    shutil.copy(synth_root / "sequences/00/image_2/000004.png", root / "sequences/00/image_2/000004.png")
    (root / "sequences/00/depth_2/000006.png").unlink()  # a missing ground-truth depth map
    assert main(args) == 2
    assert capsys.readouterr().err.strip() == f"error: {root / 'sequences/00/depth_2/000006.png'}: file not found"


def test_help_is_instant_and_python_m_pipeline_works():
    code = "import sys; from pipeline.cli import main\ntry:\n main(['--help'])\nexcept SystemExit:\n pass\n" \
           "print('torch' in sys.modules, 'zarr' in sys.modules, 'cv2' in sys.modules)"
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert res.stdout.strip().splitlines()[-1] == "False False False"
    res = subprocess.run([sys.executable, "-m", "pipeline", "run", "--help"], capture_output=True, text=True,
                         timeout=60, env={**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[2])})
    assert res.returncode == 0 and "--filters.occlusion_threshold" in res.stdout
