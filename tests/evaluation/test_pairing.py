"""What a split's frame 2 holds (evaluation.pairing): a re-scan of the same surfaces, or frame 1's points moved."""

from __future__ import annotations

import numpy as np

from evaluation.pairing import CHECKED_SCENES, MIN_SHARE, choose_pairing, landed_share
from evaluation.sample import SceneFlowSample


def _surfaces(rng: np.random.Generator, n: int) -> np.ndarray:
    """``n`` points on a floor-less street: two walls (x = ±4 m) and a box, 5–30 m ahead (camera frame, m)."""
    side = rng.choice([-4.0, 4.0], n)
    y, z = rng.uniform(-2.0, 1.0, n), rng.uniform(5.0, 30.0, n)
    pts = np.stack([side + rng.normal(0, 0.01, n), y, z], 1)
    box = rng.random(n) < 0.2
    pts[box] = np.stack([rng.uniform(-1, 1, box.sum()), rng.uniform(-1.5, 0.0, box.sum()), np.full(box.sum(), 12.0)], 1)
    return pts.astype(np.float32)


def _pair(seed: int, rescan: bool, keep: float = 1.0) -> SceneFlowSample:
    """A camera 1 m forward over the scene, the box 0.8 m towards it. ``rescan``: frame 2 samples the same moved
    surfaces afresh (a LiDAR re-scan); else frame 2 is frame 1's points moved, shuffled, a share ``keep`` of them."""
    rng = np.random.default_rng(seed)
    pc1 = _surfaces(rng, 3000)
    flow = np.tile(np.float32([0.0, 0.0, -1.0]), (len(pc1), 1))
    flow[np.abs(pc1[:, 2] - 12.0) < 1e-6, 2] -= 0.8
    if rescan:
        pc2 = _surfaces(rng, 2800)
        pc2[:, 2] -= 1.0
        pc2[np.abs(pc2[:, 2] - 11.0) < 1e-6, 2] -= 0.8
    else:
        moved = (pc1 + flow)[rng.permutation(len(pc1))]
        pc2 = moved[: int(keep * len(moved))]
    return SceneFlowSample("s", pc1, pc2, flow)


def test_a_moved_copy_lands_on_frame_two_and_a_rescan_does_not() -> None:
    assert landed_share(_pair(0, rescan=False)) == 1.0
    assert abs(landed_share(_pair(0, rescan=False, keep=0.3)) - 0.3) < 0.05  # the kept rows, wherever they went
    assert landed_share(_pair(0, rescan=True)) < 0.01


def test_auto_pairing_follows_the_format_then_the_files() -> None:
    moved = [_pair(s, rescan=False, keep=0.5) for s in range(3)]
    rescans = [_pair(s, rescan=True) for s in range(3)]
    assert choose_pairing(rescans, "flownet3d", by_format=True).pairing == "points"  # the format's own word
    chosen = choose_pairing(moved, "flownet3d", by_format=False)
    assert chosen.pairing == "points" and "50%" in chosen.reason and "correspondences" in chosen.reason
    assert choose_pairing(rescans, "flownet3d", by_format=False).pairing == "surface"
    assert choose_pairing([], "flownet3d", by_format=False).pairing == "surface"
    # a median: one stray scene of the other kind does not decide it
    assert choose_pairing([*rescans, moved[0]], "flownet3d", by_format=False).pairing == "surface"
    assert choose_pairing([*moved, rescans[0]], "flownet3d", by_format=False).pairing == "points"
    assert MIN_SHARE < 0.3  # a split that keeps 30 % of the moved points (test above) still counts as moved


class _Counting(list):
    """A list that records which scenes were read."""

    def __init__(self, items) -> None:
        super().__init__(items)
        self.read: list[int] = []

    def __getitem__(self, i):
        self.read.append(i)
        return super().__getitem__(i)


def test_auto_pairing_reads_a_few_scenes_spread_over_the_split() -> None:
    scenes = _Counting([_pair(0, rescan=True)] * 50)
    choose_pairing(scenes, "flownet3d", by_format=False)
    assert len(scenes.read) == CHECKED_SCENES and scenes.read[0] == 0 and scenes.read[-1] == 49
