"""Writing stage one's cache one finished block at a time (resumable, multi-machine safe).

A block is written completely into ``blocks/<seq>/<block:05d>.tmp-<pid>-<host>/``, its files fsynced, and
then renamed into place: a present block is a finished block. A killed run leaves at most a temp
directory, which readers never look at and the next writer on that host removes; rerunning skips the
finished blocks (:meth:`CacheWriter.has_block`) and, since a block's bytes depend only on its record,
ends with a cache identical to an uninterrupted run's.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path
from typing import Any

from pipeline.cache.encode import encode_block
from pipeline.cache.integrity import CHUNK_FILES_ATTR, list_block_files
from pipeline.cache.layout import (
    BLOCKS_DIR,
    HEADER_NAME,
    block_dir,
    canonical_json,
    code_version,
    config_hash,
    fsync_dir,
    tmp_suffix,
    write_json_atomic,
)
from pipeline.cache.manifest import ExpectedBlocks, make_header, merge, read_header, remove_stale_tmp
from pipeline.cache.records import BlockRecord
from core.errors import ConfigError, InputError


class CacheWriter:
    """Writes blocks into the cache at ``root`` (normally ``cache_root(out, dataset, config)``).

    ``config``: the resolved stage-one config (plain JSON data); it names the cache (:func:`config_hash`)
    and a root already holding another config's cache is refused (ConfigError).
    ``source``: a description of the input (dataset, path, sequences, ...); the first writer's is kept.
    On start, temp directories of dead writers on this host are removed (:attr:`removed_tmp`).
    """

    def __init__(self, root: str | os.PathLike[str], config: dict, source: dict) -> None:
        self.root = Path(root)
        self.config_hash = config_hash(config)
        self._code_version = code_version()
        (self.root / BLOCKS_DIR).mkdir(parents=True, exist_ok=True)
        header_path = self.root / HEADER_NAME
        if header_path.exists():
            header = read_header(self.root)
            if header["config_hash"] != self.config_hash or canonical_json(header["config"]) != canonical_json(config):
                raise ConfigError(
                    f"{self.root} holds the cache of another config (hash {header['config_hash']}, "
                    f"this config's is {self.config_hash}); use cache_root() or another folder"
                )
            changed = _changed_inputs(header["source"], source)
            if changed:
                raise ConfigError(
                    f"{self.root} was written from other inputs: sequence {changed[0]} of "
                    f"{source.get('root', 'the dataset')} has changed since; remove that cache folder or write elsewhere"
                )
        else:
            write_json_atomic(header_path, make_header(config, source, self.config_hash))
        self.removed_tmp: list[Path] = remove_stale_tmp(self.root)

    def has_block(self, sequence: str, block_index: int) -> bool:
        """Whether block ``block_index`` of ``sequence`` is finished (present = complete)."""
        return (block_dir(self.root, sequence, block_index) / "zarr.json").is_file()

    def write_block(self, block: BlockRecord) -> bool:
        """Write one block atomically; return False (writing nothing) if it is already present.

        Raises ValueError for an inconsistent record; on any error nothing of the block stays on disk.
        """
        from pipeline.cache import block_format

        final = block_dir(self.root, block.sequence, block.block_index)
        if self.has_block(block.sequence, block.block_index):
            return False
        encoded = encode_block(block, self.config_hash, self._code_version)
        final.parent.mkdir(parents=True, exist_ok=True)
        tmp = final.with_name(final.name + tmp_suffix())
        if tmp.exists():
            shutil.rmtree(tmp)
        try:
            group = block_format.create_group(tmp)
            group.attrs.update(encoded.attrs)
            block_format.write_arrays(group, encoded.arrays)
            # every chunk file and its size, so that a lost or truncated chunk is seen (integrity.py)
            group.attrs[CHUNK_FILES_ATTR] = list_block_files(tmp)
            block_format.consolidate(tmp)
            _fsync_tree(tmp)
            try:
                os.rename(tmp, final)
            except OSError:
                if self.has_block(block.sequence, block.block_index):  # another writer finished it first
                    shutil.rmtree(tmp, ignore_errors=True)
                    return False
                raise
            fsync_dir(final.parent)
        except OSError as exc:  # disk full, quota, permissions: nothing of the block stays, one line
            shutil.rmtree(tmp, ignore_errors=True)
            raise InputError(final, f"cannot write block ({exc.strerror or exc}); nothing of it was kept") from None
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
        return True

    def finalize(self, expected_blocks: ExpectedBlocks) -> dict[str, Any]:
        """Check every expected block is present and readable, write ``manifest.json``, return it.

        ``expected_blocks``: ``{sequence: number of blocks}`` or an iterable of ``(sequence, block_index)``.
        """
        return merge(self.root, expected_blocks)


def _changed_inputs(kept: dict, now: dict) -> list[str]:
    """The sequences whose input fingerprint (``source["inputs"]``, :func:`pipeline.preprocess.identity.
    input_fingerprint`) differs between the cache's header ``kept`` and this run's ``now``; a cache written before
    fingerprints existed, or a run without them, compares nothing."""
    a, b = kept.get("inputs") or {}, now.get("inputs") or {}
    return sorted(n for n in a.keys() & b.keys() if a[n] != b[n])


def _fsync_tree(path: Path) -> None:
    for dirpath, _, files in os.walk(path):
        for name in files:
            fd = os.open(os.path.join(dirpath, name), os.O_RDONLY)
            try:
                os.fsync(fd)
            finally:
                os.close(fd)
        fsync_dir(Path(dirpath))
