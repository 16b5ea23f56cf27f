"""Crash safety, resume, merge of array-job shards, verify, and manifest errors."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from pipeline.cache import CacheReader, CacheWriter, merge, verify
from pipeline.cache import block_format
from pipeline.cache.layout import MANIFEST_NAME, block_dir
from core.errors import InputError
from testkit.demo_scene import street_block

H, W = 20, 48
CONFIG = {"size": [W, H], "block_pairs": 2}
SOURCE = {"dataset": "synth", "seed": 0}
PLAN = {"00": 3, "01": 2}
REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def blocks():
    return {(s, b): street_block(s, b, 2, H, W, seed=len(s) + int(s)) for s, n in PLAN.items() for b in range(n)}


def _files(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def _write_all(root: Path, blocks) -> dict:
    w = CacheWriter(root, CONFIG, SOURCE)
    for key in sorted(blocks):
        w.write_block(blocks[key])
    return w.finalize(PLAN)


@pytest.fixture(scope="module")
def clean(tmp_path_factory, blocks):
    root = tmp_path_factory.mktemp("clean")
    _write_all(root, blocks)
    return root


def _crash_during(monkeypatch, after: str = "depth"):
    """Make block_format._write_arrays raise after writing the array ``after``."""
    real = block_format._sharded

    def boom(group, name, *args, **kw):
        real(group, name, *args, **kw)
        if name == after:
            raise RuntimeError("simulated crash")

    monkeypatch.setattr(block_format, "_sharded", boom)


def test_exception_mid_write_leaves_nothing(tmp_path, blocks, monkeypatch):
    w = CacheWriter(tmp_path, CONFIG, SOURCE)
    _crash_during(monkeypatch)
    with pytest.raises(RuntimeError, match="simulated"):
        w.write_block(blocks[("00", 0)])
    assert not w.has_block("00", 0)
    assert list((tmp_path / "blocks" / "00").iterdir()) == []  # no temp dir either


def test_resume_after_crash_is_identical_to_uninterrupted(tmp_path, blocks, clean, monkeypatch):
    w = CacheWriter(tmp_path, CONFIG, SOURCE)
    order = sorted(blocks)
    for key in order[:2]:
        assert w.write_block(blocks[key])
    with monkeypatch.context() as m:
        _crash_during(m, after="rgb")
        with pytest.raises(RuntimeError):
            w.write_block(blocks[order[2]])
    # a new run: skip finished blocks, write the rest
    w2 = CacheWriter(tmp_path, CONFIG, SOURCE)
    written = [key for key in order if not w2.has_block(*key) and w2.write_block(blocks[key])]
    assert written == order[2:]
    w2.finalize(PLAN)
    a, b = _files(clean), _files(tmp_path)
    assert sorted(a) == sorted(b)
    differing = [k for k in a if a[k] != b[k]]
    assert differing == []  # every array chunk, zarr.json, cache.json and manifest.json byte-identical


def test_killed_writer_tmp_ignored_by_reader_and_removed_by_next_writer(tmp_path, blocks):
    w = CacheWriter(tmp_path, CONFIG, SOURCE)
    for key in sorted(blocks):
        w.write_block(blocks[key])
    w.finalize(PLAN)
    shutil.rmtree(block_dir(tmp_path, "01", 1))  # this block will be rewritten by a process we kill
    script = f"""
import os, signal, sys
sys.path.insert(0, {str(REPO)!r})
from pipeline.cache import CacheWriter, block_format
from testkit.demo_scene import street_block
real = block_format._sharded
def die(group, name, *a, **k):
    real(group, name, *a, **k)
    if name == "rgb":
        os.kill(os.getpid(), signal.SIGKILL)
block_format._sharded = die
CacheWriter({str(tmp_path)!r}, {CONFIG!r}, {SOURCE!r}).write_block(street_block("01", 1, 2, {H}, {W}, seed=3))
"""
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert proc.returncode == -9, proc.stderr
    tmps = [p for p in (tmp_path / "blocks" / "01").iterdir() if ".tmp-" in p.name]
    assert len(tmps) == 1 and tmps[0].name.startswith("00001.tmp-")
    assert not (block_dir(tmp_path, "01", 1) / "zarr.json").exists()  # the partial block is not visible
    # readers never see it: a reader refuses the cache whose listed block is gone (naming it)...
    with pytest.raises(InputError, match="blocks/01/00001: block listed in the manifest is missing"):
        CacheReader(tmp_path)
    # ...unless told not to check every block first; the other listed blocks then read fine...
    r = CacheReader(tmp_path, check_files=False)
    assert len(r) == 10
    r[0]
    # ...and merge, which scans the tree, ignores the temp dir
    assert merge(tmp_path)["num_pairs"] == 8
    assert len(CacheReader(tmp_path)) == 8
    # the next writer removes it, then completes the block
    w2 = CacheWriter(tmp_path, CONFIG, SOURCE)
    assert w2.removed_tmp == tmps and not tmps[0].exists()
    assert not w2.has_block("01", 1) and w2.write_block(blocks[("01", 1)])
    assert w2.finalize(PLAN)["num_pairs"] == 10
    assert verify(tmp_path).ok


def test_merge_of_two_shards_equals_single_run(tmp_path, blocks, clean):
    order = sorted(blocks)
    for shard in range(2):  # like `--shard i/2` jobs writing into one tree
        w = CacheWriter(tmp_path, CONFIG, SOURCE)
        for key in order[shard::2]:
            w.write_block(blocks[key])
    with pytest.raises(InputError, match="no manifest"):
        CacheReader(tmp_path)  # not merged yet
    manifest = merge(tmp_path)
    assert manifest["num_pairs"] == 10 and manifest["num_blocks"] == 5
    assert (tmp_path / MANIFEST_NAME).read_bytes() == (clean / MANIFEST_NAME).read_bytes()
    r = CacheReader(tmp_path)
    assert np.array_equal(r[9].pc1, CacheReader(clean)[9].pc1)


def test_merge_and_finalize_refuse_missing_blocks(tmp_path, blocks):
    w = CacheWriter(tmp_path, CONFIG, SOURCE)
    for key in [("00", 0), ("00", 2), ("01", 0)]:
        w.write_block(blocks[key])
    with pytest.raises(InputError, match=r"00: \[1\]"):
        merge(tmp_path)
    with pytest.raises(InputError, match=r"2 expected block\(s\) missing: 00/00001, 01/00001"):
        w.finalize(PLAN)
    assert not (tmp_path / MANIFEST_NAME).exists()


def test_manifest_corrupt_or_other_schema_is_one_line_input_error(tmp_path, blocks):
    _write_all(tmp_path, {k: v for k, v in blocks.items()})
    path = tmp_path / MANIFEST_NAME
    good = path.read_text()
    path.write_text(good[: len(good) // 2])
    with pytest.raises(InputError) as exc:
        CacheReader(tmp_path)
    assert str(exc.value).startswith(str(path) + ": ") and "not valid JSON" in str(exc.value)
    assert "\n" not in str(exc.value)
    m = json.loads(good)
    m["schema_version"] = 999
    path.write_text(json.dumps(m))
    with pytest.raises(InputError, match="schema version 999, this code reads 2") as exc:
        CacheReader(tmp_path)
    assert "\n" not in str(exc.value)
    path.unlink()
    with pytest.raises(InputError, match="manifest.json: no manifest"):
        CacheReader(tmp_path)


def test_verify_catches_corrupted_and_missing_blocks(tmp_path, blocks):
    _write_all(tmp_path, blocks)
    report = verify(tmp_path)
    assert report.ok, report.summary()
    assert (report.blocks_checked, report.pairs_checked) == (5, 10)
    # flip bytes in the middle of one block's depth shard: the chunk CRC no longer matches
    shard = next((block_dir(tmp_path, "00", 1) / "depth" / "c").rglob("*"))
    while shard.is_dir():
        shard = next(shard.iterdir())
    data = bytearray(shard.read_bytes())
    mid = len(data) // 3
    data[mid : mid + 8] = bytes(255 - x for x in data[mid : mid + 8])
    shard.write_bytes(bytes(data))
    shutil.rmtree(block_dir(tmp_path, "01", 0))
    report = verify(tmp_path)
    assert not report.ok
    assert len(report.errors) == 2, report.summary()
    assert any(str(block_dir(tmp_path, "00", 1)) in e for e in report.errors)
    assert any(str(block_dir(tmp_path, "01", 0)) in e and "missing" in e for e in report.errors)
    with pytest.raises(InputError, match="missing"):
        CacheReader(tmp_path)[6]


def test_verify_catches_counts_that_disagree_with_the_manifest(tmp_path, blocks):
    _write_all(tmp_path, blocks)
    path = tmp_path / MANIFEST_NAME
    m = json.loads(path.read_text())
    m["sequences"]["00"]["blocks"][1]["num_points1"] += 1
    path.write_text(json.dumps(m))
    report = verify(tmp_path)
    assert len(report.errors) == 1 and "num_points1" in report.errors[0]
    os.makedirs(block_dir(tmp_path, "00", 1).with_name("00007.tmp-1-otherhost"))
    assert any("temp entry" in w for w in verify(tmp_path).warnings)
