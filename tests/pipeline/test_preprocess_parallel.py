"""Stage one with spawned workers and shards: the cache is byte-identical to a one-process run, and an
error in a worker stops the run with the same one-line message, leaving no partial block."""

from __future__ import annotations

from test_preprocess import check_corrupt_png_stops_cleanly, gt_config, tree_bytes

from pipeline.preprocess import run_preprocess


def test_workers_and_shards_write_the_same_cache(synth_root, tmp_path):  # noqa: F811
    one = run_preprocess(gt_config(synth_root, tmp_path / "one", block_size=2))
    two = run_preprocess(gt_config(synth_root, tmp_path / "two", block_size=2, workers=2))
    assert two.blocks_written == 4 and two.manifest_written
    s0 = run_preprocess(gt_config(synth_root, tmp_path / "sh", block_size=2, shard="0/2"))
    assert s0.blocks_planned == 2 and not s0.manifest_written  # blocks 0 and 2
    s1 = run_preprocess(gt_config(synth_root, tmp_path / "sh", block_size=2, shard="1/2"))
    assert s1.blocks_planned == 2 and s1.manifest_written  # the last shard sees every block: writes the manifest
    ref = tree_bytes(one.cache_root)
    assert len(ref) > 10
    assert tree_bytes(two.cache_root) == ref
    assert tree_bytes(s1.cache_root) == ref
    assert one.cache_root.name == two.cache_root.name  # workers / shard do not change the cache's name


def test_corrupt_png_in_a_worker_stops_cleanly(synth_root, tmp_path, capsys):  # noqa: F811
    check_corrupt_png_stops_cleanly(synth_root, tmp_path, capsys, workers=2)
