"""Chaining edge points into ordered sub-pixel edge lines (method.md section 2).

The edge pixels of each class (vertical rising / falling, horizontal rising / falling) are
linked from each pixel row to the next: pixel (x, y) continues to (x', y + 1) when
``|x' - x - round(s)| <= 1``, ``s`` the edge's step in x per row (the mean of the two pixels'
``-g_y / g_x``, their gradients' tangent direction). For an edge within 27 degrees of upright
``round(s) = 0`` and this is 8-connectivity between rows; a tilted edge (more than one pixel
across per row, as the vertical bands on the teapot's lid) still forms one chain. A vertical
edge meets each pixel row at most once, so a connected component that holds two pixels of one
row has a junction or a spur there: those pixels are removed and the components are formed
again, which splits the chain at the junction. (Horizontal edges: the same with columns and
``-g_x / g_y``.) Chains are therefore split at junctions, at gaps (a missing pixel breaks the
links) and at depth discontinuities (a jump of more than one pixel across the edge between
neighbouring rows). Each chain is ordered along its run (by row for vertical edges, by column
for horizontal ones); chains shorter than ``min_length`` points are dropped.
"""

from __future__ import annotations

import numpy as np

from .._jit import njit
from .decode import small_ints
from .edges import EdgePoints


def _links(run: np.ndarray, acr: np.ndarray, slope: np.ndarray, cls: np.ndarray,
           size: int) -> tuple[np.ndarray, np.ndarray]:
    """Pairs (p, q) of points of one class in neighbouring runs r, r + 1 that continue each
    other: ``|acr_q - acr_p - round((slope_p + slope_q) / 2)| <= 1`` (pixel units)."""
    n = len(run)
    if n == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    base = cls.astype(np.int64) * size + run
    key = base * size + acr
    o = np.argsort(key)
    skey = key[o]
    step = np.rint(slope).astype(np.int64)
    # the keys are distinct (one point per pixel and class): the insertion point of q + 1
    # is that of q, one further where q is there, and one search serves the five offsets
    # (the same pairs; 4 of 5 searches saved)
    distinct = bool(np.all(skey[1:] != skey[:-1]))
    src, dst = [], []
    q = (base + 1) * size + acr + step - 2
    at = np.searchsorted(skey, q)
    here = np.zeros(n, bool)
    for k in range(-2, 3):
        if k > -2:
            q = q + 1
            at = at + here if distinct else np.searchsorted(skey, q)
        j = np.minimum(at, n - 1)
        hit = skey[j] == q
        here = hit & (at < n)
        src.append(np.nonzero(hit)[0])
        dst.append(o[j[hit]])
    p, q = np.concatenate(src), np.concatenate(dst)
    mean = np.rint(0.5 * (slope[p] + slope[q])).astype(np.int64)
    ok = np.abs(acr[q] - acr[p] - mean) <= 1
    return p[ok], q[ok]


def trace_lines(pts: EdgePoints, shape: tuple[int, int], min_length: int = 4,
                max_slope: float = 4.0) -> tuple[np.ndarray, np.ndarray]:
    """Group edge points into ordered chains.

    Parameters
    ----------
    pts : EdgePoints
        Edge points (N,) from :func:`~nurbscan.detect.edges.detect_edge_points`.
    shape : (H, W)
        Image size, px.
    min_length : int
        Fewest points of a kept chain.
    max_slope : float
        Largest step across the edge per step along it (px per px) that the links follow:
        4 is an edge 76 degrees off its run's normal.

    Returns
    -------
    order : ndarray int64 (M,)
        Indices into ``pts`` of the kept points, grouped by chain and ordered along each chain.
    line : ndarray int64 (M,)
        Chain id 0 .. L - 1 of each kept point (non-decreasing).
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    n = len(pts.x)
    if n == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    vert = pts.cls < 2
    run = np.where(vert, pts.iy, pts.ix).astype(np.int64)
    acr = np.where(vert, pts.ix, pts.iy).astype(np.int64)
    gx, gy = pts.gx.astype(np.float64), pts.gy.astype(np.float64)
    with np.errstate(all="ignore"):
        slope = np.clip(np.nan_to_num(np.where(vert, -gy / gx, -gx / gy), posinf=max_slope,
                                      neginf=-max_slope), -max_slope, max_slope)
    size = int(max(shape)) + 8
    p, q = _links(run, acr, slope, pts.cls, size)

    def components(p, q, keep):
        m = keep[p] & keep[q]
        g = coo_matrix((np.ones(int(m.sum())), (p[m], q[m])), shape=(n, n))
        return connected_components(g, directed=False)[1].astype(np.int64)

    keep = np.ones(n, bool)
    comp = components(p, q, keep)
    # a component with two points in one run has a junction or a spur there: drop them
    key = comp * size + run
    _, inv, cnt = np.unique(key, return_inverse=True, return_counts=True)
    keep = cnt[inv] == 1
    comp = components(p, q, keep)
    idx = np.nonzero(keep)[0]
    o = np.lexsort((small_ints(run[idx]), small_ints(comp[idx])))
    idx = idx[o]
    c = comp[idx]
    _, inv, cnt = np.unique(c, return_inverse=True, return_counts=True)
    good = cnt[inv] >= min_length
    idx, inv = idx[good], inv[good]
    _, line = np.unique(inv, return_inverse=True)
    return idx, line.astype(np.int64)


def fit_lines(t: np.ndarray, v: np.ndarray, wts: np.ndarray):
    """Weighted least-squares lines ``v = c0 + c1 t``, one per row of (G, K) arrays.

    Returns c0, c1 (G,) and the weight sums (G,); c0, c1 are finite only where at least two
    distinct ``t`` carry weight.
    """
    return _line_fit(t, v, wts, lambda a: a.sum(1))


def _line_fit(t: np.ndarray, v: np.ndarray, wts: np.ndarray, total):
    """:func:`fit_lines` with the sums of its products taken by ``total`` (array -> sums)."""
    wt = wts * t  # (wts * t * t is evaluated as (wts * t) * t: the same numbers)
    sw = total(wts)
    st = total(wt)
    stt = total(wt * t)
    sv = total(wts * v)
    stv = total(wt * v)
    del wt
    det = sw * stt - st * st
    with np.errstate(all="ignore"):
        c1 = (sw * stv - st * sv) / det
        c0 = (sv - c1 * st) / sw
    return c0, c1, sw


def _window_fit(along: np.ndarray, across: np.ndarray, line: np.ndarray, offs: np.ndarray,
                use: np.ndarray | None = None, weight: np.ndarray | None = None,
                reach: float | None = None, at: np.ndarray | None = None):
    """Least-squares lines ``across = c0 + c1 (along - along_i)`` through the points i + offs
    of each point's chain (those with ``use``, and within ``reach`` px of ``along_i`` if
    given), weighted by ``weight`` (M,) (default 1) (:func:`fit_lines`). Returns c0, c1 (M,),
    the weight sums sw (M,) (the number of points without ``weight``) and the weights
    (M, len(offs)); with ``at`` (Q,) int, for the points i in ``at`` only ((Q,), (Q, K): the
    same numbers, each point's fit is its own). The same numbers as :func:`fit_lines` over
    the (Q, K) windows, bit for bit: a compiled loop over the points (numba) that sums in
    numpy's order (:func:`_row_sums`)."""
    n = len(along)
    i = np.arange(n) if at is None else np.asarray(at, np.int64)
    counts = np.bincount(line)
    stop = np.cumsum(counts)
    first = (stop - counts)[line[i]]
    last = stop[line[i]] - 1
    return _window_fits(np.asarray(along, np.float64), np.asarray(across, np.float64),
                        first, last, i, np.asarray(offs, np.int64),
                        np.zeros(1, np.bool_) if use is None else np.asarray(use, np.bool_),
                        use is not None,
                        np.zeros(1) if weight is None else np.asarray(weight, np.float64),
                        weight is not None, 0.0 if reach is None else float(reach),
                        reach is not None)


@njit(cache=True, nogil=True, inline="always")
def _pairwise_sum(a, k):
    """``a[:k].sum()`` of float64 in numpy's order for k <= 128 (0 plus the pairwise sum: up
    to 8 elements one by one; more in 8 running sums, added as ((r0 + r1) + (r2 + r3)) +
    ((r4 + r5) + (r6 + r7)), then the rest one by one)."""
    if k < 8:
        res = a[0] + 0.0
        for c in range(1, k):
            res += a[c]
        return res
    r0, r1, r2, r3, r4, r5, r6, r7 = a[0], a[1], a[2], a[3], a[4], a[5], a[6], a[7]
    c = 8
    while c < k - k % 8:
        r0 += a[c]
        r1 += a[c + 1]
        r2 += a[c + 2]
        r3 += a[c + 3]
        r4 += a[c + 4]
        r5 += a[c + 5]
        r6 += a[c + 6]
        r7 += a[c + 7]
        c += 8
    res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    for c in range(k - k % 8, k):
        res += a[c]
    return res + 0.0


@njit(cache=True, nogil=True, error_model="numpy")
def _window_fits(along, across, first, last, i, offs, use, has_use, weight, has_weight,
                 reach, has_reach):
    """:func:`_window_fit`'s loop: per point its window's weights and the five sums of
    :func:`_line_fit`, each product formed as there."""
    q, k, n = len(i), len(offs), len(along)
    c0, c1, sw = np.empty(q), np.empty(q), np.empty(q)
    wts = np.empty((q, k))
    w, wt, wtt, wv, wtv = np.empty(k), np.empty(k), np.empty(k), np.empty(k), np.empty(k)
    for p in range(q):
        ip = i[p]
        for c in range(k):
            j = ip + offs[c]
            inside = first[p] <= j <= last[p]
            j = min(max(j, 0), n - 1)
            if has_use:
                inside = inside and use[j]
            dt = along[j] - along[ip]
            if has_reach:
                inside = inside and abs(dt) <= reach
            ww = 1.0 if inside else 0.0
            if has_weight:
                ww *= weight[j]
            v = across[j]
            w[c] = ww
            wt[c] = ww * dt
            wtt[c] = wt[c] * dt
            wv[c] = ww * v
            wtv[c] = wt[c] * v
            wts[p, c] = ww
        s_w, s_t = _pairwise_sum(w, k), _pairwise_sum(wt, k)
        s_tt, s_v, s_tv = _pairwise_sum(wtt, k), _pairwise_sum(wv, k), _pairwise_sum(wtv, k)
        det = s_w * s_tt - s_t * s_t
        slope = (s_w * s_tv - s_t * s_v) / det
        c0[p] = (s_v - slope * s_t) / s_w
        c1[p] = slope
        sw[p] = s_w
    return c0, c1, sw, wts


def _row_sums(a: np.ndarray) -> np.ndarray:
    """``np.sum(a.T, axis=1)`` of a (K, G) float64 array, K <= 128, in numpy's order
    (:func:`_pairwise_sum` of each column; the check that it is numpy's)."""
    a = np.ascontiguousarray(np.asarray(a, np.float64).T)
    return np.array([_pairwise_sum(row, len(row)) for row in a])


def chain_slope(along: np.ndarray, across: np.ndarray, line: np.ndarray, reach: int = 4
                ) -> np.ndarray:
    """Local slope d(across)/d(along) of each chain point (M,), from a least-squares line.

    The line is fitted to the points i - reach .. i + reach of the chain (the point itself
    included); 0 where fewer than 3 points are there. Arrays (M,) ordered by chain
    (:func:`trace_lines`).
    """
    if len(along) == 0:
        return np.zeros(0)
    _, c1, sw, _ = _window_fit(along, across, line, np.arange(-reach, reach + 1))
    return np.where((sw >= 3) & np.isfinite(c1), c1, 0.0)


def chain_normals(x: np.ndarray, y: np.ndarray, vertical: np.ndarray, line: np.ndarray
                  ) -> np.ndarray:
    """Unit normal (M, 2) of each chain point's edge, from its chain's local slope.

    :func:`chain_slope` gives ``s = dx/dy`` along a vertical-band edge (``x = c + s y``) and
    ``dy/dx`` along a horizontal one; the normals are ``(1, -s)`` and ``(-s, 1)``, normalised.
    ``x``, ``y`` (M,) px, ``vertical`` (M,) bool, ``line`` (M,) chain ids, in chain order.
    """
    slope = chain_slope(np.where(vertical, y, x), np.where(vertical, x, y), line)
    nn = np.hypot(1.0, slope)
    return np.where(np.asarray(vertical)[:, None], np.c_[1.0 / nn, -slope / nn],
                    np.c_[-slope / nn, 1.0 / nn])


def smooth_chains(along: np.ndarray, across: np.ndarray, line: np.ndarray,
                  weight: np.ndarray, reach: int = 3) -> np.ndarray:
    """Across-edge position of each point on its chain's local weighted straight line.

    For point i, the points of its chain within ``reach`` px along the edge (``along_i -
    reach .. along_i + reach``, i itself included) are fitted by weighted least squares
    ``across = c0 + c1 (along - along_i)`` and ``c0`` is returned: a local linear
    (Savitzky-Golay-like) smoother along the edge, the points weighted by ``weight``
    (the inverse variance of their position: the squared edge strength, as the sub-pixel
    fit's noise is inversely proportional to the edge contrast). A smooth edge is kept: on an
    edge of curvature ``kappa`` the line is off by ``kappa / 2`` times the weighted mean of
    ``(along - along_i)^2``, at most ``kappa reach^2 / 2`` (``2 kappa``, 0.0067 px for a
    radius of 300 px, with equal weights at ``reach`` 3), while the independent part of the
    points' noise drops (by up to the square root of the window's point count).

    Parameters
    ----------
    along, across : (M,) float
        Point coordinates along and across the edge (y, x for vertical-band edges), px,
        ordered by chain (:func:`trace_lines`).
    line : (M,) int
        Chain of each point.
    weight : (M,) float
        Weight of each point (> 0).
    reach : int
        Half-width of the window along the edge, px.

    Returns
    -------
    (M,) float
        Smoothed across-edge positions, px (the point's own where the fit is undetermined).

    References
    ----------
    .. [1] A. Savitzky and M. J. E. Golay, "Smoothing and differentiation of data by
       simplified least squares procedures", Analytical Chemistry 36(8), 1964.
    """
    if len(along) == 0 or reach <= 0:
        return np.asarray(across, np.float64)
    c0, _, _, _ = _window_fit(along, across, line, np.arange(-reach, reach + 1),
                              weight=np.asarray(weight, np.float64), reach=reach + 0.5)
    return np.where(np.isfinite(c0), c0, across)


def local_residual(along: np.ndarray, across: np.ndarray, line: np.ndarray, reach: int = 4,
                   at: np.ndarray | None = None) -> np.ndarray:
    """Distance of each point from the straight line fitted to its chain neighbours.

    For point i of a chain, the points i - reach .. i + reach of the same chain, i itself left
    out, are fitted by least squares with ``across = c0 + c1 (along - along_i)``; the residual
    is the distance from that line, ``|across_i - c0| / sqrt(1 + c1^2)`` px, perpendicular
    to it (0 where fewer than 3 neighbours exist): a chain tilted by ``atan(c1)`` from its
    sampling axis has its ``across`` noise enlarged by ``sqrt(1 + c1^2)``, and its points'
    distance to the true edge is the perpendicular one. A point off its own chain by more
    than the noise is an outlier (a disturbed profile at a crossing's corner). Arrays (M,)
    ordered by chain as returned by :func:`trace_lines`; with ``at`` (Q,) int, the residuals
    of those points only, (Q,).
    """
    if len(along) == 0 or (at is not None and len(at) == 0):
        return np.zeros(0)
    offs = np.r_[np.arange(-reach, 0), np.arange(1, reach + 1)]
    c0, c1, sw, _ = _window_fit(along, across, line, offs, at=at)
    res = np.abs((across if at is None else across[at]) - c0) / np.hypot(1.0, np.nan_to_num(c1))
    return np.where((sw >= 3) & np.isfinite(res), res, 0.0)


def _end_fit(along: np.ndarray, across: np.ndarray, idx: np.ndarray, step: int, k: int
             ) -> tuple[np.ndarray, np.ndarray]:
    """Position and slope d(across)/d(along) at a chain end from its ``k`` end points."""
    j = idx[:, None] + step * np.arange(k)[None, :]
    t = along[j] - along[idx][:, None]
    v = across[j]
    tm, vm = t.mean(1), v.mean(1)
    with np.errstate(all="ignore"):
        slope = ((t - tm[:, None]) * (v - vm[:, None])).sum(1) / ((t - tm[:, None]) ** 2).sum(1)
    slope = np.nan_to_num(slope)
    return vm - slope * tm, slope


def join_collinear(x: np.ndarray, y: np.ndarray, cls: np.ndarray, line: np.ndarray,
                   max_gap: float, tol: float = 0.8, k: int = 4, slack: float = 0.03,
                   pairs_only: bool = False, span: float | None = None
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Join chains of one edge class that continue each other across a gap.

    A band edge is cut into pieces where a band of the other direction crosses it (the edge
    pixels there belong to a junction or are hidden). Chain ``j`` continues chain ``i`` when
    it is of the same class, starts after ``i`` ends (along the edge: y for vertical edges, x
    for horizontal ones) within ``max_gap`` px, and the straight lines fitted to the ``k``
    end points of each (least squares) predict the other's end point within ``tol`` px
    across the edge. Each chain end takes its nearest admissible continuation, only mutual
    choices are kept, and the chains are merged by connected components (``pairs_only``:
    the (predecessor, successor) chain ids of the kept joins are returned instead).

    Parameters
    ----------
    x, y : (M,) float, cls : (M,) int, line : (M,) int
        Points grouped by chain and ordered along each chain (:func:`trace_lines`).
    span : float, optional
        The spacing of the classes' planes of the end points (beyond every coordinate and
        ``max_gap``); default four times the largest coordinate plus 10 px. The points of a
        part of the classes joined with the span of all give the joins of all among them.

    Returns
    -------
    order : (M,) int64
        Permutation of the points that groups them by joined chain, ordered along it.
    new_line : (M,) int64
        Joined chain id (0 .. L' - 1) of each point of ``order``.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    n = len(x)
    if n == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    nl = int(line.max()) + 1
    counts = np.bincount(line, minlength=nl)
    stop = np.cumsum(counts)
    start = stop - counts
    lcls = cls[start] % 4
    along = np.where(cls < 2, y, x)
    across = np.where(cls < 2, x, y)
    kk = np.minimum(counts, k)
    ok = counts >= 2
    # fits at the ends (k points, fewer for short chains)
    ce = np.zeros(nl)
    se = np.zeros(nl)
    cs = np.zeros(nl)
    ss = np.zeros(nl)
    for kn in np.unique(kk[ok]):
        m = ok & (kk == kn)
        c, s = _end_fit(along, across, stop[m] - 1, -1, int(kn))
        ce[m], se[m] = c, s
        c, s = _end_fit(along, across, start[m], 1, int(kn))
        cs[m], ss[m] = c, s
    ae = along[stop - 1]
    as_ = along[start]
    if span is None:
        span = join_span(x, y)
    # end points and start points in a (class-shifted) plane: along, across
    pe = np.c_[ae + lcls * span, ce]
    ps = np.c_[as_ + lcls * span, cs]
    tree = cKDTree(ps)
    m = min(8, nl)
    dd, jj = tree.query(pe, k=m, distance_upper_bound=max_gap)
    dd, jj = dd.reshape(nl, m), jj.reshape(nl, m)
    ii = np.repeat(np.arange(nl), m).reshape(nl, m)
    valid = np.isfinite(dd) & ok[:, None]
    jj = np.where(valid, jj, 0)
    gap = as_[jj] - ae[ii]
    valid &= ok[jj] & (jj != ii) & (lcls[jj] == lcls[ii]) & (gap > 0.5) & (gap <= max_gap)
    pred_f = ce[ii] + se[ii] * gap
    pred_b = cs[jj] - ss[jj] * gap
    err = np.maximum(np.abs(pred_f - cs[jj]), np.abs(pred_b - ce[ii]))
    valid &= err < tol + slack * gap
    score = np.where(valid, err + 0.01 * gap, np.inf)
    best = np.argmin(score, axis=1)
    has = np.isfinite(score[np.arange(nl), best])
    fwd = np.where(has, jj[np.arange(nl), best], -1)  # i -> j
    # mutual: j's best predecessor is i
    src = np.nonzero(has)[0]
    dst = fwd[src]
    sc = score[src, best[src]]
    o = np.lexsort((sc, dst))
    first = np.r_[True, dst[o][1:] != dst[o][:-1]][:len(o)]
    src, dst = src[o][first], dst[o][first]
    if pairs_only:
        return src.astype(np.int64), dst.astype(np.int64)
    g = coo_matrix((np.ones(len(src)), (src, dst)), shape=(nl, nl))
    _, comp = connected_components(g, directed=False)
    pc = comp[line]
    o = np.lexsort((along, small_ints(pc)))
    _, nl2 = np.unique(pc[o], return_inverse=True)
    return o.astype(np.int64), nl2.astype(np.int64)


def join_span(x: np.ndarray, y: np.ndarray) -> float:
    """:func:`join_collinear`'s spacing of the classes' planes for the points ``x``, ``y``
    (N,): four times their largest coordinate plus 10 px (0 without points)."""
    return float(max(x.max(), y.max()) + 10.0) * 4 if len(x) else 0.0


def neighbour_fit(along: np.ndarray, across: np.ndarray, line: np.ndarray, use: np.ndarray,
                  reach: int = 5, both_sides: bool = True, at: np.ndarray | None = None
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Across-edge position of each point predicted from its chain neighbours' straight line.

    For point i, the points i - reach .. i + reach of the same chain with ``use`` true (i
    itself left out) are fitted by weighted least squares ``across = c0 + c1 (along -
    along_i)``; returns ``c0`` (M,) px and a bool (M,) that is true where at least 3 such
    neighbours exist, on both sides of the point (an interpolation, not an extrapolation).
    Arrays (M,) ordered by chain as returned by :func:`trace_lines`; with ``at`` (Q,) int,
    the results for those points only, (Q,) (the same numbers, computed for them alone).
    """
    if len(along) == 0 or (at is not None and len(at) == 0):
        return np.zeros(0), np.zeros(0, bool)
    offs = np.r_[np.arange(-reach, 0), np.arange(1, reach + 1)]
    c0, _, sw, wts = _window_fit(along, across, line, offs, use, at=at)
    before = (wts[:, :reach] > 0).any(1)
    after = (wts[:, reach:] > 0).any(1)
    ok = (sw >= 3) & ((before & after) | (not both_sides)) & np.isfinite(c0)
    return np.where(ok, c0, across if at is None else across[at]), ok
