"""Rigid polish: another method's ego-motion and movers' motions sharpened by robust ICP (label-free).

The net's flow gets the camera's motion roughly right but not precisely: on the synthetic worlds' LiDAR
splits the rigid motion fitted to it is typically 0.3–0.7° and 0.1–0.4 m off, which at
15–30 m range is most of the net's static error (docs/learned-flow.md, fourth round). Registration
does the opposite: robust ICP from the identity lands in a wrong basin on fast-driving scenes (1.1 m
static error on the demo's split), but started inside the right basin it is precise. This wrapper,
usable around any method, combines the two:

1. runs the method and fits one rigid motion ``T₀ = (R, t)`` to its flow robustly
   (:func:`evaluation.rigid_fit.rigid_fit`, IRLS with Cauchy weights);
1b. (``ego_check``) weighs ``T₀`` against the camera motions that the rigid vote finds without the method
   (:mod:`training.model.rigid_vote`): the vote's translation hypotheses, the fullest maxima of the same
   histogram with each frame-1 point's pairs weighted by its range, and ``T₀`` itself, each refined by the
   vote's trimmed rigid rounds on farthest-point samples against the whole pc2. Each is scored by the share
   of frame 1 that lands within ``static_scale_min`` of a pc2 point, each occupied cube of edge
   ``ego_check_voxel`` counting once (its points share its weight), so that how densely a part of the scene
   is sampled — a near mover densely, the far scene sparsely — does not decide. When another
   motion's share beats the refined ``T₀``'s by more than ``ego_check_margin``, it becomes ``T₀`` and the
   method's flow is re-based onto it (``f + T_b p − T_a p``: what the method added to its own ego-motion
   stays). In dense traffic the method's camera motion can be a near mover's (the net's pre-alignment
   follows the vote, whose histogram the near, densely sampled movers can outvote): there the far static
   scene, which such a motion leaves unexplained, decides (docs/learned-flow.md, twenty-fifth round). Each
   point weighted by its range instead (``ego_check_voxel`` 0, the twenty-fifth round's weights) still let a
   third of the points on cars driving along with the camera outweigh a static street that a wrong motion
   leaves mostly explained (twenty-sixth round);
2. keeps the frame-1 points whose flow agrees with ``T₀`` (residual below
   ``max(static_scale_min, mad_factor · 1.4826 · median residual)``): the method's own guess of what is
   static;
3. registers them onto pc2 by point-to-plane ICP with Cauchy weights, started at ``T₀``
   (:func:`evaluation.baselines.icp.icp`, ``kernel="cauchy"``, ``max_distance`` as the pair limit); where the
   start's pairs hold some direction weakly (``hold_vertical``) it fits the motion in the ground plane alone (the
   turn about camera y and the translation along x and z) and keeps ``T₀``'s height, pitch and roll: with the
   ground removed few surfaces face up or down, the vertical is then set by the small, wrongly estimated vertical
   parts of wall normals, and the six-degree registration slid vertically (up to 0.6 m) from motions the method
   had right to a centimetre, a slide that leaves every point on frame 2's surfaces, so no later check sees it
   (docs/learned-flow.md, forty-seventh round);
3b. (``ego_check``) keeps step 1b's motion instead when the registered one explains less of the scene — its
   share (as in step 1b) below ``(1 − ego_check_margin)`` times step 1b's: on a street whose walls run along
   the camera's path, the point-to-plane pairs hardly hold the motion along it, and a registration can slide
   with the traffic ahead (docs/learned-flow.md, twenty-fifth round);
3c. (``pairs_check``, splits whose frame 2 holds frame 1's own points) keeps ``T₀`` when the registered motion
   leaves frame 1 farther from pc2 — the mean nearest distance, truncated at ``pairs_check`` metres. On noisy
   stereo clouds the point-to-plane registration has a floor of a few centimetres, above a good method's own
   motion (docs/learned-flow.md, thirty-fifth round);
4. a frame-1 point takes the rigid flow ``T p − p`` when both say it moves with the camera: the method
   (it was kept in step 2) and the geometry (its polished target ``T p`` lands on pc2: the nearest pc2
   point is closer than ``max(static_scale_min, mad_factor · 1.4826 · median distance)``). The others —
   movers, points without a counterpart — keep the method's own flow for now. The geometry alone would not
   do: a car that drives less than its own length still lands on its own new surface;
5. (``objects``) the remaining points are split into Euclidean clusters (points closer than
   ``cluster_radius`` are linked); each cluster of at least ``cluster_min_points`` is registered by robust
   point-to-point ICP onto the pc2 points that the polished static scene does not explain, started at the
   ego-motion plus the cluster's median disagreement with it in the method's flow (so the start is the
   method's own guess of the object's motion). A cluster takes its rigid flow when more than
   ``cluster_min_fitness`` of its points then land within ``static_scale_min`` of those pc2 points; else
   it keeps the method's flow. Cars, cyclists and pedestrians move rigidly from one frame to the next.
6. (``rigid_objects``) every object-sized cluster of frame 1 (:func:`core.clusters.object_clusters`: a
   single-linkage component no longer than ``object_max_extent`` on any axis — things, not walls —
   however many of the cloud's points it holds: a car right ahead can hold a third of them, and counted
   out by a share of 0.1 it kept the method's flow; docs/learned-flow.md, twenty-seventh round; or no longer
   than ``object_whole_extent`` when it lies wholly inside frame 1's view, so that both its ends are seen: a
   van, a lorry, a bus; thirty-third round) moves
   rigidly: it takes the ego-motion's rotation and the median translation of the flow so far (one point
   that snapped onto a wrong surface, or a part of a mover that step 4 took for static, follows the rest of
   its object). Then a two-way point-to-point ICP (:class:`evaluation.baselines.icp.ICPConfig` ``two_way``)
   registers the cluster onto the pc2 points
   that the rest of the static scene does not explain, started at that motion; the fit replaces it when
   its score — the mean distance (truncated at ``static_scale_min``) from the moved cluster to those points
   plus the mean from those of them within ``max_distance`` back to the moved cluster — is below
   ``(1 − object_margin)`` times the median motion's score. The reverse half brings in the pc2 points near
   the cluster that nothing explains, such as a car's new front end; a cluster that no pc2 point lies near
   explains nothing and scores as if every pair were ``static_scale_min`` off. With ``score_in_view`` the
   first mean runs only over the cluster's points that every motion compared keeps inside pc2's own field of
   view (:class:`core.view.ViewExtent`: its azimuth sector, elevation range and reach, read from pc2):
   a point carried out of view could not have been seen, so it is neither matched nor missed. A near car that
   comes closer loses its lower part below the sensor's lowest beam, and counted as missed those points made
   its true motion score worse than a fit that leaves it sliding along its own surface (docs/learned-flow.md,
   twenty-eighth round). A car that the method missed
   wholly and that slid along itself is still not found (under the Cauchy weights the few pairs at its ends
   weigh little, and the score cannot tell that motion from the camera's at this sampling density;
   docs/learned-flow.md, twenty-fourth round).
6b. (``object_search``) a fit started at the median motion cannot reach a car more than ``max_distance``
   from it (the ICP pairs end there): an oncoming or overtaking car that the method left with the camera's
   motion. When the camera's motion leaves the cluster off pc2 (fewer than ``cluster_min_fitness`` of its
   points within ``static_scale_min`` of a pc2 point), or the cluster holds at least
   ``object_search_min_points`` points (a near car that the camera overtakes lands on its own surface, yet
   a small far cluster's score is too noisy to search on), the cluster is fitted a second time, started at the
   median motion shifted by the best-scoring (two-way score) of the ``object_search_peaks`` fullest maxima of
   the histogram of offsets from the moved cluster to the pc2 points around it, within ``object_search``
   metres (:func:`training.model.translation_vote.histogram_peaks`, the vote's histogram per object), of
   those rising or falling no more than ``object_search_rise`` (things on the ground move along it). That fit
   replaces the first when it scores lower, lies in another basin (its points on average more than
   ``static_scale_min`` from the first fit's) and rises no more than ``object_search_rise``; the margin
   against the median motion is unchanged (docs/learned-flow.md, twenty-seventh round).
7. (``pairs_exact``, splits whose frame 2 holds frame 1's own points) the points that still carry step 4's rigid
   flow take that of the motion refitted onto exact landings (:func:`evaluation.landing.register_on_landings`, on
   step 4's static points): those whose counterpart the sampling kept land on it exactly under the right motion, so
   least squares on the pairs within a shrinking radius, keeping the motion that lands the most of them within
   ``pairs_exact`` metres, takes a motion centimetres off onto the exact one. Last, so that steps 5 and 6 see the
   registration they were tuned with: started from the exact motion the object fits of step 6 lost the cars driving
   with the camera on the synthetic LiDAR pairs (docs/learned-flow.md, forty-fifth round). The refit starts from
   ``T`` and from ``T₀`` (the method's motion, or step 1b's), and the one that lands the most wins (``T``'s on a
   tie): where few surfaces face up or down (ground-removed clouds of walls and poles) the point-to-plane
   registration can slide vertically by more than the refit's widest pairs without leaving frame 2's surfaces,
   which neither step 3b nor 3c sees, while the landings do (docs/learned-flow.md, forty-sixth round).

No learning and no gradient steps: a bounded number of closed-form (Gauss–Newton / Kabsch) steps, with
no labels, pose or calibration. Without a good start it is no better than ICP: started from zero flow
(the identity) it lands in the same wrong basin as plain ICP on fast-driving scenes
(docs/learned-flow.md, fifth round) — the method supplies the basin, registration the precision.
Clouds: camera frames of frames 1 and 2 (x right, y down, z forward), metres. The row it adds is named
``"<method> + rigid polish"``; the method's own row is unchanged. A refinement stacked after it holds the
registered ego-motion (:meth:`evaluation.optimise.RefineConfig.after_registration`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from core.clusters import object_clusters, radius_components, view_interior
from core.view import ViewExtent
from evaluation.baselines.base import apply_transform, within_box
from evaluation.baselines.icp import ICPConfig, icp
from evaluation.landing import register_on_landings
from evaluation.pairing import PAIRINGS
from evaluation.rigid_fit import rigid_fit
from evaluation.answers import ask
from evaluation.wrapping import MethodWrapper


@dataclass
class RigidPolishConfig:
    """iterations: ICP iterations at most (point-to-plane, Cauchy-weighted).
    max_distance: metres; ICP pairs farther apart are ignored.
    kernel_scale_min: metres; the smallest Cauchy scale of the ICP residuals.
    static_scale_min: metres; the smallest residual scale that separates the points that move with the
        camera from those that do not, both for the method's flow (step 2) and for the polished targets
        against pc2 (step 4).
    mad_factor: the scale used is max(static_scale_min, mad_factor × 1.4826 × the cloud's median residual).
    min_points: fewer points agreeing with the method's rigid motion than this: the method's flow is
        returned unchanged.
    sigma, fit_iterations: the Cauchy scale (metres) and rounds of the rigid fit to the method's flow
        (:func:`evaluation.rigid_fit.rigid_fit`).
    objects: also polish each cluster of the points left out of the ego-motion (step 5 of the module
        docstring); false = the ego-motion only.
    cluster_radius: metres; points of one cluster are linked by hops shorter than this.
    cluster_min_points: smaller clusters keep the method's flow.
    cluster_iterations: ICP iterations at most per cluster (point-to-point, Cauchy-weighted).
    cluster_min_fitness: share of a cluster's points that must land on unexplained pc2 points for the
        cluster to take its rigid flow.
    rigid_objects: make every object-sized cluster of frame 1 move rigidly and try a two-way fit for it
        (step 6 of the module docstring); false = steps 1–5 only (the fifth round's polish).
    object_max_extent: metres; a cluster longer than this along any axis is a wall or a row of things.
    object_whole_extent: metres; a cluster wholly inside frame 1's own view (every point at least
        ``cluster_radius`` from its azimuth edges and its farthest depth, :func:`core.clusters.view_interior`)
        is an object up to this long: both its ends are seen, so its length is its own, not the view's. 12 m: a
        lorry or a bus (KITTI's Van, Truck and Tram classes outgrow ``object_max_extent``); an oncoming van in
        a real stereo scene was no object at 6 m (docs/learned-flow.md, thirty-third round). 0 (or
        ``object_max_extent``) = the extent rule alone, as before that round.
    object_min_link: metres; a cluster that is no object is split again at half the link radius, and so on down
        to this radius; its parts that lie wholly inside the view and are no longer than ``object_whole_extent``
        are objects (:func:`core.clusters.object_clusters` ``min_link_m``): things that touch in a dense cloud
        come apart. ``cluster_radius`` = no second split.
    object_max_share: a cluster holding more than this share of the cloud is not an object (1 = the extent alone
        decides: a near car can hold a large share; 0.1 before the twenty-seventh round).
    object_margin: the two-way fit replaces the cluster's median motion when its score is below
        (1 − object_margin) times that motion's score (0 = whenever lower).
    object_search: metres; the half-side of the translation search of step 6b around the median motion
        (0 = step 6 from the median motion alone, the twenty-sixth round's polish).
    object_search_peaks: how many of the search histogram's fullest maxima are considered.
    object_search_rise: metres; the largest vertical part (camera y) of a searched object's motion beyond its
        median motion.
    object_search_min_points: step 6b also searches for every cluster of at least this many points, not only
        for those the camera's motion leaves off pc2 (a near car coming closer lands on its own surface).
        Above the cloud's size: only those (the twenty-seventh round's polish).
    score_in_view: the two-way scores of a cluster's motions count in their first mean only the points that
        every motion compared keeps inside pc2's own field of view (:class:`core.view.ViewExtent`,
        its azimuth margin, the view pruning's too), when at least ``cluster_min_points`` are (step 6 of the module
        docstring); false = every point counts.
    ego_check: before step 2, weigh the ego-motion fitted to the method's flow against the camera motions the
        rigid vote finds without it, and after step 3 refuse a registration that explains less of the scene
        than the motion so chosen (steps 1b and 3b of the module docstring); false = the method's motion and
        its registration as they come.
    ego_check_margin: another motion replaces the method's when its share of explained frame 1 is more than
        (1 + this) times the method's; the registration is refused when its share is below (1 − this) times
        that motion's.
    ego_check_voxel: metres; the edge of the cubes by which that share weighs frame 1: each occupied cube
        counts once, its points sharing its weight. 0 = each point weighted by its range from camera 1 (the
        twenty-fifth round's weights).
    ego_check_points: the vote and the trimmed rounds run on this many farthest-point samples of each cloud
        (0 = every point).
    pairs_check: metres; for a split whose frame 2 holds frame 1's own points moved (``--pairing points``,
        :mod:`evaluation.pairing`), step 3c: the registration is refused when it leaves frame 1 farther from
        pc2 than step 2's motion did — the mean distance from each moved frame-1 point to its nearest pc2
        point, truncated at this many metres. Where frame 2 holds the points' counterparts that distance is
        near zero at the right motion for the points it kept, so it tells centimetres apart, which a re-scan's
        sampling offsets hide (docs/learned-flow.md, thirty-fifth round). 0 = off (re-scans: the default).
    level_starts: the start of each cluster's fit (steps 5, 6 and 6b) and step 6's median motion take the method's
        median departure from the camera's motion along the ground only: its vertical part (camera y) is dropped.
        Things on the ground move along it, and a re-scan's rings put a wrong vertical shift of one beam spacing
        (0.43° for a 64-beam sensor such as KITTI's: 0.24 m at 32 m) within a point-to-point fit's reach: a method
        whose movers carry a vertical error starts the fit there and the fit settles a ring off (docs/learned-flow.md,
        forty-second round). false = the method's whole median departure (before that round).
    hold_vertical: step 3's registration fits the motion in the ground plane alone (the turn about camera y and
        the translation along x and z) and keeps ``T₀``'s height, pitch and roll when its start's pairs hold their
        least held direction by less than this (:class:`evaluation.baselines.icp.ICPConfig` ``hold_vertical``:
        the smallest eigenvalue of the normal equations per pair, 1 = every normal along it). 0.03 lies between
        the synthetic LiDAR worlds' and box streets' scenes (0–0.027) and the real KITTI scans' (0.065–0.096):
        a direction in which the surfaces' normals have an RMS part of less than 0.17 (10°), which PCA normals over
        a LiDAR's rings do not resolve. 0 = all six degrees of freedom (before the forty-seventh round); 0 for
        point pairs (step 7 reads the vertical from exact landings; the hold was measured on re-scans only).
    pairs_exact: metres; for a split whose frame 2 holds frame 1's own points moved, step 7: the registered motion
        (and ``T₀``, step 1's or 1b's) is refitted to step 4's static points that land on frame-2 points, keeping the
        motion that lands the most of them within this distance, and the points that kept step 4's rigid flow take the
        refitted one
        (:func:`evaluation.landing.register_on_landings`). A few millimetres: the split's own rounding is far below
        it, a motion a centimetre off lands almost none. 0 = off (re-scans: the default)."""

    iterations: int = 20
    max_distance: float = 1.0
    kernel_scale_min: float = 0.05
    static_scale_min: float = 0.3
    mad_factor: float = 3.0
    min_points: int = 32
    sigma: float = 0.25
    fit_iterations: int = 4
    objects: bool = True
    cluster_radius: float = 0.8
    cluster_min_points: int = 8
    cluster_iterations: int = 15
    cluster_min_fitness: float = 0.5
    rigid_objects: bool = True
    object_max_extent: float = 6.0
    object_max_share: float = 1.0
    object_whole_extent: float = 12.0
    object_min_link: float = 0.8
    object_margin: float = 0.4
    object_search: float = 2.5
    object_search_peaks: int = 8
    object_search_rise: float = 0.3
    object_search_min_points: int = 32
    score_in_view: bool = True
    ego_check: bool = True
    ego_check_margin: float = 0.05
    ego_check_points: int = 512
    ego_check_voxel: float = 1.0
    pairs_check: float = 0.0
    level_starts: bool = True
    hold_vertical: float = 0.03
    pairs_exact: float = 0.0

    @classmethod
    def for_pairing(cls, pairing: str = "surface") -> "RigidPolishConfig":
        """The settings for what frame 2 holds (:mod:`evaluation.pairing`, ``--pairing``): ``"surface"`` (a
        re-scan) the defaults; ``"points"`` (frame 1's own points moved) adds step 3c with ``pairs_check`` 0.1 m
        — the nearest distance of a point whose counterpart frame 2 holds is its motion's error, and 0.1 m
        keeps a point whose counterpart was not sampled from outweighing the centimetres it compares — and step 7
        with ``pairs_exact`` 5 mm, without ``hold_vertical`` (step 7 reads the vertical from exact landings)."""
        if pairing not in PAIRINGS:
            raise ValueError(f"pairing must be one of {PAIRINGS}, got {pairing!r}")
        return cls(pairs_check=0.1, pairs_exact=0.005, hold_vertical=0.0) if pairing == "points" else cls()

    def __post_init__(self) -> None:
        if self.iterations < 1 or self.fit_iterations < 1 or self.cluster_iterations < 1 or self.min_points < 6:
            raise ValueError("iterations, fit_iterations and cluster_iterations must be >= 1, min_points >= 6")
        if not (self.cluster_radius > 0 and self.cluster_min_points >= 3 and 0 <= self.cluster_min_fitness < 1):
            raise ValueError("need cluster_radius > 0, cluster_min_points >= 3 and 0 <= cluster_min_fitness < 1")
        if (self.ego_check_margin < 0 or self.ego_check_points < 0 or not self.ego_check_voxel >= 0
                or not self.pairs_check >= 0 or not self.pairs_exact >= 0 or not self.hold_vertical >= 0):
            raise ValueError("need ego_check_margin >= 0, ego_check_points >= 0, ego_check_voxel >= 0, "
                             "pairs_check >= 0, pairs_exact >= 0 and hold_vertical >= 0")
        if not (self.object_search >= 0 and self.object_search_peaks >= 1 and self.object_search_rise >= 0
                and self.object_search_min_points >= 0):
            raise ValueError("need object_search >= 0, object_search_peaks >= 1, object_search_rise >= 0 and "
                             "object_search_min_points >= 0")
        if not (self.object_max_extent > 0 and 0 < self.object_max_share <= 1 and 0 <= self.object_margin < 1):
            raise ValueError("need object_max_extent > 0, 0 < object_max_share <= 1 and 0 <= object_margin < 1")
        if not (self.object_whole_extent >= 0 and self.object_min_link > 0):
            raise ValueError("need object_whole_extent >= 0 and object_min_link > 0")
        if not (self.max_distance > 0 and self.kernel_scale_min > 0 and self.static_scale_min > 0
                and self.sigma > 0 and self.mad_factor >= 0):
            raise ValueError("max_distance, kernel_scale_min, static_scale_min and sigma must be > 0, "
                             "mad_factor >= 0")


def _mean_gaps(p2: np.ndarray, clouds: list[np.ndarray], truncate: float) -> np.ndarray:
    """(K,) for each of ``clouds`` (K of them, each (N, 3)): the mean distance (metres) from its points to their
    nearest point of ``p2`` (M, 3), each truncated at ``truncate`` — the rigid vote's
    :func:`~training.model.rigid_vote.mean_gap`, one search structure over ``p2`` for all K."""
    import torch

    from training.model.rigid_vote import mean_gap

    return mean_gap(torch.from_numpy(np.stack(clouds)), torch.from_numpy(p2)[None], truncate).numpy()


def _agreeing(residual: np.ndarray, cfg: RigidPolishConfig) -> np.ndarray:
    """(N,) bool: residuals (metres) below ``max(static_scale_min, mad_factor · 1.4826 · median)``."""
    limit = max(cfg.static_scale_min, cfg.mad_factor * 1.4826 * float(np.median(residual)))
    return residual < limit


def polish_rigid(pc1: np.ndarray, pc2: np.ndarray, flow: np.ndarray,
               cfg: RigidPolishConfig | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(flow_out (N, 3) float32, T (4, 4), static (N,) bool)``: ``flow`` (N, 3) at ``pc1`` (N, 3) with its
    ego-motion (and, with ``objects``, its movers' motions) polished against ``pc2`` (M, 3) (module
    docstring); ``T`` maps camera 1 to camera 2 and ``static`` marks the points that took its rigid flow in
    step 4 (step 6 may since have moved some of them with their object). Metres."""
    cfg = cfg or RigidPolishConfig()
    p1, p2 = np.asarray(pc1, np.float64), np.asarray(pc2, np.float64)
    f = np.asarray(flow, np.float64)
    R, t = rigid_fit(p1, f, cfg.sigma, cfg.fit_iterations, cfg.mad_factor)
    init = np.eye(4)
    init[:3, :3], init[:3, 3] = R, t
    tree2 = cKDTree(p2) if len(p2) else None
    checked = None  # step 1b's refined motion (4, 4) and its explained share
    if cfg.ego_check and tree2 is not None and len(p1) >= cfg.min_points:
        weights = _share_weights(p1, cfg.ego_check_voxel)  # each frame-1 point's part in the explained share
        f, init, checked = _ego_check(p1, p2, tree2, weights, f, init, cfg)
    agree = _agreeing(np.linalg.norm(p1 + f - apply_transform(init, p1), axis=1), cfg)
    if agree.sum() < cfg.min_points or len(p2) < 6:
        return f.astype(np.float32), init, np.zeros(len(p1), bool)
    icp_cfg = ICPConfig(method="point_to_plane", max_correspondence_distance=cfg.max_distance,
                        max_iterations=cfg.iterations, kernel="cauchy", kernel_scale_min=cfg.kernel_scale_min,
                        hold_vertical=cfg.hold_vertical)
    T = icp(p1[agree], p2, icp_cfg, init=init).transform
    if checked is not None and (_explained_share(p1, weights, tree2, T, cfg.static_scale_min)
                                < (1 - cfg.ego_check_margin) * checked[1]):
        T = checked[0]  # step 3b: the registration slid away from what explains the scene
    if cfg.pairs_check:
        registered, started = _mean_gaps(p2, [apply_transform(T, p1), apply_transform(init, p1)], cfg.pairs_check)
        if registered > started:
            T = init  # step 3c: frame 2 holds frame 1's points, and they lie farther from them after the registration
    target = apply_transform(T, p1)
    dist, _ = tree2.query(target)
    static = agree & _agreeing(dist, cfg)
    out = f.copy()
    out[static] = (target - p1)[static]
    if cfg.objects or cfg.rigid_objects:
        gap, owner = _explained(p1, p2, T, static, cfg)
        if cfg.objects:
            _polish_clusters(p1, p2, out, T, static, gap, cfg)
        if cfg.rigid_objects:
            view = ViewExtent.of(p2) if cfg.score_in_view else None
            _rigid_objects(p1, p2, out, T, owner, dist < cfg.static_scale_min, view, cfg)
    if cfg.pairs_exact and static.any():  # step 7: onto exact landings, where step 4's rigid flow still stands
        unmoved = static & (np.abs(out - (target - p1)).max(axis=1) == 0)  # not moved since by steps 5 and 6
        starts = (T,) if np.array_equal(T, init) else (T, init)  # step 3c may have kept T₀: one refit then
        fits = [register_on_landings(p1[static], p2, start, cfg.pairs_exact, tree2=tree2) for start in starts]
        T = max(fits, key=lambda fit: fit[1])[0]  # the first of equals: the registered motion
        out[unmoved] = (apply_transform(T, p1) - p1)[unmoved]
    return out.astype(np.float32), T, static


def _share_weights(p1: np.ndarray, voxel: float) -> np.ndarray:
    """Each frame-1 point's weight (N,) in the explained share of steps 1b and 3b: one over the number of points
    of ``p1`` (N, 3) in its cube of edge ``voxel`` metres (so every occupied cube weighs one), or, for
    ``voxel`` 0, its range from camera 1 (metres)."""
    if voxel == 0:
        return np.linalg.norm(p1, axis=1)
    _, cube, count = np.unique(np.floor(p1 / voxel).astype(np.int64), axis=0, return_inverse=True,
                               return_counts=True)
    return 1.0 / count[cube.ravel()]


def _explained_share(p1: np.ndarray, weights: np.ndarray, tree2: cKDTree, T: np.ndarray, radius: float) -> float:
    """The weighted share of frame-1 points ``p1`` (N, 3) (``weights`` (N,), :func:`_share_weights`) whose
    position moved by ``T`` (4, 4) has a frame-2 point (``tree2``) within ``radius`` metres."""
    dist, _ = tree2.query(apply_transform(T, p1))
    return float((weights * (dist < radius)).sum() / max(weights.sum(), 1e-12))


def _ego_check(p1: np.ndarray, p2: np.ndarray, tree2: cKDTree, weights: np.ndarray, f: np.ndarray,
               T_a: np.ndarray, cfg: RigidPolishConfig) -> tuple[np.ndarray, np.ndarray, tuple[np.ndarray, float]]:
    """Step 1b of the module docstring: ``(flow, T₀, (T_chosen, share))``, either the method's ``f`` (N, 3)
    and its fitted motion ``T_a`` (4, 4) unchanged, or — when one of the rigid vote's motions explains clearly
    more of the scene — that motion and ``f`` re-based onto it (``f + T_b p − T_a p``: what the method put on
    top of its own ego-motion stays); and the refined motion that won (4, 4) with its explained share
    (``weights`` (N,), :func:`_share_weights`), for step 3b. Metres, camera frames."""
    import torch

    from training.model.rigid_vote import RigidVoteConfig, trimmed_rounds
    from training.model.translation_vote import farthest_samples, histogram_peaks, vote_hypotheses

    rc = RigidVoteConfig()
    cloud2 = torch.tensor(p2)[None]  # copies: the caller's arrays may be read-only
    cloud1 = torch.tensor(p1, dtype=torch.float32)[None]
    if len(p1) == len(p2):  # both samples in one batched pass (the same samples, half the loop's steps)
        a, b = farthest_samples(torch.cat([cloud1, cloud2.float()]), cfg.ego_check_points).split(1)
    else:
        a, b = (farthest_samples(c, cfg.ego_check_points) for c in (cloud1, cloud2.float()))
    plain = vote_hypotheses(a, b, rc.vote).t[0]  # the vote's refined translations
    far, _ = histogram_peaks(a, b, rc.vote, weights=a.norm(dim=-1))  # the far scene's, range-weighted
    starts = torch.cat([torch.from_numpy(T_a[:3, 3])[None], plain.double(), far[0].double()])
    H = len(starts)
    rot = torch.eye(3, dtype=torch.float64).repeat(H, 1, 1)
    rot[0] = torch.from_numpy(T_a[:3, :3])
    a64, b64 = a.double().expand(H, -1, -1), cloud2.expand(H, -1, -1)
    Rs, ts, _ = trimmed_rounds(a64, b64, rot, starts, rc)
    fitted = np.tile(np.eye(4), (H, 1, 1))
    fitted[:, :3, :3], fitted[:, :3, 3] = Rs.numpy(), ts.numpy()
    share = [_explained_share(p1, weights, tree2, T, cfg.static_scale_min) for T in fitted]
    best = int(np.argmax(share))
    if share[best] <= (1 + cfg.ego_check_margin) * share[0]:
        return f, T_a, (fitted[0], share[0])
    T_b = fitted[best]
    return f + apply_transform(T_b, p1) - apply_transform(T_a, p1), T_b, (T_b, share[best])


def _explained(p1: np.ndarray, p2: np.ndarray, T: np.ndarray, static: np.ndarray,
               cfg: RigidPolishConfig) -> tuple[np.ndarray, np.ndarray]:
    """For each pc2 point (M,): its distance to the nearest static frame-1 point moved by ``T`` (metres; inf
    without static points) and that point's row in ``p1`` when nearer than ``static_scale_min``, else −1."""
    rows = np.flatnonzero(static)
    if not len(rows):
        return np.full(len(p2), np.inf), np.full(len(p2), -1)
    gap, near = cKDTree(apply_transform(T, p1[rows])).query(p2)
    return gap, np.where(gap < cfg.static_scale_min, rows[near], -1)


def _median_start(T: np.ndarray, pts: np.ndarray, flow: np.ndarray, level: bool = False) -> np.ndarray:
    """The ego-motion ``T`` plus the median disagreement with it of the flow ``flow`` (k, 3) at ``pts`` (k, 3): the
    method's own guess of a cluster's rigid motion (4×4); with ``level`` that disagreement's vertical part (camera
    y) is dropped (``RigidPolishConfig.level_starts``)."""
    start = T.copy()
    departure = np.median(pts + flow - apply_transform(T, pts), axis=0)
    if level:
        departure[1] = 0.0
    start[:3, 3] += departure
    return start


def _cluster_icp(cfg: RigidPolishConfig, two_way: bool = False) -> ICPConfig:
    """The robust point-to-point ICP that registers one cluster (steps 5 and 6)."""
    return ICPConfig(method="point_to_point", max_correspondence_distance=cfg.max_distance,
                     max_iterations=cfg.cluster_iterations, kernel="cauchy", kernel_scale_min=cfg.kernel_scale_min,
                     two_way=two_way)


def _polish_clusters(p1: np.ndarray, p2: np.ndarray, flow: np.ndarray, T: np.ndarray, static: np.ndarray,
                     gap: np.ndarray, cfg: RigidPolishConfig) -> None:
    """Step 5 of the module docstring, in place on ``flow`` (N, 3): each cluster of the non-static points
    registered onto the pc2 points that the static scene moved by ``T`` does not explain (``gap`` (M,): each
    pc2 point's distance to it, :func:`_explained`)."""
    rest = np.flatnonzero(~static)
    if len(rest) < cfg.cluster_min_points or not static.any():
        return
    free = p2[gap > cfg.static_scale_min]  # pc2 points the static scene does not explain
    if len(free) < cfg.cluster_min_points:
        return
    label = radius_components(p1[rest], cfg.cluster_radius)
    free_tree = cKDTree(free)
    icp_cfg = _cluster_icp(cfg)
    for c in np.unique(label):
        rows = rest[label == c]
        if len(rows) < cfg.cluster_min_points:
            continue
        pts = p1[rows]
        start = _median_start(T, pts, flow[rows], cfg.level_starts)
        moved = apply_transform(icp(pts, free, icp_cfg, init=start).transform, pts)
        dist, _ = free_tree.query(moved)
        if (dist < cfg.static_scale_min).mean() > cfg.cluster_min_fitness:
            flow[rows] = moved - pts


def _two_way_score(moved: np.ndarray, target: np.ndarray, cfg: RigidPolishConfig,
                   counted: np.ndarray | None = None) -> float:
    """How well ``moved`` (k, 3) lands on ``target`` (m, 3): mean distance from each moved point to the targets
    plus the mean from the targets within ``max_distance`` of it back to it, both truncated at
    ``static_scale_min`` (metres); with no target that near, the second mean counts as ``static_scale_min``.
    ``counted`` (k,) bool, optional: the moved points the first mean runs over (:func:`_in_view`)."""
    if len(target) == 0:
        return 0.0
    scale = cfg.static_scale_min
    ahead_of = moved if counted is None else moved[counted]
    target = target[within_box(target, moved, max(scale, cfg.max_distance))]  # the others are beyond both bounds
    ahead = np.full(len(ahead_of), scale)
    back = np.empty(0)
    if len(target):
        ahead = np.minimum(cKDTree(target).query(ahead_of, distance_upper_bound=scale)[0], scale)
        back, _ = cKDTree(moved).query(target, distance_upper_bound=cfg.max_distance)
    ahead = ahead.mean()
    near = back[np.isfinite(back)]
    return float(ahead + (np.minimum(near, scale).mean() if len(near) else scale))


def _in_view(view: ViewExtent | None, hypotheses: list[np.ndarray], cfg: RigidPolishConfig) -> np.ndarray | None:
    """The points of a cluster that every one of ``hypotheses`` (each (k, 3), the cluster moved) keeps inside
    pc2's own field of view ``view``, to be the points the two-way scores of those hypotheses count
    (:func:`_two_way_score`); None (every point) without a view or when fewer than ``cluster_min_points``
    are. A point carried out of pc2's view could not have been seen, so it is neither matched nor missed —
    a near car that comes closer loses its lower part below the sensor's lowest beam, and counting those
    points as missed favoured motions that keep it where it was — and the same points count for every
    hypothesis compared, so that none gains by carrying its worst points out of view (docs/learned-flow.md,
    twenty-eighth round)."""
    if view is None:
        return None
    seen = np.logical_and.reduce([view.contains(h) for h in hypotheses])
    return seen if seen.sum() >= cfg.cluster_min_points else None


def _rigid_objects(p1: np.ndarray, p2: np.ndarray, flow: np.ndarray, T: np.ndarray, owner: np.ndarray,
                   landed: np.ndarray, view: ViewExtent | None, cfg: RigidPolishConfig) -> None:
    """Steps 6 and 6b of the module docstring, in place on ``flow`` (N, 3): each object-sized cluster of ``p1``
    moves rigidly, by the median motion or by a two-way fit onto the pc2 points the rest of the static scene
    does not explain (``owner`` (M,): each pc2 point's explaining static row of ``p1``, or −1;
    :func:`_explained`). ``T`` (4, 4): the polished camera motion; ``landed`` (N,): whether each point moved by
    ``T`` lies within ``static_scale_min`` of a pc2 point (step 4's test, reused by step 6b); ``view``: pc2's
    field of view for the scores, or None (:func:`_in_view`)."""
    whole_extent = cfg.object_whole_extent or cfg.object_max_extent  # 0: the extent rule alone
    whole = None
    if whole_extent > cfg.object_max_extent or cfg.object_min_link < cfg.cluster_radius:
        whole = view_interior(p1, cfg.cluster_radius)
    objects = object_clusters(p1, cfg.cluster_radius, cfg.cluster_min_points, cfg.object_max_extent,
                              cfg.object_max_share, whole, whole_extent, min(cfg.object_min_link, cfg.cluster_radius))
    if not objects:
        return
    icp_cfg = _cluster_icp(cfg, two_way=True)
    member = np.zeros(len(p1), bool)
    for idx in objects:
        member[:] = False
        member[idx] = True
        target = p2[(owner < 0) | member[owner]]  # unexplained, or explained by this cluster itself (owner −1
        # reads member[-1], which the first test has already settled)
        pts = p1[idx]
        median = _median_start(T, pts, flow[idx], cfg.level_starts)
        moved = apply_transform(median, pts)
        if len(target) < cfg.cluster_min_points:
            flow[idx] = moved - pts
            continue
        fits = [apply_transform(icp(pts, target, icp_cfg, init=median).transform, pts)]
        if landed[idx].mean() < cfg.cluster_min_fitness or len(idx) >= cfg.object_search_min_points:  # step 6b
            fits += [apply_transform(icp(pts, target, icp_cfg, init=start).transform, pts)
                     for start in _searched_start(pts, moved, target, median, view, cfg)]
        counted = _in_view(view, [moved, *fits], cfg)
        best, best_score = fits[0], _two_way_score(fits[0], target, cfg, counted)
        for fitted in fits[1:]:
            score = _two_way_score(fitted, target, cfg, counted)
            rise = abs(float(np.mean(fitted[:, 1] - moved[:, 1])))
            if (score < best_score and rise <= cfg.object_search_rise
                    and np.linalg.norm(fitted - best, axis=1).mean() > cfg.static_scale_min):
                best, best_score = fitted, score
        if best_score < (1 - cfg.object_margin) * _two_way_score(moved, target, cfg, counted):
            moved = best
        flow[idx] = moved - pts


def _searched_start(pts: np.ndarray, moved: np.ndarray, target: np.ndarray, median: np.ndarray,
                    view: ViewExtent | None, cfg: RigidPolishConfig) -> list[np.ndarray]:
    """Step 6b's start for the cluster ``pts`` (k, 3), ``moved`` (k, 3) by its median motion ``median`` (4×4):
    ``median`` shifted by the translation within ``object_search`` metres that the histogram of offsets from
    ``moved`` to the ``target`` points (m, 3) around it favours (:func:`training.model.translation_vote.
    histogram_peaks`; of its ``object_search_peaks`` fullest maxima rising no more than ``object_search_rise``,
    the one with the lowest two-way score, over the points the median motion keeps in ``view``, pc2's field of
    view, or over all without one). Empty when the search is off or finds nothing. Metres, camera frames."""
    if cfg.object_search == 0:
        return []
    import torch

    from training.model.translation_vote import VoteConfig, histogram_peaks

    reach = cfg.object_search + cfg.max_distance
    near = target[within_box(target, moved, reach)]
    if len(near) < cfg.cluster_min_points:
        return []
    vote = VoteConfig(max_translation_m=cfg.object_search, candidates=cfg.object_search_peaks)
    peaks, found = histogram_peaks(torch.from_numpy(moved)[None].float(), torch.from_numpy(near)[None].float(), vote)
    shifts = peaks[0].double().numpy()
    shifts = shifts[np.abs(shifts[:, 1]) <= cfg.object_search_rise]  # things on the ground move along it
    if not bool(found[0]) or not len(shifts):
        return []
    start = median.copy()
    counted = _in_view(view, [moved], cfg)
    start[:3, 3] += min(shifts, key=lambda d: _two_way_score(moved + d, target, cfg, counted))
    return [start]


class RigidPolished(MethodWrapper):
    """``inner`` (any flow method) with its ego-motion and movers polished by robust ICP (:func:`polish_rigid`)."""

    suffix = "rigid polish"
    config_type = RigidPolishConfig
    registered_ego = True  # a refinement after it holds this ego-motion (RefineConfig.after_registration)

    def __call__(self, pc1, pc2, color1=None, color2=None) -> np.ndarray:
        return self.marked(pc1, pc2, color1, color2)[0]

    def marked(self, pc1, pc2, color1=None, color2=None) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """The polished flow and its marks: ``{"static": (N,) bool}``, the points step 4 gave the registered
        camera motion. A refinement stacked after it (:class:`evaluation.optimise.RefinedMethod`,
        ``RefineConfig.static_weight``) holds them; a stack's book keeps them with the flow (:mod:`evaluation.answers`)."""
        flow = ask(self.inner, pc1, pc2, color1, color2)
        out, _, static = polish_rigid(pc1, pc2, flow, self.config)
        return out, {"static": static}


def rigid_polished(method, config: RigidPolishConfig | None = None) -> RigidPolished:
    """``method`` with its ego-motion and movers polished, named ``"<method name> + rigid polish"`` (its own row)."""
    return RigidPolished(method, config)
