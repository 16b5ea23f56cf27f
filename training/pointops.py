"""Point operations in plain PyTorch (the pointnet2 CUDA ops' jobs): sampling, gathering, grouping,
inverse-distance interpolation.

Farthest point sampling runs as one Triton kernel on CUDA tensors when Triton is installed
(:mod:`training.fps_triton`, ~75× faster on an H100); ``MONOFLOW_TRITON=0`` forces the PyTorch loop.

Layout is channels-last throughout: points (B, N, 3), features (B, N, C). Indices are int64 and index the
second axis of the tensor they were computed for. Sampling indices carry no gradient; gathering and
grouping are differentiable in the gathered tensor. Coordinates in metres (camera frame in monoflow),
but nothing here depends on the frame.
"""

from __future__ import annotations

import os
from typing import Literal

import torch
from torch import Tensor

from core.errors import InputError
from training import fps_triton
from training.knn import KnnBackend, knn

SamplingMethod = Literal["fps", "first", "random"]


def _check_points(where: str, xyz: Tensor, n: int | None = None) -> None:
    if not isinstance(xyz, Tensor) or xyz.ndim != 3:
        shape = tuple(xyz.shape) if isinstance(xyz, Tensor) else type(xyz).__name__
        raise InputError(where, f"points must be a (B, N, D) tensor, got {shape}")
    if n is not None and (isinstance(n, bool) or not isinstance(n, int) or not 1 <= n <= xyz.shape[1]):
        raise InputError(where, f"number of samples must be an int in [1, {xyz.shape[1]}], got {n!r}")


def gather_points(feat: Tensor, idx: Tensor) -> Tensor:
    """Rows of ``feat`` (B, N, C) at ``idx`` (B, M) -> (B, M, C). Differentiable in ``feat``."""
    return group(feat, idx.unsqueeze(-1)).squeeze(2)


def group(feat: Tensor, idx: Tensor) -> Tensor:
    """Rows of ``feat`` (B, N, C) at neighbour indices ``idx`` (B, M, k) -> (B, M, k, C).

    Differentiable in ``feat`` (backward scatters-adds into the gathered rows).
    """
    if feat.ndim != 3 or idx.ndim != 3 or feat.shape[0] != idx.shape[0]:
        raise InputError(
            "group", f"expected feat (B, N, C) and idx (B, M, k), got {tuple(feat.shape)} and {tuple(idx.shape)}"
        )
    B, N, C = feat.shape
    _, M, k = idx.shape
    offset = (torch.arange(B, device=idx.device) * N).view(B, 1, 1)
    flat_idx = (idx + offset).reshape(-1)
    return feat.reshape(B * N, C).index_select(0, flat_idx).view(B, M, k, C)


def farthest_point_sample(xyz: Tensor, n: int) -> Tensor:
    """Farthest point sampling: (B, N, D) -> indices (B, n), int64, no gradient.

    Deterministic: starts at index 0, then repeatedly takes the point farthest (Euclidean) from the
    ones already taken; ties go to the lowest index. Indices are distinct for ``n <= N`` even when points
    coincide. One vectorised step over the batch per sample (``n`` steps in all); on CUDA with Triton, one
    kernel (:mod:`training.fps_triton`).
    """
    _check_points("farthest_point_sample", xyz, n)
    if os.environ.get("MONOFLOW_TRITON", "1") != "0" and fps_triton.available(xyz):
        return fps_triton.farthest_point_sample_triton(xyz, n)
    if xyz.device.type == "cpu" and xyz.dtype in (torch.float32, torch.float64):
        return farthest_point_sample_numpy(xyz, n)
    return farthest_point_sample_loop(xyz, n)


def farthest_point_sample_numpy(xyz: Tensor, n: int) -> Tensor:
    """:func:`farthest_point_sample` as a NumPy loop on a CPU tensor: the same arithmetic as
    :func:`farthest_point_sample_loop` (per-axis squared differences summed x, y, z in order, in ``xyz``'s
    dtype), so the same indices, at a third of the per-step overhead of torch's small operations (the demo's
    training samples ≈1,400 points per step this way)."""
    import numpy as np

    pts = xyz.detach().numpy()
    B, N, _ = pts.shape
    planar = np.ascontiguousarray(pts.transpose(0, 2, 1))  # (B, D, N)
    min_d2 = np.full((B, N), np.inf, dtype=pts.dtype)
    rows = np.arange(B)
    far = np.zeros(B, dtype=np.int64)  # start at index 0
    out = np.empty((B, n), dtype=np.int64)
    diff = np.empty_like(planar)
    d2 = np.empty((B, N), dtype=pts.dtype)
    for s in range(n):
        out[:, s] = far
        np.subtract(planar, planar[rows, :, far][:, :, None], out=diff)
        np.square(diff, out=diff)
        np.copyto(d2, diff[:, 0])
        for axis in range(1, planar.shape[1]):
            np.add(d2, diff[:, axis], out=d2)
        np.minimum(min_d2, d2, out=min_d2)
        min_d2[rows, far] = -1.0  # never pick a taken point again, even among duplicates
        far = min_d2.argmax(axis=1)
    return torch.from_numpy(out)


def farthest_point_sample_loop(xyz: Tensor, n: int) -> Tensor:
    """:func:`farthest_point_sample` as the pure-PyTorch loop, on any device."""
    B, N, D = xyz.shape
    with torch.no_grad():
        pts = xyz.detach()
        planar = pts.transpose(1, 2).contiguous()  # (B, D, N): 3x faster per step than (B, N, D)
        flat = pts.reshape(B * N, D)
        offset = torch.arange(B, device=xyz.device) * N
        min_d2 = torch.full((B * N,), float("inf"), dtype=pts.dtype, device=xyz.device)
        min_view = min_d2.view(B, N)
        diff = torch.empty_like(planar)
        far = offset.clone()  # flat indices of the points just taken; start at index 0
        taken = []
        for _ in range(n):
            taken.append(far)
            torch.sub(planar, flat.index_select(0, far).view(B, D, 1), out=diff)
            diff.square_()
            torch.minimum(min_view, diff.sum(1), out=min_view)
            min_d2.index_fill_(0, far, -1.0)  # never pick a taken point again, even among duplicates
            far = min_view.argmax(dim=-1) + offset
        return torch.stack(taken, dim=1) - offset.unsqueeze(1)


def first_n_sample(xyz: Tensor, n: int) -> Tensor:
    """The first ``n`` points: indices ``0..n-1`` for every batch element, (B, n) int64.

    This is the released port's sampling: its inputs are already a random subset in random order, so
    the first ``n`` are a uniform random sample, and the levels nest (level l+1 = first points of level l).
    """
    _check_points("first_n_sample", xyz, n)
    return torch.arange(n, device=xyz.device).expand(xyz.shape[0], n).contiguous()


def random_sample(xyz: Tensor, n: int, generator: torch.Generator | None = None) -> Tensor:
    """``n`` distinct uniformly random indices per batch element, (B, n) int64; seedable by ``generator``
    (a CPU generator; the indices are moved to ``xyz``'s device)."""
    _check_points("random_sample", xyz, n)
    B, N, _ = xyz.shape
    rows = [torch.randperm(N, generator=generator)[:n] for _ in range(B)]
    return torch.stack(rows).to(xyz.device)


def sample_points(
    xyz: Tensor, n: int, method: SamplingMethod = "fps", generator: torch.Generator | None = None
) -> Tensor:
    """Indices (B, n) of ``n`` points of ``xyz`` by ``method``: ``"fps"`` | ``"first"`` | ``"random"``."""
    if method == "fps":
        return farthest_point_sample(xyz, n)
    if method == "first":
        return first_n_sample(xyz, n)
    if method == "random":
        return random_sample(xyz, n, generator)
    raise InputError("sample_points", f"method must be 'fps', 'first' or 'random', got {method!r}")


def knn_interpolate(
    query_xyz: Tensor,
    ref_xyz: Tensor,
    ref_feat: Tensor,
    k: int = 3,
    eps: float = 1e-10,
    backend: KnnBackend = "auto",
) -> Tensor:
    """Inverse-distance-weighted interpolation of ``ref_feat`` at ``query_xyz`` from its ``k`` nearest
    reference points: ``f(q) = Σ w_j f_j / Σ w_j`` with ``w_j = 1 / max(‖q − p_j‖, eps)``.

    Args:
        query_xyz: (B, M, 3) where to interpolate.
        ref_xyz: (B, N, 3) where the features live; ``k`` is clamped to N.
        ref_feat: (B, N, C) features at ``ref_xyz``.
    Returns:
        (B, M, C). A query coinciding with a reference point gets that point's feature (to ~eps/d);
        a constant field is reproduced exactly (weights sum to one). Differentiable in ``ref_feat`` and,
        through the recomputed distances, in both point sets.
    """
    if ref_feat.ndim != 3 or ref_feat.shape[:2] != ref_xyz.shape[:2]:
        raise InputError(
            "knn_interpolate", f"ref_feat {tuple(ref_feat.shape)} does not match ref_xyz {tuple(ref_xyz.shape)}"
        )
    k = min(k, ref_xyz.shape[1])
    _, idx = knn(query_xyz, ref_xyz, k, backend)
    d2 = ((group(ref_xyz, idx) - query_xyz.unsqueeze(2)) ** 2).sum(-1)  # (B, M, k), with grad
    dist = d2.clamp_min(eps * eps).sqrt()
    w = 1.0 / dist
    w = w / w.sum(-1, keepdim=True)
    return (w.unsqueeze(-1) * group(ref_feat, idx)).sum(2)


def three_nn_interpolate(
    query_xyz: Tensor, ref_xyz: Tensor, ref_feat: Tensor, eps: float = 1e-10, backend: KnnBackend = "auto"
) -> Tensor:
    """PointNet++'s feature propagation weights: :func:`knn_interpolate` with ``k = 3``."""
    return knn_interpolate(query_xyz, ref_xyz, ref_feat, 3, eps, backend)


NORMAL_K = 8
"""Points (the point itself included) whose covariance gives a frame-2 point's surface normal."""


def surface_normals(points: Tensor, k: int = NORMAL_K, backend: KnnBackend = "auto") -> Tensor:
    """Unit normals (B, N, 3) of the surface through each of ``points`` (B, N, 3), sign arbitrary.

    The normal is the direction of least spread of the point's ``k`` nearest points (itself included):
    the eigenvector of the smallest eigenvalue of their covariance. No gradient (the normals are a
    property of the fixed frame-2 cloud). Where fewer than three points span a plane the direction is
    arbitrary; the losses' blend (``loss.chamfer_plane`` < 1) keeps a share of the plain distance there.
    """
    with torch.no_grad():
        _, idx = knn(points, points, min(k, points.shape[1]), backend)
        near = group(points, idx).double()
        centred = near - near.mean(dim=2, keepdim=True)
        _, vectors = torch.linalg.eigh(centred.transpose(-1, -2) @ centred)
        return vectors[..., 0].to(points.dtype)
