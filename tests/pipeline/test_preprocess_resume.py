"""A stage-one run killed mid-way (SIGKILL after its first block) and rerun ends with exactly the cache of an
uninterrupted run; while killed, no partial block is visible to the reader."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from test_preprocess import tree_bytes

REPO = Path(__file__).resolve().parents[2]


def _args(root: Path, out: Path) -> list[str]:
    return [sys.executable, "-m", "pipeline", "--root", str(root), "--depth", "gt", "--pose", "gt", "--size", "native",
            "--block_size", "1", "--progress", "false", "--out", str(out)]


def _env() -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": str(REPO)}


def test_killed_run_resumes_to_an_identical_cache(synth_root, tmp_path):  # noqa: F811
    from pipeline.cache import CacheReader
    from pipeline.cache.manifest import find_tmp, inspect_block, scan_blocks
    from core.errors import InputError

    killed = tmp_path / "killed"
    proc = subprocess.Popen(_args(synth_root, killed), env=_env(), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    first = None
    deadline = time.monotonic() + 60
    while first is None and time.monotonic() < deadline and proc.poll() is None:
        found = list(killed.glob("*/*/blocks/00/00000/zarr.json"))
        first = found[0] if found else None
        time.sleep(0.002)
    if first is None:
        proc.kill()
        pytest.fail(f"no block appeared (rc {proc.poll()}): {proc.stderr.read().decode()[-500:]}")
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=30)
    assert proc.returncode == -signal.SIGKILL
    root = first.parents[3]

    # Killed mid-way: some but not all of the 8 blocks; every block present is complete, and the reader
    # sees nothing (no manifest yet).
    present = scan_blocks(root).get("00", [])
    assert 1 <= len(present) < 8, present
    for b in present:
        inspect_block(root, "00", b)
    with pytest.raises(InputError):
        CacheReader(root)

    rerun = subprocess.run(_args(synth_root, killed), env=_env(), capture_output=True, text=True, timeout=120)
    assert rerun.returncode == 0, rerun.stderr
    assert f"({8 - len(present)} written, {len(present)} already done)" in rerun.stdout
    assert find_tmp(root) == []  # the killed writer's temp block was cleared

    clean = tmp_path / "clean"
    full = subprocess.run(_args(synth_root, clean), env=_env(), capture_output=True, text=True, timeout=120)
    assert full.returncode == 0, full.stderr
    (clean_root,) = list(clean.glob("*/*"))
    assert clean_root.name == root.name
    reference = tree_bytes(clean_root)
    assert "manifest.json" in reference and len(reference) > 20
    assert tree_bytes(root) == reference
    assert len(CacheReader(root)) == 8


def test_a_cache_of_another_world_at_the_same_path_is_refused_and_the_same_world_resumes(tmp_path, capsys):
    """Stage one resumes a cache only from the inputs it was written from: a world drawn again at the same path with
    another seed is refused in one line naming the cache and the sequence; drawn again alike, it is resumed."""
    from pipeline.cli import main
    from pipeline.synth import SynthConfig, generate

    world, out = tmp_path / "world", tmp_path / "cache"
    tiny = dict(width=64, height=32, n_sequences=1, frames=4, test_frames=0, lidar_scans="test")
    args = ["--root", str(world), "--depth", "gt", "--pose", "gt", "--size", "native", "--progress", "false",
            "--out", str(out)]
    generate(SynthConfig(seed=1, **tiny), world)
    assert main(args) == 0
    (cache,) = list(out.glob("*/*"))
    before = tree_bytes(cache)
    generate(SynthConfig(seed=1, **tiny), world, force=True)  # the same world written again: resumed as it is
    capsys.readouterr()
    assert main(args) == 0 and "already done" in capsys.readouterr().out
    assert tree_bytes(cache) == before
    generate(SynthConfig(seed=2, **tiny), world, force=True)  # another world at the same path
    assert main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(cache) in err[0] and "sequence 00" in err[0] and "changed" in err[0]
    assert tree_bytes(cache) == before  # nothing of it was touched


def test_the_input_digest_reads_the_world_s_identity_not_its_frames(synth_root, tmp_path):
    import json
    import shutil

    from pipeline.kitti.odometry import OdometrySequence
    from pipeline.preprocess.identity import input_fingerprint

    root = tmp_path / "world"
    shutil.copytree(synth_root, root)
    first = input_fingerprint(OdometrySequence(root, "00"))
    image = root / "sequences/00/image_2/000003.png"
    image.write_bytes(image.read_bytes()[:100])  # a frame damaged (and later repaired): the same inputs
    assert input_fingerprint(OdometrySequence(root, "00")) == first
    meta = json.loads((root / "synth.json").read_text())
    meta["version"] = "another"  # the same seed and config drawn by another generator version: other inputs
    (root / "synth.json").write_text(json.dumps(meta))
    assert input_fingerprint(OdometrySequence(root, "00")) != first
