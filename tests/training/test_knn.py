"""training.knn: both backends against brute force and against each other."""

from __future__ import annotations

import pytest
import torch

from core.errors import InputError
from training.knn import knn


def brute_force(query: torch.Tensor, ref: torch.Tensor, k: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Float64 all-pairs answer, explicit differences (no |a|²+|b|²-2ab)."""
    d2 = ((query.double().unsqueeze(2) - ref.double().unsqueeze(1)) ** 2).sum(-1)
    d2, idx = d2.sort(dim=-1, stable=True)
    return d2[..., :k], idx[..., :k]


def assert_same_neighbours(d_a, i_a, d_b, i_b, rtol=1e-5, atol=1e-6):
    """Same distances; same indices wherever the distance is not tied with a neighbour's."""
    torch.testing.assert_close(d_a.double(), d_b.double(), rtol=rtol, atol=atol)
    d = d_b.double()
    gap = torch.full_like(d, float("inf"))
    gap[..., 1:] = d[..., 1:] - d[..., :-1]
    gap[..., :-1] = torch.minimum(gap[..., :-1], d[..., 1:] - d[..., :-1])
    clear = gap > 1e-4 * (1 + d)
    assert clear.float().mean() > 0.9  # the check below must actually bite
    assert torch.equal(i_a[clear], i_b[clear])


@pytest.mark.parametrize("backend", ["kdtree", "torch", "auto"])
def test_against_brute_force(backend):
    g = torch.Generator().manual_seed(0)
    ref = torch.rand(2, 500, 3, generator=g) * torch.tensor([20.0, 3.0, 35.0])  # camera-like extent, metres
    query = torch.rand(2, 123, 3, generator=g) * torch.tensor([20.0, 3.0, 35.0])
    d2, idx = knn(query, ref, 16, backend)
    assert d2.shape == idx.shape == (2, 123, 16)
    assert idx.dtype == torch.int64 and d2.dtype == torch.float32
    assert not d2.requires_grad and not idx.requires_grad
    assert torch.all(d2[..., 1:] >= d2[..., :-1])  # ascending
    bd2, bidx = brute_force(query, ref, 16)
    assert_same_neighbours(d2, idx, bd2, bidx)


def test_one_cloud_expanded_over_the_batch_gives_every_element_its_own_answer():
    """A ref expanded over the batch (stride 0, the rigid vote's hypotheses) is searched with one KD-tree; the
    answer is the one a contiguous copy gets, and each batch element keeps its own queries."""
    g = torch.Generator().manual_seed(4)
    cloud = torch.rand(1, 400, 3, generator=g, dtype=torch.float64) * 20.0
    query = torch.rand(5, 90, 3, generator=g, dtype=torch.float64) * 20.0
    shared = cloud.expand(5, -1, -1)
    assert shared.stride(0) == 0
    d_s, i_s = knn(query, shared, 4, "kdtree")
    d_c, i_c = knn(query, shared.contiguous(), 4, "kdtree")
    assert torch.equal(i_s, i_c) and torch.equal(d_s, d_c)
    bd2, bidx = brute_force(query, shared, 4)
    assert_same_neighbours(d_s, i_s, bd2, bidx)


def test_backends_agree_far_from_origin_and_chunked():
    """Points 30 m away with cm spacing: the torch backend must centre before |a|²+|b|²-2ab."""
    g = torch.Generator().manual_seed(1)
    ref = torch.rand(1, 2000, 3, generator=g) * 2.0 + torch.tensor([10.0, 1.0, 30.0])
    query = ref[:, :300] + 0.005 * torch.randn(1, 300, 3, generator=g)
    d_kd, i_kd = knn(query, ref, 32, "kdtree")
    d_t, i_t = knn(query, ref, 32, "torch", chunk_size=7)  # many uneven chunks
    assert_same_neighbours(d_t, i_t, d_kd, i_kd)
    bd2, bidx = brute_force(query, ref, 32)
    assert_same_neighbours(d_kd, i_kd, bd2, bidx)


def test_hand_made_example():
    ref = torch.tensor([[[0.0, 0, 0], [1, 0, 0], [0, 2, 0], [0, 0, 3]]])
    query = torch.tensor([[[0.9, 0, 0], [0, 0, 2.9]]])
    for backend in ("kdtree", "torch"):
        d2, idx = knn(query, ref, 2, backend)
        assert idx.tolist() == [[[1, 0], [3, 0]]]
        torch.testing.assert_close(d2, torch.tensor([[[0.01, 0.81], [0.01, 8.41]]]))


def test_self_query_and_k_equals_n():
    pts = torch.randn(3, 40, 3, generator=torch.Generator().manual_seed(2))
    for backend in ("kdtree", "torch"):
        d2, idx = knn(pts, pts, 40, backend)
        assert torch.equal(idx[..., 0], torch.arange(40).expand(3, 40))  # itself first
        assert torch.all(d2[..., 0] == 0)
        assert torch.equal(idx.sort(-1).values, torch.arange(40).expand(3, 40, 40))  # k = N: a permutation


def test_k1_and_float64():
    ref = torch.randn(2, 50, 3, dtype=torch.float64)
    query = torch.randn(2, 10, 3, dtype=torch.float64)
    d_kd, i_kd = knn(query, ref, 1, "kdtree")
    d_t, i_t = knn(query, ref, 1, "torch")
    assert d_kd.dtype == torch.float64 and d_kd.shape == (2, 10, 1)
    assert torch.equal(i_kd, i_t)
    torch.testing.assert_close(d_kd, d_t)


def test_distances_do_not_track_grad_but_callers_can_regather():
    ref = torch.randn(1, 30, 3, requires_grad=True)
    query = torch.randn(1, 5, 3)
    d2, idx = knn(query, ref, 4)
    assert not d2.requires_grad
    regathered = ((ref[0][idx[0]] - query[0].unsqueeze(1)) ** 2).sum(-1)
    torch.testing.assert_close(regathered.detach(), d2[0])
    regathered.sum().backward()
    assert ref.grad is not None and ref.grad.abs().sum() > 0


@pytest.mark.parametrize(
    "query, ref, k, backend, message",
    [
        (torch.zeros(1, 5, 3), torch.zeros(1, 4, 3), 5, "auto", "k must be"),
        (torch.zeros(1, 5, 3), torch.zeros(1, 4, 3), 0, "auto", "k must be"),
        (torch.zeros(5, 3), torch.zeros(1, 4, 3), 2, "auto", "query must be a (B, n, D)"),
        (torch.zeros(2, 5, 3), torch.zeros(1, 4, 3), 2, "auto", "differ in batch"),
        (torch.zeros(1, 5, 2), torch.zeros(1, 4, 3), 2, "auto", "differ in batch size or dimension"),
        (torch.zeros(1, 5, 3, dtype=torch.int64), torch.zeros(1, 4, 3), 2, "auto", "floating point"),
        (torch.zeros(1, 5, 3), torch.zeros(1, 4, 3), 2, "faiss", "backend must be"),
    ],
)
def test_bad_input(query, ref, k, backend, message):
    with pytest.raises(InputError, match=message.replace("(", r"\(").replace(")", r"\)")):
        knn(query, ref, k, backend)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
def test_cuda_matches_cpu():
    g = torch.Generator().manual_seed(3)
    ref = torch.rand(2, 3000, 3, generator=g) * 30
    query = torch.rand(2, 1000, 3, generator=g) * 30
    d_cpu, i_cpu = knn(query, ref, 32, "kdtree")
    d_gpu, i_gpu = knn(query.cuda(), ref.cuda(), 32)  # auto -> torch on CUDA
    assert i_gpu.device.type == "cuda"
    assert_same_neighbours(d_gpu.cpu(), i_gpu.cpu(), d_cpu, i_cpu)


def test_kdtree_threads_follow_torch_s_threads(monkeypatch):
    """A data-parallel process of one thread (the demo's training) queries with one thread, not one per core."""
    import training.knn as knn_module

    threads = torch.get_num_threads()
    try:
        torch.set_num_threads(1)
        assert knn_module.kdtree_workers(knn_module.PARALLEL_MIN_NEIGHBOURS) == 1
        torch.set_num_threads(2)
        assert knn_module.kdtree_workers(knn_module.PARALLEL_MIN_NEIGHBOURS) == 2
        assert knn_module.kdtree_workers(knn_module.PARALLEL_MIN_NEIGHBOURS - 1) == 1  # small queries: one thread
        monkeypatch.setattr(knn_module, "KDTREE_WORKERS", -1)
        assert knn_module.kdtree_workers(knn_module.PARALLEL_MIN_NEIGHBOURS) == -1  # an explicit setting wins
    finally:
        torch.set_num_threads(threads)


def test_non_finite_points_are_one_named_error_in_the_kd_tree_and_the_vote():
    """NaN or inf coordinates reach scipy's KD-tree as one NonFiniteError naming the caller, not a traceback."""
    from training.knn import NonFiniteError
    from training.model.translation_vote import histogram_peaks

    pts = torch.rand(1, 64, 3)
    bad = pts.clone()
    bad[0, 5, 1] = float("nan")
    with pytest.raises(NonFiniteError, match=r"^knn: non-finite point coordinates \(NaN or inf\) reached the neighbour"):
        knn(bad, pts, 4, backend="kdtree")
    bad[0, 5, 1] = float("inf")
    with pytest.raises(NonFiniteError, match=r"^translation vote: non-finite point coordinates \(NaN or inf\)$"):
        histogram_peaks(pts, bad)
    d, i = knn(pts, pts, 1, backend="kdtree")  # finite points pass: each point is its own nearest
    assert torch.equal(i[0, :, 0], torch.arange(64)) and float(d.max()) == 0.0
