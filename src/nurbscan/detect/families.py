"""The family-fit stage of :func:`~nurbscan.detect.detect_grid`: labels from each family's own
camera-to-projector map, and, with a calibrated rig, from the epipolar prediction.

The projector coordinate of one family's edges is a smooth function of the camera pixel on a
surface: a least-squares plane (:func:`local_plane`) through the labelled points around an
unlabelled chain predicts its coordinate (:func:`family_coordinates`); with the rig the other
family's decoded points predict it too (:func:`epipolar_coordinates`). The chains vote for
the pattern edge nearest to the prediction (:func:`epipolar_labels`), and the rig unlabels
the chains it contradicts (:func:`epipolar_check`). :func:`family_labels` runs the rounds.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ._threads import parallel_map
from .chains import Chains
from .crossings import Reading
from .labels import (
    Labels,
    _assign_votes,
    _until_stable,
    check_adjacencies,
    nearest_band,
    point_coordinates,
    row_consistent,
    row_order,
)
from .neighbours import nearest_within
from .prepare import Prepared

#: The family plane's neighbourhood (camera pitches), largest RMS residual (projector px) and
#: largest distance of the prediction from a pattern edge (pitches), ``fit_rounds``.
FIT_RADIUS, FIT_RMS, FIT_TOL = 3.0, 1.0, 0.125
#: The epipolar prediction's neighbourhood (pitches) and rounds (with ``epipolar``). Teapot
#: scan (7.1 MP, 8 views, 1x noise, rig calibrated from the images): Gordon coverage 54.8 ->
#: 61.1 %, Table I unchanged; detection, views 0-7: coverage 0.685 -> 0.706, RMS 0.044 ->
#: 0.057 px, labels 99.997 %; about 0.7 s more per view.
EPIPOLAR_RADIUS, EPIPOLAR_ROUNDS = 2.0, 2


def family_labels(labels: Labels, chains: Chains, reading: Reading, prep: Prepared, pattern,
                  options, min_votes: int, min_agreement: float, epipolar=None) -> Labels:
    """More labels from the family fits (``options``:
    :class:`~nurbscan.detect.options.FamilyOptions`) and the rig's epipolar prediction
    (``epipolar``: ``other_coordinate(pixels (N, 2), direction, coord (N,)) -> (N,)``), where
    the bands are resolved; the labels their neighbours contradict are undone."""
    if not prep.fine:
        return labels
    px, py, cls, line = chains.x, chains.y, chains.cls, chains.line
    pitch_px_est = prep.pitch_px
    label = labels.label
    lcode_all = reading.lcode
    if options.fit_rounds:
        fit_r = FIT_RADIUS * pitch_px_est
        # lines of a pitch or more may be extrapolated to (fit_reach), shorter ones not
        long_line = np.bincount(line, minlength=len(label))[line] >= pitch_px_est
        reach_margin = np.where(long_line, -options.fit_reach * pattern.pitch, 2.0)
        rows = labels.rows if labels.rows is not None else row_order(px, py, cls)
        grid_rows = reading.grid_rows

        def fit_round(lab):
            pred = family_coordinates(lab, px, py, cls, line, pattern, fit_r, max_rms=FIT_RMS,
                                      margin=reach_margin)
            # the edge count agrees along the pixel row (column) or along the grid run: a
            # pixel column through the slanted bands of the other family misses the edges
            # hidden in them (the bottom of the teapot), the grid run does not
            ok = row_consistent(lab, line, cls, pred, pattern, rows)
            if grid_rows:
                ok |= row_consistent(lab, line, cls, pred, pattern, grid_rows)
            pred = np.where(ok, pred, np.nan)
            return epipolar_labels(lab, pred, cls, line, lcode_all, pattern, tol=FIT_TOL,
                                   min_votes=min_votes, min_agreement=min_agreement,
                                   dissent=True)

        label = _until_stable(fit_round, label, options.fit_rounds)
        label = check_adjacencies(label, reading.props, pattern)
    if epipolar is not None and EPIPOLAR_ROUNDS:
        radius = EPIPOLAR_RADIUS * pitch_px_est
        memo: dict = {}

        def epipolar_round(lab):
            pred = epipolar_coordinates(lab, px, py, cls, line, pattern, epipolar, radius,
                                        stride=3, memo=memo)
            lab = epipolar_labels(lab, pred, cls, line, lcode_all, pattern,
                                  min_votes=min_votes, min_agreement=min_agreement)
            return epipolar_check(lab, pred, cls, line, pattern)

        label = _until_stable(epipolar_round, label, EPIPOLAR_ROUNDS)
        label = check_adjacencies(label, reading.props, pattern)
    return replace(labels, label=label)


def local_plane(xs, ys, v, qx, qy, min_spread: float = 1.0, weights=None,
                return_gradient: bool = False) -> tuple:
    """Least-squares plane through scattered values, evaluated at query points.

    For each query point ``n`` (``qx``, ``qy`` (N,), camera px) the plane
    ``v = v0 + g . (p - mean p)`` through its K neighbours (``xs``, ``ys``, ``v`` (N, K);
    camera px and any value, e.g. projector px) is fitted by least squares, weighted by
    ``weights`` (N, K) if given (0 leaves a neighbour out). The gradient ``g`` is only
    fitted along the directions in which the neighbours spread by at least ``min_spread``
    px RMS (neighbours on one line do not tell how ``v`` changes across it: taken as 0
    there).

    Returns
    -------
    pred, rms, lo, hi : (N,) float
        The plane's value at (``qx``, ``qy``) (N,), the (weighted) RMS residual of the
        neighbours, and the least and largest neighbour value (of all K).
    g, spread : (N, 2), (N,) float
        With ``return_gradient``: the gradient (0 along the directions not fitted) and the
        neighbours' (weighted) variance along their direction of least spread, px^2.
    """
    # the weighted 2 x 2 moments and their eigen-decomposition in closed form (a rotation by
    # half the angle of (cxx - cyy, 2 cxy)), per point: 3.5 x faster than einsum and eigh
    # over (N, K, 2) arrays (25 instead of 87 ms per 7.1 MP view), equal to 1e-13
    if weights is None:
        sw = np.full(len(xs), float(xs.shape[1]))
        mx, my, vm = xs.mean(1), ys.mean(1), v.mean(1)
    else:
        w = np.asarray(weights, np.float64)
        sw = np.maximum(w.sum(1), 1e-12)
        mx, my, vm = (w * xs).sum(1) / sw, (w * ys).sum(1) / sw, (w * v).sum(1) / sw
    X, Y, V = xs - mx[:, None], ys - my[:, None], v - vm[:, None]
    wX, wY = (X, Y) if weights is None else (w * X, w * Y)
    cxx, cyy, cxy = (wX * X).sum(1), (wY * Y).sum(1), (wX * Y).sum(1)
    bx, by = (wX * V).sum(1), (wY * V).sum(1)
    half, dev = 0.5 * (cxx + cyy), np.hypot(0.5 * (cxx - cyy), cxy)
    lo_val, hi_val = half - dev, half + dev  # eigenvalues, with the vectors (-s, c), (c, s)
    th = 0.5 * np.arctan2(2.0 * cxy, cxx - cyy)
    c, s = np.cos(th), np.sin(th)
    lim = sw * min_spread**2
    k_hi = np.where(hi_val > lim, (c * bx + s * by) / np.maximum(hi_val, 1e-12), 0.0)
    k_lo = np.where(lo_val > lim, (c * by - s * bx) / np.maximum(lo_val, 1e-12), 0.0)
    gx, gy = c * k_hi - s * k_lo, s * k_hi + c * k_lo
    r2 = X * gx[:, None] + Y * gy[:, None] - V
    r2 *= r2
    rms = np.sqrt((r2 if weights is None else w * r2).sum(1) / sw)
    out = (vm + (qx - mx) * gx + (qy - my) * gy, rms, v.min(1), v.max(1))
    return out + (np.c_[gx, gy], lo_val / sw) if return_gradient else out


def _plane_at(x, y, v, src, dst, k: int, radius: float) -> tuple:
    """:func:`local_plane` through the ``k`` nearest points ``src`` (indices into ``x``, ``y``,
    ``v``) of each point ``dst``, for the ``dst`` that have all ``k`` within ``radius`` px.
    Returns those ``dst`` and the plane's value, RMS residual, least and largest value."""
    dist, j = nearest_within(np.c_[x[src], y[src]], np.c_[x[dst], y[dst]], k, radius)
    full = np.isfinite(dist).all(1)
    dst, j = dst[full], j[full]
    return (dst,) + local_plane(x[src][j], y[src][j], v[src][j], x[dst], y[dst])


def epipolar_coordinates(label, x, y, cls, line, pattern, other_coordinate, radius: float,
                         k: int = 32, max_rms: float = 1.0, stride: int = 1,
                         memo: dict | None = None) -> np.ndarray:
    """Each edge point's own projector coordinate, predicted from the other family's labelled
    points with a calibrated rig (epipolar decoding).

    With the rig, a labelled vertical-band edge point (camera px, projector ``x = c``) is
    triangulated on its edge's light surface, and the 3-D point's projector ``y`` is then
    known at that camera pixel as well (``other_coordinate(pixels (N, 2), "vertical", c (N,))
    -> y (N,)``, e.g. :func:`nurbscan.reconstruct.light.other_coordinate`); likewise ``x``
    for horizontal-band edge points. A point of the other family then gets its own
    coordinate (a horizontal-band edge point its projector ``y``) from the ``k`` nearest of
    those within ``radius`` camera px, by a least-squares plane in camera (x, y); NaN where
    there are fewer or where their RMS residual exceeds ``max_rms`` projector px (a depth
    step among them). Only every ``stride``-th point is predicted (NaN for the others: the
    callers decide per line). Arrays (N,) as in :func:`detect_grid`'s lines; returns (N,)
    projector px. ``memo`` (a dict, empty at first) keeps each point's edge coordinate and
    other coordinate between the calls of one detection: a point whose edge is unchanged
    is not intersected again (``other_coordinate`` is computed per point).
    """
    lab = label[line]
    d = cls // 2
    known = lab >= 0
    coord = point_coordinates(lab, cls, pattern)
    other = np.full(len(x), np.nan)
    done = np.zeros(len(x), bool)
    if memo:
        done = known & (memo["coord"] == coord)
        other[done] = memo["other"][done]
    for dd, name in ((0, "vertical"), (1, "horizontal")):
        m = np.nonzero(known & ~done & (d == dd))[0]
        if len(m):
            other[m] = other_coordinate(np.c_[x[m], y[m]], name, coord[m])
    if memo is not None:
        memo.update(coord=coord, other=other)
    pred = np.full(len(x), np.nan)

    def family(dd):  # one family's predictions (the two side by side: _threads)
        src = np.nonzero(known & (d == 1 - dd) & np.isfinite(other))[0]
        dst = np.nonzero(d == dd)[0]
        dst = dst[dst % stride == 0]
        if len(src) < k or not len(dst):
            return None
        dst, p, rms, _, _ = _plane_at(x, y, other, src, dst, k, radius)
        return dst, np.where(rms <= max_rms, p, np.nan)

    for out in parallel_map(family, (0, 1)):
        if out is not None:
            pred[out[0]] = out[1]
    return pred


def family_coordinates(label, x, y, cls, line, pattern, radius: float, k: int = 40,
                       max_rms: float = 1.0, margin=2.0, stride: int = 3) -> np.ndarray:
    """The projector coordinate of the unlabelled lines' points, interpolated from the
    labelled points of their own family around them.

    A vertical-band edge point's projector ``x`` is a smooth function of its camera pixel on
    one surface. Every point of an unlabelled line gets it from the ``k`` nearest labelled
    points of its own family (every ``stride``-th point of their lines) within ``radius``
    camera px, by a least-squares plane in camera (x, y) (:func:`local_plane`); likewise the
    projector ``y`` of horizontal-band edge points. NaN where there are fewer neighbours,
    where their RMS residual exceeds ``max_rms`` projector px (a depth step or a misread
    neighbour among them), or where the prediction is not at least ``margin`` projector px
    inside the neighbours' coordinates (an extrapolation: beyond an occluding contour the
    plane of the near surface says nothing; a negative ``margin`` allows that much of it,
    for callers that check the prediction further, as :func:`detect_grid` does with
    :func:`row_consistent`; ``margin`` is a number or one per point, (N,)).
    :func:`interpolate_labels` does the same along
    rows and columns, from the two labelled edges beside a point; the plane also reaches
    the pieces whose rows cross no labelled edge near them (the teapot's lid, where the
    vertical bands are tilted and cut the horizontal edges into cell-long pieces). The
    local camera-to-projector map is what phase-unwrapping decoders unwrap with.

    Arrays (N,) as in :func:`detect_grid`'s lines, ``label`` (L,); returns (N,) projector px
    (NaN for the points of labelled lines).
    """
    lab = label[line]
    d = cls // 2
    known = lab >= 0
    coord = point_coordinates(lab, cls, pattern)
    pred = np.full(len(x), np.nan)

    def family(dd):  # one family's predictions (the two side by side: _threads)
        src = np.nonzero(known & (d == dd))[0]
        src = src[src % stride == 0]
        dst = np.nonzero(~known & (d == dd))[0]
        if len(src) < k or not len(dst):
            return None
        dst, p, rms, lo, hi = _plane_at(x, y, coord, src, dst, k, radius)
        mg = margin[dst] if np.ndim(margin) else margin
        ok = (rms <= max_rms) & (p >= lo + mg) & (p <= hi - mg)
        return dst, np.where(ok, p, np.nan)

    for out in parallel_map(family, (0, 1)):
        if out is not None:
            pred[out[0]] = out[1]
    return pred


def epipolar_labels(label, pred, cls, line, lcode, pattern, tol: float = 0.25,
                    min_points: int = 6, min_votes: int = 3,
                    min_agreement: float = 0.9, dissent: bool = False) -> np.ndarray:
    """Label unlabelled lines by the projector coordinates the rig predicts for their points.

    ``pred`` (N,) is :func:`epipolar_coordinates` (or :func:`family_coordinates`). Each point of
    an unlabelled line of at least ``min_points`` points votes for the nearest pattern edge of
    its kind (rising / falling) to its predicted coordinate, within ``tol`` pitches. A line
    takes the band that ``min_votes`` of its votes, a share ``min_agreement`` of them, agree on,
    unless its own colour code ``lcode`` (-1 unknown) contradicts the band's. Where the bands of
    the other direction cut the edges into pieces too short for the colour windows (the teapot's
    lid and bottom), the other family is mostly decoded, so the pieces are labelled here. With
    ``dissent``, a predicted point farther than ``tol`` from every pattern edge of its kind
    votes against its line's labelling (a tracer chain that runs on past its edge along another
    feature). Returns labels (L,).
    """
    seq = np.asarray(pattern.sequence)
    counts = np.bincount(line, minlength=len(label))
    vl, vv = [], []
    for dd in (0, 1):
        dst = np.nonzero((label[line] < 0) & (cls // 2 == dd) & (counts[line] >= min_points)
                         & np.isfinite(pred))[0]
        edges = pattern.vertical_edges if dd == 0 else pattern.horizontal_edges
        e = cls[dst] % 2
        b = nearest_band(edges, pred[dst], e, pattern.pitch)
        good = np.abs(pred[dst] - edges[b, e]) <= tol * pattern.pitch
        vl.append(line[dst] if dissent else line[dst[good]])
        vv.append(np.where(good, b, len(seq)) if dissent else b[good])
    return _assign_votes(label, np.concatenate(vl), np.concatenate(vv), lcode, seq, min_votes,
                         min_agreement, accept_unknown=True)


def epipolar_check(label, pred, cls, line, pattern, tol: float = 0.25,
                   min_points: int = 3) -> np.ndarray:
    """Unlabel lines that the rig's epipolar prediction contradicts.

    A labelled line with at least ``min_points`` predicted points (``pred``,
    :func:`epipolar_coordinates`) more than half of which lie farther than ``tol`` pitches
    from its own edge coordinate is labelled wrongly, or is not one edge (a tracer chain that
    crosses from one band's edge to the next): it is unlabelled. Returns labels (L,).
    """
    nl = len(label)
    lab = label[line]
    m = (lab >= 0) & np.isfinite(pred)
    off = m & (np.abs(pred - point_coordinates(lab, cls, pattern)) > tol * pattern.pitch)
    n = np.bincount(line[m], minlength=nl)
    bad = (n >= min_points) & (np.bincount(line[off], minlength=nl) > 0.5 * n)
    return np.where(bad, -1, label)
