"""nearest_within against scipy's cKDTree, the oracle it replaces."""

import numpy as np
import pytest
from scipy.spatial import cKDTree

from nurbscan.detect.neighbours import nearest_within


def _oracle(points, queries, k, radius):
    return cKDTree(points).query(queries, k=k, distance_upper_bound=radius)


@pytest.mark.parametrize("k, radius", [(1, 5.0), (8, 20.0), (32, 58.3)])
def test_same_neighbours_as_ckdtree(k, radius):
    rng = np.random.default_rng(k)
    # edge-like points: dense along lines, a sparse scatter, queries inside and outside
    t = rng.uniform(0, 400, 6000)
    lines = np.c_[t, 7.3 * rng.integers(0, 40, 6000) + rng.normal(0, 0.3, 6000)]
    pts = np.r_[lines, rng.uniform(-50, 450, (500, 2))]
    q = np.r_[rng.uniform(-100, 500, (3000, 2)), pts[::7]]
    dist, idx = nearest_within(pts, q, k, radius)
    d0, i0 = _oracle(pts, q, k, radius)
    d0, i0 = d0.reshape(len(q), k), i0.reshape(len(q), k)
    assert np.isinf(dist).any() and np.isfinite(dist).all(1).any()  # both cases occur
    np.testing.assert_array_equal(idx, i0)
    np.testing.assert_array_equal(dist, d0)


def test_ties_by_index_and_fallbacks():
    # integer grid: many equal distances; the k found are the oracle's distances, and among
    # equal distances the lower index comes first
    g = np.stack(np.meshgrid(np.arange(30.0), np.arange(20.0)), -1).reshape(-1, 2)
    perm = np.random.default_rng(1).permutation(len(g))
    pts = g[perm]
    q = np.array([[10.0, 10.0], [0.0, 0.0], [14.5, 3.5], [-3.0, 25.0]])
    dist, idx = nearest_within(pts, q, 12, 6.0)
    d0, _ = _oracle(pts, q, 12, 6.0)
    np.testing.assert_array_equal(dist, d0)
    fin = np.isfinite(dist)
    np.testing.assert_allclose(np.hypot(*(pts[idx[fin]] - q[np.nonzero(fin)[0]]).T), dist[fin])
    same = fin[:, 1:] & (dist[:, 1:] == dist[:, :-1])
    assert same.any() and (idx[:, 1:][same] > idx[:, :-1][same]).all()
    assert (idx[~fin] == len(pts)).all()
    # an infinite radius and a NaN point go to cKDTree, with its shapes
    d1, i1 = nearest_within(pts, q, 3, np.inf)
    d2, i2 = _oracle(pts, q, 3, np.inf)
    np.testing.assert_array_equal(d1, d2)
    bad = np.r_[pts, [[np.nan, 1.0]]]
    d3, i3 = nearest_within(bad, q, 1, 6.0)
    assert d3.shape == (4, 1) and np.isinf(d3[3, 0]) and i3[3, 0] == len(bad)


def test_closest_pairs_per_group_pair():
    """closest_pairs against the brute-force oracle: every pair within the radius, reduced to
    the least distant of each (group of a, group of b); the tree fallback gives the same."""
    import nurbscan.detect.neighbours as nb

    rng = np.random.default_rng(5)
    a = rng.uniform(0, 200, (700, 2))
    b = rng.uniform(0, 200, (600, 2))
    ga, gb = rng.integers(0, 30, 700) * 3, rng.integers(0, 20, 600) - 5  # any integers
    i, j, d = nb.closest_pairs(a, ga, b, gb, 6.0)
    dd = np.linalg.norm(a[:, None] - b[None], axis=2)
    ii, jj = np.nonzero(dd <= 6.0)
    want = {}
    for p, q in zip(ii, jj, strict=True):
        k = (ga[p], gb[q])
        if k not in want or dd[p, q] < dd[want[k]]:
            want[k] = (p, q)
    keys = sorted(want)
    assert len(keys) > 100
    np.testing.assert_array_equal(i, [want[k][0] for k in keys])
    np.testing.assert_array_equal(j, [want[k][1] for k in keys])
    np.testing.assert_allclose(d, [dd[want[k]] for k in keys], rtol=1e-15)
    i2, j2, d2 = nb._closest_pairs_tree(a, np.unique(ga, return_inverse=True)[1], b,
                                        np.unique(gb, return_inverse=True)[1],
                                        len(np.unique(gb)), 6.0)
    np.testing.assert_array_equal(i2, i)
    np.testing.assert_array_equal(j2, j)
    assert [len(x) for x in nb.closest_pairs(a[:0], ga[:0], b, gb, 6.0)] == [0, 0, 0]
