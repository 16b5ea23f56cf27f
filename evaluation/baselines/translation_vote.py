"""The translation vote as a registration baseline: every pc1 point takes the one camera translation
that a vote over all point-pair offsets finds (:mod:`training.model.translation_vote`, the same code
that pre-aligns the net under ``model.translation_vote``). A translation-only registration with no
initial guess: it shows what the vote alone is worth, beside ICP (local) and FGR (features)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from evaluation.baselines.base import as_cloud
from training.model.translation_vote import VoteConfig


@dataclass
class TranslationVoteBaseline:
    """``flow = t`` for every pc1 point, ``t`` the voted translation (metres, camera frame)."""

    config: VoteConfig = field(default_factory=VoteConfig)
    name: str = "tvote"

    def __call__(self, pc1: np.ndarray, pc2: np.ndarray) -> np.ndarray:
        import torch

        from training.model.translation_vote import vote_translation

        p1, p2 = as_cloud("pc1", pc1), as_cloud("pc2", pc2)
        t = vote_translation(torch.from_numpy(p1[None]).float(), torch.from_numpy(p2[None]).float(), self.config)
        return np.broadcast_to(t[0].numpy().astype(np.float32), p1.shape).copy()
