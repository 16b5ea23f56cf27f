"""k-nearest neighbours between batched point clouds — the hot spot of stage two.

One entry point, :func:`knn`, with two backends that return the same answer:

- ``"kdtree"``: :class:`scipy.spatial.cKDTree` per batch element (torch's threads for large queries); the fast
  choice on CPU (several times to tens of times faster than a dense distance matrix at 8192 points).
- ``"torch"``: dense squared distances + ``topk``, chunked over the query points so that memory stays
  bounded; the choice on CUDA.
- ``"auto"``: ``"kdtree"`` for CPU tensors, ``"torch"`` otherwise.

Indices never carry gradient, so everything here runs under :func:`torch.no_grad`. The squared distances
returned are exact and sorted ascending (the KD-tree's float64 distances; the dense backend recomputes
them from the chosen neighbours' coordinates, free of ``|a|²+|b|²−2ab`` cancellation). Callers that need
distances *with* gradient gather the neighbours themselves (:func:`training.pointops.group`) and
recompute them.

Coordinates are in any consistent unit (metres in monoflow); distances are in that unit squared.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

from core.errors import InputError, MonoflowError
from training.choices import BACKENDS, KnnBackend  # noqa: F401  (re-exported: the backend names)


class NonFiniteError(MonoflowError):
    """NaN or inf coordinates given to the kNN (scipy's KD-tree would fail with a traceback)."""


# Entries of the (B, chunk, N) distance block the torch backend materialises at once (128 MiB in fp32).
DEFAULT_BLOCK_ELEMENTS = 1 << 25
# Query sets with at least this many (query, neighbour) pairs use KDTREE_WORKERS threads in the KD-tree
# backend; smaller ones use one (thread start-up would cost more than it saves). None: torch's intra-op
# threads (``--threads``), so that a data-parallel process of one thread does not start a thread per core
# beside its siblings; -1: every core.
PARALLEL_MIN_NEIGHBOURS = 1 << 14
KDTREE_WORKERS: int | None = None


def require_finite(where: str, *arrays: np.ndarray, detail: str = "") -> None:
    """Raise :class:`NonFiniteError` (``"<where>: non-finite point coordinates (NaN or inf)<detail>"``) unless every
    coordinate of ``arrays`` is finite: scipy's KD-tree would fail on them with a traceback."""
    if not all(np.isfinite(a).all() for a in arrays):
        raise NonFiniteError(f"{where}: non-finite point coordinates (NaN or inf){detail}")


def kdtree_workers(pairs: int) -> int:
    """KD-tree query threads for ``pairs`` (query, neighbour) pairs (what the KD-tree backend uses; public so
    that benchmarks can print it)."""
    if pairs < PARALLEL_MIN_NEIGHBOURS:
        return 1
    return torch.get_num_threads() if KDTREE_WORKERS is None else KDTREE_WORKERS


def knn(
    query: Tensor,
    ref: Tensor,
    k: int,
    backend: KnnBackend = "auto",
    chunk_size: int | None = None,
) -> tuple[Tensor, Tensor]:
    """The ``k`` nearest points of ``ref`` to every point of ``query``, per batch element.

    Args:
        query: (B, M, D) floating tensor, the points that ask.
        ref: (B, N, D) floating tensor on the same device, the points searched; ``1 <= k <= N``.
        k: number of neighbours.
        backend: ``"auto"`` | ``"kdtree"`` | ``"torch"`` (see the module docstring). ``"kdtree"`` on a
            CUDA tensor works by a round trip through host memory.
        chunk_size: query points per block for the ``"torch"`` backend; default keeps the
            (B, chunk, N) distance block near 2**25 entries.

    Returns:
        ``(dist2, idx)``: (B, M, k) squared Euclidean distances in ``query``'s dtype, ascending along the
        last axis, and (B, M, k) int64 indices into ``ref``'s second axis. Neither requires grad.
        Among exactly tied distances the order of indices is unspecified (backends may differ there).
    """
    _check(query, ref, k, backend)
    if backend == "auto":
        backend = "kdtree" if query.device.type == "cpu" else "torch"
    with torch.no_grad():
        if backend == "kdtree":
            return _knn_kdtree(query, ref, k)
        return _exact_sorted(query, ref, _knn_torch(query, ref, k, chunk_size))


def _check(query: Tensor, ref: Tensor, k: int, backend: str) -> None:
    where = "knn"
    if backend not in BACKENDS:
        raise InputError(where, f"backend must be one of {BACKENDS}, got {backend!r}")
    for name, t in (("query", query), ("ref", ref)):
        if not isinstance(t, Tensor) or t.ndim != 3:
            shape = tuple(t.shape) if isinstance(t, Tensor) else type(t).__name__
            raise InputError(where, f"{name} must be a (B, n, D) tensor, got {shape}")
        if not t.is_floating_point():
            raise InputError(where, f"{name} must be floating point, got {t.dtype}")
    if query.shape[0] != ref.shape[0] or query.shape[2] != ref.shape[2]:
        raise InputError(
            where, f"query {tuple(query.shape)} and ref {tuple(ref.shape)} differ in batch size or dimension"
        )
    if query.device != ref.device:
        raise InputError(where, f"query is on {query.device} but ref on {ref.device}")
    if isinstance(k, bool) or not isinstance(k, int) or not 1 <= k <= ref.shape[1]:
        raise InputError(where, f"k must be an int in [1, {ref.shape[1]}] (points in ref), got {k!r}")


def _knn_kdtree(query: Tensor, ref: Tensor, k: int) -> tuple[Tensor, Tensor]:
    """(dist2, idx) from one cKDTree per batch element (one for all when ``ref`` is one cloud expanded over the
    batch, stride 0: the rigid vote's hypotheses), computed on CPU in float64 (already exact and sorted;
    squared and cast to ``query``'s dtype, which keeps the order)."""
    from scipy.spatial import cKDTree

    shared = ref.shape[0] > 1 and ref.stride(0) == 0  # one cloud for every batch element (an expanded view)
    q = query.detach().to("cpu", torch.float64).numpy()
    r = (ref[:1] if shared else ref).detach().to("cpu", torch.float64).numpy()
    require_finite("knn", q, r, detail=" reached the neighbour search: the net diverged (lower --optim.lr?) or its "
                   "weights or inputs are not finite")
    B, M = q.shape[:2]
    idx = torch.empty(B, M, k, dtype=torch.int64)
    dist2 = torch.empty(B, M, k, dtype=torch.float64)
    if shared:  # one tree serves every batch element
        workers = kdtree_workers(B * M * k)
        d, i = cKDTree(r[0]).query(q.reshape(B * M, -1), k=k, workers=workers)
        idx[:] = torch.from_numpy(i.reshape(B, M, k).astype("int64", copy=False))
        dist2[:] = torch.from_numpy(d.reshape(B, M, k)).square_()
        return dist2.to(query.device, query.dtype), idx.to(query.device)
    workers = kdtree_workers(M * k)
    for b in range(B):
        d, i = cKDTree(r[b]).query(q[b], k=k, workers=workers)
        idx[b] = torch.from_numpy(i.reshape(M, k).astype("int64", copy=False))
        dist2[b] = torch.from_numpy(d.reshape(M, k)).square_()
    return dist2.to(query.device, query.dtype), idx.to(query.device)


def _knn_torch(query: Tensor, ref: Tensor, k: int, chunk_size: int | None) -> Tensor:
    """Indices (B, M, k) from chunked dense squared distances and ``topk``."""
    B, M, _ = query.shape
    N = ref.shape[1]
    if chunk_size is None:
        chunk_size = max(1, DEFAULT_BLOCK_ELEMENTS // max(1, B * N))
    # Centre on the reference cloud: the |q|²+|r|²−2q·r form loses precision far from the origin.
    centre = ref.mean(dim=1, keepdim=True)
    r = ref - centre
    q = query - centre
    r2 = (r * r).sum(-1).unsqueeze(1)  # (B, 1, N)
    rt = r.transpose(1, 2)  # (B, D, N)
    out = torch.empty(B, M, k, dtype=torch.int64, device=query.device)
    for s in range(0, M, chunk_size):
        qc = q[:, s : s + chunk_size]
        d2 = torch.baddbmm(r2, qc, rt, alpha=-2.0)  # |r|² − 2 q·r, (B, m, N)
        d2 += (qc * qc).sum(-1, keepdim=True)
        out[:, s : s + chunk_size] = d2.topk(k, dim=-1, largest=False, sorted=False).indices
    return out


def _exact_sorted(query: Tensor, ref: Tensor, idx: Tensor) -> tuple[Tensor, Tensor]:
    """Recompute squared distances at ``idx`` from coordinates, sort ascending, reorder ``idx``."""
    B, M, k = idx.shape
    flat = ref.reshape(-1, ref.shape[-1])
    offset = (torch.arange(B, device=idx.device) * ref.shape[1]).view(B, 1, 1)
    neighbours = flat.index_select(0, (idx + offset).reshape(-1)).view(B, M, k, -1)
    dist2 = ((neighbours - query.unsqueeze(2)) ** 2).sum(-1)
    dist2, order = dist2.sort(dim=-1, stable=True)
    return dist2, idx.gather(-1, order)
