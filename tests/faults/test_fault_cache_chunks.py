"""A finished cache that lost or truncated any single chunk file is refused, naming the block: by
``verify`` (the API and ``monoflow-preprocess verify``), by the reader (so by training, before its first
step), and by ``merge``. Before, zarr read the lost chunk as zeros and training ran on garbage."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from _faults import assert_one_error_line, run_cli
from _trainer_fixtures import config_flags, tiny_cache, tiny_config  # noqa: F401

from pipeline.cache import CacheReader, merge, verify
from core.errors import InputError

BLOCK = "blocks/00/00001"


def _listed_files(cache: Path) -> list[str]:
    attrs = json.loads((cache / BLOCK / "zarr.json").read_text())["attributes"]
    return sorted(attrs["chunk_files"])


def test_every_array_of_the_fixture_has_a_listed_chunk(tiny_cache: Path) -> None:  # noqa: F811
    arrays = {f.split("/")[0] for f in _listed_files(tiny_cache) if "/c/" in f}
    assert arrays == {"K", "T", "scale", "depth", "rgb", "idx1", "idx2", "offsets1", "offsets2", "gt_flow", "moving"}


@pytest.mark.parametrize("damage", ["delete", pytest.param("truncate", marks=pytest.mark.slow)])
def test_each_lost_or_short_chunk_is_named(tiny_cache: Path, tmp_path: Path, damage: str) -> None:  # noqa: F811
    files = _listed_files(tiny_cache)
    assert len(files) >= 22  # 11 arrays: a chunk file and a zarr.json each
    for rel in files:
        cache = tmp_path / rel.replace("/", "_")
        shutil.copytree(tiny_cache, cache)
        target = cache / BLOCK / rel
        if damage == "delete":
            target.unlink()
        else:
            data = target.read_bytes()
            target.write_bytes(data[: len(data) // 2])
        report = verify(cache)
        assert not report.ok, rel
        assert any(BLOCK in e and rel in e for e in report.errors), (rel, report.errors)
        assert all("\n" not in e for e in report.errors)
        with pytest.raises(InputError) as err:
            CacheReader(cache)
        assert BLOCK in str(err.value) and rel in str(err.value) and "\n" not in str(err.value)
        with pytest.raises(InputError, match=BLOCK):
            merge(cache)
        shutil.rmtree(cache)


@pytest.mark.slow
def test_verify_cli_and_training_refuse_a_lost_chunk(tiny_cache: Path, tmp_path: Path) -> None:  # noqa: F811
    for rel in ("T/c/0/0/0", "gt_flow/c/0/0"):
        cache = tmp_path / rel.split("/")[0] / "cache"
        shutil.copytree(tiny_cache, cache)
        (cache / BLOCK / rel).unlink()
        proc = run_cli("pipeline", ["verify", cache])
        assert proc.returncode == 1 and f"{BLOCK}: chunk file(s) missing: {rel}" in proc.stdout, proc.stdout
        run = tmp_path / rel.split("/")[0] / "run"
        proc = run_cli("training", config_flags(tiny_config(cache, run, steps=2)))
        line = assert_one_error_line(proc, str(cache / BLOCK))
        assert rel in line
        assert not (run / "latest.pt").exists()
