"""Chamfer, dynamic-static and Laplacian losses with hand-computed values, and the multi-level sum."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from core import geometry as g
from core.errors import ConfigError, InputError
from training.losses import (
    LevelInputs,
    LossWeights,
    chamfer,
    dynamic_static,
    laplacian,
    laplacian_coordinates,
    level_alphas,
    multi_level_loss,
    nearest_sq_dist,
    neighbours,
)
from training.pointops import surface_normals

F64 = torch.float64


def t64(x) -> torch.Tensor:
    return torch.tensor(x, dtype=F64)


# --------------------------------------------------------------------------- Chamfer


def test_chamfer_hand_computed():
    warped = t64([[[0, 0, 0], [1, 0, 0]], [[0, 0, 0], [2, 0, 0]]])
    pc2 = t64([[[0, 0, 1], [3, 0, 0], [1, 1, 0]], [[0, 0, 0.5], [2, 0, 0], [5, 0, 0]]])
    # Element 0, warped -> pc2: (0,0,0): min(1, 9, 2) = 1; (1,0,0): min(2, 4, 1) = 1; mean 1.
    #            pc2 -> warped: (0,0,1): min(1, 2) = 1; (3,0,0): min(9, 4) = 4; (1,1,0): min(2, 1) = 1; mean 2.
    # Element 1, warped -> pc2: 0.25, 0 -> mean 0.125;  pc2 -> warped: 0.25, 0, 9 -> mean 9.25 / 3.
    np.testing.assert_allclose(nearest_sq_dist(warped, pc2).numpy(), [[1, 1], [0.25, 0]])
    np.testing.assert_allclose(nearest_sq_dist(pc2, warped).numpy(), [[1, 4, 1], [0.25, 0, 9]])
    expected = ((1 + 2) + (0.125 + 9.25 / 3)) / 2
    np.testing.assert_allclose(chamfer(warped, pc2).item(), expected, rtol=1e-12)


def test_chamfer_gradient_pulls_towards_nearest_point_and_is_finite_for_duplicates():
    warped = t64([[[0, 0, 0], [0, 0, 0], [2, 0, 0]]]).requires_grad_(True)
    pc2 = t64([[[0, 0, 0], [0, 0, 0], [2, 0, 1]]])  # duplicates on both sides, and exact hits
    loss = chamfer(warped, pc2)
    loss.backward()
    assert torch.isfinite(warped.grad).all()
    # Only (2,0,0) is off: d/dz of its squared distance to (2,0,1) is −2, counted from both directions:
    # warped->pc2 mean over 3 points and pc2->warped mean over 3 points -> −2/3 − 2/3.
    np.testing.assert_allclose(warped.grad[0, 2].numpy(), [0, 0, -4 / 3], atol=1e-12)
    assert (warped.grad[0, :2] == 0).all()


def test_truncated_chamfer_caps_unmatched_points_and_takes_their_gradient_away():
    """``truncate`` τ: the hand-computed pairs of :func:`test_chamfer_hand_computed` with τ = 1.5 m: the
    squared distances 4 and 9 (2 m and 3 m) count as 2.25, the others as they are; the capped points get
    no gradient, the others the paper's."""
    warped = t64([[[0, 0, 0], [1, 0, 0]], [[0, 0, 0], [2, 0, 0]]]).requires_grad_(True)
    pc2 = t64([[[0, 0, 1], [3, 0, 0], [1, 1, 0]], [[0, 0, 0.5], [2, 0, 0], [5, 0, 0]]])
    expected = ((1 + (1 + 2.25 + 1) / 3) + (0.125 + (0.25 + 0 + 2.25) / 3)) / 2
    np.testing.assert_allclose(chamfer(warped, pc2, truncate=1.5).item(), expected, rtol=1e-12)
    assert chamfer(warped, pc2, truncate=math.inf).item() == chamfer(warped, pc2).item()  # the paper's form
    # (5,0,0) of element 1 is 3 m from its nearest warped point (2,0,0): capped, it no longer pulls that point
    far = t64([[[0, 0, 0]], [[2, 0, 0]]])
    pc2_far = t64([[[0, 0, 0]], [[5, 0, 0]]])
    x = far.clone().requires_grad_(True)
    chamfer(x, pc2_far, truncate=1.5).backward()
    assert (x.grad == 0).all()
    x.grad = None
    chamfer(x, pc2_far).backward()
    assert x.grad[1, 0, 0].item() < 0  # untruncated: pulled 3 m towards (5,0,0)
    with pytest.raises(ConfigError, match="chamfer_truncate"):
        LossWeights(chamfer_truncate=-1.0)


def _wall_grid(step: float = 0.5, n: int = 9) -> torch.Tensor:
    """Frame-2 samples of a wall: the plane z = 10 m, an n × n grid ``step`` metres apart, (1, n², 3)."""
    u = torch.arange(n, dtype=F64) * step
    x, y = torch.meshgrid(u, u, indexing="ij")
    return torch.stack([x.ravel(), y.ravel(), torch.full_like(x.ravel(), 10.0)], -1)[None]


def test_surface_normals_of_a_plane_are_its_normal():
    normals = surface_normals(_wall_grid())
    np.testing.assert_allclose(normals[0, :, 2].abs().numpy(), 1.0, atol=1e-9)


def test_plane_chamfer_drops_the_pull_along_the_surface_and_keeps_the_pull_onto_it():
    """A point that lands between two samples of a wall: the plain Chamfer term pulls it along the wall
    onto a sample, the point-to-plane form (λ = 1) does not; a point off the wall is pulled onto it by both,
    and λ blends the two squared distances linearly."""
    wall = _wall_grid()
    between = t64([[[1.2, 1.0, 10.0]]]).requires_grad_(True)  # 0.2 m from the sample (1.0, 1.0)
    chamfer(between, wall, plane=1.0).backward()
    assert between.grad.abs().max().item() < 1e-12
    between.grad = None
    chamfer(between, wall).backward()
    # plain: pulled along the wall, onto its sample (+0.4) and by every sample towards their centre (−1.6)
    np.testing.assert_allclose(between.grad[0, 0].numpy(), [2 * 0.2 - 2 * 0.8, -2 * 1.0, 0], atol=1e-12)
    off = t64([[[1.0, 1.0, 10.3]]]).requires_grad_(True)  # on a sample's normal, 0.3 m off the wall
    chamfer(off, wall, plane=1.0).backward()
    assert off.grad[0, 0, 2].item() > 0 and off.grad[0, 0, :2].abs().max().item() < 1e-12
    # the forward pair (0.3 m along the normal) scores 0.09 in every form; only the wall's other samples,
    # whose nearest warped point lies along the wall, tell the forms apart
    plain, plane, half = (chamfer(off.detach(), wall, plane=lam).item() for lam in (0.0, 1.0, 0.5))
    assert plane < plain
    np.testing.assert_allclose(half, (plain + plane) / 2, rtol=1e-12)
    far = t64([[[1.0, 1.0, 13.0]]])  # 3 m off: the truncation reads the plain distance in every form
    np.testing.assert_allclose(chamfer(far, wall, truncate=1.5, plane=1.0).item(), 2 * 2.25, rtol=1e-12)
    with pytest.raises(ConfigError, match="chamfer_plane"):
        LossWeights(chamfer_plane=1.5)
    with pytest.raises(ConfigError, match="laplacian_plane"):
        LossWeights(laplacian_plane=-0.5)


# --------------------------------------------------------------------------- dynamic-static


def test_dynamic_static_zero_when_consistent_and_hand_value_otherwise():
    gen = torch.Generator().manual_seed(1)
    sf_s = torch.randn(2, 5, 3, generator=gen)
    f_d = torch.randn(2, 5, 3, generator=gen)
    assert dynamic_static(sf_s + f_d, sf_s, f_d).item() == pytest.approx(0.0, abs=1e-12)
    f_o = t64([[[1, 0, 0], [0, 2, 0]]])
    zero = torch.zeros_like(f_o)
    f_d = t64([[[0, 0, 0], [0, 0, 1]]])
    # residuals (1,0,0) -> 1 and (0,2,−1) -> 5: mean 3.
    assert dynamic_static(f_o, zero, f_d).item() == pytest.approx(3.0)
    with pytest.raises(InputError, match="flow_d"):
        dynamic_static(f_o, zero, f_d[:, :1])


# --------------------------------------------------------------------------- Laplacian


def test_laplacian_coordinates_hand_computed():
    pts = t64([[[0, 0, 0], [1, 0, 0], [3, 0, 0]]])
    idx = neighbours(pts, 2)
    assert sorted(idx[0, 0].tolist()) == [1, 2] and sorted(idx[0, 2].tolist()) == [0, 1]
    gamma = laplacian_coordinates(pts, idx)
    # γ(0) = ((1−0) + (3−0))/2 = 2; γ(1) = ((0−1) + (3−1))/2 = 0.5; γ(3) = ((0−3) + (1−3))/2 = −2.5.
    np.testing.assert_allclose(gamma[0, :, 0].numpy(), [2.0, 0.5, -2.5])
    assert (gamma[..., 1:] == 0).all()


def test_neighbours_leave_out_the_point_itself_even_among_duplicates():
    pts = t64([[[0, 0, 0], [0, 0, 0], [1, 0, 0], [5, 0, 0]]])
    idx = neighbours(pts, 1)[0, :, 0].tolist()
    assert idx == [1, 0, 0, 2] or idx == [1, 0, 1, 2]
    for i, row in enumerate(neighbours(pts, 3)[0].tolist()):
        assert i not in row and len(set(row)) == 3


def _cloud(n: int, seed: int) -> torch.Tensor:
    gen = torch.Generator().manual_seed(seed)
    return torch.rand(1, n, 3, generator=gen, dtype=F64) * torch.tensor([4.0, 2.0, 6.0], dtype=F64) + t64([-2, -1, 4])


def test_laplacian_zero_for_rigid_motion_positive_for_non_rigid():
    pc1 = _cloud(80, 0)
    T = torch.as_tensor(g.pose_vec_to_mat(np.array([0.5, -0.2, 1.0, 0.05, 0.1, -0.03])))
    moved = g.transform_points(T, pc1)
    perm = torch.randperm(80, generator=torch.Generator().manual_seed(3))
    pc2 = moved[:, perm]  # pc2's order is its own
    translated = pc1 + t64([0.5, -0.2, 1.0])
    assert laplacian(translated, pc1, translated[:, perm]) < 1e-12
    assert laplacian(moved, pc1, pc2) < 1e-12  # rotation too: γ turns with the cloud
    # The flow stretches x by 1.3 about the centre: the warped cloud's Laplacian no longer matches pc2's.
    stretched = moved.clone()
    stretched[..., 0] = moved[..., 0].mean() + 1.3 * (moved[..., 0] - moved[..., 0].mean())
    bent = moved + 0.2 * torch.sin(3.0 * pc1[..., [1, 2, 0]])
    stretch_loss, bent_loss = laplacian(stretched, pc1, pc2).item(), laplacian(bent, pc1, pc2).item()
    assert stretch_loss > 1e-4 and bent_loss > 1e-4


def test_plane_laplacian_ignores_where_two_samples_of_a_wall_fall_and_sees_a_bump():
    """Two different samples of the same wall at the true (zero) flow: their Laplacians differ along the
    wall, so the paper's term is positive and pulls the points along it; the point-to-plane form (λ = 1) is
    zero there, and positive once a point is pushed off the wall."""
    gen = torch.Generator().manual_seed(0)
    wall = _wall_grid(step=0.5, n=10)[0]

    def sample() -> torch.Tensor:
        jitter = (torch.rand(wall.shape, generator=gen, dtype=F64) - 0.5) * 0.3
        jitter[:, 2] = 0.0
        return (wall + jitter)[None]

    pc1, pc2 = sample(), sample()
    flow = torch.zeros_like(pc1, requires_grad=True)
    plain = laplacian(pc1 + flow, pc1, pc2)
    plain.backward()
    assert plain.item() > 1e-4 and flow.grad[..., :2].abs().max().item() > 1e-4
    flow.grad = None
    plane = laplacian(pc1 + flow, pc1, pc2, plane=1.0)
    plane.backward()
    assert plane.item() < 1e-20 and flow.grad.abs().max().item() < 1e-12
    bump = torch.zeros_like(pc1)
    bump[0, 45, 2] = 0.3
    assert laplacian(pc1 + bump, pc1, pc2, plane=1.0).item() > 1e-4


def test_laplacian_gradient_finite_with_duplicates_and_exact_hits():
    pc1 = _cloud(30, 1)
    pc1[:, 5] = pc1[:, 4]  # a duplicate point in pc1
    pc2 = pc1 + 0.3
    pc2 = torch.cat([pc2, pc2[:, :3]], dim=1)  # duplicates in pc2
    flow = torch.full_like(pc1, 0.3)
    flow[:, 10] += 0.05  # one point off; the others land exactly on pc2 points (distance 0)
    flow.requires_grad_(True)
    loss = laplacian(pc1 + flow, pc1, pc2)
    loss.backward()
    assert torch.isfinite(loss) and loss.item() > 0
    assert torch.isfinite(flow.grad).all() and flow.grad.abs().sum() > 0


# --------------------------------------------------------------------------- multi-level sum

H, W = 16, 24
K_NP = np.array([[20.0, 0.0, 11.5], [0.0, 20.0, 7.5], [0.0, 0.0, 1.0]])


def _level(n: int, seed: int, requires_grad: bool = True) -> LevelInputs:
    gen = torch.Generator().manual_seed(seed)
    K = torch.as_tensor(K_NP, dtype=torch.float32).unsqueeze(0)
    uv = torch.rand(1, n, 2, generator=gen) * torch.tensor([W - 1.0, H - 1.0])
    pc1 = g.backproject(4.0 + 4.0 * torch.rand(1, n, generator=gen), K, uv=uv)
    pc1[:, 1] = pc1[:, 0]  # a duplicate point
    sf_s = torch.tensor([0.05, 0.0, -0.4]).expand(1, n, 3).clone()
    pc2 = pc1 + sf_s + 0.05 * torch.randn(1, n, 3, generator=gen)
    flow_o = sf_s + 0.2 * torch.randn(1, n, 3, generator=gen)
    flow_o[:, 2] = torch.tensor([0.0, 0.0, -20.0])  # this warped point goes behind the camera
    flow_o[:, 3] = torch.tensor([30.0, 0.0, 0.0])  # and this one leaves the image
    flow_d = 0.2 * torch.randn(1, n, 3, generator=gen)
    depth2 = 3.5 + torch.rand(1, H, W, generator=gen)
    depth2[:, :3, :3] = 0.0  # unknown depth
    if requires_grad:
        flow_o.requires_grad_(True)
        flow_d.requires_grad_(True)
    return LevelInputs(pc1=pc1, pc2=pc2, flow_o=flow_o, flow_d=flow_d, static_flow=sf_s, K=K, depth2=depth2)


LEVEL_SIZES = (48, 24, 16, 12)


@pytest.mark.parametrize("norm", ["l1", "l2"])
def test_all_terms_have_finite_gradients_including_masked_and_duplicate_points(norm):
    levels = [_level(n, seed) for seed, n in enumerate(LEVEL_SIZES)]
    # the random depth map is edges everywhere: switch the edge mask off so the depth term is exercised
    total, terms = multi_level_loss(levels, LossWeights(depth_norm=norm, depth_edge_tolerance=0.0))
    total.backward()
    for k, lv in enumerate(levels):
        for name in ("depth1", "depth2", "depth", "ds", "chamfer", "laplacian", "weighted"):
            assert math.isfinite(terms[f"l{k}/{name}"]) and terms[f"l{k}/{name}"] > 0, (k, name)
        assert torch.isfinite(lv.flow_o.grad).all() and torch.isfinite(lv.flow_d.grad).all()
        assert lv.flow_o.grad.abs().sum() > 0 and lv.flow_d.grad.abs().sum() > 0
    # Each term alone reaches the flows.
    for use in ("use_depth", "use_ds", "use_chamfer", "use_laplacian"):
        only = {u: u == use for u in ("use_depth", "use_ds", "use_chamfer", "use_laplacian")}
        lv = _level(24, 7)
        t, _ = multi_level_loss([lv] * 4, LossWeights(**only, depth_norm=norm, depth_edge_tolerance=0.0))
        t.backward()
        assert torch.isfinite(lv.flow_o.grad).all() and lv.flow_o.grad.abs().sum() > 0, use


def test_total_is_the_alpha_beta_weighted_sum_and_alpha_order_flag_reverses_levels():
    assert level_alphas(LossWeights(), 4) == (0.16, 0.08, 0.04, 0.02)
    assert level_alphas(LossWeights(alpha_order="paper"), 4) == (0.02, 0.04, 0.08, 0.16)
    levels = [_level(n, seed, requires_grad=False) for seed, n in enumerate(LEVEL_SIZES)]
    beta = (0.1, 0.1, 1.0, 0.3)
    names = ("depth", "ds", "chamfer", "laplacian")
    totals = {}
    for order in ("released", "paper"):
        total, terms = multi_level_loss(levels, LossWeights(alpha_order=order))
        alphas = level_alphas(LossWeights(alpha_order=order), 4)
        sums = [sum(b * terms[f"l{k}/{n}"] for b, n in zip(beta, names)) for k in range(4)]
        np.testing.assert_allclose(total.item(), sum(a * s for a, s in zip(alphas, sums)), rtol=1e-5)
        np.testing.assert_allclose(terms["total"], total.item(), rtol=1e-6)
        for k in range(4):
            np.testing.assert_allclose(terms[f"l{k}/weighted"], alphas[k] * sums[k], rtol=1e-5)
            np.testing.assert_allclose(terms[f"l{k}/depth"], terms[f"l{k}/depth1"] + terms[f"l{k}/depth2"], rtol=1e-5)
        totals[order] = (total.item(), sums)
    # Same level terms under both orders; the finest level weighs 0.16 (released) vs 0.02 (paper).
    np.testing.assert_allclose(totals["released"][1], totals["paper"][1], rtol=1e-6)
    assert totals["released"][0] != pytest.approx(totals["paper"][0], rel=1e-3)


def test_switches_remove_terms_and_beta_scales_them():
    levels = [_level(n, seed, requires_grad=False) for seed, n in enumerate(LEVEL_SIZES)]
    full, terms = multi_level_loss(levels, LossWeights())
    no_cha, terms_nc = multi_level_loss(levels, LossWeights(use_chamfer=False))
    assert "l0/chamfer" not in terms_nc and "l0/depth" in terms_nc
    alphas = level_alphas(LossWeights(), 4)
    removed = sum(a * 1.0 * terms[f"l{k}/chamfer"] for k, a in enumerate(alphas))
    np.testing.assert_allclose(full.item() - no_cha.item(), removed, rtol=1e-4)
    doubled, _ = multi_level_loss(levels, LossWeights(beta=(0.2, 0.2, 2.0, 0.6)))
    np.testing.assert_allclose(doubled.item(), 2 * full.item(), rtol=1e-5)
    dense, _ = multi_level_loss(levels, LossWeights(knn_backend="torch"))  # the other kNN backend agrees
    np.testing.assert_allclose(dense.item(), full.item(), rtol=1e-5)
    released, terms_r = multi_level_loss(levels, LossWeights(depth_variant="released"))
    assert terms_r["l0/depth"] != pytest.approx(terms["l0/depth"])
    assert terms_r["l0/chamfer"] == pytest.approx(terms["l0/chamfer"])


def test_config_errors():
    with pytest.raises(ConfigError):
        LossWeights(alpha_order="reversed")
    with pytest.raises(ConfigError):
        LossWeights(depth_variant="lidar")
    with pytest.raises(ConfigError):
        LossWeights(beta=(1.0, 1.0))
    with pytest.raises(ConfigError, match="3 levels"):
        multi_level_loss([_level(12, s, False) for s in range(3)], LossWeights())
    with pytest.raises(InputError):
        multi_level_loss([], LossWeights())
    lv = _level(12, 0, False)
    lv.flow_d = lv.flow_d[:, :5]
    with pytest.raises(InputError, match="flow_d"):
        multi_level_loss([lv] * 4, LossWeights())
