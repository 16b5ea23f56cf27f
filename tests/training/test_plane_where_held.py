"""``loss.plane_where_held``: the plane forms of the Chamfer and Laplacian terms count only where the ego
head's gate holds a point at the rigid motion (training/losses/chamfer.py, laplacian.py, total.py), and the
gate the net reports for it (training/model/ego_motion.py, halflownet.py)."""

from __future__ import annotations

import pytest
import torch

from core.errors import ConfigError
from training.losses import LevelInputs, LossWeights
from training.losses.chamfer import chamfer
from training.losses.laplacian import laplacian
from training.losses.total import level_terms
from training.model.ego_motion import rigid_plus_residual


def _wall(n_side: int = 10, spacing: float = 0.4) -> torch.Tensor:
    """A flat wall of n_side² points at z = 8 m (its normal is ±z), ``spacing`` metres apart."""
    u = torch.arange(n_side, dtype=torch.float64) * spacing
    x, y = torch.meshgrid(u, u, indexing="ij")
    return torch.stack([x.reshape(-1), y.reshape(-1), torch.full((n_side * n_side,), 8.0, dtype=torch.float64)],
                       -1)[None]


def _slid(pc2: torch.Tensor) -> torch.Tensor:
    """pc2's samples slid 0.15 m along the wall (x): on the surface, off every sample."""
    return pc2 + torch.tensor([0.15, 0.0, 0.0], dtype=torch.float64)


def test_a_held_point_counts_along_the_normal_and_a_let_through_point_point_to_point():
    pc2 = _wall()
    warped = _slid(pc2)
    n = warped.shape[1]
    plain = chamfer(warped, pc2).item()
    assert plain > 0.01  # 0.15 m off the samples in the point-to-point form (0.25 m to the far side)
    assert chamfer(warped, pc2, plane=1.0).item() == pytest.approx(0.0, abs=1e-12)  # on the surface
    held, through = torch.ones(1, n, dtype=torch.float64), torch.zeros(1, n, dtype=torch.float64)
    assert chamfer(warped, pc2, plane=1.0, plane_weight1=held).item() == pytest.approx(0.0, abs=1e-12)
    assert chamfer(warped, pc2, plane=1.0, plane_weight1=through).item() == pytest.approx(plain, rel=1e-12)
    # half held: λ scales each point's share, in both directions
    half = chamfer(warped, pc2, plane=1.0, plane_weight1=held / 2).item()
    assert half == pytest.approx(plain / 2, rel=1e-9)


def test_each_pc2_point_takes_the_share_of_its_nearest_warped_point():
    pc2 = _wall()
    warped = _slid(pc2)
    n = warped.shape[1]
    weight = torch.ones(1, n, dtype=torch.float64)
    weight[0, : n // 2] = 0.0  # the first half let through (the rows at x ≤ 1.95 m), the rest held
    value = chamfer(warped, pc2, plane=1.0, plane_weight1=weight)
    # by hand: warped → pc2 counts 0.15² for each let-through point (its nearest sample is its own origin,
    # 0.15 m away; the next is 0.25 m) and 0 for each held one (on the surface); pc2 → warped likewise, as
    # each pc2 point's nearest warped point is its own slid copy: half of each direction's points count 0.15²
    expected = 0.5 * 0.15 ** 2 + 0.5 * 0.15 ** 2
    assert value.item() == pytest.approx(expected, rel=1e-9)


def test_the_laplacian_plane_share_follows_the_weight():
    torch.manual_seed(0)
    pc1 = _wall() + torch.randn(1, 100, 3, dtype=torch.float64) * 0.05
    pc2 = _wall(12, 0.33)
    warped = pc1 + torch.tensor([0.1, 0.0, 0.0], dtype=torch.float64)
    n = pc1.shape[1]
    ones, zeros = torch.ones(1, n, dtype=torch.float64), torch.zeros(1, n, dtype=torch.float64)
    full = laplacian(warped, pc1, pc2, k=6).item()
    along = laplacian(warped, pc1, pc2, k=6, plane=1.0).item()
    assert along < full
    assert laplacian(warped, pc1, pc2, k=6, plane=1.0, plane_weight=ones).item() == pytest.approx(along, rel=1e-12)
    assert laplacian(warped, pc1, pc2, k=6, plane=1.0, plane_weight=zeros).item() == pytest.approx(full, rel=1e-12)


def test_the_head_reports_the_gate_it_applied():
    torch.manual_seed(0)
    p = torch.randn(1, 200, 3, dtype=torch.float64) * 5 + torch.tensor([0.0, 0.0, 15.0], dtype=torch.float64)
    flow = torch.tensor([0.0, 0.0, -1.0], dtype=torch.float64).expand_as(p).clone()
    flow[0, :30] += torch.tensor([2.0, 0.0, 0.0], dtype=torch.float64)  # a mover
    flow = flow + torch.randn_like(flow) * 0.002  # static noise far below σ: gate ≈ (r²/σ²)² ~ 1e-7
    split = rigid_plus_residual(p, flow, sigma=0.1, iterations=4)
    rigid = p @ split.R.transpose(1, 2) + split.t[:, None] - p
    torch.testing.assert_close(split.flow, rigid + split.gate[..., None] * (flow - rigid))
    assert split.gate.shape == (1, 200) and not split.gate.requires_grad
    assert bool((split.gate[0, :30] > 0.99).all()) and bool((split.gate[0, 30:] < 0.01).all())


def _level(gate: torch.Tensor | None) -> LevelInputs:
    pc2 = _wall()
    pc1 = pc2 - torch.tensor([0.0, 0.0, -1.0], dtype=torch.float64)
    flow = torch.tensor([0.15, 0.0, -1.0], dtype=torch.float64).expand_as(pc1).clone()
    z = torch.zeros_like(flow)
    return LevelInputs(pc1=pc1, pc2=pc2, flow_o=flow, flow_d=z, static_flow=z, K=torch.eye(3)[None],
                       depth2=torch.zeros(1, 4, 4), gate_o=gate)


def test_level_terms_scale_both_plane_forms_by_one_minus_the_gate():
    w = dict(use_depth=False, use_ds=False, chamfer_plane=1.0, laplacian_plane=1.0)
    n = 100
    everywhere = level_terms(_level(None), LossWeights(**w))
    point = level_terms(_level(None), LossWeights(use_depth=False, use_ds=False))
    held = level_terms(_level(torch.zeros(1, n, dtype=torch.float64)), LossWeights(**w, plane_where_held=True))
    through = level_terms(_level(torch.ones(1, n, dtype=torch.float64)), LossWeights(**w, plane_where_held=True))
    for term in ("chamfer", "laplacian"):
        assert held[term].item() == pytest.approx(everywhere[term].item(), rel=1e-12, abs=1e-15)
        assert through[term].item() == pytest.approx(point[term].item(), rel=1e-12)
    assert point["chamfer"].item() > 0.01 and everywhere["chamfer"].item() < 1e-12
    with pytest.raises(ConfigError, match="plane_where_held"):
        level_terms(_level(None), LossWeights(**w, plane_where_held=True))
    assert LossWeights().plane_where_held is False
