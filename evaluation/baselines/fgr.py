"""Fast Global Registration (Zhou, Park & Koltun, ECCV 2016) on FPFH features.

1. FPFH descriptors of both clouds (:mod:`evaluation.baselines.fpfh`, same radii for both).
2. Correspondences: nearest neighbours in feature space both ways; the reciprocity test keeps mutual
   pairs; the tuple test draws random triples of pairs and keeps those whose three pairwise distances
   agree across the clouds within ``tuple_scale`` (``τ < ‖p_i − p_j‖ / ‖q_i − q_j‖ < 1/τ``), until
   ``maximum_tuple_count`` triples pass or 100 × (number of pairs) draws are spent.
3. Both clouds are centred and divided by one scale (the largest distance of a point from its cloud's
   centroid, unless ``use_absolute_scale``), then the Geman–McClure objective
   ``Σ ρ(‖T p − q‖)`` with ``ρ(x) = μ x² / (μ + x²)`` is minimised through its line process
   ``l = (μ / (μ + ‖T p − q‖²))²`` and Gauss–Newton steps on the 6-DoF twist; graduated
   non-convexity starts at μ = 1 (squared normalised units, i.e. the clouds' extent) and divides μ by
   ``division_factor`` every 4 iterations down to δ², δ = ``maximum_correspondence_distance`` — the
   paper's floor (Open3D's implementation compares μ with δ itself, which stops the schedule earlier
   and leaves centimetre-level bias on our synthetic tests).
4. The transform is mapped back to metres.

Defaults are Open3D's ``FastGlobalRegistrationOption`` (1.4, relative scale, decrease μ, δ = 0.025,
0.95, 1000 tuples, tuple test on) except ``iteration_number`` = 100 (Open3D: 64), enough for the
schedule to reach its floor (1.4^-22 ≈ 0.025², 88 iterations). An optional ICP refinement polishes
the result.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from evaluation.baselines.base import RegistrationResult, as_cloud, rigid_flow, skew, twist_to_transform
from evaluation.baselines.fpfh import FPFHConfig, compute_fpfh, point_spacing
from evaluation.baselines.icp import ICPConfig, icp


@dataclass
class FGRConfig:
    """FGR settings (Open3D's defaults) plus the FPFH settings and an optional ICP refinement.

    Attributes:
        fpfh: feature settings (radii default to multiples of the clouds' point spacing).
        division_factor: μ is divided by this every 4 iterations (graduated non-convexity).
        use_absolute_scale: keep metres instead of normalising by the clouds' extent.
        decrease_mu: apply graduated non-convexity.
        maximum_correspondence_distance: δ; μ stops decreasing at δ² (normalised units unless
            absolute scale).
        iteration_number: Gauss–Newton iterations (Open3D: 64).
        tuple_scale: tuple-test similarity τ.
        maximum_tuple_count: stop the tuple test after this many accepted triples.
        tuple_test: run the tuple test (else keep all mutual pairs).
        seed: seed of the tuple test's random triples.
        refine_icp: optional ICP settings to polish the FGR transform (None = no refinement).
    """

    fpfh: FPFHConfig = field(default_factory=FPFHConfig)
    division_factor: float = 1.4
    use_absolute_scale: bool = False
    decrease_mu: bool = True
    maximum_correspondence_distance: float = 0.025
    iteration_number: int = 100
    tuple_scale: float = 0.95
    maximum_tuple_count: int = 1000
    tuple_test: bool = True
    seed: int = 0
    refine_icp: ICPConfig | None = None


def mutual_matches(feat1: np.ndarray, feat2: np.ndarray) -> np.ndarray:
    """(K, 2) index pairs (i in cloud 1, j in cloud 2) that are each other's nearest feature."""
    if len(feat1) == 0 or len(feat2) == 0:
        return np.zeros((0, 2), dtype=np.int64)
    _, nn12 = cKDTree(feat2).query(feat1, k=1)
    _, nn21 = cKDTree(feat1).query(feat2, k=1)
    i = np.arange(len(feat1))
    mutual = nn21[nn12] == i
    return np.stack([i[mutual], nn12[mutual]], 1).astype(np.int64)


def tuple_filter(
    p: np.ndarray, q: np.ndarray, pairs: np.ndarray, scale: float, max_tuples: int, rng: np.random.Generator
) -> np.ndarray:
    """Correspondences (rows of ``pairs``, three per accepted triple) passing the tuple test."""
    k = len(pairs)
    if k < 3:
        return pairs[:0]
    trials = 100 * k
    out = []
    accepted = 0
    chunk = 20000
    for start in range(0, trials, chunk):
        m = min(chunk, trials - start)
        tri = rng.integers(0, k, size=(m, 3))
        distinct = (tri[:, 0] != tri[:, 1]) & (tri[:, 1] != tri[:, 2]) & (tri[:, 0] != tri[:, 2])
        tri = tri[distinct]
        a = p[pairs[tri, 0]]  # (m, 3, 3)
        b = q[pairs[tri, 1]]
        ok = np.ones(len(tri), dtype=bool)
        for u, v in ((0, 1), (1, 2), (2, 0)):
            la = np.linalg.norm(a[:, u] - a[:, v], axis=1)
            lb = np.linalg.norm(b[:, u] - b[:, v], axis=1)
            ok &= (la * scale < lb) & (lb < la / scale)
        good = tri[ok][: max_tuples - accepted]
        out.append(good)
        accepted += len(good)
        if accepted >= max_tuples:
            break
    if not out or accepted == 0:
        return pairs[:0]
    return pairs[np.concatenate(out).ravel()]


def _optimise(p: np.ndarray, q: np.ndarray, cfg: FGRConfig, start_mu: float) -> np.ndarray:
    """Graduated-non-convexity Gauss–Newton: 4×4 T minimising Σ ρ_μ(‖T p − q‖)."""
    transform = np.eye(4)
    mu = start_mu
    mu_floor = cfg.maximum_correspondence_distance**2
    for it in range(cfg.iteration_number):
        if cfg.decrease_mu and it % 4 == 0 and mu > mu_floor:
            mu = max(mu / cfg.division_factor, mu_floor)
        pt = p @ transform[:3, :3].T + transform[:3, 3]
        r = pt - q  # (K, 3)
        line = (mu / (mu + np.einsum("ki,ki->k", r, r))) ** 2
        jac = np.concatenate([-skew(pt), np.broadcast_to(np.eye(3), (len(pt), 3, 3))], axis=2)  # (K, 3, 6)
        jtj = np.einsum("k,kai,kaj->ij", line, jac, jac)
        jtr = np.einsum("k,kai,ka->i", line, jac, r)
        try:
            xi = np.linalg.solve(jtj, -jtr)
        except np.linalg.LinAlgError:
            break
        transform = twist_to_transform(xi) @ transform
    return transform


def fast_global_registration(
    pc1: np.ndarray,
    pc2: np.ndarray,
    config: FGRConfig | None = None,
    feat1: np.ndarray | None = None,
    feat2: np.ndarray | None = None,
) -> RegistrationResult:
    """Register ``pc1`` (N, 3) onto ``pc2`` (M, 3), metres, globally (no initial guess needed).

    Args:
        pc1, pc2: the clouds.
        config: FGR settings.
        feat1, feat2: optional precomputed (N, 33) / (M, 33) FPFH descriptors.

    Returns:
        The transform mapping pc1 onto pc2; ``n_correspondences`` counts the pairs after the tuple test
        (identity with ``converged=False`` when fewer than 3 survive).
    """
    cfg = config or FGRConfig()
    p_all = as_cloud("pc1", pc1)
    q_all = as_cloud("pc2", pc2)
    if len(p_all) < 3 or len(q_all) < 3:
        return RegistrationResult(np.eye(4), 0, False, 0.0, float("nan"), 0)
    if feat1 is None or feat2 is None:
        spacing = 0.5 * (point_spacing(p_all) + point_spacing(q_all))
        feat1 = compute_fpfh(p_all, config=cfg.fpfh, spacing=spacing) if feat1 is None else feat1
        feat2 = compute_fpfh(q_all, config=cfg.fpfh, spacing=spacing) if feat2 is None else feat2
    pairs = mutual_matches(np.asarray(feat1, np.float64), np.asarray(feat2, np.float64))

    mean1, mean2 = p_all.mean(0), q_all.mean(0)
    extent = max(np.linalg.norm(p_all - mean1, axis=1).max(), np.linalg.norm(q_all - mean2, axis=1).max())
    extent = extent if extent > 0 else 1.0
    scale = 1.0 if cfg.use_absolute_scale else extent
    start_mu = (extent / scale) ** 2  # μ starts at the squared extent: 1 in normalised units
    p = (p_all - mean1) / scale
    q = (q_all - mean2) / scale
    if cfg.tuple_test:
        pairs = tuple_filter(p, q, pairs, cfg.tuple_scale, cfg.maximum_tuple_count, np.random.default_rng(cfg.seed))
    if len(pairs) < 3:
        return RegistrationResult(np.eye(4), 0, False, 0.0, float("nan"), int(len(pairs)))

    t_norm = _optimise(p[pairs[:, 0]], q[pairs[:, 1]], cfg, start_mu)
    rot = t_norm[:3, :3]
    transform = np.eye(4)
    transform[:3, :3] = rot
    transform[:3, 3] = scale * t_norm[:3, 3] + mean2 - rot @ mean1
    iterations = cfg.iteration_number
    if cfg.refine_icp is not None:
        refined = icp(p_all, q_all, cfg.refine_icp, init=transform)
        refined.n_correspondences = int(len(pairs))
        refined.iterations += iterations
        return refined
    return RegistrationResult(transform, iterations, True, float("nan"), float("nan"), int(len(pairs)))


@dataclass
class FGRBaseline:
    """Scene flow of the rigid FGR fit: ``flow = T(p) − p`` for every pc1 point."""

    config: FGRConfig = field(default_factory=FGRConfig)
    name: str = ""

    def __post_init__(self) -> None:
        if not self.name:
            self.name = "fgr" if self.config.refine_icp is None else "fgr+icp"

    def register(self, pc1: np.ndarray, pc2: np.ndarray) -> RegistrationResult:
        """The full registration result."""
        return fast_global_registration(pc1, pc2, self.config)

    def __call__(self, pc1: np.ndarray, pc2: np.ndarray) -> np.ndarray:
        return rigid_flow(self.register(pc1, pc2).transform, as_cloud("pc1", pc1))
