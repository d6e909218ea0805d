"""The line-check stage of :func:`~nurbscan.detect.detect_grid`: the labelled lines judged by
their grid intersections and by the labelled edges of their rows (columns).

A line with more inconsistent than consistent intersections goes, and so does one left with
too few points. Where the bands are resolved, each point is compared with the labelled edges
of its row (:func:`row_support`) or, where its rows hold none, of the other lines of its
family around it (:func:`plane_support`); lone lines, points far off their rows'
extrapolation and the new chain ends they leave are dropped, and so are lines off their
rows' prediction that no intersection confirms (:func:`row_disagreement`).
:func:`check_lines` applies it all.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ._threads import parallel_map
from .chains import _along_across, by_family, chain_end_residual
from .decode import small_ints
from .families import local_plane
from .intersections import Intersections
from .labels import group_median
from .lines import chain_slope
from .neighbours import nearest_within
from .prepare import NoGrid, Prepared
from .refine import Lines

#: :func:`check_labels`: with at least ``CONFIRM_MIN_LINES`` lines of ``CONFIRM_LENGTH`` points
#: or more in one family and not one line in the other, the decoding is refused. Simulated
#: teapot views (768 x 576, whole and random crops) rotated by 90 degrees: one family decoded,
#: 1-2 % of the labels right; upright views, crops and calibration boards: both families.
#: Lines of 20 points or more once: bench_fuzz case 296 (a 409 x 296 crop of view 1, turned,
#: noise and JPEG; too few windows for the orientation) decoded 20 lines of 4-19 points of
#: one family, all wrong; 4 is the chains' least length.
CONFIRM_LENGTH, CONFIRM_MIN_LINES = 4, 5

#: :func:`check_extent`: a result with fewer than ``MIN_LONG_LINES`` lines longer than
#: ``LONG_LINE_PX`` (camera px, the benchmark's own "lines over 20 px") is refused. bench_fuzz
#: at 9cae89e: the three wrong results left once the tilt was measured (cases 3222, 3970, 4707:
#: crops of views turned, with noise and JPEG) had 17, 5 and 37 lines, every one labelled
#: wrongly, and 1 line each over 20 px; of the first 1,500 cases' results with the truth, the
#: 3 with fewer than 4 such lines (1 to 3 lines each) were right but too small to be of use.
LONG_LINE_PX, MIN_LONG_LINES = 20.0, 4

#: ``plane_support``'s neighbours and largest distance from the plane's edge (camera px), for
#: ``plane_radius``.
PLANE_K, PLANE_TOL = 24, 0.5


def check_lines(lines: Lines, coord: np.ndarray, inter: Intersections, prep: Prepared,
                pattern, options, min_length: int) -> tuple[Lines, np.ndarray, Intersections]:
    """The lines, their coordinates ``coord`` (L,) and the intersections after the checks
    (``options``: :class:`~nurbscan.detect.options.CheckOptions`); the intersections kept are
    those of ``inter.keep`` between kept lines, renumbered."""
    px, py, line, strength = lines.x, lines.y, lines.line, lines.strength
    lab, ldir = lines.band, lines.direction
    pitch_px_est = prep.pitch_px
    nl = len(lab)
    okc, cl = inter.consistent, inter.line
    counts = np.bincount(line, minlength=nl)
    bad_n = np.bincount(cl[~okc].ravel(), minlength=nl)
    good_n = np.bincount(cl[okc].ravel(), minlength=nl)
    if options.refuse_one_family:
        check_labels(counts, ldir, prep)
    unconfirmed = good_n == 0  # lines without a consistent intersection
    # and lines left with fewer than min_length points after the point filters
    drop = ((bad_n >= 2) & (bad_n > good_n)) | (counts < min_length)
    keep_pt = np.ones(len(px), bool)
    if prep.fine:
        min_row_support, max_row_residual = options.min_row_support, options.max_row_residual
        keep_unsupported = options.keep_unsupported
    else:
        min_row_support, max_row_residual, keep_unsupported = 0.0, 0.0, True
    new_end_residual = options.new_end_residual
    if (min_row_support > 0 or max_row_residual > 0 or not keep_unsupported) and nl:
        # agreement with the labelled edges of the same row (column), row_support: lines
        # whose points are (almost) never accompanied by labelled neighbours are lone lines,
        # the least accurate; so are single points without support or far off the
        # extrapolation from their neighbours
        rres, kind = row_support(px, py, ldir[line], coord[line], 2.2 * pattern.pitch)
        if options.plane_radius > 0 and np.isfinite(pitch_px_est):
            # points without support in their row, or off its extrapolation by up to a
            # quarter pitch: the edges of other lines around them, in two dimensions, may
            # support them (slanted crossing bands hide the rows' neighbours; a row's
            # extrapolation is poor where the band spacing changes along it; farther off,
            # the label is misread, and pieces of one misread edge would support each other)
            far = ((kind == 2) & (max_row_residual > 0) & (rres > max_row_residual)
                   & (rres <= 0.25 * pitch_px_est))
            lone = np.nonzero((kind == 0) | far)[0]
            if len(lone):
                pres = plane_support(px, py, ldir[line], coord[line], line,
                                     options.plane_radius * pitch_px_est, k=PLANE_K, at=lone)
                kind[lone] = np.where(pres[lone] <= PLANE_TOL, 3, kind[lone])  # 3: plane
        share = np.bincount(line, weights=kind > 0, minlength=nl) / np.maximum(counts, 1)
        drop |= share < min_row_support
        if max_row_residual > 0:
            keep_pt &= ~((kind == 2) & (rres > max_row_residual))
            # a line that no consistent intersection confirms and whose points lie, on
            # median, farther than max_row_residual (across the line) from where the
            # labelled edges of their rows put them is no edge of its band (demo view 4: a
            # 14 px edge inside the crossing of two red bands, drifting 0.4 -> 5 px off)
            # over the unconfirmed lines' points (whole lines, in chain order); the other
            # lines' medians are NaN and compare False
            un = np.nonzero(unconfirmed[line])[0]
            drop |= row_disagreement(px[un], py[un], ldir[line[un]] == 0, line[un], rres[un],
                                     kind[un], nl) > max_row_residual
        if not keep_unsupported:
            keep_pt &= kind > 0
        for _ in range(3 if new_end_residual > 0 else 0):
            # the points dropped here leave new chain ends (next to the disturbance that
            # dropped their neighbours): gross outliers among them go too
            kk = np.nonzero(keep_pt)[0]
            if len(kk) == len(keep_pt):
                break
            kdir = ldir[line[kk]]
            off = by_family(chain_end_residual, kdir == 0, (px[kk], py[kk], kdir),
                            line[kk]) > new_end_residual
            if not np.any(off):
                break
            keep_pt[kk[off]] = False
    kept_n = np.bincount(line[keep_pt], minlength=nl)
    drop |= kept_n < min_length
    if options.min_checked_length > 0 and np.isfinite(pitch_px_est):
        # a short line (counted after the point filters) that no consistent intersection
        # confirms (a piece of an occluding contour or of a shadow edge that took a
        # neighbour's label) is dropped
        drop |= unconfirmed & (kept_n < options.min_checked_length * pitch_px_est)
    keep_i = inter.keep
    if np.any(drop) or not np.all(keep_pt):
        keepl = ~drop
        new_id = np.cumsum(keepl) - 1
        kp = keepl[line] & keep_pt
        lines = Lines(x=px[kp], y=py[kp], strength=strength[kp], line=new_id[line[kp]],
                      band=lab[keepl], direction=ldir[keepl], edge=lines.edge[keepl],
                      votes=lines.votes[keepl], agreement=lines.agreement[keepl])
        sel_i = keep_i & keepl[cl].all(axis=1)
        inter = replace(inter, cam=inter.cam[sel_i], proj=inter.proj[sel_i],
                        band=inter.band[sel_i], edge=inter.edge[sel_i],
                        line=new_id[cl[sel_i]], consistent=okc[sel_i],
                        keep=np.ones(int(sel_i.sum()), bool))
        return lines, coord[keepl], inter
    inter = replace(inter, cam=inter.cam[keep_i], proj=inter.proj[keep_i],
                    band=inter.band[keep_i], edge=inter.edge[keep_i], line=cl[keep_i],
                    consistent=okc[keep_i], keep=np.ones(int(keep_i.sum()), bool))
    return lines, coord, inter


def check_labels(counts: np.ndarray, direction: np.ndarray, prep: Prepared) -> None:
    """Refuse a decoding that labels one family of the grid and not one line of the other.

    A photograph of the grid shows both families of edges wherever it shows the grid; when
    the lines of one family are labelled and none of the other, the photograph is rotated
    by 90 degrees (the other family is then read backwards, and its windows do not decode)
    and the labels of the one decoded are those of the other family's bands: a simulated
    teapot view rotated so had 1-2 % of its labels right. Raises
    :class:`~nurbscan.detect.prepare.NoGrid` (an empty result, with the reason) when one
    family has at least ``CONFIRM_MIN_LINES`` lines of ``CONFIRM_LENGTH`` points or more and
    the other none.

    Since the orientation is found from the windows (:mod:`~nurbscan.detect.orientation`,
    before the decoding), a turned photograph is decoded upright and this check is the
    fallback for what that cannot tell (too few windows agreeing in either direction).

    Parameters
    ----------
    counts : (L,) int
        Points of each line.
    direction : (L,) int
        0 vertical-band edge, 1 horizontal-band edge.
    prep : Prepared
        The photograph (for its size in the reason).
    """
    long = np.bincount(direction[counts >= CONFIRM_LENGTH], minlength=2)
    every = np.bincount(direction, minlength=2)
    for d, other in ((0, 1), (1, 0)):
        if long[d] >= CONFIRM_MIN_LINES and every[other] == 0:
            names = ("vertical", "horizontal")
            raise NoGrid(f"image: grid labels inconsistent: {every[d]} {names[d]}-band edges "
                         f"decoded and no {names[other]}-band edge (is the photograph "
                         "rotated? the projector's vertical bands must appear upright)",
                         prep.size)


def check_extent(result) -> None:
    """Refuse a result too small for its labels to have been checked against each other.

    The labels of a line are confirmed by its neighbours along the rows and by its
    intersections (:func:`check_lines`); a handful of short pieces has neither, and in a
    noisy crop of a turned view such pieces were decoded consistently and all wrongly. Raises
    :class:`~nurbscan.detect.prepare.NoGrid` when fewer than ``MIN_LONG_LINES`` of the
    result's lines are longer than ``LONG_LINE_PX`` (arc length of their points, camera px).

    Parameters
    ----------
    result : DetectionResult
        The detection's result (its points ``x``, ``y`` in line order, ``line``).
    """
    n = result.nlines
    if n == 0:
        return
    long = int(np.sum(result.line_lengths() > LONG_LINE_PX))
    if long < MIN_LONG_LINES:
        raise NoGrid(f"image: only {long} of the {n} decoded lines are longer than "
                     f"{LONG_LINE_PX:.0f} px, too few to check their labels: no grid found",
                     tuple(result.image_size))


def row_support(x: np.ndarray, y: np.ndarray, direction: np.ndarray, coord: np.ndarray,
                span: float) -> tuple[np.ndarray, np.ndarray]:
    """How well each labelled edge point agrees with the labelled edges of its row (column).

    Along a pixel row the vertical-band edges' projector coordinates grow with x, and over a
    few bands the camera-to-projector map is close to linear. Each point's x is predicted
    from two labelled points of its row whose coordinates lie within ``span`` projector px
    of its own: by interpolation between its two neighbours, else by extrapolation from the
    two on one side. (Horizontal-band edges: the same along columns.) A point with no such
    pair has no support: it belongs to a band whose neighbours in the row are not labelled
    (a lone line, often a piece of an occluding contour or a shadow edge).

    Parameters
    ----------
    x, y : (M,) float
        Points, camera px (vertical-edge points on or, with a slanted fit line, within
        0.3 px of pixel rows, rounded to them; horizontal ones on columns).
    direction : (M,) int
        0 vertical-band edge, 1 horizontal-band edge.
    coord : (M,) float
        Projector coordinate of each point's labelled edge.
    span : float
        Largest spread of the three coordinates, projector px.

    Returns
    -------
    residual : (M,) float
        Distance from the prediction, camera px (NaN without support).
    kind : (M,) int
        0 no support, 1 interpolated, 2 extrapolated.
    """
    n = len(x)
    res = np.full(n, np.nan)
    kind = np.zeros(n, np.int64)
    run = np.round(np.where(direction == 0, y, x)).astype(np.int64)
    acr = np.where(direction == 0, x, y)

    def family(d):  # one family's support (the two side by side: _threads)
        idx = np.nonzero(direction == d)[0]
        o = idx[np.lexsort((acr[idx], small_ints(run[idx])))]
        a, c, r = acr[o], coord[o], run[o]
        m = len(o)
        p = np.arange(m)
        res_o, kind_o = np.full(m, np.nan), np.zeros(m, np.int64)
        for k, (i1, i2) in ((1, (-1, 1)), (2, (-2, -1)), (2, (1, 2))):
            j1, j2 = np.clip(p + i1, 0, m - 1), np.clip(p + i2, 0, m - 1)
            cc = np.stack([c[j1], c[p], c[j2]])
            ok = ((p + i1 >= 0) & (p + i2 < m) & (r[j1] == r) & (r[j2] == r)
                  & (c[j1] < c[j2]) & (cc.max(0) - cc.min(0) <= span))
            with np.errstate(all="ignore"):
                pred = a[j1] + (c - c[j1]) * (a[j2] - a[j1]) / (c[j2] - c[j1])
            take = ok & (kind_o == 0)
            res_o[take] = np.abs(a - pred)[take]
            kind_o[take] = k
        return o, res_o, kind_o

    for o, res_o, kind_o in parallel_map(family, (0, 1)):
        res[o], kind[o] = res_o, kind_o
    return res, kind


def row_disagreement(x: np.ndarray, y: np.ndarray, vertical: np.ndarray, line: np.ndarray,
                     residual: np.ndarray, kind: np.ndarray, n: int) -> np.ndarray:
    """Median distance of each line's points from where the labelled edges of their rows
    (columns) put them, measured across the line.

    :func:`row_support` measures along the pixel row (column); a line tilted by ``atan(s)``
    from its sampling axis (:func:`~nurbscan.detect.lines.chain_slope`) is ``sqrt(1 + s^2)``
    times nearer its predicted edge than that. Only the points with support (``kind`` 1 or
    2) count.

    Parameters
    ----------
    x, y : (M,) float
        Points, camera px, ordered by chain (:func:`~nurbscan.detect.lines.trace_lines`).
    vertical : (M,) bool
        Vertical-band edge points.
    line : (M,) int
        Each point's line, in [0, n).
    residual, kind : (M,) float, (M,) int
        :func:`row_support`'s result.
    n : int
        Number of lines.

    Returns
    -------
    (n,) float
        Median distance, camera px; NaN for a line without supported points.
    """
    slope = chain_slope(*_along_across(x, y, vertical), line)
    across = np.where((kind == 1) | (kind == 2), residual / np.hypot(1.0, slope), np.nan)
    return group_median(across, line, n)[0]


def plane_support(x: np.ndarray, y: np.ndarray, direction: np.ndarray, coord: np.ndarray,
                  line: np.ndarray, radius: float, k: int = 24, max_rms: float = 1.0,
                  min_spread: float = 2.0, at: np.ndarray | None = None) -> np.ndarray:
    """How well each labelled edge point agrees with the labelled edges of other lines of its
    family around it, in two dimensions.

    :func:`row_support` compares a point with the labelled edges of its own pixel row
    (column); where the bands of the other direction slant across a surface, they hide the
    neighbouring edges of most rows, and a well-measured piece of edge has none there. The
    projector coordinate is a smooth function of the camera pixel on one surface: a
    least-squares plane (:func:`local_plane`) through the ``k`` nearest points of the same
    family on *other* lines within ``radius`` camera px (so that a line does not support
    itself) predicts the point's coordinate, and the distance of the point from the
    predicted edge is ``|plane(p) - coord| / |grad plane|`` camera px (the first-order
    distance to a level set, as in :func:`~nurbscan.detect.evaluate.evaluate_detection`).

    Parameters
    ----------
    x, y : (M,) float
        Points, camera px.
    direction : (M,) int
        0 vertical-band edge, 1 horizontal-band edge.
    coord : (M,) float
        Projector coordinate of each point's labelled edge, px.
    line : (M,) int
        Each point's line.
    radius : float
        Neighbourhood, camera px.
    k : int
        Neighbours of the plane; fewer than ``k // 2`` within ``radius`` give no support.
    max_rms : float
        Largest RMS residual of the plane, projector px (more: a depth step or a misread
        neighbour among them, no support).
    min_spread : float
        The neighbours must spread by this (camera px RMS) in every direction (edges on
        both sides of the point's, or along and across them), else no support.
    at : (Q,) int, optional
        Indices of the points to judge (default all).

    Returns
    -------
    (M,) float
        Distance from the plane's edge, camera px; NaN without support (and off ``at``).
    """
    out = np.full(len(x), np.nan)
    judge = np.zeros(len(x), bool)
    judge[np.arange(len(x)) if at is None else at] = True

    def family(d):  # one family's distances (the two side by side: _threads)
        src = np.nonzero(direction == d)[0]
        dst = np.nonzero(judge & (direction == d))[0]
        if len(src) < k or not len(dst):
            return None
        dist, j = nearest_within(np.c_[x[src], y[src]], np.c_[x[dst], y[dst]], 3 * k, radius)
        jj = src[np.minimum(j, len(src) - 1)]
        ok = np.isfinite(dist) & (line[jj] != line[dst][:, None])
        ok &= np.cumsum(ok, axis=1) <= k
        pred, rms, _, _, g, spread = local_plane(x[jj], y[jj], coord[jj], x[dst], y[dst],
                                                 min_spread=min_spread, weights=ok,
                                                 return_gradient=True)
        gn = np.hypot(g[:, 0], g[:, 1])
        valid = ((ok.sum(1) >= k // 2) & (spread > min_spread**2) & (rms <= max_rms)
                 & (gn > 0))
        return dst[valid], np.abs(pred[valid] - coord[dst][valid]) / gn[valid]

    for got in parallel_map(family, (0, 1)):
        if got is not None:
            out[got[0]] = got[1]
    return out
