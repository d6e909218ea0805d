"""Neighbours among image points on a bucket grid: the ``k`` nearest within a radius
(:func:`nearest_within`) and, per pair of point groups, the closest pair within a radius
(:func:`closest_pairs`).

They are :meth:`scipy.spatial.cKDTree.query` with ``k`` and ``distance_upper_bound``, and
``cKDTree.sparse_distance_matrix`` reduced per group pair, for points in the image plane, with
the same answers (ties: the lower index first).

Why by hand: the family and epipolar planes (:func:`nurbscan.detect.families._plane_at`) ask
for the 32 nearest of 5 x 10^4 labelled edge points within two pitches around each of 2 x 10^4
points, four times per 7.1 MP view with a rig; cKDTree, being general, spent 0.077 s per call
there (the largest single cost of detection with a rig), the grid 0.028 s. The intersections
listed 2.5 x 10^5 close pairs of points only to keep one per pair of lines (0.076 -> 0.048 s
for the stage). Edge points cover the image densely, so a query visits the grid's cells ring by
ring around its own and stops once the next ring lies farther than the ``k``-th neighbour
found. The loops are compiled by numba (:mod:`nurbscan._jit`: on first use, cached on disk)
and release the GIL, so the two edge families run side by side
(:mod:`nurbscan.detect._threads`).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial import cKDTree

from .._jit import njit

__all__ = ["closest_pairs", "nearest_within"]

#: Grid cell size as a share of the search radius (8 cells per radius; 4 and 16 were 10 and
#: 20 % slower on the bench view).
CELLS_PER_RADIUS = 8
#: Most grid cells per point before the grid gives way to cKDTree (points far apart).
MAX_CELLS_PER_POINT = 64


def nearest_within(points: np.ndarray, queries: np.ndarray, k: int,
                   radius: float) -> tuple[np.ndarray, np.ndarray]:
    """The ``k`` nearest ``points`` within ``radius`` of each query point.

    Parameters
    ----------
    points : ndarray, shape (M, 2)
        Camera px.
    queries : ndarray, shape (N, 2)
        Camera px.
    k : int
        Neighbours per query.
    radius : float
        Only neighbours closer than this (px) are returned.

    Returns
    -------
    dist : ndarray, shape (N, k)
        Distances (px), ascending; ``inf`` where fewer than ``k`` lie within ``radius``.
    idx : ndarray, shape (N, k)
        Indices into ``points``; ``M`` where ``dist`` is ``inf``.

    Notes
    -----
    As ``cKDTree(points).query(queries, k, distance_upper_bound=radius)``, which it falls back
    to when the radius is not finite or the points lie too sparsely for a grid; points and
    queries with a coordinate not finite take no part (cKDTree refuses them).
    """
    points = np.ascontiguousarray(points, np.float64).reshape(-1, 2)
    queries = np.ascontiguousarray(queries, np.float64).reshape(-1, 2)
    m, n = len(points), len(queries)
    dist, idx = np.full((n, k), np.inf), np.full((n, k), m, np.int64)
    (sx, sy), (qx, qy) = _columns(points), _columns(queries)
    good = np.isfinite(sx) & np.isfinite(sy)
    ask = np.isfinite(qx) & np.isfinite(qy)
    if not good.any() or not ask.any():
        return dist, idx
    if not good.all() or not ask.all():  # points and queries with a NaN or inf: none found
        keep = np.nonzero(good)[0]
        d, i = nearest_within(points[keep], queries[ask], k, radius)
        dist[ask] = d
        idx[ask] = np.where(i < len(keep), keep[np.minimum(i, len(keep) - 1)], m)
        return dist, idx
    cell = radius / CELLS_PER_RADIUS
    ok = math.isfinite(radius) and radius > 0
    if ok:
        ok = (_span(sx) / cell + 1) * (_span(sy) / cell + 1) <= MAX_CELLS_PER_POINT * m + 4096
    if not ok:
        dist, idx = cKDTree(points).query(queries, k=k, distance_upper_bound=radius)
        return dist.reshape(n, k), idx.reshape(n, k)
    return _grid_query(sx, sy, qx, qy, int(k), float(radius), float(cell))


def _columns(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The x and y columns of ``points`` (M, 2), each contiguous (M,).

    The tests and spans below run over them: numpy reduces an (M, 2) array along its short
    axis row by row (1.5 ms for ``isfinite(p).all(1)`` at M = 10^5 against 0.07 ms for the
    columns), the same values."""
    return points[:, 0].copy(), points[:, 1].copy()


def _span(c: np.ndarray) -> np.float64:
    """``c.max() - c.min()``: the extent of one coordinate, px (float64, as the spans of the
    (M, 2) array were)."""
    return c.max() - c.min()


@njit(cache=True, nogil=True)
def _buckets(sx, sy, cell):
    """The points in a grid of ``cell`` px from their least coordinates: the grid's origin
    ``x0, y0`` and size ``nx, ny``, the points by cell (a stable sort) and each cell's first
    position in that order (``start``, nx * ny + 1)."""
    m = sx.shape[0]
    x0 = sx.min()
    y0 = sy.min()
    nx = int((sx.max() - x0) / cell) + 1
    ny = int((sy.max() - y0) / cell) + 1
    cid = np.empty(m, np.int64)
    for i in range(m):
        cid[i] = int((sy[i] - y0) / cell) * nx + int((sx[i] - x0) / cell)
    order = np.argsort(cid, kind="mergesort")
    start = np.zeros(nx * ny + 1, np.int64)
    for i in range(m):
        start[cid[i] + 1] += 1
    for c in range(nx * ny):
        start[c + 1] += start[c]
    return x0, y0, nx, ny, order, start


@njit(cache=True, nogil=True, inline="always")
def _scan_cell(c, start, px, py, order, x, y, r2, k, bd, bi, cnt, worst):
    """Offer cell ``c``'s points to the sorted list ``bd`` (squared distances), ``bi``."""
    for t in range(start[c], start[c + 1]):
        dx = px[t] - x
        dy = py[t] - y
        d = dx * dx + dy * dy
        if d < r2 and (cnt < k or d <= worst):
            o = order[t]
            if cnt == k and d == worst and o > bi[k - 1]:
                continue
            p = cnt if cnt < k else k - 1
            while p > 0 and (bd[p - 1] > d or (bd[p - 1] == d and bi[p - 1] > o)):
                bd[p] = bd[p - 1]
                bi[p] = bi[p - 1]
                p -= 1
            bd[p] = d
            bi[p] = o
            if cnt < k:
                cnt += 1
            if cnt == k:
                worst = bd[k - 1]
    return cnt, worst


@njit(cache=True, nogil=True)
def _grid_query(sx, sy, qx, qy, k, r, cell):
    """:func:`nearest_within` on a grid of ``cell`` px: bucket the points (a counting sort by
    cell), then per query visit the cells ring by ring, keeping the ``k`` nearest by
    insertion, until a ring's nearest possible point lies beyond the ``k``-th."""
    m = sx.shape[0]
    n = qx.shape[0]
    x0, y0, nx, ny, order, start = _buckets(sx, sy, cell)
    px = sx[order]
    py = sy[order]
    r2 = r * r
    dist = np.full((n, k), np.inf)
    idx = np.full((n, k), m, np.int64)
    bd = np.empty(k)
    bi = np.empty(k, np.int64)
    rings = int(math.ceil(r / cell)) + 1
    for q in range(n):
        x = qx[q]
        y = qy[q]
        cx = int(math.floor((x - x0) / cell))
        cy = int(math.floor((y - y0) / cell))
        cnt = 0
        worst = r2
        for ring in range(rings + 1):
            if ring >= 2:
                near = (ring - 1) * cell
                if near * near > worst:
                    break
            for gy in range(cy - ring, cy + ring + 1):
                if gy < 0 or gy >= ny:
                    continue
                if gy == cy - ring or gy == cy + ring:  # the ring's top and bottom rows
                    for gx in range(max(cx - ring, 0), min(cx + ring + 1, nx)):
                        cnt, worst = _scan_cell(gy * nx + gx, start, px, py, order, x, y, r2,
                                                k, bd, bi, cnt, worst)
                else:  # its left and right cells
                    for gx in (cx - ring, cx + ring):
                        if 0 <= gx < nx:
                            cnt, worst = _scan_cell(gy * nx + gx, start, px, py, order, x, y,
                                                    r2, k, bd, bi, cnt, worst)
        for j in range(cnt):
            dist[q, j] = math.sqrt(bd[j])
            idx[q, j] = bi[j]
    return dist, idx


def closest_pairs(a: np.ndarray, a_group: np.ndarray, b: np.ndarray, b_group: np.ndarray,
                  radius: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per pair of groups, the closest pair of points within ``radius`` px.

    Of all pairs (point ``i`` of ``a``, point ``j`` of ``b``) with ``|a_i - b_j| <= radius``
    the least distant one of each ``(a_group[i], b_group[j])``; among equal distances the
    least ``i``, then ``j``. As the pairs of
    ``cKDTree(a).sparse_distance_matrix(cKDTree(b), radius)`` reduced per group pair
    (:func:`nurbscan.detect.intersections.grid_intersections` finds the crossing of two edge
    lines so), on a bucket grid, without listing every pair.

    Parameters
    ----------
    a, b : ndarray, shapes (M, 2) and (N, 2)
        Camera px (finite).
    a_group, b_group : ndarray of int, shapes (M,) and (N,)
        Each point's group (e.g. its line family).
    radius : float
        px.

    Returns
    -------
    i, j : ndarray of int, shape (K,)
        The pairs, ordered by ``(a_group[i], b_group[j])``.
    dist : ndarray, shape (K,)
        Their distances, px.
    """
    a = np.ascontiguousarray(a, np.float64).reshape(-1, 2)
    b = np.ascontiguousarray(b, np.float64).reshape(-1, 2)
    if not len(a) or not len(b) or not radius > 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0)
    ga, ia = np.unique(np.asarray(a_group), return_inverse=True)
    gb, ib = np.unique(np.asarray(b_group), return_inverse=True)
    cell = float(radius)
    (ax, ay), (bx, by) = _columns(a), _columns(b)
    if len(ga) * len(gb) > MAX_GROUP_PAIRS or (
            (_span(bx) / cell + 1) * (_span(by) / cell + 1) > MAX_CELLS_PER_POINT * len(b) + 4096):
        return _closest_pairs_tree(a, ia, b, ib, len(gb), radius)
    i, j, d = _closest_pairs_grid(ax, ay, ia.astype(np.int64), bx, by, ib.astype(np.int64),
                                  len(ga), len(gb), float(radius), cell)
    return i, j, d


#: Most (a group, b group) pairs for :func:`closest_pairs`' table (16 bytes each).
MAX_GROUP_PAIRS = 1 << 22


def _closest_pairs_tree(a, ia, b, ib, nb: int, radius: float):
    """:func:`closest_pairs` by cKDTree's pair list and a sort (many groups, sparse points)."""
    pairs = cKDTree(a).sparse_distance_matrix(cKDTree(b), radius, output_type="ndarray")
    i, j, d = pairs["i"].astype(np.int64), pairs["j"].astype(np.int64), pairs["v"]
    o = np.lexsort((j, i, d, ia[i] * np.int64(nb) + ib[j]))
    key = (ia[i] * np.int64(nb) + ib[j])[o]
    first = np.r_[True, key[1:] != key[:-1]]
    return i[o][first], j[o][first], d[o][first]


@njit(cache=True, nogil=True)
def _closest_pairs_grid(ax, ay, ag, bx, by, bg, na, nb, r, cell):
    """:func:`closest_pairs` on a grid of ``cell`` (>= ``r``) px: each ``a`` point meets the
    ``b`` points of the 3 x 3 cells around its own; a table of ``na`` x ``nb`` group pairs
    keeps the closest."""
    x0, y0, nx, ny, order, start = _buckets(bx, by, cell)
    best = np.full(na * nb, np.inf)
    bi = np.full(na * nb, -1, np.int64)
    bj = np.full(na * nb, -1, np.int64)
    r2 = r * r
    for i in range(ax.shape[0]):
        x = ax[i]
        y = ay[i]
        cx = int(math.floor((x - x0) / cell))
        cy = int(math.floor((y - y0) / cell))
        for gy in range(max(cy - 1, 0), min(cy + 2, ny)):
            for gx in range(max(cx - 1, 0), min(cx + 2, nx)):
                c = gy * nx + gx
                for t in range(start[c], start[c + 1]):
                    j = order[t]
                    dx = x - bx[j]
                    dy = y - by[j]
                    d2 = dx * dx + dy * dy
                    if d2 <= r2:
                        d = math.sqrt(d2)
                        key = ag[i] * nb + bg[j]
                        if d < best[key] or (d == best[key] and (
                                i < bi[key] or (i == bi[key] and j < bj[key]))):
                            best[key] = d
                            bi[key] = i
                            bj[key] = j
    keep = np.nonzero(bi >= 0)[0]
    return bi[keep], bj[keep], best[keep]
