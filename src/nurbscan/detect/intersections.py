"""The intersection stage of :func:`~nurbscan.detect.detect_grid`: crossings of the labelled
vertical and horizontal edges (:func:`grid_intersections`) and their consistency with their
neighbours (:func:`grid_consistency`). :func:`intersect_lines` returns :class:`Intersections`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from ._threads import in_halves, parallel_map
from .lines import fit_lines
from .neighbours import closest_pairs
from .prepare import Prepared


@dataclass(frozen=True)
class Intersections:
    """Grid intersections of labelled lines (K).

    Attributes
    ----------
    cam, proj : (K, 2) float
        Camera px and exact projector px.
    band, edge, line : (K, 2) int
        (vertical, horizontal) band index, edge and line id.
    consistent : (K,) bool
        Agrees with its neighbours' local affine map (:func:`grid_consistency`).
    keep : (K,) bool
        Consistent, both fits straight edges (:data:`INTERSECTION_FIT_RMS`) and inside the
        photograph: the intersections a result keeps.
    """

    cam: np.ndarray
    proj: np.ndarray
    band: np.ndarray
    edge: np.ndarray
    line: np.ndarray
    consistent: np.ndarray
    keep: np.ndarray


def intersect_lines(lines, coord: np.ndarray, pitch_px: float, prep: Prepared,
                    pattern) -> Intersections:
    """All crossings of the labelled lines (``lines``: :class:`~nurbscan.detect.refine.Lines`,
    ``coord`` their projector coordinates), with the radius from the measured crossing pitch
    ``pitch_px`` (camera px)."""
    w, h = prep.size
    band_px = pitch_px * pattern.band / pattern.pitch
    cam, proj, cb, ce, cl, fit_rms = _intersections(
        lines.x, lines.y, lines.line, lines.direction, lines.band, lines.edge, coord,
        max(2.0, 0.5 * band_px) + 1.5 * prep.sigma, 8)
    # whole-grid consistency: intersections that disagree with their neighbours reveal a
    # wrongly labelled line; lines with more inconsistent than consistent crossings are dropped
    okc = grid_consistency(cam, proj, tol=0.5 * pattern.band)
    # all of them serve the checks of the lines; the result keeps the consistent ones whose
    # two fits are straight edges (grid_intersections' max_fit_rms)
    keep_i = okc & (fit_rms <= INTERSECTION_FIT_RMS)
    # (two lines' fits extrapolated to a crossing outside the photograph: no grid point)
    keep_i &= ((cam[:, 0] >= -0.5) & (cam[:, 0] <= w - 0.5) & (cam[:, 1] >= -0.5)
               & (cam[:, 1] <= h - 0.5))
    return Intersections(cam, proj, cb, ce, cl, okc, keep_i)


INTERSECTION_FIT_RMS = 0.5  # px, grid_intersections' max_fit_rms


def grid_intersections(x, y, line, direction, band, edge, coord, radius: float, k: int = 8,
                       max_fit_rms: float = INTERSECTION_FIT_RMS):
    """Crossings of labelled vertical and horizontal edges (method.md section 5, step 4).

    A vertical edge (band i, edge e) and a horizontal edge (band j, edge f) cross once in the
    projector, at (coord_v, coord_h), so once in the image. Candidate pairs are the
    (vertical family, horizontal family) pairs with points closer than ``radius`` px (where a
    band's colour hides the other band's edge, the two edge lines end at a common corner;
    otherwise they cross). Around the candidate (the midpoint of the closest pair), each
    family's ``k`` nearest points (of any of its segments) are fitted by a straight line,
    x = a + b (y - y0) for the vertical edge and y = c + d (x - x0) for the horizontal one, and
    the two lines are intersected. Pairs whose fitted points do not reach within ``radius`` of
    the intersection are dropped, and so are those where either fit's RMS residual exceeds
    ``max_fit_rms`` px: the k points are then not one straight edge (pieces of two surfaces
    at an occluding contour). 7.1 MP teapot view 0: intersection RMS 0.140 -> 0.123 px at 0
    noise (4 of 3843 dropped, one of them 3.4 px off), 0.147 -> 0.142 px at 1x noise.
    :func:`detect_grid` checks its lines with all crossings and keeps these in its result.

    Returns
    -------
    cam : (K, 2) camera px; proj : (K, 2) projector px; bands, edges, lines : (K, 2) int
        (vertical, horizontal) band index, edge, and a line id of each family near the point.
    """
    *out, fit_rms = _intersections(x, y, line, direction, band, edge, coord, radius, k)
    keep = fit_rms <= max_fit_rms
    return tuple(a[keep] for a in out)


def _intersections(x, y, line, direction, band, edge, coord, radius: float, k: int):
    """:func:`grid_intersections` before its residual test; also returns the larger of the
    two fits' RMS residuals of each crossing, (K,) px."""

    empty = (np.zeros((0, 2)), np.zeros((0, 2)), np.zeros((0, 2), np.int64),
             np.zeros((0, 2), np.int64), np.zeros((0, 2), np.int64), np.zeros(0))
    if len(band) == 0 or len(x) == 0:
        return empty
    fam_line = band * 2 + edge  # family within a direction
    pd = direction[line]
    pf = fam_line[line]
    vi = np.nonzero(pd == 0)[0]
    hi = np.nonzero(pd == 1)[0]
    if len(vi) < 2 or len(hi) < 2:
        return empty
    # per (vertical family, horizontal family), the closest pair of their points
    ia, ib, _ = closest_pairs(np.c_[x[vi], y[vi]], pf[vi], np.c_[x[hi], y[hi]], pf[hi], radius)
    if not len(ia):
        return empty
    a, b = vi[ia], hi[ib]
    cx, cy = 0.5 * (x[a] + x[b]), 0.5 * (y[a] + y[b])
    span = float(max(x.max(), y.max()) + 10.0)

    def family_fit(job):  # one family's fits (the two side by side: _threads)
        sel, fam, along, across, centre = job
        tree = cKDTree(np.c_[x[sel] + pf[sel] * span, y[sel]])
        kk = min(k, len(sel))
        dd, ii = tree.query(np.c_[cx + fam * span, cy], k=kk)
        dd = dd.reshape(len(cx), kk)
        ii = sel[np.minimum(ii.reshape(len(cx), kk), len(sel) - 1)]
        wts = (np.isfinite(dd) & (dd < 4 * radius)).astype(np.float64)
        t_ = along[ii] - centre[:, None]
        fit = np.c_[fit_lines(t_, across[ii], wts)[:2]]
        with np.errstate(all="ignore"):
            r2 = (wts * (across[ii] - fit[:, :1] - fit[:, 1:] * t_) ** 2).sum(1) / wts.sum(1)
        return fit, centre, np.sqrt(r2), wts, ii

    (fv, y0, rv, wv, iv), (fh, x0, rh, wh, ih) = parallel_map(
        family_fit, ((vi, pf[a], y, x, cy), (hi, pf[b], x, y, cx)))
    # x = fv0 + fv1 (y - y0); y = fh0 + fh1 (x - x0)
    with np.errstate(all="ignore"):
        px = (fv[:, 0] + fv[:, 1] * (fh[:, 0] - fh[:, 1] * x0 - y0)) / (1 - fv[:, 1] * fh[:, 1])
        py = fh[:, 0] + fh[:, 1] * (px - x0)
    ok = np.isfinite(px) & np.isfinite(py) & (wv.sum(1) >= 4) & (wh.sum(1) >= 4)
    ok &= np.hypot(px - cx, py - cy) < radius
    lv, lh = line[a], line[b]
    cam = np.c_[px, py][ok]
    proj = np.c_[coord[lv], coord[lh]][ok]
    return (cam, proj, np.c_[band[lv], band[lh]][ok], np.c_[edge[lv], edge[lh]][ok],
            np.c_[lv, lh][ok], np.fmax(rv, rh)[ok])


def grid_consistency(cam: np.ndarray, proj: np.ndarray, tol: float, k: int = 8) -> np.ndarray:
    """Whether each grid intersection agrees with its neighbours (a local affine map).

    The camera-to-projector map is smooth on a surface, so around each intersection it is
    fitted (least squares) by an affine map from its ``k`` nearest neighbours in the image,
    the intersection itself left out; an intersection whose projector point is more than
    ``tol`` projector px from the map's prediction is inconsistent (a wrong label of one of
    its lines). Returns a bool array (K,).
    """

    n = len(cam)
    if n < k + 2:
        return np.ones(n, bool)
    tree = cKDTree(cam)

    def part(rows):  # one half of the intersections (the two side by side: _threads)
        c = cam[rows]
        _, nb = tree.query(c, k=k + 1)
        nb = nb[:, 1:]
        d = cam[nb] - c[:, None, :]  # (m, k, 2), centred on the point: prediction = offset
        a = np.concatenate([d, np.ones((len(c), k, 1))], axis=2)
        ata = np.einsum("nki,nkj->nij", a, a) + np.eye(3)[None] * 1e-6
        atb = np.einsum("nki,nkj->nij", a, proj[nb])
        coef = np.linalg.solve(ata, atb)  # (m, 3, 2)
        pred = coef[:, 2, :]
        return np.hypot(*(pred - proj[rows]).T) < tol

    return in_halves(part, n)
