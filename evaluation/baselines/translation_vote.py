"""The translation vote as a registration baseline: every pc1 point takes the one camera translation
that a vote over all point-pair offsets finds (:mod:`training.model.translation_vote`, the same code
that pre-aligns the net under ``model.translation_vote``), voted between the two clouds' farthest-point
samples of ``sample_points`` points as the net votes between its L0 points. A translation-only
registration with no initial guess: it shows what the vote alone is worth, beside ICP (local) and FGR
(features).

Why a sample (:func:`~training.model.translation_vote.farthest_samples`): on the raw points the dense
near field of a LiDAR cloud outvotes the scene. On the tenth round's own splits the raw-point vote's static
error was 0.19–0.27 m, the sampled vote's 0.02–0.08 m per scene (docs/learned-flow.md, eleventh round)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from evaluation.baselines.base import as_cloud
from training.model.translation_vote import VoteConfig

if TYPE_CHECKING:
    from torch import Tensor


@dataclass
class TranslationVoteBaseline:
    """``flow = t`` for every pc1 point, ``t`` the voted translation (metres, camera frame).

    sample_points: the vote runs on this many farthest-point samples of each cloud (all points when a
        cloud has fewer; 0 = every point); 512 = the demo net's L0 at 2048 input points."""

    config: VoteConfig = field(default_factory=VoteConfig)
    name: str = "tvote"
    sample_points: int = 512

    def __call__(self, pc1: np.ndarray, pc2: np.ndarray) -> np.ndarray:
        from training.model.translation_vote import vote_translation

        p1, a, b = sampled_clouds(pc1, pc2, self.sample_points)
        t = vote_translation(a, b, self.config)
        return np.broadcast_to(t[0].numpy().astype(np.float32), p1.shape).copy()


def sampled_clouds(pc1: np.ndarray, pc2: np.ndarray, sample_points: int) -> tuple[np.ndarray, "Tensor", "Tensor"]:
    """What the vote baselines fit on: ``pc1`` checked as an (N, 3) array, and both clouds' farthest-point
    samples of ``sample_points`` points as (1, n, 3) float32 tensors
    (:func:`~training.model.translation_vote.farthest_samples`; the whole cloud when it has fewer, or 0)."""
    import torch

    from training.model.translation_vote import farthest_samples

    p1, p2 = as_cloud("pc1", pc1), as_cloud("pc2", pc2)
    a, b = (torch.from_numpy(np.ascontiguousarray(p)[None]).float() for p in (p1, p2))
    return p1, farthest_samples(a, sample_points), farthest_samples(b, sample_points)
