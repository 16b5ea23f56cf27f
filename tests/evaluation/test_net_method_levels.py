"""NetMethod's ``level``: the flow of a coarser pyramid level, interpolated onto the input points."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from evaluation.methods import NetMethod
from testkit.flow_checkpoint import tiny_flow_checkpoint
from training.pointops import three_nn_interpolate


def _clouds(n: int = 256):
    rng = np.random.default_rng(3)
    pc1 = (rng.random((n, 3)) * [10.0, 2.0, 20.0] + [-5.0, -1.0, 4.0]).astype(np.float32)
    return pc1, pc1 + np.array([0.1, 0.0, -0.8], np.float32)


def test_each_level_returns_that_levels_flow_interpolated_onto_the_input(tmp_path):
    path = tiny_flow_checkpoint(tmp_path / "net.pt")
    pc1, pc2 = _clouds()
    nets = [NetMethod(path, device="cpu", level=lvl) for lvl in range(4)]
    with torch.no_grad():
        p1 = torch.from_numpy(pc1)[None]
        out = nets[0].net(p1, torch.from_numpy(pc2)[None])
    flows = [net(pc1, pc2) for net in nets]
    for lvl, flow in enumerate(flows):
        want = three_nn_interpolate(p1, out.points[lvl], out.flows[lvl].float())[0].numpy()
        assert flow.shape == (len(pc1), 3)
        np.testing.assert_allclose(flow, want, atol=1e-5)
    assert np.allclose(flows[0], NetMethod(path, device="cpu")(pc1, pc2))  # level 0 is the default
    assert not np.allclose(flows[0], flows[3], atol=1e-4)  # the levels differ: the test can tell them apart


def test_a_level_the_net_does_not_have_names_the_checkpoint(tmp_path):
    path = tiny_flow_checkpoint(tmp_path / "net.pt")
    with pytest.raises(ValueError, match=r"net\.pt: level 4 is not one of the net's levels 0\.\.3"):
        NetMethod(path, device="cpu", level=4)
