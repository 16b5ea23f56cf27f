"""core.clusters: single-linkage components by a link radius, and the object-sized ones."""

from __future__ import annotations

import numpy as np

from _street import street
from core.clusters import object_clusters, radius_components


def test_chains_join_and_gaps_split():
    # a chain of points 0.5 m apart (one component at a 0.6 m link), a lone point 3 m beyond, a pair far away
    chain = np.c_[np.arange(5) * 0.5, np.zeros(5), np.zeros(5)]
    pts = np.concatenate([chain, [[5.0, 0, 0], [20.0, 0, 0], [20.3, 0, 0]]])
    label = radius_components(pts, 0.6)
    assert len(set(label[:5])) == 1 and len(set(label)) == 3 and label[6] == label[7] != label[5]
    assert sorted(set(label)) == [0, 1, 2]
    assert len(set(radius_components(pts, 0.25))) == 8  # every gap too wide: each point alone


def test_object_clusters_are_the_object_sized_components():
    """Single-linkage components: the boxes are found whole; the wall (longer than 6 m) and lone points are not."""
    pts, boxes = street(np.random.default_rng(0))
    found = sorted(object_clusters(pts), key=len, reverse=True)
    assert [sorted(c.tolist()) for c in found] == [b.tolist() for b in boxes]
    assert max(len(c) for c in object_clusters(pts, max_extent_m=40.0, max_share=1.0)) == 2000  # the wall, when allowed
    assert object_clusters(pts[:5]) == []
