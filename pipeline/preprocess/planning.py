"""Block planning: every sequence's consecutive pairs (t, t+1) cut into blocks of ``block_size`` pairs.

A block is stage one's unit of work and of storage; its global index (over all sequences, sorted) decides
which shard takes it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class BlockPlan:
    """One block: sequence, its index there, its global index over all sequences, its pairs as positions."""

    sequence: str
    index: int
    global_index: int
    pairs: tuple[tuple[int, int], ...]


def sequence_pairs(frames: list[int]) -> list[tuple[int, int]]:
    """Positions (k, k+1) whose frame ids are consecutive (a gap in the numbering makes no pair)."""
    return [(k, k + 1) for k in range(len(frames) - 1) if frames[k + 1] == frames[k] + 1]


def plan_blocks(sequence_frames: dict[str, list[int]], block_size: int) -> list[BlockPlan]:
    """Split every sequence's pairs into blocks of ``block_size`` consecutive pairs (sequences sorted)."""
    plans: list[BlockPlan] = []
    for seq in sorted(sequence_frames):
        pairs = sequence_pairs(sequence_frames[seq])
        for b in range(math.ceil(len(pairs) / block_size)):
            chunk = tuple(pairs[b * block_size : (b + 1) * block_size])
            plans.append(BlockPlan(seq, b, len(plans), chunk))
    return plans


def shard_plans(plans: list[BlockPlan], shard: tuple[int, int]) -> list[BlockPlan]:
    """The blocks of shard ``(i, n)``: those whose global index b has ``b % n == i``."""
    shard_i, shard_n = shard
    return [p for p in plans if p.global_index % shard_n == shard_i]


__all__ = ["BlockPlan", "plan_blocks", "sequence_pairs", "shard_plans"]
