"""The camera's translation between two clouds by voting over all point-pair offsets (no learning).

Most points of a driving scene are static, so frame 2's cloud is frame 1's moved by one rigid motion
``p ↦ R p + t``; over one frame (0.1 s) the rotation is a few degrees at most and the translation is
what dominates the static flow. For a pure translation, every static frame-1 point ``p_i`` has a
frame-2 point near ``p_i + t``, so among all offsets ``d_ij = q_j − p_i`` (metres, one common camera
frame: x right, y down, z forward) the offsets near ``t`` are much denser than anywhere else. Their
density is the kernel correlation of the two clouds as a function of the shift (Tsin & Kanade's
kernel-correlation registration), computed here for all shifts at once:

1. vote: a histogram of the offsets inside the search cube ``|d|_∞ ≤ max_translation_m`` with cells of
   ``cell_m``, smoothed by a 3×3×3 binomial kernel; its ``candidates`` fullest local maxima are the
   hypotheses (no initial guess, unlike ICP);
2. refine each hypothesis by translation-only trimmed matching with shrinking radii ``bandwidths_m``:
   every frame-1 point takes its nearest frame-2 point after the shift, those within the radius are
   inliers, and ``t ← mean(q_nn(i) − p_i)`` over the inliers;
3. keep the hypothesis under which the most frame-1 points find a frame-2 point within their own
   sampling spacing (the distance to their nearest frame-1 neighbour, at least the last radius).

Step 3 is there because the histogram counts *pairs*: a dense mover close to the camera (a car driving
ahead at about the camera's speed, near zero offset) can outvote the static scene, which covers more
of the view but is sampled more sparsely. Counting each frame-1 point once, with a radius that grows
with its sampling spacing, lets the static majority win where it is a majority (measured on training
caches, not test splits: docs/learned-flow.md, tenth round). In dense traffic, where the movers are
the majority, the vote returns their motion, and the net's residual has to correct it.
A rotation spreads the static votes (by the rotation angle times the distance), which the wide first
radius absorbs. The result has no gradient: it serves :class:`~training.model.halflownet.HALFlowNet`
(``model.translation_vote``) as a pre-alignment whose response to a change of speed is one by
construction, and the ``tvote`` baseline of :mod:`evaluation.methods` as a rigid-translation
registration.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import torch
from torch import Tensor


@dataclass(frozen=True)
class VoteConfig:
    """The translation vote's search, in metres.

    max_translation_m: half the side of the search cube around zero offset (twice KITTI's largest
        motion per frame at 10 Hz, about 2.5 m, would be 5; 3 covers 100 km/h).
    cell_m: the histogram's cell size.
    bandwidths_m: inlier radii of the refinement, widest first, two rounds each; the last one is also
        the smallest matching radius when the hypotheses are scored.
    candidates: how many histogram maxima are refined and scored (1 = the fullest cell alone).
    """

    max_translation_m: float = 3.0
    cell_m: float = 0.25
    bandwidths_m: tuple[float, ...] = (0.5, 0.25, 0.1)
    candidates: int = 4

    def __post_init__(self) -> None:
        if not (self.max_translation_m > 0 and self.cell_m > 0 and self.bandwidths_m
                and all(h > 0 for h in self.bandwidths_m) and self.candidates >= 1):
            raise ValueError(f"need a positive max_translation_m, cell_m, bandwidths_m and candidates, got {self}")


def _binomial_blur(grid: Tensor) -> Tensor:
    """(B, X, Y, Z) counts smoothed by the separable [1, 2, 1] / 4 kernel along every axis."""
    k = torch.tensor([0.25, 0.5, 0.25], dtype=grid.dtype, device=grid.device)
    kernel = (k[:, None, None] * k[None, :, None] * k[None, None, :])[None, None]
    return torch.nn.functional.conv3d(grid[:, None], kernel, padding=1)[:, 0]


def nearest(moved: Tensor, b: Tensor) -> tuple[Tensor, Tensor]:
    """Each point of ``moved`` (H, M, 3)'s nearest point of ``b``: (squared distance (H, M), index (H, M)).
    ``b`` is (H, N, 3), one cloud per row, or (B, N, 3) with H a multiple of B: rows ``h·B/H … `` of ``moved``
    (every cloud's hypotheses in a row, as :func:`per_hypothesis` lays them out) all search cloud ``h // (H/B)``,
    so each cloud is indexed once (one KD-tree per cloud on the CPU, :func:`training.knn.knn`)."""
    from training.knn import knn

    H, M = moved.shape[:2]
    B = b.shape[0]
    if H % B:
        raise ValueError(f"{H} hypotheses do not group over {B} clouds")
    d2, idx = knn(moved.reshape(B, (H // B) * M, 3), b, 1)
    return d2.reshape(H, M), idx.reshape(H, M)


def gather_nearest(b: Tensor, idx: Tensor) -> Tensor:
    """The points (H, M, 3) of ``b`` (H or B, N, 3; see :func:`nearest`) at ``idx`` (H, M)."""
    H, M = idx.shape
    B = b.shape[0]
    flat = idx.reshape(B, (H // B) * M)
    return torch.gather(b, 1, flat[..., None].expand(-1, -1, 3)).reshape(H, M, 3)


def _refine(a: Tensor, b: Tensor, t: Tensor, radii: tuple[float, ...]) -> Tensor:
    """Translations ``t`` (H, 3) of ``a`` (H, M, 3) onto ``b`` (H or B, N, 3, :func:`nearest`), one per
    hypothesis, refined by trimmed nearest-neighbour matching: two rounds per radius, widest first, each
    ``t ← mean(q_nn(i) − p_i)`` over the points whose nearest neighbour lies within the radius."""
    for h in radii:
        for _ in range(2):
            d2, nn = nearest(a + t[:, None], b)
            inlier = (d2 < h * h).to(a.dtype)
            count = inlier.sum(1)
            q = gather_nearest(b, nn)
            mean = ((q - a) * inlier[..., None]).sum(1) / count.clamp_min(1)[:, None]
            t = torch.where(count[:, None] > 0, mean, t)
    return t


def per_hypothesis(x: Tensor, k: int) -> Tensor:
    """``x`` (B, …) repeated for each of ``k`` hypotheses: (B·k, …), every cloud's copies in a row."""
    B = x.shape[0]
    return x[:, None].expand(B, k, *x.shape[1:]).reshape(B * k, *x.shape[1:])


def explained(moved: Tensor, b: Tensor, spacing: Tensor, weights: Tensor | None = None) -> Tensor:
    """How many of the moved frame-1 points ``moved`` (H, M, 3) have a point of ``b`` (H or B, N, 3,
    :func:`nearest`) within their own ``spacing`` (H, M): a sparse far point counts as readily as a dense near
    one, so the count measures how much of the scene a motion explains (step 3 of the module docstring).
    ``weights`` (H, M): what each such point counts (default 1)."""
    hit = (nearest(moved, b)[0] < spacing * spacing).to(moved.dtype)
    return (hit if weights is None else hit * weights).sum(1)


def spacing_of(x: Tensor) -> Tensor:
    """Each point's distance (B, M) to the nearest *other* point of its cloud ``x`` (B, M, 3), metres (0 for a
    point with a duplicate)."""
    from training.knn import knn

    if x.shape[1] < 2:
        return x.new_full(x.shape[:2], float("inf"))
    return knn(x, x, 2)[0][..., 1].sqrt()


class VoteHypotheses(NamedTuple):
    """What the vote weighs before it picks (:func:`vote_hypotheses`).

    t (B, K, 3): the refined translations of the K fullest histogram maxima, metres. explained (B, K): how
    many frame-1 points each explains. spacing (B, M): each frame-1 point's sampling spacing (distance to
    its nearest frame-1 neighbour, at least the last radius). found (B,): whether any offset fell inside
    the search cube."""

    t: Tensor
    explained: Tensor
    spacing: Tensor
    found: Tensor


def _pair_offsets(x1: Tensor, x2: Tensor, R: float) -> tuple[Tensor, Tensor, Tensor]:
    """The offsets ``q_j − p_i`` (P, 3) between ``x1`` (B, M, 3) and ``x2`` (B, N, 3) that can lie in the cube
    ``|d|_∞ ≤ R``, with their cloud ``b`` (P,) and frame-1 index ``i`` (P,). On the CPU only the pairs within
    ``R·√3`` (the cube's corner, plus a millimetre) of each other, from a KD-tree range search per cloud: at
    the net's 512 points 14–15 % of all pairs on the demo's test scenes, the same offsets in the cube; elsewhere
    every pair."""
    B, M, N = x1.shape[0], x1.shape[1], x2.shape[1]
    if x1.device.type != "cpu":
        which = torch.arange(B, device=x1.device).repeat_interleave(M * N)
        first = torch.arange(M, device=x1.device).repeat_interleave(N).repeat(B)
        return which, first, (x2[:, None, :, :] - x1[:, :, None, :]).reshape(-1, 3)
    import numpy as np
    from scipy.spatial import cKDTree

    from training.knn import require_finite

    a, b = x1.double().numpy(), x2.double().numpy()
    require_finite("translation vote", a, b)
    parts = []
    for k in range(B):
        pairs = cKDTree(a[k]).sparse_distance_matrix(cKDTree(b[k]), R * 3**0.5 + 1e-3, output_type="ndarray")
        i, j = torch.from_numpy(pairs["i"].astype(np.int64)), torch.from_numpy(pairs["j"].astype(np.int64))
        parts.append((torch.full_like(i, k), i, x2[k, j] - x1[k, i]))
    which, first, d = (torch.cat(p) for p in zip(*parts))
    return which, first, d


@torch.no_grad()
def histogram_peaks(xyz1: Tensor, xyz2: Tensor, config: VoteConfig | None = None,
                    weights: Tensor | None = None) -> tuple[Tensor, Tensor]:
    """Step 1 of the module docstring: the centres (B, K, 3) of the ``candidates`` fullest local maxima of the
    smoothed histogram of the offsets ``q_j − p_i`` between ``xyz1`` (B, M, 3) and ``xyz2`` (B, N, 3), metres,
    and (B,) whether any offset fell inside the search cube. ``weights`` (B, M): what each frame-1 point's
    pairs count (default 1; e.g. its range, so that the sparse far scene is not outvoted by a dense near
    mover)."""
    cfg = config or VoteConfig()
    R, c = cfg.max_translation_m, cfg.cell_m
    n = int(round(2 * R / c))
    grid, found = offset_histogram(xyz1, xyz2, cfg, weights)
    peak = grid == torch.nn.functional.max_pool3d(grid[:, None], 3, stride=1, padding=1)[:, 0]
    score = torch.where(peak, grid, torch.full_like(grid, -1.0)).reshape(grid.shape[0], -1)
    k = min(cfg.candidates, score.shape[1])
    best = score.topk(k, dim=1).indices  # (B, K) the fullest local maxima
    ix, iy, iz = best // (n * n), (best // n) % n, best % n
    t = (torch.stack([ix, iy, iz], dim=-1).to(grid.dtype) + 0.5) * c - R
    return t, found


def offset_histogram(xyz1: Tensor, xyz2: Tensor, config: VoteConfig,
                     weights: Tensor | None = None) -> tuple[Tensor, Tensor]:
    """The smoothed histogram (B, n, n, n) of the offsets ``q_j − p_i`` between ``xyz1`` (B, M, 3) and ``xyz2``
    (B, N, 3) inside the search cube ``|d|_∞ ≤ max_translation_m`` (n = 2·max_translation_m / cell_m cells per
    axis, float32 counts, each pair counting its frame-1 point's ``weights`` (B, M) or 1), and (B,) whether
    any offset fell inside. Metres. The fuller its fullest cell, the more points agree on one translation."""
    x1, x2 = xyz1.detach().float(), xyz2.detach().float()
    B = x1.shape[0]
    R, c = config.max_translation_m, config.cell_m
    n = int(round(2 * R / c))
    which, first, d = _pair_offsets(x1, x2, R)
    cell = torch.floor((d + R) / c).long()
    inside = ((cell >= 0) & (cell < n)).all(dim=-1)
    which, first, cell = which[inside], first[inside], cell[inside]
    flat = ((which * n + cell[:, 0]) * n + cell[:, 1]) * n + cell[:, 2]
    vote = torch.ones(len(flat), dtype=x1.dtype, device=x1.device)
    if weights is not None:
        vote = weights.detach().to(x1.dtype)[which, first]
    counts = torch.zeros(B * n * n * n, dtype=x1.dtype, device=x1.device).index_add_(0, flat, vote)
    found = torch.zeros(B, dtype=torch.bool, device=x1.device).index_fill_(0, which, True)
    return _binomial_blur(counts.reshape(B, n, n, n)), found


@torch.no_grad()
def vote_hypotheses(xyz1: Tensor, xyz2: Tensor, config: VoteConfig | None = None) -> VoteHypotheses:
    """Steps 1–2 of the module docstring and the scores of step 3, for frame-1 points ``xyz1`` (B, M, 3)
    and frame-2 points ``xyz2`` (B, N, 3), metres (float32 results)."""
    cfg = config or VoteConfig()
    x1, x2 = xyz1.detach().float(), xyz2.detach().float()
    B = x1.shape[0]
    t, found = histogram_peaks(x1, x2, cfg)
    k = t.shape[1]
    # every hypothesis with its own copy of frame 1, (B·k, M, 3), searching its cloud's frame 2
    a = per_hypothesis(x1, k)
    t = _refine(a, x2, t.reshape(B * k, 3), cfg.bandwidths_m)
    # each frame-1 point's sampling spacing (its nearest other frame-1 point), at least the last radius
    spacing = spacing_of(x1).clamp_min(cfg.bandwidths_m[-1])
    matched = explained(a + t[:, None], x2, per_hypothesis(spacing, k)).reshape(B, k)
    return VoteHypotheses(t.reshape(B, k, 3), matched, spacing, found)


@torch.no_grad()
def vote_translation(xyz1: Tensor, xyz2: Tensor, config: VoteConfig | None = None) -> Tensor:
    """The dominant translation (B, 3) in metres that moves frame-1 points ``xyz1`` (B, M, 3) onto
    frame-2 points ``xyz2`` (B, N, 3); zero for a cloud with no offset inside the search cube."""
    h = vote_hypotheses(xyz1, xyz2, config)
    t = h.t[torch.arange(h.t.shape[0]), h.explained.argmax(dim=1)]
    t = torch.where(h.found[:, None], t, torch.zeros_like(t))
    return t.to(xyz1.dtype)


def farthest_samples(xyz: Tensor, sample_points: int) -> Tensor:
    """``sample_points`` farthest-point samples of ``xyz`` (B, N, 3), as the net's L0 takes them; the cloud
    itself when it has no more points than that or ``sample_points`` is 0. The vote baselines vote between
    such samples: a LiDAR cloud is densest near the sensor, and on its raw points the count of explained
    frame-1 points is dominated by the nearest few metres; the sample spreads them over the scene."""
    from training.pointops import farthest_point_sample, gather_points

    if sample_points <= 0 or xyz.shape[1] <= sample_points:
        return xyz
    return gather_points(xyz, farthest_point_sample(xyz, sample_points))
