"""The rigid vote as a registration baseline: every pc1 point takes the rigid flow ``R p + t − p`` of the
camera motion that the translation vote followed by trimmed rigid matching finds
(:mod:`training.model.rigid_vote`, the same code that pre-aligns the net under ``model.rigid_vote``),
fitted between the two clouds' farthest-point samples of ``sample_points`` points as the net fits it
between its L0 points. No initial guess (the vote supplies it), no learning: what the net's pre-alignment
alone is worth, beside ``tvote`` (the translation alone), ICP (from the identity) and FGR (features)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from evaluation.baselines.translation_vote import sampled_clouds
from training.model.rigid_vote import RigidVoteConfig


@dataclass
class RigidVoteBaseline:
    """``flow = R p + t − p`` for every pc1 point (metres, camera frame of frame 1).

    sample_points: the fit runs on this many farthest-point samples of each cloud (all points when a cloud
        has fewer; 0 = every point); 512 = the demo net's L0 at 2048 input points.
    dense_target: the rigid rounds match pc1's samples against the whole pc2 given, not only its samples,
        as the demo preset's net does (``model.rigid_vote_dense``; twenty-first round); false = the
        samples alone (the eighteenth to twentieth rounds' ``rvote``). The default config weighs the choice
        among the vote's hypotheses by range and scans the camera's turn within ±6° first, as the preset's net
        does (``model.rigid_vote_far``, ``model.rigid_vote_yaw_deg``; before the thirty-second round the
        ``rvote`` rows started the rounds at no turn)."""

    config: RigidVoteConfig = field(default_factory=lambda: RigidVoteConfig(range_weighted=True, yaw_search_deg=6.0))
    name: str = "rvote"
    sample_points: int = 512
    dense_target: bool = True

    def __call__(self, pc1: np.ndarray, pc2: np.ndarray) -> np.ndarray:
        import torch

        from training.model.rigid_vote import vote_rigid

        p1, a, b = sampled_clouds(pc1, pc2, self.sample_points)
        target = torch.tensor(np.asarray(pc2, dtype=np.float32))[None] if self.dense_target else None  # a copy
        R, t = vote_rigid(a, b, self.config, target)
        flow = p1 @ R[0].double().numpy().T + t[0].double().numpy() - p1  # p1: float64 (N, 3)
        return flow.astype(np.float32)
