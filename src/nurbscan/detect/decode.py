"""Decoding the PRMVS grid: band colours, windows of n bands, and a vote per line.

method.md sections 1-2. Along every pixel row the vertical-edge points, sorted by x, alternate
rising / falling where the row crosses vertical bands; a rising point followed by a falling one
(narrower than the band pitch suggests) is one *band crossing*, whose colour is read at its
centre. n consecutive band crossings of one row that are evenly spaced (no band missing between
them) form a window; ``pattern.lookup`` gives the index of its first band, hence a vote for the
band index of every crossing in the window (its own position in the window added). Columns and
the horizontal-edge points are handled the same way. Where the surface shears the grid, the
"rows" are the other family's edges instead (:func:`oblique_runs`). Each edge line collects
the votes of all its points; it is labelled with the winning index only when enough votes
agree (``min_votes`` and a ``min_agreement`` fraction), so that a misread colour, which spoils
a few windows only, is outvoted, and lines without a clear majority are dropped (label -1),
not guessed.

Colour classification: the chromaticity ``c / max(c)`` of the normalised colour at each band
centre is assigned to the nearest of the q pattern colours, whose centres are first adapted to
the image by a few Lloyd (k-means) iterations started at the ideal colours (this absorbs the
camera's colour crosstalk); ambiguous samples (nearest / second-nearest distance ratio above
``ambiguity``) get code -1 and spoil their windows.
"""

from __future__ import annotations

from functools import reduce

import numpy as np

from .._jit import njit


def bilinear(img: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Bilinear samples of ``img`` (H, W[, C]) at points (x, y) px (clamped to the image)."""
    return bilinear_at(img, bilinear_taps(img.shape[:2], x, y))


def bilinear_taps(shape: tuple[int, int], x: np.ndarray, y: np.ndarray) -> tuple:
    """The taps of :func:`bilinear` at points (x, y) px in images of ``shape`` (H, W): the
    flat index of each point's upper left pixel (N,) int64 and its fractions ``fx``, ``fy``
    (N,) float64, for :func:`bilinear_at` (several images sampled at the same points)."""
    h, w = shape
    x = np.clip(x, 0, w - 1.001)
    y = np.clip(y, 0, h - 1.001)
    x0 = np.floor(x).astype(np.int64)
    y0 = np.floor(y).astype(np.int64)
    return y0 * w + x0, x - x0, y - y0, w


def bilinear_at(img: np.ndarray, taps: tuple) -> np.ndarray:
    """``img`` (H, W[, C]) sampled with the taps of :func:`bilinear_taps` (N[, C])."""
    i00, fx, fy, w = taps
    flat = img.reshape(img.shape[0] * img.shape[1], -1) if img.ndim == 3 else img.ravel()
    if img.ndim == 3:
        fx = fx[:, None]
        fy = fy[:, None]
    i10 = i00 + w
    return ((flat[i00] * (1 - fx) + flat[i00 + 1] * fx) * (1 - fy)
            + (flat[i10] * (1 - fx) + flat[i10 + 1] * fx) * fy)


def classify_colours(samples: np.ndarray, rgb: np.ndarray, iterations: int = 5,
                     ambiguity: float = 0.7, min_level: float = 0.25,
                     centres: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Colour code of each sample (module notes).

    Parameters
    ----------
    samples : ndarray (N, 3)
        Normalised colours.
    rgb : ndarray (q, 3)
        Pattern colours (0..255).
    iterations : int
        Lloyd iterations adapting the colour centres.
    ambiguity : float
        Largest ratio of the distances to the nearest and the second-nearest centre.
    min_level : float
        Least brightness (max channel) of a band centre.
    centres : ndarray (q, 3), optional
        Starting chromaticity centres (default the pattern's colours).

    Returns
    -------
    codes : ndarray int64 (N,)
        Colour code 0..q-1, or -1 (ambiguous or too dark).
    centres : ndarray (q, 3)
        Adapted chromaticity centres.
    """
    s = np.maximum(np.asarray(samples, np.float64), 0.0)
    level = reduce(np.maximum, [s[:, c] for c in range(s.shape[1])])  # (s.max(axis=1))
    chroma = s / np.maximum(level, 1e-6)[:, None]
    if centres is None:
        centres = np.asarray(rgb, np.float64) / 255.0
        centres = centres / np.maximum(centres.max(axis=1, keepdims=True), 1e-6)
    centres = np.array(centres, np.float64)
    ok = level > min_level
    train = chroma[ok]
    if len(train) > 20000:
        train = train[:: len(train) // 20000 + 1]
    q = len(centres)
    its = iterations if len(train) >= 10 * q else 0
    train_t = np.ascontiguousarray(train.T) if its else None
    for _ in range(its):
        a = _nearest_two(_sq_distances(train_t, centres), index_only=True)[0]
        cnt = np.bincount(a, minlength=q)
        for c in range(3):
            sums = np.bincount(a, weights=train[:, c], minlength=q)
            centres[:, c] = np.where(cnt > 5, sums / np.maximum(cnt, 1), centres[:, c])
    nearest, d1, d2 = _nearest_two(np.sqrt(_sq_distances(np.ascontiguousarray(chroma.T),
                                                         centres)))
    codes = np.where(ok & (d1 < ambiguity * d2), nearest, -1)
    return codes.astype(np.int64), centres


def _nearest_two(d: np.ndarray, index_only: bool = False
                 ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """Per column of ``d`` (q, N), q >= 2: the row of its least value (the first of equal
    ones, as ``d.argmin(0)``), that value and the second least (the least of the other rows;
    equal to it on a tie; None with ``index_only``), element by element over the q rows
    (numpy's ``argmin`` and ``argsort`` work column by column here, 5 x slower). A tie of the
    two nearest centres leaves a sample unclassified whichever comes first (``d1 <
    ambiguity * d2`` fails for ``ambiguity`` <= 1). Where ``d`` is not all finite (a
    non-finite sample or centre), as before: ``argmin``, and a stable ``argsort`` of each
    sample's distances, which puts NaN last."""
    if not np.isfinite(d).all():
        if index_only:
            return d.argmin(0), None, None
        per_sample = np.ascontiguousarray(d.T)
        o = np.argsort(per_sample, axis=1)
        return (o[:, 0], np.take_along_axis(per_sample, o[:, :1], 1)[:, 0],
                np.take_along_axis(per_sample, o[:, 1:2], 1)[:, 0])
    idx = np.zeros(d.shape[1], np.int64)
    least = d[0].copy()
    for k in range(1, len(d)):
        less = d[k] < least
        idx[less] = k
        np.minimum(least, d[k], out=least)
    if index_only:
        return idx, None, None
    second = np.full(d.shape[1], np.inf)
    for k in range(len(d)):
        np.minimum(second, np.where(idx == k, np.inf, d[k]), out=second)
    return idx, least, second


def _sq_distances(points_t: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """``((p[:, None, :] - centres[None]) ** 2).sum(-1)`` of the points ``p`` (N, 3), from
    ``points_t`` = ``p.T`` (3, N), transposed: (q, N), the same numbers (numpy's sum of 3
    along the contiguous axis adds them one by one to 0), centre by centre on rows of the
    points' length."""
    out = np.empty((len(centres), points_t.shape[1]))
    for k, ck in enumerate(centres):
        a = out[k]
        np.subtract(points_t[0], ck[0], out=a)
        a *= a
        for c in (1, 2):
            b = points_t[c] - ck[c]
            b *= b
            a += b
    return out


def small_ints(values: np.ndarray, bound: int | None = None) -> np.ndarray:
    """An integer sort key as uint16 where its values fit (non-negative, below ``bound``,
    default their maximum + 1), else as it is: the same order, and :func:`numpy.lexsort`'s
    stable sort of a 16-bit key is a radix sort (about a third faster than the merge sort
    of 64-bit keys)."""
    values = np.asarray(values)
    if not len(values):
        return values
    if bound is None:
        bound = int(values.max()) + 1
    if bound <= 65536 and int(values.min()) >= 0:
        return values.astype(np.uint16)
    return values


def band_crossings(across: np.ndarray, run: np.ndarray, cls: np.ndarray, ratio: float,
                   tol: float = 0.6) -> tuple[np.ndarray, np.ndarray]:
    """Band crossings along rows (or columns) from edge points of one direction.

    Parameters
    ----------
    across : ndarray (N,)
        Sub-pixel coordinate across the bands (x for vertical bands), px.
    run : ndarray (N,) int
        Row (column) of each point.
    cls : ndarray (N,) int
        0 rising, 1 falling.
    ratio : float
        Pattern band / pitch.
    tol : float
        Relative tolerance on the band width against the local pitch.

    Returns
    -------
    order : ndarray (N,) int64
        Points sorted by (run, across).
    start : ndarray (K,) int64
        Positions in ``order`` of the rising point of each band crossing (the falling one is
        the next position).
    """
    order = np.lexsort((across, small_ints(run)))
    a, r, c = across[order], run[order], cls[order]
    n = len(a)
    if n < 2:
        return order, np.zeros(0, np.int64)
    p = np.arange(n - 1)
    isb = (c[p] == 0) & (c[p + 1] == 1) & (r[p] == r[p + 1])
    start = p[isb]
    width = a[start + 1] - a[start]
    # local pitch: distance to the neighbouring crossings of the same row
    mid = 0.5 * (a[start] + a[start + 1])
    nb = np.full(len(start), np.nan)
    if len(start) > 1:
        same_next = (start[1:] == start[:-1] + 2) & (r[start[1:]] == r[start[:-1]])
        dnext = np.where(same_next, mid[1:] - mid[:-1], np.nan)
        both = np.c_[np.r_[np.nan, dnext], np.r_[dnext, np.nan]]
        with np.errstate(all="ignore"):
            nb = np.fmin(both[:, 0], both[:, 1])
    with np.errstate(invalid="ignore"):
        okw = np.isnan(nb) | ((width > (1 - tol) * ratio * nb) & (width < (1 + tol) * ratio * nb))
    return order, start[okw & (width > 0.5)]


def oblique_runs(x: np.ndarray, y: np.ndarray, direction: np.ndarray, line: np.ndarray,
                 shape: tuple[int, int], reach: float, tol: float = 0.75
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Group edge points of one family into runs along given directions (slanted "rows").

    On an upright grid a pixel column crosses the horizontal bands one after the other, so
    the column is the run along which :func:`band_crossings` pairs their edges and
    :func:`window_votes` reads their colours. Where the surface shears the grid, the bands
    of the other family slant across the column: the column then leaves a cell of the grid
    after one band and meets the next bands inside the slanted ones, and no window is read
    (the teapot's lid, where the two families meet at about 33 degrees). The run the pattern
    is read along is the other family's edge direction (``direction``: the point's
    :attr:`~nurbscan.detect.edges.EdgePoints.across` vector), along which the cells of one
    grid column line up.

    Each point is linked to the first point of another chain (``line``) that the ray from it
    along its ``direction`` meets: the ray is sampled every half px up to ``reach`` px, the
    points are looked up in a raster of their pixels and the pixels around them, and of the
    point met and its three chain neighbours on either side the one nearest the ray is
    taken, when it lies within ``tol`` px of it. A point met by several rays keeps the
    nearest one. The links form paths: the runs.

    Parameters
    ----------
    x, y : ndarray (N,) float
        Points, camera px, grouped by chain and in chain order.
    direction : ndarray (N, 2) float
        Direction of each point's run (any length, oriented as the points' rising edge).
    line : ndarray (N,) int
        Chain of each point (a point is not linked to its own chain).
    shape : (H, W)
        Image size.
    reach, tol : float
        Longest link and largest distance from the ray, px.

    Returns
    -------
    run : ndarray (N,) int64
        Run id of each point (0 .. R - 1; a point without links is a run of its own).
    along : ndarray (N,) float64
        Position along the run (px, along the run's mean direction).
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    n = len(x)
    if n == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.float64)
    h, w = shape
    u = np.asarray(direction, np.float64)
    u = u / np.maximum(np.hypot(u[:, 0], u[:, 1]), 1e-12)[:, None]
    steps = np.arange(0.5, max(float(reach), 0.5) + 0.25, 0.5)
    # raster of the points, each also in the 8 pixels around its own (where no point is),
    # over the (H + 2, W + 2) image with an empty border ring; only the window of it that the
    # rays can reach is stored (rows y0.., columns x0..), and where that window reaches past
    # the ring, the cells beyond it are empty too: the samples need no clamping to the ring
    gx = np.clip(np.rint(x).astype(np.int64), -1, w) + 1
    gy = np.clip(np.rint(y).astype(np.int64), -1, h) + 1
    m = int(np.ceil(steps[-1])) + 3
    y0, x0 = int(gy.min()) - m, int(gx.min()) - m
    y1, x1 = int(gy.max()) + m + 1, int(gx.max()) + m + 1
    gw = x1 - x0
    # (16-bit point ids where they fit, 65535 for none: half the raster's memory traffic)
    gtype = np.uint16 if n < 65535 else np.int32
    none = np.iinfo(gtype).max if gtype == np.uint16 else -1
    grid = np.full((y1 - y0, gw), none, gtype)
    idx = np.arange(n, dtype=gtype)
    # (flat raster indices from the clamped rows and columns, each computed once)
    rows = {d: (np.clip(gy + d, 0, h + 1) - y0) * gw for d in (-1, 0, 1)}
    cols = {d: np.clip(gx + d, 0, w + 1) - x0 for d in (-1, 0, 1)}
    flat_grid = grid.reshape(-1)
    for dy, dx in ((-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1)):
        flat_grid[rows[dy] + cols[dx]] = idx
    flat_grid[(gy - y0) * gw + (gx - x0)] = idx
    del rows, cols, flat_grid
    grid[:max(1 - y0, 0), :] = none
    grid[max(h + 1 - y0, 0):, :] = none
    grid[:, :max(1 - x0, 0)] = none
    grid[:, max(w + 1 - x0, 0):] = none
    grid = grid.ravel()
    # the flat raster pixel of the image's row r and column c: r gw + c + offset
    offset = (1 - y0) * gw + (1 - x0)
    succ, perp_of = _first_hits(grid, np.int64(none), steps, x, y,
                                np.ascontiguousarray(u[:, 0]), np.ascontiguousarray(u[:, 1]),
                                np.asarray(line, np.int64), gw, offset, float(tol))
    src = np.nonzero(succ >= 0)[0]
    dst = succ[src]
    # a point met by several rays keeps the one passing nearest to it
    o = np.lexsort((perp_of[src], small_ints(dst, n)))
    first = np.r_[True, dst[o][1:] != dst[o][:-1]] if len(o) else np.zeros(0, bool)
    src, dst = src[o][first], dst[o][first]
    g = coo_matrix((np.ones(len(src)), (src, dst)), shape=(n, n))
    _, run = connected_components(g, directed=False)
    mu = np.stack([np.bincount(run, weights=u[:, c]) for c in (0, 1)], 1)
    mu /= np.maximum(np.hypot(mu[:, 0], mu[:, 1]), 1e-12)[:, None]
    along = x * mu[run, 0] + y * mu[run, 1]
    return run.astype(np.int64), along


@njit(cache=True, nogil=True)
def _first_hits(grid, none, steps, x, y, ux, uy, line, gw, offset, tol):
    """The links of :func:`oblique_runs`' rays, ray by ray (compiled: a loop that stops at the
    first point met, where numpy sampled every ray in blocks of steps).

    The ray from point i along ``(ux, uy)`` is sampled at the ``steps`` (px); a sample's
    raster pixel is ``rint(y + s uy) gw + rint(x + s ux) + offset`` of the flat raster
    ``grid`` (``none`` where no point is). The first point met of another chain that lies
    ahead (more than 0.5 px along the ray) and within 1.5 px of it ends the ray: of it and
    its chain neighbours up to three positions away, the one nearest the ray (the first of
    equals) is linked to when within ``tol`` px. Returns the linked point (N,) (-1: none) and
    its distance from the ray (N,) (inf where none), float64 throughout.
    """
    n = len(x)
    succ = np.full(n, -1, np.int64)
    perp = np.full(n, np.inf)
    for i in range(n):
        xa, ya, ua, va, own = x[i], y[i], ux[i], uy[i], line[i]
        for k in range(len(steps)):
            st = steps[k]
            flat = np.rint(st * va + ya) * gw + np.rint(st * ua + xa) + offset
            j = np.int64(grid[np.int64(flat)])
            if j == none or line[j] == own:
                continue
            rx, ry = x[j] - xa, y[j] - ya
            if not (rx * ua + ry * va > 0.5 and abs(rx * va - ry * ua) <= 1.5):
                continue
            best, at = np.inf, -1
            for d in range(-3, 4):
                c = min(max(j + d, 0), n - 1)
                if line[c] != line[j]:
                    continue
                p = abs((x[c] - xa) * va - (y[c] - ya) * ua)
                if p < best:
                    best, at = p, c
            if best <= tol:
                succ[i], perp[i] = at, best
            break
    return succ, perp


def window_votes(order: np.ndarray, start: np.ndarray, run: np.ndarray, across: np.ndarray,
                 codes: np.ndarray, pattern, direction: str, dark_after: np.ndarray | None = None,
                 spacing_tol: float = 0.3) -> tuple[np.ndarray, np.ndarray]:
    """Votes (point, band index) from windows of n consecutive band crossings.

    ``codes`` holds the colour code of each crossing in ``start``; ``dark_after`` (optional,
    bool per crossing) says whether the gap after the crossing is dark (a row running inside a
    band of the other direction sees lit gaps and only the bands that colour does not hide, so
    its windows are not trusted). Returns the point indices (into the arrays given to
    :func:`band_crossings`) and the band index each votes for; every window votes for the
    rising and the falling point of each of its n crossings.
    """
    n = pattern.n
    k = len(start)
    if k < n:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.int64)
    r = run[order]
    a = across[order]
    mid = 0.5 * (a[start] + a[start + 1])
    w0 = np.arange(k - n + 1)
    ok = np.ones(len(w0), bool)
    for j in range(1, n):
        ok &= (start[w0 + j] == start[w0 + j - 1] + 2) & (r[start[w0 + j]] == r[start[w0]])
        if dark_after is not None:
            ok &= dark_after[w0 + j - 1]
    # (the windows' largest and least gap, and their codes' test, element by element over
    # the columns: numpy reduces an (N, 2) array along its short axis row by row, 10 x slower)
    if n >= 3:
        gaps = [mid[w0 + j] - mid[w0 + j - 1] for j in range(1, n)]
        least = reduce(np.minimum, gaps)
        with np.errstate(all="ignore"):
            ok &= (reduce(np.maximum, gaps) < (1 + spacing_tol) * least) & (least > 0)
    win = np.stack([codes[w0 + j] for j in range(n)], 1)
    ok &= reduce(np.logical_and, [win[:, j] >= 0 for j in range(n)])
    w0 = w0[ok]
    idx = pattern.lookup(win[ok], direction)
    good = idx >= 0
    w0, idx = w0[good], idx[good]
    pts, lab, pos = [], [], []
    for j in range(n):
        s = start[w0 + j]
        pts += [order[s], order[s + 1]]
        lab += [idx + j, idx + j]
        pos += [np.full(len(s), j), np.full(len(s), j)]
    return np.concatenate(pts), np.concatenate(lab), np.concatenate(pos)


def line_labels(line: np.ndarray, vote_pts: np.ndarray | None, vote_idx: np.ndarray,
                nlines: int, min_votes: int = 3, min_agreement: float = 0.8,
                direct: bool = False, vote_pos: np.ndarray | None = None,
                min_positions: int = 1) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Majority band index of each line from the votes of its points.

    ``line[vote_pts]`` is the line of each vote (``direct``: ``line`` itself lists the line
    of each vote and ``vote_pts`` is ignored); ``vote_idx`` the value voted for (>= 0).
    With ``vote_pos`` (the line's position in each voting window), the winner must also be
    supported from at least ``min_positions`` different window positions: windows at
    different positions read different colours, so one misread colour repeated along a line
    (every row reads the same few bands) cannot confirm a wrong label on its own.

    Returns
    -------
    label : ndarray int64 (nlines,)
        Winning band index, -1 where there are fewer than ``min_votes`` for it or it has less
        than ``min_agreement`` of the line's votes.
    votes : ndarray int64 (nlines,)
        Votes for the winner.
    agreement : ndarray float64 (nlines,)
        Winner's share of the line's votes (0 without votes).
    """
    label = np.full(nlines, -1, np.int64)
    votes = np.zeros(nlines, np.int64)
    agree = np.zeros(nlines, np.float64)
    ln = np.asarray(line if direct else line[vote_pts], np.int64)
    if not len(ln):
        return label, votes, agree
    key = ln * 100000 + vote_idx
    uk, cnt = np.unique(key, return_counts=True)
    kl = uk // 100000
    ki = uk % 100000
    total = np.bincount(kl, weights=cnt, minlength=nlines)
    o = np.lexsort((-cnt, kl))
    first = np.r_[True, kl[o][1:] != kl[o][:-1]]
    wl, wi, wc = kl[o][first], ki[o][first], cnt[o][first]
    votes[wl] = wc
    agree[wl] = wc / total[wl]
    good = (wc >= min_votes) & (wc >= min_agreement * total[wl])
    if vote_pos is not None:
        trip = np.unique((ln * 100000 + vote_idx) * 16 + vote_pos)
        npos = np.unique(trip // 16, return_counts=True)
        support = np.zeros(len(wl), np.int64)
        j = np.searchsorted(npos[0], wl * 100000 + wi)
        hit = (j < len(npos[0])) & (npos[0][np.minimum(j, len(npos[0]) - 1)] == wl * 100000 + wi)
        support[hit] = npos[1][j[hit]]
        good &= support >= min_positions
    label[wl[good]] = wi[good]
    return label, votes, agree
