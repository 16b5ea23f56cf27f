"""Depth consistency loss (eqs. 7–10) on an analytic scene, hand values, masks and the released variant.

The scene: camera 1 looks at a slanted plane ``nᵀX = c`` and a box (axis-aligned in camera-1
coordinates) that moves by ``m`` between t and t+1; the camera moves by a known ``T_{1→2}``. Both depth
maps are ray-cast exactly (no mesh, no sampling). Ground-truth flow of a point: ``T(X) − X`` on the plane,
``T(X + m) − X`` on the box.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from core import geometry as g
from core.errors import InputError
from training.losses import depth_consistency, depth_consistency_residuals

H, W = 24, 32
K_NP = np.array([[30.0, 0.0, 15.5], [0.0, 30.0, 11.5], [0.0, 0.0, 1.0]])
PLANE_N = np.array([-0.3, 0.4, 1.0])  # nᵀX = c: depth grows to the left and downwards
PLANE_C = 8.0
BOX_LO, BOX_HI = np.array([-1.2, -0.6, 4.5]), np.array([0.4, 0.5, 5.5])
BOX_MOVE = np.array([0.3, 0.05, -0.2])


def _pose() -> np.ndarray:
    return g.pose_vec_to_mat(np.array([0.1, -0.02, -0.5, 0.01, math.radians(2.0), -0.005]))


def _ray_depth(origin: np.ndarray, dirs: np.ndarray, box_shift: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Ray parameter s of the first hit (plane or box) for rays ``origin + s·dirs`` (…, 3); and box-hit mask."""
    s_plane = (PLANE_C - PLANE_N @ origin) / (dirs @ PLANE_N)
    s_plane = np.where(s_plane > 0, s_plane, np.inf)
    with np.errstate(divide="ignore", invalid="ignore"):
        t0 = (BOX_LO + box_shift - origin) / dirs
        t1 = (BOX_HI + box_shift - origin) / dirs
    near = np.minimum(t0, t1).max(-1)
    far = np.maximum(t0, t1).min(-1)
    s_box = np.where((near <= far) & (near > 0), near, np.inf)
    return np.minimum(s_plane, s_box), s_box < s_plane


def render_depths() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exact depth maps D_t, D_{t+1} (H, W) and the box mask of frame t+1."""
    rays = g.backproject(np.ones((H, W)), K_NP)  # K⁻¹[u, v, 1], z = 1
    d1, _ = _ray_depth(np.zeros(3), rays, np.zeros(3))
    T = _pose()
    R, t = T[:3, :3], T[:3, 3]
    origin2 = -R.T @ t  # camera-2 centre in camera-1 coordinates
    d2, box2 = _ray_depth(origin2, rays @ R, BOX_MOVE)  # rays @ R = Rᵀ r, a ray of camera 2 in camera 1
    return d1, d2, box2  # s is the camera-2 depth because the camera-2 ray has z = 1


def scene_points() -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Points of frame t seen at frame t+1's pixel centres, their GT flow, K and both depth maps.

    Every point is taken where frame t+1 sees it, so ``p1 + flow_gt`` projects onto a pixel centre of
    D_{t+1} and its depth is read there exactly (no interpolation error): the loss must be zero.
    """
    d1, d2, box2 = render_depths()
    T = _pose()
    R, t = T[:3, :3], T[:3, 3]
    p_bar = g.backproject(d2, K_NP)[::2, ::2].reshape(-1, 3)  # camera 2
    on_box = box2[::2, ::2].reshape(-1)
    world_t1 = (p_bar - t) @ R  # Rᵀ(p̄ − t): camera-1 coordinates at time t+1
    p1 = world_t1 - np.where(on_box[:, None], BOX_MOVE, 0.0)
    flow = p_bar - p1
    to = lambda a: torch.as_tensor(a, dtype=torch.float64).unsqueeze(0)  # noqa: E731
    return to(p1), to(flow), to(K_NP), to(d2), torch.as_tensor(on_box)


def test_scene_is_what_it_claims():
    d1, d2, box2 = render_depths()
    assert np.isfinite(d1).all() and np.isfinite(d2).all()
    assert 20 < box2.sum() < box2.size - 20  # both the box and the plane are in view
    # A plane pixel of frame t+1, taken back to frame t with the inverse pose, lands on D_t's plane depth.
    p1, flow, _, _, on_box = scene_points()
    plane = p1[0][~on_box].numpy()
    np.testing.assert_allclose(plane @ PLANE_N, PLANE_C, atol=1e-9)
    # The static part of the flow is the camera motion: sf_s = T(p1) − p1 on the plane.
    np.testing.assert_allclose(flow[0][~on_box].numpy(), g.static_flow(plane, _pose()), atol=1e-9)


def test_zero_for_exact_flow_and_decreasing_towards_it():
    p1, flow, K, d2, _ = scene_points()
    exact = depth_consistency(p1 + flow, K, d2)
    assert exact.item() < 1e-20
    assert depth_consistency_residuals(p1 + flow, K, d2)[1].all()  # every point counts, border ones too
    noise = torch.randn(p1.shape, generator=torch.Generator().manual_seed(0), dtype=p1.dtype) * 0.3
    losses = [depth_consistency(p1 + flow + s * noise, K, d2).item() for s in (1.0, 0.5, 0.1)]
    assert losses[0] > losses[1] > losses[2] > 1e-4
    # Most points stay in view (the loss is not shrinking because points drop out).
    _, valid = depth_consistency_residuals(p1 + flow + noise, K, d2)
    assert valid.float().mean() > 0.8


def test_paper_residual_hand_value_on_fronto_parallel_plane():
    # D_{t+1} ≡ 5 m. p̄ at depth 6 m: p̂ = 5·K⁻¹[u', v', 1] = (5/6)·p̄, so ‖p̄ − p̂‖² = ‖p̄‖² / 36.
    K = torch.as_tensor(K_NP).unsqueeze(0)
    d2 = torch.full((1, H, W), 5.0, dtype=torch.float64)
    p = torch.tensor([[[0.6, -0.3, 6.0], [0.0, 0.0, 5.0]]], dtype=torch.float64)
    res2, valid = depth_consistency_residuals(p, K, d2)
    assert valid.all()
    np.testing.assert_allclose(res2[0].numpy(), [(0.36 + 0.09 + 36.0) / 36.0, 0.0], rtol=1e-12)
    np.testing.assert_allclose(depth_consistency(p, K, d2).item(), (0.36 + 0.09 + 36.0) / 72.0, rtol=1e-12)


def _masking_case() -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    K = torch.as_tensor(K_NP, dtype=torch.float32).unsqueeze(0)
    d2 = torch.full((1, H, W), 5.0)
    d2[0, 20:, 25:] = 0.0  # no depth in the bottom-right corner
    d2[0, 0, 0] = float("nan")
    p = torch.tensor(
        [
            [
                [0.5, 0.2, 6.0],  # valid: residual ‖p‖²/36
                [0.5, 0.2, -2.0],  # behind the camera
                [0.0, 0.0, 0.0],  # at the camera centre (z = 0)
                [3.0, 0.0, 5.0],  # u = 33.5 > W − 1: outside the image
                [0.3, 0.3, 5.0],  # u = 17.3, v = 13.3, on the surface: valid, residual 0
                [(28.0 - 15.5) / 30.0 * 5.0, (21.0 - 11.5) / 30.0 * 5.0, 5.0],  # lands on invalid depth
                [(0.4 - 15.5) / 30.0 * 5.0, (0.4 - 11.5) / 30.0 * 5.0, 5.0],  # bilinear weight on the NaN pixel
            ]
        ]
    )
    return p, K, d2


def test_masked_points_do_not_contribute_and_have_finite_zero_gradient():
    p, K, d2 = _masking_case()
    res2, valid = depth_consistency_residuals(p, K, d2)
    assert valid[0].tolist() == [True, False, False, False, True, False, False]
    expected = (0.25 + 0.04 + 36.0) / 36.0 / 2.0  # mean over the two valid points
    p = p.clone().requires_grad_(True)
    loss = depth_consistency(p, K, d2)
    np.testing.assert_allclose(loss.item(), expected, rtol=1e-5)
    loss.backward()
    assert torch.isfinite(p.grad).all()
    assert (p.grad[0, [1, 2, 3, 5, 6]] == 0).all()
    assert p.grad[0, 0].abs().sum() > 0


def test_all_points_masked_gives_zero_with_graph():
    K = torch.as_tensor(K_NP, dtype=torch.float32).unsqueeze(0)
    p = torch.tensor([[[0.0, 0.0, -1.0], [50.0, 0.0, 1.0]]], requires_grad=True)
    loss = depth_consistency(p, K, torch.full((1, H, W), 5.0))
    assert loss.item() == 0.0
    loss.backward()
    assert torch.isfinite(p.grad).all() and (p.grad == 0).all()


def test_per_batch_element_mean_over_valid_points():
    K = torch.as_tensor(K_NP).unsqueeze(0).repeat(2, 1, 1)
    d2 = torch.full((2, H, W), 5.0, dtype=torch.float64)
    p = torch.tensor(
        [[[0.0, 0.0, 6.0], [0.0, 0.0, 7.0]], [[0.0, 0.0, 3.0], [0.0, 0.0, -1.0]]], dtype=torch.float64
    )
    # element 0: (1 + 4) / 2 = 2.5; element 1: only the first point counts: 4. Batch mean 3.25.
    np.testing.assert_allclose(depth_consistency(p, K, d2).item(), 3.25, rtol=1e-12)


def test_border_pixels_are_inside():
    K = torch.as_tensor(K_NP).unsqueeze(0)
    d2 = torch.full((1, H, W), 5.0, dtype=torch.float64)
    corner = g.backproject(torch.tensor([[6.0]], dtype=torch.float64), K, uv=torch.tensor([[[W - 1.0, H - 1.0]]], dtype=torch.float64))
    res2, valid = depth_consistency_residuals(corner, K, d2)
    assert valid.all()
    np.testing.assert_allclose(res2.item(), (corner**2).sum().item() / 36.0, rtol=1e-12)
    beyond = g.backproject(torch.tensor([[6.0]], dtype=torch.float64), K, uv=torch.tensor([[[W - 0.99, 3.0]]], dtype=torch.float64))
    assert not depth_consistency_residuals(beyond, K, d2)[1].any()  # 0.01 px outside: masked


def test_released_variant_backprojects_at_the_source_pixel():
    # Identity camera, fronto-parallel D_{t+1} ≡ 5. p1 on pixel (10, 8) at 5 m moves sideways by dx:
    # the paper's loss is 0 (the point stays on the surface); the released one back-projects at the
    # source pixel, p̂ = p1, so it penalises the sideways motion itself: dx².
    K = torch.as_tensor(K_NP).unsqueeze(0)
    d2 = torch.full((1, H, W), 5.0, dtype=torch.float64)
    p1 = g.backproject(torch.tensor([[5.0]], dtype=torch.float64), K, uv=torch.tensor([[[10.0, 8.0]]], dtype=torch.float64))
    dx = 0.4
    warped = p1 + torch.tensor([dx, 0.0, 0.0], dtype=torch.float64)
    assert depth_consistency(warped, K, d2).item() < 1e-24
    np.testing.assert_allclose(depth_consistency(warped, K, d2, "released", p1).item(), dx**2, rtol=1e-12)
    # A motion along the source ray (no image motion): both variants agree, and are positive.
    radial = p1 * 1.1
    a = depth_consistency(radial, K, d2).item()
    b = depth_consistency(radial, K, d2, "released", p1).item()
    np.testing.assert_allclose(a, b, rtol=1e-12)
    np.testing.assert_allclose(a, 0.01 * (p1**2).sum().item(), rtol=1e-12)


def test_released_variant_clamps_at_the_border_instead_of_masking():
    K = torch.as_tensor(K_NP).unsqueeze(0)
    d2 = torch.full((1, H, W), 5.0, dtype=torch.float64)
    d2[0, :, -1] = 7.0  # the right border column
    p1 = torch.tensor([[[1.0, 0.0, 5.0]]], dtype=torch.float64)  # pixel (21.5, 11.5)
    warped = torch.tensor([[[4.0, 0.0, 5.0]]], dtype=torch.float64)  # u = 39.5 > W − 1
    _, valid = depth_consistency_residuals(warped, K, d2)
    assert not valid.any()
    res2, valid = depth_consistency_residuals(warped, K, d2, "released", p1)
    assert valid.all()
    # Sampled at the clamped pixel (31, 11.5): depth 7; back-projected at the source pixel: 7/5·p1.
    np.testing.assert_allclose(res2.item(), ((7.0 / 5.0 * p1 - warped) ** 2).sum().item(), rtol=1e-12)


def test_released_variant_is_not_zero_at_the_exact_flow():
    p1, flow, K, d2, _ = scene_points()
    assert depth_consistency(p1 + flow, K, d2, "released", p1).item() > 1e-3


def test_bad_input_raises_input_error():
    p1, flow, K, d2, _ = scene_points()
    with pytest.raises(InputError, match="source_points"):
        depth_consistency(p1 + flow, K, d2, "released")
    with pytest.raises(InputError, match="variant"):
        depth_consistency(p1 + flow, K, d2, "other")
    with pytest.raises(InputError, match="depth2"):
        depth_consistency(p1 + flow, K, d2[0])
    with pytest.raises(InputError, match="points_warped"):
        depth_consistency(p1[0], K, d2)


def _step_scene():
    """A 6×8 depth map: 5 m on the left half (u ≤ 3), 50 m on the right; K with f = 10, c = (3.5, 2.5)."""
    import torch

    H, W = 6, 8
    depth = torch.full((1, H, W), 5.0)
    depth[..., 4:] = 50.0
    K = torch.tensor([[[10.0, 0.0, 3.5], [0.0, 10.0, 2.5], [0.0, 0.0, 1.0]]])
    return depth, K


def test_edge_tolerance_masks_samples_straddling_a_depth_edge():
    import torch

    from training.losses.depth_consistency import depth_consistency_residuals

    depth, K = _step_scene()
    # u = 3.5 lies between the 5 m column 3 and the 50 m column 4; u = 1 is inside the 5 m half.
    pts = torch.tensor([[[(3.5 - 3.5) * 5.0 / 10.0, 0.0, 5.0], [(1.0 - 3.5) * 5.0 / 10.0, 0.0, 5.0]]])
    res_plain, valid_plain = depth_consistency_residuals(pts, K, depth)
    assert valid_plain.all()
    assert float(res_plain[0, 0]) == pytest.approx((27.5 - 5.0) ** 2 * (1 + 0.0 + 0.0), rel=1e-5)  # bilinear mix
    res_edge, valid_edge = depth_consistency_residuals(pts, K, depth, edge_tolerance=0.05)
    assert valid_edge.tolist() == [[False, True]]
    assert float(res_edge[0, 1]) == pytest.approx(0.0, abs=1e-9)


def test_l1_norm_is_the_residual_length():
    import torch

    from training.losses.depth_consistency import depth_consistency

    depth, K = _step_scene()
    pts = torch.tensor([[[(1.0 - 3.5) * 6.0 / 10.0, 0.0, 6.0]]], requires_grad=True)  # 1 m behind the 5 m wall
    # residual = (D̂ − z̄)·K⁻¹[u, v, 1] = −1 · (−0.25, 0, 1): length sqrt(1.0625)
    l2 = depth_consistency(pts, K, depth)
    l1 = depth_consistency(pts, K, depth, norm="l1")
    assert float(l2.detach()) == pytest.approx(1.0625, rel=1e-5)
    assert float(l1.detach()) == pytest.approx(1.0625 ** 0.5, abs=2e-3)
    l1.backward()
    assert torch.isfinite(pts.grad).all()
    with pytest.raises(Exception, match="norm"):
        depth_consistency(pts, K, depth, norm="l3")


def test_a_prepared_depth_sampler_gives_the_same_terms_and_the_loss_prepares_one_per_map(monkeypatch):
    """The trainer prepares the batch's depth map once for every level's two depth terms
    (training.losses.total); the residuals, masks and gradients are those of preparing it in each call."""
    import importlib

    total = importlib.import_module("training.losses.total")
    from training.losses.depth_consistency import depth_sampler

    p1, flow, K, d2, _ = scene_points()
    d2 = d2.clone()
    d2[0, :3] = 0.0  # unknown pixels, and an edge between them and the plane
    for tol in (0.0, 0.05):
        got = []
        for sampler in (None, depth_sampler(d2, torch.float64, edges=tol > 0)):
            pts = (p1 + 0.9 * flow).requires_grad_(True)
            res, valid = depth_consistency_residuals(pts, K, d2, edge_tolerance=tol, sampler=sampler)
            res.sum().backward()
            got.append((res.detach(), valid, pts.grad))
        assert valid.any() and not valid.all()
        for a, b in zip(*got):
            assert torch.equal(a, b)
    calls = []
    prepare = depth_sampler
    monkeypatch.setattr(total, "depth_sampler", lambda *a, **k: calls.append(1) or prepare(*a, **k))
    n = p1.shape[1]
    level = total.LevelInputs(pc1=p1, pc2=p1 + flow, flow_o=flow, flow_d=flow * 0.5, static_flow=flow * 0.5, K=K,
                              depth2=d2)
    weights = total.LossWeights(depth_edge_tolerance=0.05, use_chamfer=False, use_laplacian=False)
    loss, terms = total.multi_level_loss([level] * 4, weights)
    assert len(calls) == 1 and n > 0  # one map, four levels, eight depth terms
    alone = total.level_terms(level, weights)
    assert terms["l3/depth"] == float(alone["depth"]) and len(calls) == 2


def test_the_static_anchor_s_check_samples_the_loss_s_prepared_depth_map(monkeypatch):
    """With ``loss.static_anchor`` on, the anchor's verification shares the depth terms' prepared map (one
    preparation for all levels) and verifies the same points as preparing its own."""
    import importlib

    total = importlib.import_module("training.losses.total")
    from training.losses.depth_consistency import depth_sampler
    from training.losses.static_anchor import static_anchor, verified_static

    p1, flow, K, d2, _ = scene_points()
    d2 = d2.clone()
    d2[0, :3] = 0.0
    own = verified_static(p1, flow, K, d2, edge_tolerance=0.05)
    shared = verified_static(p1, flow, K, d2, edge_tolerance=0.05, sampler=depth_sampler(d2, p1.dtype, edges=True))
    assert own.any() and not own.all() and torch.equal(own, shared)
    calls = []
    prepare = depth_sampler
    monkeypatch.setattr(total, "depth_sampler", lambda *a, **k: calls.append(1) or prepare(*a, **k))
    level = total.LevelInputs(pc1=p1, pc2=p1 + flow, flow_o=0.8 * flow, flow_d=flow * 0.5, static_flow=flow, K=K,
                              depth2=d2)
    weights = total.LossWeights(depth_edge_tolerance=0.05, use_chamfer=False, use_laplacian=False, static_anchor=1.0)
    _, terms = total.multi_level_loss([level] * 4, weights)
    assert len(calls) == 1  # one map: four levels' depth terms and anchor checks
    assert terms["l0/anchor"] == float(static_anchor(0.8 * flow, flow, own))
