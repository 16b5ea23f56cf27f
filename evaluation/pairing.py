"""What a split's frame 2 holds, for the label-free wrappers of a net (``monoflow-evaluate --pairing auto``).

Two kinds of split ask for different view pruning, rigid polish and refinement
(``monoflow-evaluate run``'s stack; :meth:`evaluation.rigid_polish.RigidPolishConfig.for_pairing`,
:meth:`evaluation.optimise.RefineConfig.for_start`):

* ``"surface"``: frame 2 is another sampling of the same surfaces — a LiDAR re-scan, a cloud from frame 2's
  own depth map. A point's nearest frame-2 sample is not its counterpart.
* ``"points"``: frame 2 is frame 1's own points moved, written from correspondences (HPLFlowNet's stereoKITTI
  and FlyingThings3D; FlowNet3D's ``kitti_rm_ground`` too, by the rows of its files quoted in that repository's
  issue 21). Where the protocol's independent sampling keeps most counterparts in frame 2's sample, the nearest
  frame-2 point often *is* the counterpart.

The protocol draws each frame's sample independently, so a frame-1 point keeps its counterpart in frame 2's sample
with probability about ``n_points / N₂`` (the real stereo scene's 9 700-point scenes at HPLFlowNet's 8192: 84 %; 2048
of image-grid clouds of 7 000–37 000 points: 6–18 %). Where it did, a right flow lands the point *on* a frame-2 point;
the polish's step 7 and the refinement's confirmation read those landings (:mod:`evaluation.landing`, forty-fifth
round), which hold however few counterparts are kept.

A format may say so by construction (:attr:`evaluation.readers.base.SceneFlowFormat.frame2_holds_frame1`: the
``hplflownet`` layout stores no flow, its flow is ``pc2 − pc1``). Otherwise the file says how it was written:
in a split built from correspondences the stored flow carries frame 1's points exactly onto frame 2's points
(share 1.0 on the stereo scene written by ``benchmarks/real_stereo.py``), while a re-scan has a point within a
millimetre of a moved point only by chance (0.00–0.3 % on the synthetic worlds' LiDAR splits and the real
re-scanned KITTI scan). This reads the split's labels once, for one answer per split about how the file was
made; no method sees them, and ``--pairing surface|points`` states the answer without reading them.
Points in metres, camera frame (x right, y down, z forward).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from evaluation.sample import SceneFlowSample

PAIRINGS = ("surface", "points")  #: what frame 2 holds, in the words of ``--pairing``
EXACT_M = 1e-3  #: a moved point "lands on" a frame-2 point within this distance (m; float32 keeps 1e-5 at 100 m)
MIN_SHARE = 0.1  #: median share of landed points from which a split counts as written from correspondences
CHECKED_SCENES = 8  #: scenes read for the check, spread evenly over the split


def landed_share(sample: SceneFlowSample) -> float:
    """Share of frame 1's points that the stored flow carries to within :data:`EXACT_M` of a frame-2 point
    (:func:`evaluation.landing.landed`)."""
    from evaluation.landing import landed

    if sample.n1 == 0:
        return 0.0
    return float(landed(sample.pc1 + sample.flow, sample.pc2, EXACT_M).mean())


@dataclass(frozen=True)
class PairingChoice:
    """The pairing ``auto`` chose and why, in words (printed as a note)."""

    pairing: str
    reason: str


def choose_pairing(scenes: Sequence[SceneFlowSample], fmt: str, by_format: bool) -> PairingChoice:
    """``"points"`` when the format stores frame 2 as frame 1's points (``by_format``), or when the median
    :func:`landed_share` over up to :data:`CHECKED_SCENES` scenes spread over ``scenes`` reaches :data:`MIN_SHARE`; else ``"surface"``."""
    if by_format:
        return PairingChoice("points", f"the {fmt} layout stores frame 2 as frame 1's points moved")
    n = len(scenes)
    picks = sorted({int(i) for i in np.linspace(0, n - 1, min(n, CHECKED_SCENES))}) if n else []
    shares = [landed_share(scenes[i]) for i in picks]
    share = float(np.median(shares)) if shares else 0.0
    where = f"{share:.0%} of frame 1's points land within {EXACT_M * 1000:g} mm of a frame-2 point under the stored flow"
    if share >= MIN_SHARE:
        return PairingChoice("points", f"{where} (median of {len(picks)} scenes): the split was written from "
                                       "correspondences")
    return PairingChoice("surface", f"{where} (median of {len(picks)} scenes): frame 2 is another sampling")
