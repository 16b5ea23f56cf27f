"""Shared assertion of the stereo-split writers' tests (benchmarks/real_stereo.py, benchmarks/synth_stereo.py)."""

from __future__ import annotations

import numpy as np


def assert_flownet3d_holds_the_same_pairs(hpl, fn3d) -> None:
    """Each scene of the FlowNet3D-layout split ``fn3d`` holds the pairs the ``hplflownet`` reader keeps of the same
    scene of ``hpl`` (pc1, flow and ``moving`` row for row once both are sorted by pc1), and its frame 2 is the same
    points moved in rows of their own order (not paired with frame 1's rows)."""
    assert fn3d.fmt == "flownet3d" and len(fn3d) == len(hpl)
    for a, b in zip(hpl, fn3d):
        order_a, order_b = np.lexsort(a.pc1.T), np.lexsort(b.pc1.T)
        np.testing.assert_allclose(b.pc1[order_b], a.pc1[order_a], atol=1e-5)
        np.testing.assert_allclose(b.flow[order_b], a.flow[order_a], atol=1e-5)
        np.testing.assert_array_equal(b.moving[order_b], a.moving[order_a])
        moved = b.pc1 + b.flow
        assert not np.allclose(b.pc2, moved)  # the rows are not paired ...
        np.testing.assert_allclose(b.pc2[np.lexsort(b.pc2.T)], moved[np.lexsort(moved.T)], atol=1e-5)  # ... the points are
