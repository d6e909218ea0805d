"""The edge-point and chain stages of :func:`~nurbscan.detect.detect_grid`, and the filters
of chain points that later stages apply.

:func:`find_edges` finds the sub-pixel edge points (:func:`~nurbscan.detect.edges.
detect_edge_points`), :func:`trace_chains` traces them into chains
(:func:`~nurbscan.detect.lines.trace_lines`) and pairs the collinear pieces of one edge
(:func:`~nurbscan.detect.lines.join_collinear`). The chain filters (:func:`chain_end_residual`,
:func:`chain_tails`) and the corner points' attachment (:func:`extend_lines`) work on any
points grouped by chain.

The links, the chains' numbering (by their first point), the joins and the corner points'
owners each stay within one edge class: the vertical and the horizontal family are traced,
joined and extended side by side (:mod:`~nurbscan.detect._threads`), with the same chains as
all at once.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ._pick import pick
from ._threads import parallel_map
from .decode import small_ints
from .edges import EdgePoints, detect_edge_points
from .lines import fit_lines, join_collinear, join_span, neighbour_fit, trace_lines
from .prepare import NoGrid, Prepared

#: Smoothing along the edges, camera px (None: ``sigma``). Smoothing more along the edges than
#: across them cost accuracy on the tilted edges (1.25 / 2.0 px: RMS 0.055 px, auto_sigma).
SIGMA_ALONG = None


@dataclass(frozen=True)
class Edges:
    """The edge points of a photograph.

    Attributes
    ----------
    points : EdgePoints
        The points to trace.
    corners : EdgePoints or None
        Points found only with a gradient dominance below ``dominance`` (the corner pixels
        beside a crossing band): not traced; they may extend the final lines.
    """

    points: EdgePoints
    corners: EdgePoints | None


def find_edges(prep: Prepared, options) -> Edges:
    """The sub-pixel edge points of the normalised signal (``options``:
    :class:`~nurbscan.detect.options.EdgeOptions`; the families told apart, and the corner
    points set aside, only where the bands are resolved). Raises :class:`NoGrid` with fewer
    than 20 points."""
    fine = prep.fine
    nrm = prep.normalised
    dominance, corner_dominance = options.dominance, options.corner_dominance
    pts = detect_edge_points(nrm.signal, sigma=prep.sigma, threshold=options.threshold,
                             valid=nrm.valid, sigma_along=SIGMA_ALONG,
                             dominance=min(dominance, corner_dominance) if fine else dominance,
                             families=options.families and fine, oblique=options.oblique,
                             fit_line=options.fit_line, camera_blur=options.camera_blur)
    corner_pts = None
    if fine and corner_dominance < dominance:
        # points found only below `dominance`: not traced, attached to the decoded lines
        main = pts.dominance >= dominance
        pts, corner_pts = pts.take(main), pts.take(~main)
    if len(pts.x) < 20:
        raise NoGrid("image: blank (no edges), no grid found", prep.size)
    return Edges(pts, corner_pts)


@dataclass(frozen=True)
class Chains:
    """Edge points traced into chains, in chain order (N points, L chains).

    Attributes
    ----------
    x, y : (N,) float
        Points, camera px.
    cls : (N,) int64
        Edge class, direction * 2 + edge (0 rising, 1 falling).
    ix, iy : (N,) int
        Edge pixels.
    across, slope : (N, 2), (N,) or None
        :class:`~nurbscan.detect.edges.EdgePoints`' fit-line vectors and slopes.
    strength, gx, gy : (N,) float
        Edge derivative and gradient components, per px.
    line : (N,) int
        Chain of each point, in [0, L).
    nlines : int
        L.
    join_src, join_dst : (J,) int
        Chains joined as collinear pieces of one edge across a gap of up to ``join_gap`` px.
    join_gap : float
        1.5 band widths + 4 sigma (0 when no band was measured).
    """

    x: np.ndarray
    y: np.ndarray
    cls: np.ndarray
    ix: np.ndarray
    iy: np.ndarray
    across: np.ndarray | None
    slope: np.ndarray | None
    strength: np.ndarray
    gx: np.ndarray
    gy: np.ndarray
    line: np.ndarray
    nlines: int
    join_src: np.ndarray
    join_dst: np.ndarray
    join_gap: float


def trace_chains(edges: Edges, prep: Prepared, min_length: int) -> Chains:
    """Trace the edge points into chains of at least ``min_length`` points and join the
    collinear pieces of one edge (:func:`~nurbscan.detect.lines.join_collinear`)."""
    pts = edges.points
    w, h = prep.size
    # the two families' points traced and joined side by side (_threads), where the vertical
    # family's points come first (as detect_edge_points gives them): the same chains, since
    # the links, the chains' numbering (by their first point) and the joins each stay within
    # one class
    cut = family_cut(pts.cls)
    split = cut is not None
    if split:
        (ov, lv), (oh, lh) = parallel_map(
            lambda part: trace_lines(pts.take(part), (h, w), min_length=min_length),
            (np.arange(cut), np.arange(cut, len(pts.cls))))
        first = int(lv[-1]) + 1 if len(lv) else 0
        order, line = np.r_[ov, oh + cut], np.r_[lv, lh + first]
        split = len(lv) > 0 and len(lh) > 0
    else:
        order, line = trace_lines(pts, (h, w), min_length=min_length)
    band_px = prep.band_px
    join_gap = 1.5 * band_px + 4 * prep.sigma if np.isfinite(band_px) else 0.0
    cls = pts.cls[order].astype(np.int64)
    x, y = pts.x[order], pts.y[order]
    if join_gap > 0 and len(line):
        span = join_span(x, y)
        if split:
            at = len(lv)
            parts = parallel_map(lambda p: join_collinear(
                x[p[0]], y[p[0]], cls[p[0]], line[p[0]] - p[1], max_gap=join_gap,
                pairs_only=True, span=span), ((slice(0, at), 0), (slice(at, None), first)))
            jsrc = np.r_[parts[0][0], parts[1][0] + first]
            jdst = np.r_[parts[0][1], parts[1][1] + first]
        else:
            jsrc, jdst = join_collinear(x, y, cls, line, max_gap=join_gap, pairs_only=True,
                                        span=span)
    else:
        jsrc = jdst = np.zeros(0, np.int64)
    nlines = int(line.max()) + 1 if len(line) else 0
    return Chains(x=x, y=y, cls=cls, ix=pts.ix[order], iy=pts.iy[order],
                  across=None if pts.across is None else pts.across[order],
                  slope=None if pts.slope is None else pts.slope[order],
                  strength=pts.strength[order], gx=pts.gx[order], gy=pts.gy[order], line=line,
                  nlines=nlines, join_src=jsrc, join_dst=jdst, join_gap=join_gap)


def family_cut(cls: np.ndarray) -> int | None:
    """Where the horizontal family's points begin in points of classes ``cls`` (N,)
    (direction * 2 + edge) that hold the vertical family's first and both families; None
    otherwise (the families' parts can then not be taken as two slices)."""
    cut = int(np.count_nonzero(cls < 2))
    return cut if 0 < cut < len(cls) and bool(np.all(cls[:cut] < 2)) else None


def by_family(fn, vertical: np.ndarray, points: tuple, line: np.ndarray,
              at: np.ndarray | None = None, **options):
    """``fn(*points, line, [at=at,] **options)`` of a chain function, the two families' chains
    side by side (:mod:`~nurbscan.detect._threads`).

    ``points`` are (M,) arrays of chain points grouped by chain (``line`` non-decreasing),
    ``vertical`` (M,) bool their family. A chain function's result for a point is computed
    from its own chain's points (the window fits read beyond a chain's ends with weight 0,
    which leaves finite values out exactly), so where the vertical family's points come
    first (:func:`family_cut`), ``line`` does not decrease and the points are finite, ``fn``
    is called on each family's slice (the chains renumbered from 0, ``at`` (Q,) int split by
    family) and the parts put together are the whole's; otherwise ``fn`` runs once on all.
    Returns what ``fn`` returns: an array (M,) or (Q,), or a tuple of them.
    """
    line = np.asarray(line)
    cut = family_cut(np.where(vertical, 0, 2))
    if cut is not None and not (np.all(line[1:] >= line[:-1])
                                and all(np.isfinite(a).all() for a in points)):
        cut = None
    if cut is None:
        return fn(*points, line, **options) if at is None else fn(*points, line, at=at,
                                                                  **options)
    if at is not None:
        at = np.asarray(at, np.int64)
        mine = at < cut

    def part(family):
        rows = slice(0, cut) if family == 0 else slice(cut, None)
        start = 0 if family == 0 else cut
        args = [a[rows] for a in points] + [line[rows] - line[rows][0]]
        if at is None:
            return fn(*args, **options)
        return fn(*args, at=at[mine if family == 0 else ~mine] - start, **options)

    parts = parallel_map(part, (0, 1))
    single = not isinstance(parts[0], tuple)
    out = []
    for a, b in zip(*((p,) if single else p for p in parts), strict=True):
        if at is None:
            out.append(np.concatenate([a, b]))
        else:
            o = np.empty(len(at), np.result_type(a, b))
            o[mine], o[~mine] = a, b
            out.append(o)
    return out[0] if single else tuple(out)


def _along_across(x: np.ndarray, y: np.ndarray, vertical: np.ndarray) -> tuple:
    """Point coordinates along and across their edges: (y, x) for vertical-band edges,
    (x, y) for horizontal ones (the chain functions of :mod:`~nurbscan.detect.lines`)."""
    return np.where(vertical, y, x), np.where(vertical, x, y)


def _chains(x, y, direction, line):
    """``along, across`` (M,) of chain points (y, x for vertical-band edges, ``direction`` 0;
    x, y for horizontal ones) and the ``counts, first, stop`` (L,) of the chains."""
    vert = direction == 0
    counts = np.bincount(line)
    stop = np.cumsum(counts)
    return np.where(vert, y, x), np.where(vert, x, y), counts, stop - counts, stop


def chain_end_residual(x: np.ndarray, y: np.ndarray, direction: np.ndarray, line: np.ndarray,
                       reach: int = 6) -> np.ndarray:
    """Distance (camera px) of each chain's first and last point from its chain's straight line.

    The line is fitted by least squares to the ``reach`` chain points next to the end point
    (:func:`~nurbscan.detect.lines.neighbour_fit`, one-sided), across the edge (x for
    vertical-band edges, ``direction`` 0; y for horizontal ones) against along it; the
    distance is measured across the edge. Interior points, and ends of chains of fewer than
    four points, get 0. Arrays (M,) grouped by chain, ``line`` non-decreasing.
    """
    n = len(x)
    out = np.zeros(n)
    if n == 0:
        return out
    along, across, counts, first, stop = _chains(x, y, direction, line)
    ends = np.unique(np.r_[first[counts > 0], stop[counts > 0] - 1])
    c0, ok = neighbour_fit(along, across, line, np.ones(n, bool), reach=reach,
                           both_sides=False, at=ends)  # (the fits at the ends only)
    out[ends] = np.where(ok, np.abs(across[ends] - c0), 0.0)
    return out


def chain_tails(x: np.ndarray, y: np.ndarray, direction: np.ndarray, line: np.ndarray,
                tol: float, tail: int = 8, reach: int = 10) -> np.ndarray:
    """Points of each chain's two tails that veer off the chain's straight line (to drop).

    Where a chain runs into a junction the tracer may follow a few pixels of another edge (a
    crossing band's, an occluding contour's): a short tail, straight in itself, that the
    end-point test (:func:`chain_end_residual`) cannot see because its neighbours are the
    tail. Here the ``tail`` points at each end are compared with the straight line fitted
    (least squares, :func:`~nurbscan.detect.lines.fit_lines`) to the up to ``reach`` points
    before them, across the edge (x for vertical-band edges, ``direction`` 0); from the first
    tail point farther than ``tol`` camera px out to the end, the points are flagged. Tails
    are at most a third of their chain, and chains too short for four fitted points are left
    alone. Arrays (M,) grouped by chain, ``line`` non-decreasing. Returns bool (M,), true for
    the points to drop.
    """
    out = np.zeros(len(x), bool)
    if len(x) == 0:
        return out
    along, across, counts, first, stop = _chains(x, y, direction, line)
    k = np.minimum(tail, counts // 3)  # tail length per chain
    nb = np.minimum(reach, counts - k)  # fitted points per chain
    use = (k >= 1) & (nb >= 4)
    at, ab = np.arange(tail), np.arange(reach)
    for side in (1, -1):
        # tail points ordered from the chain's interior out to its end
        if side == 1:
            ti = (stop - k)[:, None] + at[None, :]
            bi = (stop - k - nb)[:, None] + ab[None, :]
        else:
            ti = (first + k - 1)[:, None] - at[None, :]
            bi = (first + k)[:, None] + ab[None, :]
        tv = use[:, None] & (at[None, :] < k[:, None])
        bv = use[:, None] & (ab[None, :] < nb[:, None])
        ti, bi = np.where(tv, ti, 0), np.where(bv, bi, 0)
        ta = along[bi]
        t0 = ta[:, :1]
        c0, c1, _ = fit_lines(ta - t0, across[bi], bv.astype(np.float64))
        with np.errstate(invalid="ignore"):
            res = np.abs(across[ti] - (c0[:, None] + c1[:, None] * (along[ti] - t0)))
            bad = tv & np.isfinite(res) & (res > tol)
        bad = np.maximum.accumulate(bad, axis=1) & tv
        out[ti[bad]] = True
    return out


def attach_points(line, cls, ix, iy, extra, shape, rounds: int = 3) -> np.ndarray:
    """Attach extra edge points to the lines they continue.

    ``extra`` (:class:`~nurbscan.detect.edges.EdgePoints`, M points) were not traced (the
    corner pixels beside a crossing band, where the other family's gradient dominates).
    An extra point joins the line of its class that owns a pixel among its 8 neighbours,
    when exactly one line does; ``rounds`` times, so that a chain grows into the corner
    pixel by pixel. ``line``, ``cls`` (direction * 2 + edge), ``ix``, ``iy`` (N,) are the
    lines' points and their edge pixels; ``shape`` is the image's (H, W). Returns the line
    of each extra point (M,), -1 where none. (The two directions' points side by side:
    _threads; a point only joins a line of its own class.)
    """
    cls, ecls = np.asarray(cls), np.asarray(extra.cls)
    horizontal, extra_h = cls >= 2, ecls >= 2
    if not (np.any(extra_h) and np.any(~extra_h) and np.any(horizontal)
            and np.any(~horizontal)):
        return _attach_points(line, cls, ix, iy, extra, shape, rounds)
    parts = parallel_map(
        lambda d: _attach_points(*pick(horizontal == d, np.asarray(line), cls, np.asarray(ix),
                                       np.asarray(iy)), extra.take(extra_h == d), shape,
                                 rounds), (False, True))
    att = np.empty(len(ecls), np.int64)
    att[~extra_h], att[extra_h] = parts
    return att


def _attach_points(line, cls, ix, iy, extra, shape, rounds: int) -> np.ndarray:
    """:func:`attach_points` of any classes at once."""
    h, w = shape
    npx = h * w

    def keys(c, y, x):
        return c.astype(np.int64) * npx + y.astype(np.int64) * w + x.astype(np.int64)

    okey = keys(np.asarray(cls), np.asarray(iy), np.asarray(ix))
    oline = np.asarray(line, np.int64)
    ecls = extra.cls.astype(np.int64)
    ex, ey = extra.ix.astype(np.int64), extra.iy.astype(np.int64)
    att = np.full(len(ecls), -1, np.int64)
    dy, dx = np.mgrid[-1:2, -1:2]
    dy, dx = dy.ravel(), dx.ravel()
    free = np.nonzero(att < 0)[0]
    sk = sl = pending = None
    unique = False
    for _ in range(rounds):
        if pending is not None and unique:
            # the sorted keys with the last round's points merged in, where every key is
            # distinct (then any sort gives these arrays); else sorted again, as before
            nk, nl = pending
            on = np.argsort(nk)
            nk, nl = nk[on], nl[on]
            pos = np.searchsorted(sk, nk)
            clash = sk[np.minimum(pos, len(sk) - 1)] == nk if len(sk) else np.zeros(0, bool)
            unique = not (np.any(clash) or np.any(nk[1:] == nk[:-1]))
            if unique:
                sk, sl = np.insert(sk, pos, nk), np.insert(sl, pos, nl)
        if pending is None or not unique:
            o = np.argsort(okey)
            sk, sl = okey[o], oline[o]
            unique = bool(np.all(sk[1:] != sk[:-1]))
        if not len(free) or not len(sk):
            break
        # (9, F): the free points' 8 neighbours and own pixel, reduced over the 9 rows (numpy
        # reduces an (F, 9) array along its short axis row by row, 10 x slower)
        ny = np.clip(dy[:, None] + ey[free][None, :], 0, h - 1)
        nx = np.clip(dx[:, None] + ex[free][None, :], 0, w - 1)
        q = keys(np.broadcast_to(ecls[free], ny.shape), ny, nx)
        j = np.minimum(np.searchsorted(sk, q), len(sk) - 1)
        hit = sk[j] == q
        lid = np.where(hit, sl[j], -1)
        lo = np.where(hit, lid, np.iinfo(np.int64).max).min(0)
        hi = lid.max(0)
        new = hit.any(0) & (lo == hi)
        if not np.any(new):
            break
        att[free[new]] = hi[new]
        added = free[new]
        pending = keys(ecls[added], ey[added], ex[added]), hi[new]
        okey = np.r_[okey, pending[0]]
        oline = np.r_[oline, pending[1]]
        # the next round asks only the free points beside a point just attached (of their
        # class): the others' 8 neighbours are as they were, and so is their answer (the
        # same result; 2 of the 3 rounds' look-ups saved, 7.1 MP view)
        ny, nx = ey[added, None] + dy[None, :], ex[added, None] + dx[None, :]
        inside = (ny >= 0) & (ny < h) & (nx >= 0) & (nx < w)
        near = np.sort(keys(np.repeat(ecls[added, None], 9, 1)[inside], ny[inside],
                            nx[inside]))  # (membership below: sorted is enough)
        free = np.nonzero(att < 0)[0]
        fk = keys(ecls[free], ey[free], ex[free])
        at = np.minimum(np.searchsorted(near, fk), len(near) - 1)
        free = free[near[at] == fk] if len(near) else free[:0]
    return att


def extend_lines(x, y, strength, line, direction, edge, extra, shape, min_strength: float,
                 tol: float, reach: int = 6) -> tuple:
    """The lines (points grouped by line) extended by the extra points that continue them.

    Each extra point (``extra``, :class:`~nurbscan.detect.edges.EdgePoints`) of at least
    ``min_strength`` joins the line :func:`attach_points` finds for it (the lines' edge
    pixels are taken as their points' rounded positions) and is kept when
    it lies within ``tol`` camera px of the straight line through the line's own points
    among the ``reach`` chain positions on either side of it (one side at a chain's end;
    :func:`~nurbscan.detect.lines.neighbour_fit`). Points are re-ordered along each line
    (y for vertical-band edges, ``direction`` 0). ``x``, ``y``, ``strength``, ``line`` (N,);
    ``direction``, ``edge`` (L,) per line. Returns the four arrays extended.
    """
    # (a point off its pixel's row along the edge, EdgePoints.slope, rounds back to it)
    cx, cy = np.round(x).astype(np.int64), np.round(y).astype(np.int64)
    att = attach_points(line, 2 * direction[line] + edge[line], cx, cy, extra, shape)
    a = np.nonzero((att >= 0) & (extra.strength >= min_strength))[0]
    if not len(a):
        return x, y, strength, line
    line_all = np.r_[line, att[a]]
    vk = direction[line_all] == 0
    o = np.lexsort((np.where(vk, np.r_[y, extra.y[a]], np.r_[x, extra.x[a]]),
                    small_ints(line_all)))
    x, y = np.r_[x, extra.x[a]][o], np.r_[y, extra.y[a]][o]
    strength = np.r_[strength, extra.strength[a]][o]
    new = np.r_[np.zeros(len(line), bool), np.ones(len(a), bool)][o]
    line = line_all[o]
    vk = direction[line] == 0
    at = np.nonzero(new)[0]  # (the fits at the new points only)
    c0, ok = neighbour_fit(np.where(vk, y, x), np.where(vk, x, y), line, ~new, reach=reach,
                           both_sides=False, at=at)
    keep = ~new
    keep[at] = ok & (np.abs(np.where(vk, x, y)[at] - c0) <= tol)
    return pick(keep, x, y, strength, line)
