"""The rigid vote as a registration baseline: every pc1 point takes the rigid flow ``R p + t − p`` of the
camera motion that the translation vote followed by trimmed rigid matching finds
(:mod:`training.model.rigid_vote`, the same code that pre-aligns the net under ``model.rigid_vote``),
fitted between the two clouds' farthest-point samples of ``sample_points`` points as the net fits it
between its L0 points. No initial guess (the vote supplies it), no learning: what the net's pre-alignment
alone is worth, beside ``tvote`` (the translation alone), ICP (from the identity) and FGR (features)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from evaluation.baselines.base import as_cloud
from training.model.rigid_vote import RigidVoteConfig


@dataclass
class RigidVoteBaseline:
    """``flow = R p + t − p`` for every pc1 point (metres, camera frame of frame 1).

    sample_points: the fit runs on this many farthest-point samples of each cloud (all points when a cloud
        has fewer; 0 = every point); 512 = the demo net's L0 at 2048 input points."""

    config: RigidVoteConfig = field(default_factory=RigidVoteConfig)
    name: str = "rvote"
    sample_points: int = 512

    def __call__(self, pc1: np.ndarray, pc2: np.ndarray) -> np.ndarray:
        import torch

        from training.model.rigid_vote import vote_rigid
        from training.model.translation_vote import farthest_samples

        p1, p2 = as_cloud("pc1", pc1), as_cloud("pc2", pc2)
        a, b = (torch.from_numpy(np.ascontiguousarray(p)[None]).float() for p in (p1, p2))
        R, t = vote_rigid(farthest_samples(a, self.sample_points), farthest_samples(b, self.sample_points), self.config)
        pts = a[0].double()
        flow = pts @ R[0].double().T + t[0].double() - pts
        return flow.numpy().astype(np.float32)
