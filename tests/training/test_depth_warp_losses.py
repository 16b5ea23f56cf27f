"""Inverse warping and SC-SfMLearner's losses: known answers on hand-built images, depths and poses."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from core.geometry import pose_vec_to_mat
from training.depth.config import DepthLossConfig
from training.depth.losses import (
    SSIM_C1,
    SnippetInputs,
    downscale_intrinsics,
    mean_on_mask,
    pairwise_loss,
    smooth_loss,
    snippet_loss,
    ssim_loss,
)
from training.depth.warp import inverse_warp, pixel_to_grid

H, W = 16, 24
K = torch.tensor([[[20.0, 0.0, 11.5], [0.0, 20.0, 7.5], [0.0, 0.0, 1.0]]])


@pytest.fixture(autouse=True)
def one_thread():
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    torch.manual_seed(0)
    yield
    torch.set_num_threads(before)


def translation(tx: float = 0.0, ty: float = 0.0, tz: float = 0.0) -> torch.Tensor:
    T = torch.eye(4)[None]
    T[0, :3, 3] = torch.tensor([tx, ty, tz])
    return T


def test_pixel_to_grid_maps_pixel_centres_to_the_ends():
    uv = torch.tensor([[0.0, 0.0], [W - 1.0, H - 1.0], [(W - 1) / 2, (H - 1) / 2]])
    np.testing.assert_allclose(pixel_to_grid(uv, H, W).numpy(), [[-1, -1], [1, 1], [0, 0]], atol=1e-6)


def test_identity_pose_reproduces_the_reference_exactly():
    ref = torch.rand(1, 3, H, W)
    depth = 1.0 + torch.rand(1, 1, H, W) * 10
    w = inverse_warp(ref, depth, depth * 2, torch.eye(4)[None], K)
    torch.testing.assert_close(w.image, ref, atol=1e-5, rtol=0)
    torch.testing.assert_close(w.projected_depth, depth * 2, atol=1e-4, rtol=0)
    torch.testing.assert_close(w.computed_depth, depth)
    assert bool((w.valid == 1).all())


def test_lateral_translation_on_a_plane_shifts_by_f_t_over_z():
    """Plane at z = 5 m, camera moved so that p_r = p_t + (0.5, 0, 0): u_r = u_t + 20·0.5/5 = u_t + 2 px."""
    ref = torch.rand(1, 3, H, W)
    depth = torch.full((1, 1, H, W), 5.0)
    w = inverse_warp(ref, depth, depth, translation(tx=0.5), K)
    torch.testing.assert_close(w.image[..., : W - 2], ref[..., 2:], atol=1e-5, rtol=0)
    assert bool((w.valid[..., : W - 2] == 1).all()) and bool((w.valid[..., W - 2:] == 0).all())
    torch.testing.assert_close(w.computed_depth, depth)


def test_forward_motion_reduces_depth_and_behind_the_camera_is_invalid():
    depth = torch.full((1, 1, H, W), 5.0)
    w = inverse_warp(torch.rand(1, 3, H, W), depth, depth, translation(tz=-1.0), K)
    torch.testing.assert_close(w.computed_depth, torch.full_like(depth, 4.0))
    w = inverse_warp(torch.rand(1, 3, H, W), depth, depth, translation(tz=-6.0), K)
    assert bool((w.valid == 0).all())


def test_ssim_loss_known_values():
    x = torch.rand(2, 3, H, W)
    assert float(ssim_loss(x, x).abs().max()) < 1e-5
    a, b = 0.2, 0.6  # constant images: σ = 0, so SSIM = (2ab + C1) / (a² + b² + C1)
    s = (2 * a * b + SSIM_C1) / (a * a + b * b + SSIM_C1)
    got = ssim_loss(torch.full((1, 1, H, W), a), torch.full((1, 1, H, W), b))
    torch.testing.assert_close(got, torch.full_like(got, (1 - s) / 2), atol=0, rtol=1e-3)


def test_mean_on_mask_and_its_threshold():
    v = torch.arange(8.0).view(1, 2, 2, 2)  # channel 0: 0..3, channel 1: 4..7
    m = torch.tensor([[[[1.0, 0.0], [0.0, 1.0]]]])
    assert float(mean_on_mask(v, m, 0.0)) == pytest.approx((0 + 3 + 4 + 7) / 4)
    zero = mean_on_mask(v.requires_grad_(), m, 0.5)  # 2 of 4 pixels valid: not more than half
    assert float(zero.detach()) == 0.0 and zero.requires_grad


def test_smoothness_of_a_ramp_and_edge_awareness():
    u = torch.arange(W, dtype=torch.float32)
    disp = (u + 1).expand(1, 1, H, W)  # mean (W + 1) / 2 → normalised step 2 / (W + 1) in x, 0 in y
    flat = torch.zeros(1, 3, H, W)
    assert float(smooth_loss(disp, flat)) == pytest.approx(2 / (W + 1), rel=1e-5)
    assert float(smooth_loss(torch.full((1, 1, H, W), 3.0), torch.rand(1, 3, H, W))) == pytest.approx(0.0, abs=1e-7)
    step = torch.ones(1, 1, H, W)
    step[..., W // 2:] = 2.0  # a disparity edge …
    img = torch.zeros(1, 3, H, W)
    img[..., W // 2:] = 0.5  # … where the image has an edge of 0.5: weight e^-0.5
    assert float(smooth_loss(step, img)) == pytest.approx(float(smooth_loss(step, flat)) * math.exp(-0.5), rel=1e-5)


def test_pairwise_geometry_term_and_a_perfect_warp():
    cfg = DepthLossConfig(with_auto_mask=False, min_valid_fraction=0.0)
    img = torch.rand(1, 3, H, W)
    d_t, d_r = torch.full((1, 1, H, W), 2.0), torch.full((1, 1, H, W), 3.0)
    pl = pairwise_loss(img, img, d_t, d_r, torch.eye(4)[None], K, cfg)
    assert float(pl.geometry) == pytest.approx(1 / 5, rel=1e-5)  # |2 − 3| / (2 + 3)
    assert float(pl.photo) == pytest.approx(0.0, abs=1e-6) and float(pl.valid_fraction) == 1.0
    # auto-masking drops pixels the un-warped (static) reference explains as well: here all of them
    auto = pairwise_loss(img, img, d_t, d_r, torch.eye(4)[None], K, DepthLossConfig(min_valid_fraction=0.0))
    assert float(auto.valid_fraction) == 0.0


def test_true_motion_has_a_lower_loss_than_no_motion():
    """A textured plane at 5 m seen before/after a 0.25 m lateral move (2 px shift): the truth wins."""
    big = torch.rand(1, 3, H, W + 4)
    tgt, ref = big[..., :W], big[..., 2:W + 2]  # ref(u) = tgt(u + 2): ref shows the scene 2 px further left
    depth = torch.full((1, 1, H, W), 5.0)
    l1 = DepthLossConfig(with_auto_mask=False, with_ssim=False, min_valid_fraction=0.0)
    truth = pairwise_loss(tgt, ref, depth, depth, translation(tx=-0.5), K, l1)
    still = pairwise_loss(tgt, ref, depth, depth, torch.eye(4)[None], K, l1)
    assert float(truth.photo) < 1e-5 < 0.1 < float(still.photo)
    full = DepthLossConfig(min_valid_fraction=0.0)  # SSIM windows at the invalid border leave a little
    truth = pairwise_loss(tgt, ref, depth, depth, translation(tx=-0.5), K, full)
    still = pairwise_loss(tgt, ref, depth, depth, torch.eye(4)[None], K, full)
    assert float(truth.photo) < 0.1 * float(still.photo)


def test_downscaled_intrinsics_keep_pixel_centres():
    Ks = downscale_intrinsics(K, 0.5, 0.5)[0]
    # full-res pixel centres 0 and 1 average into half-res pixel 0: their mean 0.5 ↦ 0
    assert float(Ks[0, 2]) == pytest.approx((11.5 + 0.5) * 0.5 - 0.5) and float(Ks[0, 0]) == 10.0


def test_snippet_loss_terms_and_gradients():
    B = 2
    images = [torch.rand(B, 3, 32, 64) for _ in range(3)]
    disps = [[(0.2 + torch.rand(B, 1, 32 // 2**s, 64 // 2**s)).requires_grad_() for s in range(4)] for _ in range(3)]
    vec = (torch.randn(4 * B, 6) * 0.01).requires_grad_()
    Kb = torch.tensor([[40.0, 0, 31.5], [0, 40.0, 15.5], [0, 0, 1]]).expand(B, 3, 3)
    for mode in ("upsample", "downsample"):
        T = pose_vec_to_mat(vec)
        poses = [(T[:B], T[2 * B:3 * B]), (T[B:2 * B], T[3 * B:])]
        cfg = DepthLossConfig(num_scales=4, scale_mode=mode, min_valid_fraction=0.0)
        total, terms = snippet_loss(SnippetInputs(images, disps, poses, Kb), cfg)
        expect = terms["photo"] + 0.1 * terms["smooth"] + 0.5 * terms["geometry"]
        assert float(total.detach()) == pytest.approx(expect, rel=1e-5)
        grads = torch.autograd.grad(total, [vec, disps[1][0], disps[0][3]])
        assert all(float(g.abs().sum()) > 0 for g in grads)


def test_antisymmetric_poses_reverse_pairs_and_price_the_symmetric_part():
    """With ``antisymmetric`` the losses see v(a,b) = (net(a,b) − net(b,a))/2 and −v for the reverse pair; the
    symmetric remainder (net(a,b) + net(b,a))/2 is returned and weighted into the total. An order-blind net
    (same output for both orders) thus shows no motion to the warp and pays its whole output as remainder."""
    from training.depth.data import SnippetBatch
    from training.depth.trainer import forward_snippets

    class PoseNet(torch.nn.Module):  # v(a, b) = [mean(b) − mean(a), 0, 0.5, 0, 0, 0]·0.01: order-aware x, order-blind z
        def forward(self, a, b):
            d = (b - a).mean(dim=(1, 2, 3))
            return torch.stack([d, 0 * d, 0 * d + 0.5, 0 * d, 0 * d, 0 * d], dim=1) * 0.01

    class DepthNet(torch.nn.Module):
        def forward(self, x):
            return torch.ones(x.shape[0], 1, *x.shape[2:])

    images = torch.stack([torch.full((2, 3, 32, 64), v) for v in (0.0, 100.0, 200.0)], dim=1).to(torch.uint8)
    batch = SnippetBatch(images=images, K=K.expand(2, 3, 3).contiguous(), index=torch.arange(2))
    plain = forward_snippets(DepthNet(), PoseNet(), batch)
    anti = forward_snippets(DepthNet(), PoseNet(), batch, antisymmetric=True)
    assert plain.pose_symmetric is None
    (t_prev, prev_t), (t_next, next_t) = anti.poses
    # order-blind z is gone from the warp; the order-aware x survives and flips with the order
    for T in (t_prev, prev_t, t_next, next_t):
        assert torch.allclose(T[:, 2, 3], torch.zeros(2), atol=1e-7)
    torch.testing.assert_close(t_prev[:, 0, 3], -prev_t[:, 0, 3])
    torch.testing.assert_close(t_next[:, 0, 3], -next_t[:, 0, 3])
    assert torch.all(t_next[:, 0, 3] > 0) and torch.all(t_prev[:, 0, 3] < 0)  # each later frame is brighter
    assert torch.allclose(plain.poses[1][0][:, 2, 3], torch.full((2,), 0.005))  # the plain net's z reaches the warp
    # the remainder: |0.005| in z for every one of the 2B pairs
    torch.testing.assert_close(anti.pose_symmetric[:, 2], torch.full((4,), 0.005))
    assert torch.all(anti.pose_symmetric[:, [0, 1, 3, 4, 5]] == 0)
    cfg = DepthLossConfig(pose_antisymmetric=True, pose_symmetric_weight=2.0)
    total, terms = snippet_loss(anti, cfg)
    base, _ = snippet_loss(SnippetInputs(anti.images, anti.disps, anti.poses, anti.K), cfg)
    assert terms["pose_symmetric"] == pytest.approx(0.005)
    assert float(total - base) == pytest.approx(2.0 * 0.005, rel=1e-5)
