"""core.clusters: single-linkage components by a link radius, and the object-sized ones."""

from __future__ import annotations

import numpy as np

from _street import street
from core.clusters import object_clusters, radius_components, view_interior


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


def _box(rng: np.random.Generator, centre, size, n: int) -> np.ndarray:
    return np.asarray(centre) + (rng.random((n, 3)) - 0.5) * np.asarray(size)


def _cars_and_wall(rng: np.random.Generator) -> np.ndarray:
    """Two 4.5 m cars 0.3 m apart, densely sampled (gaps ~0.13 m), a 9.3 m row; a 20 m wall to the right whose
    far end is the view's (it reaches the cloud's farthest depth); far points that span the view."""
    car1 = _box(rng, (-2.0, 0.0, 10.0), (1.8, 1.5, 4.5), 6000)
    car2 = _box(rng, (-2.0, 0.0, 14.8), (1.8, 1.5, 4.5), 6000)
    wall = _box(rng, (6.0, 0.0, 20.0), (0.1, 2.0, 20.0), 8000)
    far = np.c_[np.linspace(-25, 25, 51), np.zeros(51), np.full(51, 30.0)]  # sparse: no component
    return np.concatenate([car1, car2, wall, far])  # the cars are rows 0–5999 and 6000–11999


def test_whole_in_view_objects_may_be_longer_and_touching_ones_are_split():
    """At a 0.8 m link the two cars make one 9.3 m component: no object at 6 m. Whole in view and allowed 12 m,
    it is one object; split down to a 0.2 m link (0.4 m still joins them: the gap is 0.3 m), the cars come apart
    and each is an object. The wall runs out of the view (its far end is the view's): no object at any length
    or link. Without ``whole`` neither rule applies."""
    rng = np.random.default_rng(1)
    pts = _cars_and_wall(rng)
    whole = view_interior(pts, 0.8)
    assert whole[:12000].all() and not whole[12000:20000].all()
    assert object_clusters(pts, max_share=1.0) == []
    assert object_clusters(pts, max_share=1.0, whole_max_extent_m=12.0, min_link_m=0.2) == []  # no ``whole``
    joined = object_clusters(pts, max_share=1.0, whole=whole, whole_max_extent_m=12.0)
    assert [sorted(c.tolist()) for c in joined] == [list(range(12000))]
    longer = object_clusters(pts, max_share=1.0, whole=whole, whole_max_extent_m=40.0)  # still not the wall
    assert [sorted(c.tolist()) for c in longer] == [list(range(12000))]
    split = sorted(object_clusters(pts, max_share=1.0, whole=whole, min_link_m=0.2), key=lambda c: c.min())
    assert len(split) == 2  # at a 0.2 m link a few loose points of each car fall away as noise (< 8 points)
    assert split[0].max() < 6000 <= split[1].min() and split[1].max() < 12000
    assert min(len(c) for c in split) >= 0.99 * 6000
    assert object_clusters(pts, max_share=1.0, whole=whole, min_link_m=0.3) == []  # 0.4 m tried, 0.2 m not


def test_view_interior_keeps_a_margin_from_the_views_own_edges():
    pts = np.array([[0.0, 0, 10], [0.0, 0, 29.5], [0.0, 0, 30], [-10.0, 0, 10], [-9.5, 0, 10], [10.0, 0, 10]])
    inner = view_interior(pts, 0.8)
    # the farthest depth is 30 m: 29.5 m lies within 0.8 m of it; ±45° are the azimuth edges: the point at
    # −43.5° is 0.8 m / 13.8 m = 3.3° from them at its range
    assert inner.tolist() == [True, False, False, False, False, False]
    assert view_interior(np.zeros((0, 3)), 0.8).shape == (0,)
    # a surround sweep cut in range (40 m), not in depth: the points near the range limit are at its edge
    ring = 40.0 * np.c_[np.sin(np.linspace(-3.1, 3.1, 63)), np.zeros(63), np.cos(np.linspace(-3.1, 3.1, 63))]
    side = np.array([[39.5, 0.0, 0.0], [30.0, 0.0, 0.0]])  # 39.5 m and 30 m to the right
    assert view_interior(np.concatenate([ring, side]), 0.8)[-2:].tolist() == [False, True]
