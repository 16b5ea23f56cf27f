"""benchmarks/vote_accuracy.py: the vote's static-point error per pair."""

from __future__ import annotations

import numpy as np

from benchmarks.vote_accuracy import main, vote_errors
from evaluation.sample import SceneFlowSample


def _pair(shift: np.ndarray, seed: int) -> SceneFlowSample:
    rng = np.random.default_rng(seed)
    pc1 = np.concatenate([rng.uniform([-8, -1, 5], [-6, 1, 35], (300, 3)),     # a wall along the street
                          rng.uniform([-6, -1, 29], [6, 1, 31], (300, 3)),      # a facade across it
                          rng.uniform([3, -1, 8], [4, 1, 9], (200, 3))]).astype(np.float32)  # a post
    moving = np.zeros(len(pc1), bool)
    moving[-50:] = True                                                        # a mover among them
    flow = np.where(moving[:, None], np.float32([0.0, 0.0, 2.0]), shift).astype(np.float32)
    return SceneFlowSample(name=f"{seed:06d}", pc1=pc1, pc2=(pc1 + flow)[rng.permutation(len(pc1))], flow=flow,
                           moving=moving)


def test_a_translated_scene_gives_a_small_error_and_a_wrong_shift_a_large_one():
    right = vote_errors([_pair(np.float32([0.1, 0.0, -1.2]), s) for s in range(2)], 512, 256, candidates=4)
    assert right.shape == (2,) and (right < 0.05).all()
    wrong = _pair(np.float32([0.1, 0.0, -1.2]), 0)
    wrong.flow[~wrong.moving] += np.float32([0.0, 0.0, 1.0])  # labels that disagree with the clouds by 1 m
    assert abs(vote_errors([wrong], 512, 256, candidates=4)[0] - 1.0) < 0.05


def test_a_missing_split_is_one_line(tmp_path, capsys):
    assert main(["--split", f"x={tmp_path / 'nothing'}"]) == 2
    out = capsys.readouterr().out.strip()
    assert out.startswith("vote_accuracy: ") and "nothing" in out and "\n" not in out


def test_the_rigid_vote_reads_a_turn_that_the_translation_leaves_as_error():
    """A 2° turn about y: the translation alone leaves θ·ρ (0.5–1 m at the facade 30 m ahead) in the static
    error, the rigid vote's flow ``R p + t − p`` (``rigid="free"``) a few centimetres."""
    a = np.radians(2.0)
    R = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]], np.float32)
    pair = _pair(np.float32([0.0, 0.0, -1.2]), 0)
    pair.flow[~pair.moving] = (pair.pc1[~pair.moving] @ R.T + np.float32([0.0, 0.0, -1.2]) - pair.pc1[~pair.moving])
    pair.pc2 = (pair.pc1 + pair.flow)[np.random.default_rng(1).permutation(len(pair.pc1))]
    translation = vote_errors([pair], 512, 256, candidates=4)[0]
    rigid = vote_errors([pair], 512, 256, candidates=4, rigid="free")[0]
    assert translation > 0.3 and rigid < 0.05, (translation, rigid)
