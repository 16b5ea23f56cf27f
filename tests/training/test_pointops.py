"""training.pointops: gathering, grouping, sampling, inverse-distance interpolation."""

from __future__ import annotations

import pytest
import torch

from core.errors import InputError
from training.pointops import (
    farthest_point_sample,
    first_n_sample,
    gather_points,
    group,
    knn_interpolate,
    random_sample,
    sample_points,
    three_nn_interpolate,
)


def test_gather_and_group_by_hand():
    feat = torch.arange(2 * 4 * 2, dtype=torch.float32).view(2, 4, 2)  # feat[b, n] = [8b+2n, 8b+2n+1]
    idx = torch.tensor([[[3, 0], [1, 1]], [[2, 3], [0, 0]]])  # (B=2, M=2, k=2)
    out = group(feat, idx)
    assert out.shape == (2, 2, 2, 2)
    assert out[0, 0].tolist() == [[6, 7], [0, 1]]
    assert out[1, 0].tolist() == [[12, 13], [14, 15]]
    assert out[1, 1].tolist() == [[8, 9], [8, 9]]
    g = gather_points(feat, torch.tensor([[2, 2, 0], [3, 1, 0]]))
    assert g.tolist() == [[[4, 5], [4, 5], [0, 1]], [[14, 15], [10, 11], [8, 9]]]


def test_group_is_differentiable():
    feat = torch.randn(1, 5, 3, requires_grad=True)
    idx = torch.tensor([[[1, 1, 4]]])
    group(feat, idx).sum().backward()
    assert feat.grad[0, :, 0].tolist() == [0, 2, 0, 0, 1]  # row 1 gathered twice, row 4 once


def test_fps_hand_made_order():
    # On a line: start at 0 (x=0); farthest is x=10; then x=4 (4 m from both); then x=2; then x=1.
    x = torch.tensor([0.0, 1.0, 2.0, 10.0, 4.0])
    pts = torch.stack([x, torch.zeros(5), torch.zeros(5)], -1).unsqueeze(0)
    assert farthest_point_sample(pts, 5).tolist() == [[0, 3, 4, 2, 1]]
    assert farthest_point_sample(pts, 2).tolist() == [[0, 3]]


def test_fps_farthest_point_property_and_distinct():
    g = torch.Generator().manual_seed(0)
    pts = torch.rand(3, 200, 3, generator=g) * 10
    n = 50
    idx = farthest_point_sample(pts, n)
    assert idx.shape == (3, n) and idx.dtype == torch.int64
    assert torch.all(idx[:, 0] == 0)
    for b in range(3):
        assert len(set(idx[b].tolist())) == n
        d = torch.cdist(pts[b].double(), pts[b].double())
        for i in range(1, n):
            min_to_taken = d[:, idx[b, :i]].min(dim=1).values
            assert torch.isclose(min_to_taken[idx[b, i]], min_to_taken.max())
    # batch elements are independent
    assert torch.equal(farthest_point_sample(pts[1:2], n), idx[1:2])


def test_fps_distinct_even_with_duplicates():
    pts = torch.zeros(2, 10, 3)
    pts[:, 5:] = 1.0  # two clusters of 5 identical points
    idx = farthest_point_sample(pts, 10)
    assert idx[0, :2].tolist() == [0, 5]
    for b in range(2):
        assert sorted(idx[b].tolist()) == list(range(10))


def test_first_n_and_random_sampling():
    pts = torch.randn(2, 30, 3)
    assert first_n_sample(pts, 4).tolist() == [[0, 1, 2, 3]] * 2
    a = random_sample(pts, 10, torch.Generator().manual_seed(7))
    b = random_sample(pts, 10, torch.Generator().manual_seed(7))
    assert torch.equal(a, b) and a.shape == (2, 10)
    assert all(len(set(row)) == 10 and min(row) >= 0 and max(row) < 30 for row in a.tolist())
    assert torch.equal(sample_points(pts, 3, "first"), first_n_sample(pts, 3))
    assert torch.equal(sample_points(pts, 3, "fps"), farthest_point_sample(pts, 3))
    with pytest.raises(InputError, match="method must be"):
        sample_points(pts, 3, "poisson")
    with pytest.raises(InputError, match="number of samples"):
        farthest_point_sample(pts, 31)


def test_interpolation_exact_at_reference_points():
    g = torch.Generator().manual_seed(1)
    ref = torch.rand(2, 40, 3, generator=g) * 5
    feat = torch.randn(2, 40, 4, generator=g)
    out = three_nn_interpolate(ref[:, 7:19], ref, feat)
    torch.testing.assert_close(out, feat[:, 7:19], rtol=1e-5, atol=1e-6)


def test_interpolation_reproduces_a_constant_field():
    g = torch.Generator().manual_seed(2)
    ref = torch.rand(1, 60, 3, generator=g) * 5
    query = torch.rand(1, 25, 3, generator=g) * 5
    const = torch.tensor([0.3, -1.2, 7.0]).expand(1, 60, 3)
    torch.testing.assert_close(three_nn_interpolate(query, ref, const), const[:, :25].contiguous())


def test_interpolation_weights_by_hand():
    ref = torch.tensor([[[0.0, 0, 0], [1, 0, 0], [10, 0, 0], [50, 0, 0]]])
    feat = torch.tensor([[[1.0], [2.0], [3.0], [100.0]]])
    query = torch.tensor([[[0.25, 0, 0]]])
    w = torch.tensor([1 / 0.25, 1 / 0.75, 1 / 9.75])  # the point at 50 m is not among the 3 nearest
    expected = (w * torch.tensor([1.0, 2.0, 3.0])).sum() / w.sum()
    torch.testing.assert_close(three_nn_interpolate(query, ref, feat)[0, 0, 0], expected)
    # fewer reference points than k: k is clamped
    torch.testing.assert_close(knn_interpolate(query, ref[:, :2], feat[:, :2], k=3)[0, 0, 0],
                               torch.tensor((4 * 1 + 4 / 3 * 2) / (4 + 4 / 3)))


def test_interpolation_gradients_are_finite_at_coincident_points():
    ref = torch.rand(1, 20, 3, requires_grad=True)
    feat = torch.randn(1, 20, 2, requires_grad=True)
    query = ref.detach()[:, :5].clone().requires_grad_(True)
    three_nn_interpolate(query, ref, feat).sum().backward()
    for t in (ref, feat, query):
        assert t.grad is not None and torch.isfinite(t.grad).all()
    assert feat.grad.abs().sum() > 0


def test_numpy_fps_takes_the_torch_loop_s_points():
    """The CPU path (NumPy) and the PyTorch loop pick the same indices: random clouds, both float types, other
    dimensions, a non-contiguous view, and a lattice with every point twice (exact ties)."""
    from training.pointops import farthest_point_sample_loop, farthest_point_sample_numpy

    g = torch.Generator().manual_seed(1)
    grid = torch.stack(torch.meshgrid(torch.arange(6.0), torch.arange(6.0), torch.arange(3.0), indexing="ij"), -1)
    clouds = [torch.rand(4, 2048, 3, generator=g) * 60 - 30, torch.rand(2, 300, 3, generator=g).double(),
              torch.rand(2, 200, 2, generator=g), torch.rand(3, 400, 3, generator=g)[:, ::2],
              grid.reshape(1, -1, 3).repeat(2, 2, 1)]
    for xyz in clouds:
        n = min(xyz.shape[1], 512)
        got = farthest_point_sample_numpy(xyz, n)
        assert got.dtype == torch.int64 and got.shape == (xyz.shape[0], n)
        assert torch.equal(got, farthest_point_sample_loop(xyz, n))
    assert torch.equal(farthest_point_sample(clouds[0], 64), farthest_point_sample_loop(clouds[0], 64))


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU")
def test_triton_fps_matches_the_loop_on_a_gpu():
    """The Triton kernel (CUDA only) takes the same points as the PyTorch loop, duplicates and ties included,
    and every pick is the farthest remaining point."""
    from training import fps_triton
    from training.pointops import farthest_point_sample_loop

    if fps_triton.triton is None:
        pytest.skip("triton is not installed")
    g = torch.Generator().manual_seed(0)
    grid = torch.stack(torch.meshgrid(torch.arange(8.0), torch.arange(8.0), torch.arange(4.0), indexing="ij"), -1)
    clouds = [torch.rand(3, 8192, 3, generator=g) * 40, torch.rand(2, 1000, 3, generator=g),
              grid.reshape(1, -1, 3).repeat(2, 2, 1)]  # 512 lattice points, each twice: exact ties
    for xyz in clouds:
        xyz = xyz.cuda()
        n = min(xyz.shape[1], 2048)
        fast = fps_triton.farthest_point_sample_triton(xyz, n)
        assert fast.dtype == torch.int64 and fast.shape == (xyz.shape[0], n)
        assert all(len(set(row.tolist())) == n for row in fast.cpu())  # distinct indices
        torch.testing.assert_close(fast, farthest_point_sample_loop(xyz, n), rtol=0, atol=0)
