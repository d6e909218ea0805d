"""Chaining edge points into ordered sub-pixel edge lines (method.md section 2).

The edge pixels of each class (vertical rising / falling, horizontal rising / falling) are
grouped into 8-connected components (``cv2.connectedComponents``). A vertical edge meets each
pixel row at most once, so a component that holds two pixels of one row has a junction or a
spur there: those pixels are removed and the components are formed again, which splits the
chain at the junction. (Horizontal edges: the same with columns.) Chains are therefore split at
junctions, at gaps (a missing pixel breaks 8-connectivity) and at depth discontinuities (a jump
of more than one pixel across the edge between neighbouring rows). Each chain is ordered along
its run (by row for vertical edges, by column for horizontal ones); chains shorter than
``min_length`` points are dropped.
"""

from __future__ import annotations

import cv2
import numpy as np

from .edges import EdgePoints


def _components(iy: np.ndarray, ix: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    mask = np.zeros(shape, np.uint8)
    mask[iy, ix] = 1
    _, lab = cv2.connectedComponents(mask, connectivity=8, ltype=cv2.CV_32S)
    return lab[iy, ix]


def trace_lines(pts: EdgePoints, shape: tuple[int, int], min_length: int = 4
                ) -> tuple[np.ndarray, np.ndarray]:
    """Group edge points into ordered chains.

    Parameters
    ----------
    pts : EdgePoints
        Edge points (N,) from :func:`~nurbscan.detect.edges.detect_edge_points`.
    shape : (H, W)
        Image size, px.
    min_length : int
        Fewest points of a kept chain.

    Returns
    -------
    order : ndarray int64 (M,)
        Indices into ``pts`` of the kept points, grouped by chain and ordered along each chain.
    line : ndarray int64 (M,)
        Chain id 0 .. L - 1 of each kept point (non-decreasing).
    """
    n = len(pts.x)
    keep = np.zeros(n, bool)
    comp = np.full(n, -1, np.int64)
    offset = 0
    for cls in range(4):
        sel = np.nonzero(pts.cls == cls)[0]
        if not len(sel):
            continue
        iy, ix = pts.iy[sel], pts.ix[sel]
        along = iy if cls < 2 else ix
        lab = _components(iy, ix, shape)
        key = lab.astype(np.int64) * (max(shape) + 1) + along
        _, inv, cnt = np.unique(key, return_inverse=True, return_counts=True)
        single = cnt[inv] == 1
        sel, iy, ix, along = sel[single], iy[single], ix[single], along[single]
        lab = _components(iy, ix, shape).astype(np.int64)
        comp[sel] = lab + offset
        keep[sel] = True
        offset += int(lab.max()) + 1 if len(lab) else 0
    idx = np.nonzero(keep)[0]
    along = np.where(pts.cls[idx] < 2, pts.iy[idx], pts.ix[idx])
    o = np.lexsort((along, comp[idx]))
    idx = idx[o]
    c = comp[idx]
    uniq, inv, cnt = np.unique(c, return_inverse=True, return_counts=True)
    good = cnt[inv] >= min_length
    idx, inv = idx[good], inv[good]
    _, line = np.unique(inv, return_inverse=True)
    return idx, line.astype(np.int64)


def local_residual(along: np.ndarray, across: np.ndarray, line: np.ndarray, reach: int = 4
                   ) -> np.ndarray:
    """Distance of each point from the straight line fitted to its chain neighbours.

    For point i of a chain, the points i - reach .. i + reach of the same chain, i itself left
    out, are fitted by least squares with ``across = c0 + c1 (along - along_i)``; the residual
    is ``|across_i - c0|`` px (0 where fewer than 3 neighbours exist). A point off its own
    chain by more than the noise is an outlier (a disturbed profile at a crossing's corner).
    Arrays (M,) ordered by chain as returned by :func:`trace_lines`.
    """
    n = len(along)
    if n == 0:
        return np.zeros(0)
    i = np.arange(n)
    counts = np.bincount(line)
    stop = np.cumsum(counts)
    first = (stop - counts)[line]
    last = stop[line] - 1
    offs = np.r_[np.arange(-reach, 0), np.arange(1, reach + 1)]
    j = i[:, None] + offs[None, :]
    wts = ((j >= first[:, None]) & (j <= last[:, None])).astype(np.float64)
    j = np.clip(j, 0, n - 1)
    t = along[j] - along[:, None]
    v = across[j]
    sw = wts.sum(1)
    st = (wts * t).sum(1)
    stt = (wts * t * t).sum(1)
    sv = (wts * v).sum(1)
    stv = (wts * t * v).sum(1)
    det = sw * stt - st * st
    with np.errstate(all="ignore"):
        c1 = (sw * stv - st * sv) / det
        c0 = (sv - c1 * st) / sw
    res = np.abs(across - c0)
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
                   pairs_only: bool = False) -> tuple[np.ndarray, np.ndarray]:
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
    span = float(max(x.max(), y.max()) + 10.0) * 4
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
    o = np.lexsort((along, pc))
    _, nl2 = np.unique(pc[o], return_inverse=True)
    return o.astype(np.int64), nl2.astype(np.int64)


def neighbour_fit(along: np.ndarray, across: np.ndarray, line: np.ndarray, use: np.ndarray,
                  reach: int = 5, both_sides: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Across-edge position of each point predicted from its chain neighbours' straight line.

    For point i, the points i - reach .. i + reach of the same chain with ``use`` true (i
    itself left out) are fitted by weighted least squares ``across = c0 + c1 (along -
    along_i)``; returns ``c0`` (M,) px and a bool (M,) that is true where at least 3 such
    neighbours exist, on both sides of the point (an interpolation, not an extrapolation).
    Arrays (M,) ordered by chain as returned by :func:`trace_lines`.
    """
    n = len(along)
    if n == 0:
        return np.zeros(0), np.zeros(0, bool)
    i = np.arange(n)
    counts = np.bincount(line)
    stop = np.cumsum(counts)
    first = (stop - counts)[line]
    last = stop[line] - 1
    offs = np.r_[np.arange(-reach, 0), np.arange(1, reach + 1)]
    j = i[:, None] + offs[None, :]
    inside = (j >= first[:, None]) & (j <= last[:, None])
    j = np.clip(j, 0, n - 1)
    wts = (inside & use[j]).astype(np.float64)
    t = along[j] - along[:, None]
    v = across[j]
    sw = wts.sum(1)
    st = (wts * t).sum(1)
    stt = (wts * t * t).sum(1)
    sv = (wts * v).sum(1)
    stv = (wts * t * v).sum(1)
    det = sw * stt - st * st
    with np.errstate(all="ignore"):
        c1 = (sw * stv - st * sv) / det
        c0 = (sv - c1 * st) / sw
    before = (wts[:, :reach] > 0).any(1)
    after = (wts[:, reach:] > 0).any(1)
    ok = (sw >= 3) & ((before & after) | (not both_sides)) & np.isfinite(c0)
    return np.where(ok, c0, across), ok
