"""The camera's whole rigid motion between two clouds: the translation vote, then trimmed rigid matching.

The translation vote (:mod:`training.model.translation_vote`) finds the camera's translation without an
initial guess, but a translation only: a turn of θ moves a static point at range ρ by about θ·ρ, 0.4 m at
30 m for KITTI's mean 0.8° per frame and 1.4 m for its 95th percentile 2.6°, and the net downstream of
the vote never learned to read that rotation (docs/learned-flow.md, seventeenth round: its rotation error
equals the split's rotation at every level). This module starts where the vote ends and fits the rotation
too, by trimmed nearest-neighbour registration (point-to-point ICP with shrinking inlier radii):

0. with ``yaw_search_deg``, the turn first (:func:`turn_scan`): frame 1 turned about the camera's y axis by each
   candidate angle, the angle whose offset histogram has the fullest cell — the turn under which the most
   points agree on one translation — turns frame 1 before the vote (``Θ``; else ``Θ = I``);
1. ``T ← (Θ, t)`` for each of the vote's refined hypotheses ``t`` (its fullest histogram maxima); with
   ``forward_starts`` also ``T ← (Θ, (0, 0, t_z))`` for each: the camera moving along its optical axis (z), as a
   vehicle's forward camera does within one frame (sideways or up, at most a few centimetres). Between two
   sparse samples, in traffic crossing the view, the histogram's maxima can all lie 0.2–0.7 m to the side and
   0.3–0.6 m above or below the camera's translation, and the rounds from there settle in a turn paired with a sideways shift
   that fits the near scene and misses the far one (static error 0.2–0.55 m on a third of one test world's
   scenes); from the forward start they reach the camera's motion (docs/learned-flow.md, thirty-seventh
   round). Those starts are only added: the choice (step 4) still decides, so a cloud whose camera moves
   otherwise keeps the vote's own hypotheses;
2. for every radius of ``radii_m``, widest first, ``rounds`` times: every frame-1 point ``p`` takes the
   frame-2 point nearest to ``T p`` (of a denser ``target`` cloud of frame 2 where one is given); the pairs
   closer than the radius are inliers; ``T`` ← the rigid motion that maps the inliers' ``p`` onto their
   matches in least squares
   (:func:`~training.model.ego_motion.weighted_rigid_fit`, Kabsch; or a turn about y and a translation in
   x–z with ``planar``, :func:`~training.model.ego_motion.weighted_planar_fit`). With ``density_rounds_m``
   every start is also refined by rounds in which each inlier weighs one over the number of frame-1 points
   within that radius of it (:func:`density_weights`), beside the rounds in which each weighs one: the
   sampling is densest near the camera, so in a street walled by façades that run along the camera's path,
   cars driving ahead hold most of the pairs that fix the motion along it, and the rounds drift towards
   their motion (0.27 m of static error on a development world's crossing sequence, from the true motion as
   well); weighed by density, a part of the scene counts by the space it fills, not by how densely it was
   sampled (docs/learned-flow.md, thirty-eighth round). Both results go to the choice (step 4);
3. a hypothesis whose last round keeps fewer than ``min_inliers`` pairs keeps its translation alone;
4. the hypothesis whose motion explains the most frame-1 points (each has a frame-2 point within its own
   sampling spacing, the vote's own step 3) wins. The vote picks among translations, so under a turn,
   which spreads the static scene's votes by θ·ρ, a dense mover can win it; picking after the rigid
   rounds compares every hypothesis at its best. With ``range_weighted`` each explained point counts its
   distance from the camera instead of 1, so a dense mover near the camera does not outweigh the far
   static scene. With ``choose_gap_m`` the hypothesis that brings frame 1 nearest to frame 2's denser cloud
   wins instead: the mean distance from each moved frame-1 point to its nearest point of ``target`` (or of
   frame 2), truncated at ``choose_gap_m`` (weighted by range with ``range_weighted``). Within one sample
   spacing a big mover's motion and the camera's can both "explain" nearly every point (on the real stereo
   scene the van's motion, 0.67 m from the camera's, did on one scene of eight); the mean gap still tells
   them apart (docs/learned-flow.md, thirty-fifth round).

The trimmed rounds started at no turn reach a turn of about a degree: a turn of θ moves a point at range ρ by
θ·ρ, past the widest radius beyond 30 m at 2°, and the near points left shift the translation instead
(docs/learned-flow.md, thirty-second round: with 2° added to the demo world's test scenes the rigid fit's
static error went from 0.04 to 0.27 m, with 4° to 0.55 m; KITTI's 95th percentile is 2.6° per frame). Step
0 puts the rounds within half a step of the turn.

The vote puts the fit in the right basin (what plain ICP from the identity lacks on fast scenes), the
trimmed rounds drop the pairs a mover or an occlusion makes, as the vote's own refinement does. No
learning and no gradient; a fixed number of closed-form steps. Camera frames (x right, y down, z forward),
metres; ``(R, t)`` maps frame-1 points onto frame 2: ``q ≈ R p + t`` (eq. 11's static flow
``R p + t − p``). Serves :class:`~training.model.halflownet.HALFlowNet` (``model.rigid_vote``) and the
``rvote`` baseline of :mod:`evaluation.methods`.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from training.model.ego_motion import weighted_planar_fit, weighted_rigid_fit
from training.model.translation_vote import (VoteConfig, explained, gather_nearest, nearest, offset_histogram,
                                             per_hypothesis, vote_hypotheses)


@dataclass(frozen=True)
class RigidVoteConfig:
    """The rigid stage after the translation vote (distances in metres).

    vote: the translation vote that starts it.
    radii_m: inlier radii of the trimmed rigid rounds, widest first; the widest should cover what a
        turn moves a far point by (θ·ρ: 1 m is 2° at 30 m).
    rounds: matching rounds per radius.
    planar: fit a turn about the camera's y axis and a translation in x–z (a level camera on a ground
        vehicle) instead of a free rigid motion.
    min_inliers: a hypothesis with fewer inlier pairs in its last round keeps its translation alone.
    range_weighted: in step 4, each explained frame-1 point counts its distance from the camera (metres)
        instead of 1. A wrong motion shows most at range (a turn's error is θ·ρ), and in dense traffic the
        movers crowd the near field while the static scene holds the far one: on training caches with
        29–61 % static points the count alone picked a mover's motion (twenty-first round).
    yaw_search_deg: step 0 of the module docstring: the turn about the camera's y axis (degrees, either way)
        scanned before the vote, in steps of ``yaw_step_deg``; 0 = no scan, the rounds start at no turn.
    yaw_step_deg: the scan's first step, degrees; the step is then halved around the best turn while it is at
        least ``yaw_resolution_deg`` (2 → 1: nine histograms for ±6°, as close as a plain 1° grid's thirteen on
        the demo world's turned test scenes); the rounds take the rest.
    yaw_resolution_deg: the scan's finest step, degrees.
    choose_gap_m: step 4 by the mean nearest gap to frame 2's denser cloud, each gap truncated at this many
        metres (the hypothesis with the smallest wins); 0 = by the frame-1 points each explains.
    forward_starts: step 1 also starts every hypothesis with its translation's x and y set to zero (the camera
        moving along its optical axis), beside the hypothesis itself; the choice (step 4) picks among both.
    density_rounds_m: step 2 also refines every start with each frame-1 point weighed by one over the number of
        frame-1 points within this radius (metres) of it, beside the rounds that weigh each alike; the choice (step
        4) picks among both; 0 = the uniform rounds alone. 0.62 m is a sphere of the volume of a 1 m cube, the
        cube by which the rigid polish's camera-motion check weighs frame 1 (:mod:`evaluation.rigid_polish`).
    yaw_margin: a turn is taken only when its fullest cell holds more than ``1 + yaw_margin`` times the no-turn
        histogram's: at no turn a ±1° neighbour can fill it a few per cent more by chance (1.01–1.04 on a fresh
        default-configuration world, where the rounds from that 1° start then failed), a real turn of 1° fills it
        4–28 % more and one of 2° 37–64 % (thirty-second round).
    """

    vote: VoteConfig = VoteConfig()
    radii_m: tuple[float, ...] = (1.0, 0.5, 0.25, 0.1)
    rounds: int = 2
    planar: bool = False
    min_inliers: int = 16
    range_weighted: bool = False
    yaw_search_deg: float = 0.0
    yaw_step_deg: float = 2.0
    yaw_resolution_deg: float = 1.0
    yaw_margin: float = 0.05
    choose_gap_m: float = 0.0
    forward_starts: bool = False
    density_rounds_m: float = 0.0

    def __post_init__(self) -> None:
        if not (self.radii_m and all(r > 0 for r in self.radii_m) and self.rounds >= 1 and self.min_inliers >= 3):
            raise ValueError(f"need positive radii_m, rounds >= 1 and min_inliers >= 3, got {self}")
        if not (0 <= self.yaw_search_deg < 90 and self.yaw_step_deg > 0 and self.yaw_resolution_deg > 0
                and self.yaw_margin >= 0):
            raise ValueError("need 0 <= yaw_search_deg < 90, yaw_step_deg > 0, yaw_resolution_deg > 0 and "
                             f"yaw_margin >= 0, got {self}")
        if not (self.choose_gap_m >= 0 and self.density_rounds_m >= 0):
            raise ValueError(f"need choose_gap_m >= 0 and density_rounds_m >= 0, got {self.choose_gap_m}, "
                             f"{self.density_rounds_m}")

    @property
    def turns_deg(self) -> tuple[float, ...]:
        """The first pass's turns, degrees: 0 first, then ±1, ±2, … times ``yaw_step_deg`` up to ``yaw_search_deg``
        (in this order, so that a tie keeps the smaller turn)."""
        steps = int(self.yaw_search_deg / self.yaw_step_deg + 1e-9)
        return (0.0, *(s * k * self.yaw_step_deg for k in range(1, steps + 1) for s in (1, -1)))


def yaw_rotation(angle: Tensor) -> Tensor:
    """Rotations (..., 3, 3) by ``angle`` (...) radians about the camera's y axis (x right, y down, z forward)."""
    c, s = angle.cos(), angle.sin()
    one, zero = torch.ones_like(c), torch.zeros_like(c)
    return torch.stack([torch.stack([c, zero, s], -1), torch.stack([zero, one, zero], -1),
                        torch.stack([-s, zero, c], -1)], -2)


def turned(xyz: Tensor, R: Tensor, origin: Tensor) -> Tensor:
    """``xyz`` (B, M, 3) turned by ``R`` (B, 3, 3) about ``origin`` (B, 3): ``R (p − o) + o``, in ``xyz``'s dtype."""
    o = origin.to(R.dtype)[:, None]
    return ((xyz.to(R.dtype) - o) @ R.transpose(1, 2) + o).to(xyz.dtype)


def _fullest(xyz1: Tensor, xyz2: Tensor, cfg: RigidVoteConfig, origin: Tensor, angle: Tensor) -> Tensor:
    """(B,) the fullest cell of the offset histogram between ``xyz1`` turned by ``angle`` (B,) radians about
    ``origin`` (B, 3) and ``xyz2``."""
    R = yaw_rotation(angle)
    grid, _ = offset_histogram(turned(xyz1, R, origin), xyz2, cfg.vote)
    return grid.reshape(xyz1.shape[0], -1).amax(dim=1)


@torch.no_grad()
def turn_scan(xyz1: Tensor, xyz2: Tensor, cfg: RigidVoteConfig, origin: Tensor) -> Tensor:
    """Step 0 of the module docstring: the turn (B,) in radians about the camera at ``origin`` (B, 3) under which
    frame 1 ``xyz1`` (B, M, 3) and frame 2 ``xyz2`` (B, N, 3) have the fullest cell of their offset histogram
    (:func:`~training.model.translation_vote.offset_histogram`): of ``cfg.turns_deg`` first (equals keep the
    smaller turn), then halving the step around the best while it is at least ``yaw_resolution_deg``; no turn
    unless the best fills its fullest cell more than ``1 + yaw_margin`` times the unturned one. Metres."""
    B = xyz1.shape[0]
    angles = torch.tensor(cfg.turns_deg, dtype=torch.float64, device=xyz1.device).deg2rad()
    full = torch.stack([_fullest(xyz1, xyz2, cfg, origin, a.expand(B)) for a in angles], dim=1)
    best = angles[full.argmax(dim=1)]
    top = full.amax(dim=1)
    step = cfg.yaw_step_deg / 2
    while step >= cfg.yaw_resolution_deg - 1e-9:
        for sign in (1.0, -1.0):
            a = best + sign * torch.tensor(step, dtype=torch.float64).deg2rad()
            f = _fullest(xyz1, xyz2, cfg, origin, a)
            better = f > top
            best, top = torch.where(better, a, best), torch.where(better, f, top)
        step /= 2
    return torch.where(top > (1 + cfg.yaw_margin) * full[:, 0], best, torch.zeros_like(best))


def density_weights(xyz: Tensor, radius: float) -> Tensor:
    """(B, N): each point of ``xyz`` (B, N, 3) weighed by one over the number of points of its own cloud within
    ``radius`` metres of it, itself included, so that every part of a cloud counts by the space it fills rather
    than by how densely it was sampled (step 2's ``density_rounds_m``). Computed one cloud at a time."""
    out = []
    for x in xyz.float():
        within = (torch.cdist(x, x) < radius).sum(1)
        out.append(1.0 / within.to(xyz.dtype))
    return torch.stack(out)


def trimmed_rounds(a: Tensor, b: Tensor, R: Tensor, t: Tensor, cfg: RigidVoteConfig,
                   weights: Tensor | None = None) -> tuple[Tensor, Tensor, Tensor]:
    """Step 2 of the module docstring for H starting motions at once: ``a`` (H, M, 3) onto ``b`` (H, P, 3), or
    (B, P, 3) with every cloud's hypotheses in a row (:func:`~training.model.translation_vote.nearest`), started
    at ``R`` (H, 3, 3), ``t`` (H, 3), metres; ``weights`` (H, M), optional: what each inlier pair weighs in the
    fits (default 1). Returns the fitted ``(R, t)`` and (H,) the inlier count of the last round (a round with
    fewer than ``min_inliers`` inliers is not taken)."""
    fit = weighted_planar_fit if cfg.planar else weighted_rigid_fit
    count = torch.zeros(a.shape[0], dtype=a.dtype, device=a.device)
    for radius in cfg.radii_m:
        for _ in range(cfg.rounds):
            d2, nn = nearest(a @ R.transpose(1, 2) + t[:, None], b)  # KD-tree on CPU, dense on CUDA
            inlier = (d2 < radius * radius).to(a.dtype)
            count = inlier.sum(1)
            q = gather_nearest(b, nn)
            R_new, t_new = fit(a, q, inlier if weights is None else inlier * weights)
            ok = count >= cfg.min_inliers
            R = torch.where(ok[:, None, None], R_new, R)
            t = torch.where(ok[:, None], t_new, t)
    return R, t, count


def mean_gap(moved: Tensor, b: Tensor, truncate_m: float, weights: Tensor | None = None) -> Tensor:
    """(H,) the mean distance from each point of ``moved`` (H, M, 3) to its nearest point of ``b`` (H, P, 3), or
    (B, P, 3) with every cloud's hypotheses in a row (:func:`~training.model.translation_vote.nearest`), each
    distance truncated at ``truncate_m`` metres; weighted by ``weights`` (H, M) when given."""
    d2, _ = nearest(moved, b)
    gap = d2.clamp(min=0).sqrt().clamp(max=truncate_m)
    if weights is None:
        return gap.mean(1)
    return (gap * weights).sum(1) / weights.sum(1).clamp(min=1e-12)


@torch.no_grad()
def vote_rigid(xyz1: Tensor, xyz2: Tensor, config: RigidVoteConfig | None = None,
               target: Tensor | None = None, origin: Tensor | None = None) -> tuple[Tensor, Tensor]:
    """The rotation R (B, 3, 3) and translation t (B, 3) taking ``xyz1`` (B, N, 3) onto ``xyz2`` (B, M, 3),
    metres, one common camera frame (module docstring). No gradient.

    ``target`` (B, P, 3), optional: a denser sample of the same frame-2 cloud (the net's input) that the
    rigid rounds match against, instead of ``xyz2``; the vote and the choice among its hypotheses still
    run between ``xyz1`` and ``xyz2``. ``origin`` (B, 3): the camera's position in the clouds' frame, for
    ``range_weighted`` and the pivot of step 0's turn (default: the frame's origin; the net passes minus the
    centre it subtracted)."""
    cfg = config or RigidVoteConfig()
    B = xyz1.shape[0]
    o = (xyz1.new_zeros(B, 3) if origin is None else origin).detach().double()
    turn = torch.eye(3, dtype=torch.float64, device=xyz1.device).expand(B, 3, 3)
    start1 = xyz1
    if cfg.yaw_search_deg > 0:  # step 0: frame 1 turned about the camera first, the vote finds the rest
        angle = turn_scan(xyz1.detach(), xyz2.detach(), cfg, o)
        turn = torch.where((angle != 0)[:, None, None], yaw_rotation(angle), turn)
        start1 = torch.where((angle != 0)[:, None, None], turned(xyz1.detach(), turn, o), xyz1)
    h = vote_hypotheses(start1, xyz2, cfg.vote)
    voted = h.t
    if cfg.forward_starts:  # step 1's forward starts: each translation along the optical axis alone, beside it
        voted = torch.cat([voted, voted * voted.new_tensor([0.0, 0.0, 1.0])], dim=1)
    x1 = xyz1.detach().double()
    fit_weights = None
    if cfg.density_rounds_m > 0:  # step 2's rounds weighed by density: every start twice, once each way
        starts = voted.shape[1]
        voted = torch.cat([voted, voted], dim=1)
        dense = density_weights(x1, cfg.density_rounds_m)  # (B, M)
        fit_weights = torch.cat([torch.ones_like(dense)[:, None].expand(-1, starts, -1),
                                 dense[:, None].expand(-1, starts, -1)], dim=1).reshape(B * 2 * starts, -1)
    K = voted.shape[1]
    # every hypothesis with its own copy of frame 1, (B·K, M, 3), searching its cloud's frame 2, in float64;
    # its start (Θ, t' + o − Θ o): the turn about the camera, then the vote's translation of the turned cloud
    a = per_hypothesis(x1, K)
    b = (xyz2 if target is None else target).detach().double()
    R0 = per_hypothesis(turn, K)
    t0 = (voted.double() + (o - (o[:, None] @ turn.transpose(1, 2))[:, 0])[:, None]).reshape(B * K, 3)
    R, t, count = trimmed_rounds(a, b, R0.clone(), t0.clone(), cfg, fit_weights)
    keep = count >= cfg.min_inliers  # else the hypothesis's start alone
    R = torch.where(keep[:, None, None], R, R0)
    t = torch.where(keep[:, None], t, t0)
    # step 3 of the vote with the whole motion: the hypothesis that explains the most frame-1 points (each
    # weighted by its range with range_weighted), against the vote's own frame-2 samples, whose spacing the
    # frame-1 spacing matches
    moved = a @ R.transpose(1, 2) + t[:, None]
    weights = None
    if cfg.range_weighted:
        rng = (x1 - o[:, None]).norm(dim=-1)  # (B, M) metres from the camera
        weights = per_hypothesis(rng, K)
    if cfg.choose_gap_m > 0:  # or the one that brings frame 1 nearest to frame 2's denser cloud
        score = -mean_gap(moved, b, cfg.choose_gap_m, weights).reshape(B, K)
    else:
        samples = b if target is None else xyz2.detach().double()
        score = explained(moved, samples, per_hypothesis(h.spacing.double(), K), weights).reshape(B, K)
    pick = score.argmax(dim=1)
    R, t = R.reshape(B, K, 3, 3)[torch.arange(B), pick], t.reshape(B, K, 3)[torch.arange(B), pick]
    R = torch.where(h.found[:, None, None], R, torch.eye(3, dtype=R.dtype, device=R.device))
    t = torch.where(h.found[:, None], t, torch.zeros_like(t))
    return R.to(xyz1.dtype), t.to(xyz1.dtype)
