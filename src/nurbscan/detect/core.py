"""Grid detection in one photograph: normalise, find edges, trace lines, decode, intersect.

method.md section 2; the steps are in :mod:`.normalize`, :mod:`.edges`, :mod:`.lines` and
:mod:`.decode`. :func:`detect_grid` runs them and returns a
:class:`~nurbscan.detect.result.DetectionResult`.

Bad input (documented behaviour): an image that is not a 2-D grey or colour array, that holds
non-finite values, or a white image of another size raises
:class:`~nurbscan.errors.NurbscanError` (one line). A black, overexposed, blank or unrelated
image, or a pattern that does not match the photograph, gives an *empty* result whose
``warnings`` say why (and a :class:`UserWarning`); the command line turns an empty result into
a one-line error.
"""

from __future__ import annotations

import warnings as _warnings

import cv2
import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from ..errors import NurbscanError
from .decode import (
    band_crossings,
    bilinear,
    classify_colours,
    line_labels,
    oblique_runs,
    window_votes,
)
from .edges import detect_edge_points, refine_by_channels
from .lines import (
    chain_normals,
    chain_slope,
    fit_lines,
    join_collinear,
    local_residual,
    neighbour_fit,
    smooth_chains,
    trace_lines,
)
from .normalize import LUMA_601, noise_level, normalize
from .result import DetectionResult


def as_float_image(image, what: str = "image", gamma: float = 1.0) -> np.ndarray:
    """An (H, W, 3) float32 copy of ``image``, scaled to [0, 1] and raised to ``gamma``.

    uint8 / uint16 data are scaled by their full scale and linearised through a look-up table;
    grey images are repeated in the three channels; float data must be finite.
    """
    a = np.asarray(image)
    if a.ndim == 2:
        a = np.repeat(a[:, :, None], 3, axis=2)
    if a.ndim != 3 or a.shape[2] not in (3, 4) or a.shape[0] < 16 or a.shape[1] < 16:
        raise NurbscanError(f"{what}: expected an (H, W, 3) image of at least 16 x 16 px, "
                            f"got shape {a.shape}")
    a = a[:, :, :3]
    if a.dtype in (np.uint8, np.uint16):
        top = 255 if a.dtype == np.uint8 else 65535
        lut = ((np.arange(top + 1, dtype=np.float64) / top) ** gamma).astype(np.float32)
        if a.dtype == np.uint8:  # OpenCV's table look-up: same values, several times faster
            return cv2.LUT(np.ascontiguousarray(a), lut)
        return lut[a]
    if a.dtype.kind not in "fiu":
        raise NurbscanError(f"{what}: unsupported sample type {a.dtype}")
    a = a.astype(np.float32)
    if not np.all(np.isfinite(a)):
        raise NurbscanError(f"{what}: holds NaN or infinite values")
    a = np.clip(a, 0.0, None)
    return a**gamma if gamma != 1 else a


def as_float_planes(image, what: str = "image", gamma: float = 1.0) -> tuple:
    """The three colour planes of :func:`as_float_image`, each (H, W) float32 and contiguous.

    8-bit images are split first and each plane looked up (OpenCV), which avoids an
    interleaved (H, W, 3) float copy and its split: 60 instead of 135 ms for 7.1 MP.
    """
    a = np.asarray(image)
    if a.dtype == np.uint8 and a.ndim == 3 and a.shape[2] in (3, 4) and min(a.shape[:2]) >= 16:
        lut = ((np.arange(256, dtype=np.float64) / 255) ** gamma).astype(np.float32)
        return tuple(cv2.LUT(c, lut) for c in cv2.split(np.ascontiguousarray(a[:, :, :3])))
    return tuple(cv2.split(as_float_image(image, what, gamma)))


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
    from scipy.spatial import cKDTree

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
    tv = cKDTree(np.c_[x[vi], y[vi]])
    th = cKDTree(np.c_[x[hi], y[hi]])
    pairs = tv.sparse_distance_matrix(th, radius, output_type="ndarray")
    if not len(pairs):
        return empty
    a, b, dist = vi[pairs["i"]], hi[pairs["j"]], pairs["v"]
    key = pf[a].astype(np.int64) * 1_000_000 + pf[b]
    o = np.lexsort((dist, key))
    first = np.r_[True, key[o][1:] != key[o][:-1]]
    a, b = a[o][first], b[o][first]
    cx, cy = 0.5 * (x[a] + x[b]), 0.5 * (y[a] + y[b])
    span = float(max(x.max(), y.max()) + 10.0)
    out = []
    for sel, fam, along, across, centre in ((vi, pf[a], y, x, cy), (hi, pf[b], x, y, cx)):
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
        out.append((fit, centre, np.sqrt(r2), wts, ii))
    (fv, y0, rv, wv, iv), (fh, x0, rh, wh, ih) = out
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


def clean_crossings(sig: np.ndarray, a: np.ndarray, r: np.ndarray, st: np.ndarray, d: int,
                    delta: float, dark_level: float, base: np.ndarray | None = None,
                    step: np.ndarray | None = None) -> np.ndarray:
    """Whether each band crossing lies outside every band of the other direction.

    Inside a band of the other direction the two colours mix (crossing rule) and the band's
    colour is misread. There the gaps on both sides of the crossing are lit too, so a
    crossing is *clean* when the edge signal ``sig`` is below ``dark_level`` at ``delta`` px
    outside its rising and its falling edge along the row (column), and no other edge point of
    the row lies within ``delta + 1`` px of its edges (the samples must fall in the gaps).
    Both sides are required and sampled near the band: a band of the other direction seen
    obliquely may light one side only, or only the middle of a wide gap.

    Parameters
    ----------
    sig : ndarray (H, W)
        Edge signal.
    a, r : ndarray (N,)
        Across coordinate (px) and row (column) index of the points, sorted by (r, a).
    st : ndarray (K,) int
        Positions of the rising points of the band crossings in ``a``.
    d : int
        0 for vertical bands (rows), 1 for horizontal bands (columns).
    base, step : ndarray (N, 2), optional
        Runs that are not pixel rows (columns), :func:`~nurbscan.detect.decode.oblique_runs`:
        the pixel of the run at coordinate ``a`` near point i is ``base[i] + (a - a[i]) *
        step[i]`` (``step`` a unit vector). By default the row (column) ``r``.
    delta : float
        Distance of the gap samples from the edges, px.
    dark_level : float
        Largest signal of a dark gap.

    Returns
    -------
    ndarray (K,) bool
    """
    n = len(a)
    if not len(st):
        return np.zeros(0, bool)
    pl, pr = a[st] - delta, a[st + 1] + delta
    prv = np.maximum(st - 1, 0)
    nxt = np.minimum(st + 2, n - 1)
    room = ((st == 0) | (r[prv] != r[st]) | (a[prv] < pl - 1.0)) & \
        ((st + 2 >= n) | (r[nxt] != r[st]) | (a[nxt] > pr + 1.0))
    if base is None:  # the pixel row (column) r
        base = np.c_[a, r] if d == 0 else np.c_[r, a]
        step = np.zeros((n, 2))
        step[:, d] = 1.0
    ql = base[st] - delta * step[st]
    qr = base[st + 1] + delta * step[st + 1]
    lev_l = bilinear(sig, ql[:, 0], ql[:, 1])
    lev_r = bilinear(sig, qr[:, 0], qr[:, 1])
    return room & (lev_l < dark_level) & (lev_r < dark_level)


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
    for d in (0, 1):
        idx = np.nonzero(direction == d)[0]
        o = idx[np.lexsort((acr[idx], run[idx]))]
        a, c, r = acr[o], coord[o], run[o]
        m = len(o)
        p = np.arange(m)
        for k, (i1, i2) in ((1, (-1, 1)), (2, (-2, -1)), (2, (1, 2))):
            j1, j2 = np.clip(p + i1, 0, m - 1), np.clip(p + i2, 0, m - 1)
            cc = np.stack([c[j1], c[p], c[j2]])
            ok = ((p + i1 >= 0) & (p + i2 < m) & (r[j1] == r) & (r[j2] == r)
                  & (c[j1] < c[j2]) & (cc.max(0) - cc.min(0) <= span))
            with np.errstate(all="ignore"):
                pred = a[j1] + (c - c[j1]) * (a[j2] - a[j1]) / (c[j2] - c[j1])
            take = ok & (kind[o] == 0)
            res[o[take]] = np.abs(a - pred)[take]
            kind[o[take]] = k
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


def grid_consistency(cam: np.ndarray, proj: np.ndarray, tol: float, k: int = 8) -> np.ndarray:
    """Whether each grid intersection agrees with its neighbours (a local affine map).

    The camera-to-projector map is smooth on a surface, so around each intersection it is
    fitted (least squares) by an affine map from its ``k`` nearest neighbours in the image,
    the intersection itself left out; an intersection whose projector point is more than
    ``tol`` projector px from the map's prediction is inconsistent (a wrong label of one of
    its lines). Returns a bool array (K,).
    """
    from scipy.spatial import cKDTree

    n = len(cam)
    if n < k + 2:
        return np.ones(n, bool)
    _, nb = cKDTree(cam).query(cam, k=k + 1)
    nb = nb[:, 1:]
    d = cam[nb] - cam[:, None, :]  # (n, k, 2), centred on the point: prediction = offset
    a = np.concatenate([d, np.ones((n, k, 1))], axis=2)
    ata = np.einsum("nki,nkj->nij", a, a) + np.eye(3)[None] * 1e-6
    atb = np.einsum("nki,nkj->nij", a, proj[nb])
    coef = np.linalg.solve(ata, atb)  # (n, 3, 2)
    pred = coef[:, 2, :]
    return np.hypot(*(pred - proj).T) < tol


def _assign_votes(label, vote_line, vote_band, lcode, seq, min_votes: int,
                  min_agreement: float, accept_unknown: bool = False) -> np.ndarray:
    """Labels (L,) with the unlabelled lines that their votes label with confidence.

    A line takes the band that ``min_votes`` of its votes (``vote_line``, ``vote_band``), a
    share ``min_agreement`` of them, agree on (:func:`~nurbscan.detect.decode.line_labels`)
    when its colour code ``lcode`` (-1 unknown) is the pattern's colour of that band in
    ``seq`` (or is unknown and ``accept_unknown``). Lines already labelled are kept.
    """
    new, _, _ = line_labels(vote_line, None, vote_band, len(label), min_votes=min_votes,
                            min_agreement=min_agreement, direct=True)
    cand = np.nonzero((new >= 0) & (new < len(seq)) & (label < 0))[0]
    col = lcode[cand]
    ok = (col == seq[new[cand]]) | (accept_unknown & (col < 0))
    out = label.copy()
    out[cand[ok]] = new[cand[ok]]
    return out


def propagate_labels(label, lr, lf, st, rw, ra, fa, lcode, seq, nbands: int, ratio: float,
                     rounds: int = 4, min_votes: int = 3, min_agreement: float = 0.9):
    """Extend the labelling to unlabelled lines from their labelled neighbours.

    Along a row (column), band crossings k and k+1 that are adjacent (no edge between them) and
    a plausible pitch apart (their distance over the band's width within 0.75 .. 1.25 of the
    pattern's pitch / band) are consecutive bands. A run k-1, k, k+1 of such crossings with
    similar spacings (ratio 0.75 .. 1.33) whose first two are labelled i - 1, i consistently
    makes the third band i + 1 (and likewise backwards). An unlabelled line takes the index
    its crossings vote for when ``min_votes`` agree (share ``min_agreement``) and the line's
    own colour is the pattern's colour of that band; each round extends the labelled region
    by one band.

    Parameters are per crossing (K,): the lines of its rising / falling point, its start
    position in the sorted edge list, its row, and the rising / falling coordinates; ``lcode``
    the colour code of each line (-1 unknown); ``seq`` the pattern sequence.
    """
    k = _adjacent(st, rw, ra, fa, ratio)
    if len(k) < 2:
        return label
    mid = 0.5 * (ra + fa)
    # runs of three neighbouring crossings k-1, k, k+1 with similar spacing
    isadj = np.zeros(len(st), bool)
    isadj[k] = True
    k2 = k[isadj[np.maximum(k - 1, 0)] & (k >= 1)]
    with np.errstate(all="ignore"):
        q = (mid[k2 + 1] - mid[k2]) / (mid[k2] - mid[k2 - 1])
    k2 = k2[(q > 0.75) & (q < 1.33)]
    label = label.copy()
    for _ in range(rounds):
        cr, cf = label[lr], label[lf]
        cl = np.where(cr < 0, cf, np.where((cf < 0) | (cf == cr), cr, -2))
        # a labelled, consistent pair (k-1, k) extends to k+1; (k, k+1) extends to k-1
        fwd = (cl[k2 - 1] >= 0) & (cl[k2] == cl[k2 - 1] + 1)
        bwd = (cl[k2 + 1] >= 0) & (cl[k2] == cl[k2 + 1] - 1)
        src = np.r_[cl[k2][fwd], cl[k2][bwd]]
        dst = np.r_[k2[fwd] + 1, k2[bwd] - 1]
        val = src + np.r_[np.ones(fwd.sum(), np.int64), -np.ones(bwd.sum(), np.int64)]
        ok = src >= 0
        dst, val = dst[ok], val[ok]
        ok = (val >= 0) & (val < nbands)
        dst, val = dst[ok], val[ok]
        vl = np.r_[lr[dst], lf[dst]]
        vv = np.r_[val, val]
        free = label[vl] < 0
        vl, vv = vl[free], vv[free]
        if not len(vl):
            break
        out = _assign_votes(label, vl, vv, lcode, seq, min_votes, min_agreement)
        if np.array_equal(out, label):
            break
        label = out
    return label


def propagate_pairs(label, lr, lf, lcode, seq, min_votes: int = 3,
                    min_agreement: float = 0.9) -> np.ndarray:
    """Label the other edge of labelled bands: both edges of a band crossing share its index.

    A band crossing (K,) pairs the rising line ``lr`` and falling line ``lf`` of one band along
    a row (column). Each crossing with one labelled and one unlabelled line votes the label to
    the unlabelled one; a line takes the index when ``min_votes`` votes agree (share
    ``min_agreement`` of its votes) and its own colour code ``lcode`` (-1 unknown) is the
    pattern's colour of that band. Returns the new labels (L,).
    """
    a, b = label[lr], label[lf]
    src = np.r_[a, b]
    dst = np.r_[lf, lr]
    ok = (src >= 0) & (label[dst] < 0)
    if not np.any(ok):
        return label
    return _assign_votes(label, dst[ok], src[ok], lcode, seq, min_votes, min_agreement)





def pooled_labels(label, src, dst, vote_line, vote_band, vote_pos, lcode, seq, min_votes: int,
                  min_agreement: float, min_positions: int) -> np.ndarray:
    """Label unlabelled chains by the pooled votes of the edge they are pieces of.

    Bands of the other direction cut an edge into chain pieces (``src -> dst`` (J,), the joins
    of :func:`~nurbscan.detect.lines.join_collinear`); each piece alone may hold too few
    window votes, from too few window positions, to be labelled (the teapot's lid, where the
    tilted vertical bands cut every horizontal edge into cell-long pieces). The votes
    (``vote_line``, ``vote_band``, ``vote_pos``) of all pieces of one joined edge are pooled
    and decided like a line's (:func:`~nurbscan.detect.decode.line_labels`); an unlabelled
    piece takes the edge's band when its own colour code ``lcode`` (L,) is the pattern's
    colour of that band. A wrong join mixes two edges' votes, which then fail the agreement
    test: it leaves the pieces unlabelled rather than mislabelled. Returns labels (L,).
    """
    nl = len(label)
    graph = coo_matrix((np.ones(len(src)), (src, dst)), shape=(nl, nl))
    ncomp, comp = connected_components(graph, directed=False)
    clab, _, _ = line_labels(comp[vote_line], None, vote_band, ncomp, min_votes=min_votes,
                             min_agreement=min_agreement, direct=True, vote_pos=vote_pos,
                             min_positions=min_positions)
    new = clab[comp]
    ok = (label < 0) & (new >= 0)
    ok[ok] &= lcode[ok] == seq[new[ok]]
    out = label.copy()
    out[ok] = new[ok]
    return out


def propagate_collinear(label, src, dst, lcode, seq, unknown: bool = False) -> np.ndarray:
    """Give an unlabelled chain the label of the chain it continues (or that continues it).

    ``src -> dst`` (J,) are joins of collinear chains of one edge class across a gap
    (:func:`~nurbscan.detect.lines.join_collinear`): pieces of one edge cut by a crossing band.
    The unlabelled piece takes the label when its own colour code ``lcode`` is the pattern's
    colour of that band (an unknown colour does not confirm it). Returns labels (L,).
    """
    out = label.copy()
    for a, b in ((src, dst), (dst, src)):
        m = (out[a] >= 0) & (out[b] < 0)
        a, b = a[m], b[m]
        ok = (lcode[b] == seq[out[a]]) | (unknown & (lcode[b] < 0))
        out[b[ok]] = out[a[ok]]
    return out


def row_order(x, y, cls) -> list:
    """Edge points in row order, per direction: ``(d, idx, run, across)`` for ``d`` 0 (vertical-
    band edges, by pixel row, then x) and 1 (horizontal-band edges, by pixel column, then y).

    ``idx`` indexes ``x``, ``y``, ``cls`` (N,); ``run`` is the rounded row (column), ``across``
    the coordinate along it. Directions with fewer than 3 points are left out. It does not
    depend on the labels, so rounds of :func:`interpolate_labels` share it.
    """
    out = []
    for d in (0, 1):
        idx = np.nonzero(cls // 2 == d)[0]
        if len(idx) < 3:
            continue
        run = np.round(y[idx] if d == 0 else x[idx]).astype(np.int64)
        acr = x[idx] if d == 0 else y[idx]
        o = np.lexsort((acr, run))
        out.append((d, idx[o], run[o], acr[o]))
    return out


def _row_neighbours(label, line, cls, pattern, d: int, idx: np.ndarray) -> tuple:
    """The labelled points of one family's rows (:func:`row_order`'s ``d`` and ``idx``):
    whether each point is labelled, its edge coordinate (projector px, NaN if not), and the
    positions in ``idx`` of the nearest labelled point at or before and at or after it
    (-1 / ``len(idx)`` where none; the caller checks that it lies in the same row)."""
    lab = label[line[idx]]
    known = lab >= 0
    c = np.full(len(idx), np.nan)
    c[known] = pattern.edge_coordinate(("vertical", "horizontal")[d], lab[known],
                                       cls[idx][known] % 2)
    m = len(idx)
    p = np.arange(m)
    prv = np.maximum.accumulate(np.where(known, p, -1))
    nxt = np.minimum.accumulate(np.where(known, p, m)[::-1])[::-1]
    return known, c, prv, nxt


def interpolate_labels(label, x, y, cls, line, lcode, pattern, span: float,
                       tol: float, min_votes: int = 3, min_agreement: float = 0.9,
                       require_colour: bool = True, rows: list | None = None) -> np.ndarray:
    """Label unlabelled lines from the projector coordinates of their labelled neighbours.

    Along a pixel row the vertical-band edges' projector x grows with the camera x, and
    between two labelled edge points of the row whose coordinates c1 < c2 differ by at most
    ``span`` projector px (a couple of pitches: no depth step between them) the map is close to
    linear. Each point of an unlabelled line lying between two such points is given the
    interpolated coordinate c; the nearest pattern edge of the point's own kind (rising or
    falling) to c is its vote when it lies within ``tol`` projector px (pattern edges of one
    kind are a pitch apart) and when the points of the row between the two labelled ones and
    it are as many as the pattern edges between their coordinates (no edge missed or spurious
    there). A line takes the band that ``min_votes`` of its votes, a share
    ``min_agreement`` of them, agree on, and whose colour in the pattern is the line's own
    colour code ``lcode`` (-1 unknown: accepted unless ``require_colour``). Horizontal-band
    edges: the same along pixel columns. This is the local camera-to-projector map that
    Gray-code and phase-unwrapping decoders use for their unwrapping, seeded here by the
    lines that the colour windows label.

    Parameters
    ----------
    label : (L,) int
        Band index of each line, -1 unlabelled.
    x, y : (N,) float
        Edge points, camera px, sorted by line.
    cls : (N,) int
        Edge class: direction * 2 + edge (0 rising, 1 falling).
    line : (N,) int
        Line of each point.
    lcode : (L,) int
        Colour code of each line, -1 unknown.
    pattern : nurbscan.pattern.Pattern
    span, tol : float
        Projector px.
    rows : list, optional
        :func:`row_order` of the points (computed when not given).

    Returns
    -------
    (L,) int
        The labels, with the newly labelled lines.
    """
    seq = np.asarray(pattern.sequence)
    rows = row_order(x, y, cls) if rows is None else rows
    ci = np.full(len(x), np.nan)  # interpolated coordinate of the unlabelled points
    for d, idx, run, acr in rows:
        known, c, prv, nxt = _row_neighbours(label, line, cls, pattern, d, idx)
        m = len(idx)
        ok = ~known & (prv >= 0) & (nxt < m)
        j1, j2 = np.clip(prv, 0, m - 1), np.clip(nxt, 0, m - 1)
        ok &= (run[j1] == run) & (run[j2] == run)
        with np.errstate(all="ignore"):
            ok &= (c[j2] > c[j1]) & (c[j2] - c[j1] <= span) & (acr[j2] > acr[j1])
            ci[idx] = np.where(ok, c[j1] + (acr - acr[j1]) * (c[j2] - c[j1])
                               / (acr[j2] - acr[j1]), np.nan)
    # every edge point of the row between the two labelled ones is one pattern edge: as many
    # points lie between them and this point as pattern edges (no edge missed or spurious on
    # either side)
    consistent = row_consistent(label, line, cls, ci, pattern, rows)
    vl, vv = [], []
    for d, edges in ((0, pattern.vertical_edges), (1, pattern.horizontal_edges)):
        k = np.nonzero(consistent & (cls // 2 == d))[0]
        e = cls[k] % 2
        b = nearest_band(edges, ci[k], e, pattern.pitch)
        good = np.abs(ci[k] - edges[b, e]) <= tol
        vl.append(line[k[good]])
        vv.append(b[good])
    return _assign_votes(label, np.concatenate(vl), np.concatenate(vv), lcode, seq, min_votes,
                         min_agreement, accept_unknown=not require_colour)


def nearest_band(edges: np.ndarray, coord: np.ndarray, edge: np.ndarray,
                 pitch: float) -> np.ndarray:
    """Index (K,) of the band whose ``edge`` (0 rising, 1 falling; (K,)) is nearest to the
    projector coordinates ``coord`` (K,), px; ``edges`` (B, 2) as ``Pattern.vertical_edges``."""
    return np.clip(np.round((coord - edges[0, edge]) / pitch).astype(np.int64), 0,
                   len(edges) - 1)


def point_coordinates(lab: np.ndarray, cls: np.ndarray, pattern) -> np.ndarray:
    """Projector coordinate (N,) of the labelled edge of each point (band ``lab``, class
    ``cls`` = direction * 2 + edge); NaN for unlabelled points (``lab`` -1)."""
    vert = cls // 2 == 0
    return np.where(vert,
                    pattern.edge_coordinate("vertical", np.where(vert, lab, -1), cls % 2),
                    pattern.edge_coordinate("horizontal", np.where(vert, -1, lab), cls % 2))


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
    w = np.ones(xs.shape) if weights is None else np.asarray(weights, np.float64)
    sw = np.maximum(w.sum(1), 1e-12)
    mx, my = (w * xs).sum(1) / sw, (w * ys).sum(1) / sw
    P = np.stack([xs - mx[:, None], ys - my[:, None]], -1)
    vm = (w * v).sum(1) / sw
    C = np.einsum("nk,nki,nkj->nij", w, P, P)
    bvec = np.einsum("nk,nki,nk->ni", w, P, v - vm[:, None])
    val, vec = np.linalg.eigh(C)
    coef = np.einsum("nji,nj->ni", vec, bvec) / np.maximum(val, 1e-12)
    coef = np.where(val > sw[:, None] * min_spread**2, coef, 0.0)
    g = np.einsum("nji,ni->nj", vec, coef)
    r2 = (vm[:, None] + np.einsum("nki,ni->nk", P, g) - v) ** 2
    rms = np.sqrt((w * r2).sum(1) / sw)
    q = np.c_[qx - mx, qy - my]
    out = (vm + np.einsum("ni,ni->n", q, g), rms, v.min(1), v.max(1))
    return out + (g, val[:, 0] / sw) if return_gradient else out


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
    for d in (0, 1):
        src = np.nonzero(direction == d)[0]
        dst = np.nonzero(judge & (direction == d))[0]
        if len(src) < k or not len(dst):
            continue
        dist, j = cKDTree(np.c_[x[src], y[src]]).query(np.c_[x[dst], y[dst]], k=3 * k,
                                                        distance_upper_bound=radius)
        jj = src[np.minimum(j, len(src) - 1)]
        ok = np.isfinite(dist) & (line[jj] != line[dst][:, None])
        ok &= np.cumsum(ok, axis=1) <= k
        pred, rms, _, _, g, spread = local_plane(x[jj], y[jj], coord[jj], x[dst], y[dst],
                                                 min_spread=min_spread, weights=ok,
                                                 return_gradient=True)
        gn = np.hypot(g[:, 0], g[:, 1])
        valid = ((ok.sum(1) >= k // 2) & (spread > min_spread**2) & (rms <= max_rms)
                 & (gn > 0))
        out[dst[valid]] = np.abs(pred[valid] - coord[dst][valid]) / gn[valid]
    return out


def _plane_at(x, y, v, src, dst, k: int, radius: float) -> tuple:
    """:func:`local_plane` through the ``k`` nearest points ``src`` (indices into ``x``, ``y``,
    ``v``) of each point ``dst``, for the ``dst`` that have all ``k`` within ``radius`` px.
    Returns those ``dst`` and the plane's value, RMS residual, least and largest value."""
    dist, j = cKDTree(np.c_[x[src], y[src]]).query(np.c_[x[dst], y[dst]], k=k,
                                                   distance_upper_bound=radius)
    full = np.isfinite(dist).all(1)
    dst, j = dst[full], j[full]
    return (dst,) + local_plane(x[src][j], y[src][j], v[src][j], x[dst], y[dst])


def epipolar_coordinates(label, x, y, cls, line, pattern, other_coordinate, radius: float,
                         k: int = 32, max_rms: float = 1.0, stride: int = 1) -> np.ndarray:
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
    projector px.
    """
    lab = label[line]
    d = cls // 2
    known = lab >= 0
    coord = point_coordinates(lab, cls, pattern)
    other = np.full(len(x), np.nan)
    for dd, name in ((0, "vertical"), (1, "horizontal")):
        m = np.nonzero(known & (d == dd))[0]
        if len(m):
            other[m] = other_coordinate(np.c_[x[m], y[m]], name, coord[m])
    pred = np.full(len(x), np.nan)
    for dd in (0, 1):
        src = np.nonzero(known & (d == 1 - dd) & np.isfinite(other))[0]
        dst = np.nonzero(d == dd)[0]
        dst = dst[dst % stride == 0]
        if len(src) < k or not len(dst):
            continue
        dst, p, rms, _, _ = _plane_at(x, y, other, src, dst, k, radius)
        pred[dst] = np.where(rms <= max_rms, p, np.nan)
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
    for dd in (0, 1):
        src = np.nonzero(known & (d == dd))[0]
        src = src[src % stride == 0]
        dst = np.nonzero(~known & (d == dd))[0]
        if len(src) < k or not len(dst):
            continue
        dst, p, rms, lo, hi = _plane_at(x, y, coord, src, dst, k, radius)
        mg = margin[dst] if np.ndim(margin) else margin
        ok = (rms <= max_rms) & (p >= lo + mg) & (p <= hi - mg)
        pred[dst] = np.where(ok, p, np.nan)
    return pred


def row_consistent(label, line, cls, pred, pattern, rows: list) -> np.ndarray:
    """Whether each point's predicted edge agrees with the edge count of its row.

    ``pred`` (N,) is a predicted projector coordinate for points of unlabelled lines (NaN
    elsewhere); its candidate is the nearest pattern edge of the point's kind (rising /
    falling). Along the point's pixel row (column for horizontal-band edges; ``rows`` is
    :func:`row_order`), between it and the nearest labelled point on each side, there must
    lie as many edge points as there are pattern edges between their coordinates and the
    candidate (no edge missed or spurious between them, as in :func:`interpolate_labels`).
    A point passes when it has a labelled neighbour in its row on at least one side and
    every such side agrees: a surface squeezed between two others (a handle's side) holds
    more edges than a plane through its neighbours allows. Returns bool (N,).
    """
    out = np.zeros(len(line), bool)
    for d, idx, run, _ in rows:
        known, c, prv, nxt = _row_neighbours(label, line, cls, pattern, d, idx)
        m = len(idx)
        k = np.nonzero(~known & np.isfinite(pred[idx]))[0]
        edges = pattern.vertical_edges if d == 0 else pattern.horizontal_edges
        flat = np.sort(edges.reshape(-1))
        e = cls[idx[k]] % 2
        cand = edges[nearest_band(edges, pred[idx[k]], e, pattern.pitch), e]
        eidx = np.searchsorted(flat, cand - 1e-6)
        j1, j2 = prv[k], nxt[k]
        has1 = (j1 >= 0) & (run[np.maximum(j1, 0)] == run[k])
        has2 = (j2 < m) & (run[np.minimum(j2, m - 1)] == run[k])
        c1, c2 = c[np.maximum(j1, 0)], c[np.minimum(j2, m - 1)]
        ok1 = (eidx - np.searchsorted(flat, c1 - 1e-6)) == (k - j1)
        ok2 = (np.searchsorted(flat, c2 - 1e-6) - eidx) == (j2 - k)
        out[idx[k]] = (has1 | has2) & (~has1 | ok1) & (~has2 | ok2)
    return out


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
                           both_sides=False)
    out[ends] = np.where(ok[ends], np.abs(across[ends] - c0[ends]), 0.0)
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
    of each extra point (M,), -1 where none.
    """
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
    for _ in range(rounds):
        o = np.argsort(okey)
        sk, sl = okey[o], oline[o]
        free = np.nonzero(att < 0)[0]
        if not len(free) or not len(sk):
            break
        ny = np.clip(ey[free, None] + dy[None, :], 0, h - 1)
        nx = np.clip(ex[free, None] + dx[None, :], 0, w - 1)
        q = keys(np.repeat(ecls[free, None], 9, 1), ny, nx)
        j = np.minimum(np.searchsorted(sk, q), len(sk) - 1)
        hit = sk[j] == q
        lid = np.where(hit, sl[j], -1)
        lo = np.where(hit, lid, np.iinfo(np.int64).max).min(1)
        hi = lid.max(1)
        new = hit.any(1) & (lo == hi)
        if not np.any(new):
            break
        att[free[new]] = hi[new]
        okey = np.r_[okey, keys(ecls[free[new]], ey[free[new]], ex[free[new]])]
        oline = np.r_[oline, hi[new]]
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
    o = np.lexsort((np.where(vk, np.r_[y, extra.y[a]], np.r_[x, extra.x[a]]), line_all))
    x, y = np.r_[x, extra.x[a]][o], np.r_[y, extra.y[a]][o]
    strength = np.r_[strength, extra.strength[a]][o]
    new = np.r_[np.zeros(len(line), bool), np.ones(len(a), bool)][o]
    line = line_all[o]
    vk = direction[line] == 0
    c0, ok = neighbour_fit(np.where(vk, y, x), np.where(vk, x, y), line, ~new, reach=reach,
                           both_sides=False)
    keep = ~new | (ok & (np.abs(np.where(vk, x, y) - c0) <= tol))
    return x[keep], y[keep], strength[keep], line[keep]


def _until_stable(step, label: np.ndarray, rounds: int) -> np.ndarray:
    """Apply ``step`` (labels -> labels) up to ``rounds`` times, stopping once a round labels
    no further line."""
    for _ in range(rounds):
        before = int(np.sum(label >= 0))
        label = step(label)
        if int(np.sum(label >= 0)) == before:
            break
    return label


def group_median(values: np.ndarray, group: np.ndarray, n: int, fill: float = np.nan
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Median of ``values`` (M,) in each of the groups ``group`` (M,) int in [0, n): (n,)
    medians (the mean of the two middle values of an even count; ``fill`` for an empty
    group) and (n,) counts. NaN values are left out."""
    ok = np.isfinite(values)
    v, g = values[ok], group[ok]
    o = np.lexsort((v, g))
    v = v[o]
    cnt = np.bincount(g, minlength=n)
    start = np.cumsum(cnt) - cnt
    med = np.full(n, fill, np.float64)
    has = cnt > 0
    med[has] = 0.5 * (v[start[has] + (cnt[has] - 1) // 2] + v[start[has] + cnt[has] // 2])
    return med, cnt


def check_band_width(label, props, ratio: float, tol: float, min_count: int = 3) -> np.ndarray:
    """Unlabel lines whose bands are consistently too narrow or too wide: occluding contours.

    Where a surface in front hides part of a band, the occluding contour is seen as an edge of
    that band, and the band between it and the band's visible edge is narrower than its
    neighbours. For every band crossing the relative width ``w / (ratio * p)`` (``w`` the
    distance from rising to falling edge, ``p`` the distance to the neighbouring crossing of
    the same row, the nearer one when both exist) is 1 on an unoccluded surface; a line whose
    crossings (at least ``min_count``) have a median relative width off 1 by more than ``tol``
    gets label -1.

    ``props`` holds per direction the tuple (lr, lf, st, row, rising, falling, ...) of the
    crossings, as in :func:`propagate_labels`. Returns labels (L,).
    """
    n = len(label)
    lines, rel = [], []
    for lr, lf, st, rw, ra, fa, *_ in props:
        if len(st) < 2:
            continue
        mid = 0.5 * (ra + fa)
        same = (st[1:] == st[:-1] + 2) & (rw[1:] == rw[:-1])
        dn = np.where(same, mid[1:] - mid[:-1], np.nan)
        with np.errstate(all="ignore"):
            nb = np.fmin(np.r_[np.nan, dn], np.r_[dn, np.nan])
            r = (fa - ra) / (ratio * nb)
        ok = np.isfinite(r)
        lines += [lr[ok], lf[ok]]
        rel += [r[ok], r[ok]]
    if not lines:
        return label
    med, cnt = group_median(np.concatenate(rel), np.concatenate(lines), n, fill=1.0)
    out = label.copy()
    out[(cnt >= min_count) & (np.abs(med - 1.0) > tol)] = -1
    return out


def _adjacent(st, rw, ra, fa, ratio: float, tol: float = 0.25) -> np.ndarray:
    """Indices k where band crossings k and k+1 are neighbouring bands (see propagate)."""
    if len(st) < 2:
        return np.zeros(0, np.int64)
    adj = (st[1:] == st[:-1] + 2) & (rw[1:] == rw[:-1])
    spacing = 0.5 * (ra[1:] + fa[1:] - ra[:-1] - fa[:-1])
    width = 0.5 * (fa[1:] - ra[1:] + fa[:-1] - ra[:-1])
    with np.errstate(all="ignore"):
        adj &= np.abs(spacing / np.maximum(width, 1e-6) / ratio - 1.0) < tol
    return np.nonzero(adj)[0]


def check_adjacency(label, lr, lf, st, rw, ra, fa, ratio: float) -> np.ndarray:
    """Unlabel lines whose labels contradict their neighbours along the rows (columns).

    For neighbouring band crossings k, k+1 (:func:`_adjacent`) that are both labelled, the
    labels must be i and i + 1. A line that takes part in at least two contradicting pairs
    and in more contradicting than agreeing ones gets label -1.
    """
    k = _adjacent(st, rw, ra, fa, ratio)
    if not len(k):
        return label
    cr, cf = label[lr], label[lf]
    cl = np.where(cr < 0, cf, np.where((cf < 0) | (cf == cr), cr, -2))
    both = (cl[k] >= 0) & (cl[k + 1] >= 0)
    k = k[both]
    agree = cl[k + 1] == cl[k] + 1
    lines = np.r_[lr[k], lf[k], lr[k + 1], lf[k + 1]]
    ag = np.r_[agree, agree, agree, agree]
    n = len(label)
    bad = np.bincount(lines[~ag], minlength=n)
    good = np.bincount(lines[ag], minlength=n)
    out = label.copy()
    out[(bad >= 2) & (bad > good)] = -1
    return out


def band_width_px(signal: np.ndarray, pattern, valid: np.ndarray | None = None) -> float:
    """Median width of the bands along the rows of a central crop (<= 768 px square), px.

    A first, cheap pass (edges at scale 1 px, rising / falling pairs along the rows) that
    sets the scale of the main pass; NaN when no band is found.
    """
    h, w = signal.shape
    c = 384
    y0, x0 = max(h // 2 - c, 0), max(w // 2 - c, 0)
    crop = signal[y0:y0 + 2 * c, x0:x0 + 2 * c]
    vc = None if valid is None else valid[y0:y0 + 2 * c, x0:x0 + 2 * c]
    pts = detect_edge_points(crop, sigma=1.0, valid=vc, families=False)
    k = pts.cls < 2
    o, st = band_crossings(pts.x[k], pts.iy[k], pts.cls[k] % 2, pattern.band / pattern.pitch)
    if len(st) < 10:
        return float("nan")
    a = pts.x[k][o]
    return float(np.median(a[st + 1] - a[st]))


#: Least band width (camera px) for the strict rules of :func:`detect_grid`. Bands 2.6-3.4 px
#: wide (a 640 x 480 camera's view of the calibration target) lose most lines to them; 4.2 px
#: (the teapot at 1280 x 960) and wider gain from them.
FINE_BAND_PX = 4.0


def auto_sigma(band_px: float, per_band: float = 8.0) -> float:
    """Edge filter scale for bands ``band_px`` wide: band / ``per_band`` (8), clipped to
    [0.8, 1.5] px.

    Wide enough to average the noise, narrow enough that a band's two edges (and the gaps'
    edges) do not bias each other: the Gaussian tail of the neighbouring edge at distance
    ``band_px`` is exp(-band^2 / (2 sigma^2)) <= exp(-32) of the peak at band = 8 sigma.
    ``band_px`` is the median width: where the surface squeezes the bands (the teapot's lower
    body, 4-6 px against a median of 10) a narrower filter still resolves them. 7.1 MP teapot
    views 0-7 (bands about 10 px): band / 7 -> band / 8 (sigma 1.46 -> 1.28 px) raises the
    coverage 0.661 -> 0.673 at RMS 0.042 px; a fixed sigma of 1.15 px gives 0.688 at
    0.046 px, 0.9 px 0.696 at 0.054 px and a wrong line. Smoothing more along the edges than
    across them (``sigma_along``) costs accuracy on the tilted edges (1.25 / 2.0 px: 0.055 px).
    """
    if not np.isfinite(band_px):
        return 1.0
    return float(np.clip(band_px / per_band, 0.8, 1.5))


def _along_across(x: np.ndarray, y: np.ndarray, vertical: np.ndarray) -> tuple:
    """Point coordinates along and across their edges: (y, x) for vertical-band edges,
    (x, y) for horizontal ones (the chain functions of :mod:`~nurbscan.detect.lines`)."""
    return np.where(vertical, y, x), np.where(vertical, x, y)


def per_band_for_noise(noise: float) -> float:
    """Band width over edge filter scale (:func:`auto_sigma`) for a noise deviation ``noise``
    of the normalised signal (:func:`~nurbscan.detect.normalize.noise_level`): 10 up to
    0.025, 8 from 0.05, linear between (a narrower filter where the noise allows it, as in
    Canny's trade-off of localisation against noise). 7.1 MP teapot view: at default noise
    (0.020) band / 10 instead of band / 8 gives coverage 0.691 -> 0.702 at RMS 0.0402 ->
    0.0400 px (demo views 0-7: 0.723 -> 0.735, 0.0411 -> 0.0396 px), without noise 0.715 ->
    0.739 at 0.0343 -> 0.0294 px; at 3x noise (0.056) it would cost coverage 0.606 -> 0.574
    and RMS 0.0658 -> 0.0672 px.
    """
    if not np.isfinite(noise):
        return 8.0
    return float(10.0 - 2.0 * np.clip((noise - 0.025) / 0.025, 0.0, 1.0))


def detect_grid(image, pattern, white=None, *, gamma: float = 2.2, sigma: float | None = None,
                sigma_along: float | None = None,
                threshold: float = 0.06, min_strength: float = 0.12, min_length: int = 4,
                min_votes: int = 3,
                min_agreement: float = 0.9, min_consensus: float = 0.85,
                crossing_margin: float = 0.0, max_residual: float = 0.3,
                window: int = 31, propagation_rounds: int = 1,
                join_gap: float | None = None, refine: bool = True,
                refit_residual: float = 0.2, end_residual: float = 0.15,
                unrefined: str = "keep", new_end_residual: float = 0.5,
                corner_dominance: float = 0.3, corner_residual: float = 0.1,
                width_tol: float = 0.35, line_width_tol: float = 0.2,
                keep_unpaired: bool = True, dominance: float = 1.0,
                corner_keep: float = 0.0, min_width: float = 3.5,
                partner_drops: str = "unmeasured", min_checked_length: float = 0.0,
                min_row_support: float = 0.1, max_row_residual: float = 1.0,
                keep_unsupported: bool = False, plane_radius: float = 2.0,
                plane_k: int = 24, plane_tol: float = 0.5, interpolation_rounds: int = 3,
                interpolation_span: float = 2.2, interpolation_tol: float = 0.1,
                require_colour: bool = True, collinear_rounds: int = 5,
                collinear_unknown: bool = True, families: bool = True,
                pool_gap: float = 2.0, pool_tol: float = 2.0, fit_rounds: int = 2,
                fit_radius: float = 3.0, fit_rms: float = 1.0, fit_tol: float = 0.125,
                fit_reach: float = 1.0, epipolar=None,
                epipolar_radius: float = 2.0, epipolar_rounds: int = 2,
                tail_residual: float | None = None, min_paired: int = 2,
                sigma_per_band: float | None = None, smooth_reach: int = 3,
                oblique: bool = True, fit_line: str = "balanced",
                camera_blur: float = 0.5, chroma_subsampled: bool = False,
                read_along: str = "grid") -> DetectionResult:
    """Find, trace and decode the grid's edge lines in one photograph.

    Parameters
    ----------
    image : ndarray (H, W, 3) (or (H, W)), uint8, uint16 or float in [0, 1]
        The object under the projected grid (gamma-encoded as cameras write images).
    pattern : nurbscan.pattern.Pattern
        The projected pattern.
    white : ndarray like ``image``, optional
        The same view under white light (albedo and shading normalisation).
    gamma : float
        The images' encoding gamma; they are linearised by ``v ** gamma`` (1 = linear data).
    sigma : float, optional
        Scale of the Gaussian derivative filters across the edges, camera px; default
        :func:`auto_sigma` of the band width measured in a first pass.
    sigma_per_band : float, optional
        The default ``sigma`` is the band width over this (:func:`auto_sigma`); by default
        10 at the noise of the default render and 8 from a noise 2.5 times that
        (:func:`per_band_for_noise` of the measured noise). A narrower filter resolves more
        of the bands that the surface squeezes (``nurbscan reconstruct`` uses 10: teapot
        demo scan, Gordon coverage 84.2 -> 86.2 %).
    sigma_along : float, optional
        Smoothing along the edges, camera px (default ``sigma``).
    threshold : float
        Least gradient of an edge in the normalised signal, per px.
    min_strength : float
        Least edge derivative (:attr:`~nurbscan.detect.edges.EdgePoints.strength`) of an
        edge point kept in the result, per px.
    min_length : int
        Fewest points of an edge line.
    min_votes, min_agreement : int, float
        Least votes for, and share of votes of, a line's band index.
    crossing_margin : float
        Drop edge points closer than this (camera px) to an edge pixel of the other direction
        (near a crossing band's corner the profile is disturbed); 0 keeps them. 3 px halves
        the 95th percentile error at the cost of about a fifth of the points.
    max_residual : float
        Drop edge points farther than this (px) from the straight line through their chain
        neighbours (:func:`~nurbscan.detect.lines.local_residual`); 0 keeps them.
    min_consensus : float
        Least share of all window votes that agree with their line's majority; below it the
        pattern is taken not to match the photograph (empty result with a warning).
    window : int
        Local normalisation window without a white image, px.
    propagation_rounds : int
        Rounds of label propagation (:func:`propagate_labels` along rows / columns,
        :func:`propagate_pairs` between a band's two edges, :func:`propagate_collinear` along
        pieces of one edge); more rounds label more lines but carry a wrong label further.
    join_gap : float, optional
        Largest gap (px) across which collinear chains of one class are taken as pieces of one
        edge (:func:`~nurbscan.detect.lines.join_collinear`); default 1.5 band widths +
        4 sigma, 0 disables.
    refine : bool
        Re-measure the decoded points in their band's clean colour channels
        (:func:`~nurbscan.detect.edges.refine_by_channels`). False also drops the unpaired
        points that only the re-measurement keeps (``keep_unpaired``) and its filters.
    refit_residual : float
        After refinement, drop points farther than this (px) from the straight line through
        their chain neighbours; 0 keeps them. The distance is perpendicular to that line
        (:func:`~nurbscan.detect.lines.local_residual`; so is ``max_residual``'s): measured
        along the pixel row (column) instead, the edges that slant across their rows (the
        vertical bands on the teapot's lower body and lid) lost their points to noise
        enlarged by ``sqrt(1 + slope^2)``. 7.1 MP teapot view 0, along the row ->
        perpendicular: at 1x noise coverage 0.7431 -> 0.7537, RMS 0.0391 -> 0.0396 px,
        intersections 0.155 -> 0.161 px; at 0x 0.7781 -> 0.7820, 0.0269 -> 0.0276 px; at 3x
        0.6512 -> 0.6632, 0.0653 -> 0.0660 px; demo scan views 0-7: 0.7744 -> 0.7845, RMS
        0.0396 -> 0.0402 px, no wrong line; 1280 x 960 view 0.5944 -> 0.6012, 0.0559 ->
        0.0568 px.
    end_residual : float
        Drop the first and the last point of every chain when farther than this (camera px)
        from the straight line through the chain's next points (:func:`chain_end_residual`);
        0 keeps them. A chain ends where a crossing band's corner, an occluding contour or a
        gap disturbs the profile on one side only, so its ends are the least exact points: on
        the 7.1 MP teapot view 0 at 1x noise, 0.1 % of the points (errors over 0.46 px) carry
        13 % of the squared error, and half of the points over 0.27 px are chain ends. Views
        0-7 at 1x noise: mean RMS 0.0494 -> 0.0460 px, coverage 0.629 -> 0.625 (0.1 px:
        0.0454 px, 0.624).
    new_end_residual : float
        The row-support filters (``max_row_residual``, ``keep_unsupported``) drop points and
        can leave a point beside them as a chain's new first or last point; after them the
        two ends of every chain are tested again, those farther than this (camera px) from
        the straight line through their chain's next points dropped, up to three times
        (:func:`chain_end_residual`; points beside a gap inside a chain are not tested); 0
        keeps them. 7.1 MP teapot view 0: RMS 0.0466
        -> 0.0458 px, coverage 0.6677 -> 0.6666 (with ``dominance=0.5``: the points off by
        more than 1 px 16 -> 10, carrying 68 -> 55 % of the squared error); demo scan views
        0-7: RMS 0.0454 -> 0.0442 px, coverage 0.6917 -> 0.6910.
    unrefined : {"keep", "fit", "drop"}
        Points that the refinement could not re-measure: "keep" them (moved onto their
        re-measured neighbours' line where there are such neighbours), keep only those so
        moved ("fit"), or "drop" them all.
    width_tol : float
        Relative tolerance of a band's width against the local pitch times band / pitch for a
        rising / falling pair to count as a band crossing (partly occluded or squeezed bands
        give inexact edges and misleading colours).
    line_width_tol : float
        Unlabel lines whose bands' median relative width is off by more than this
        (:func:`check_band_width`, occluding contours); 0 disables.
    keep_unpaired : bool
        Also keep the points of labelled lines that are not one edge of a band crossing in
        their row (column) when the second pass re-measured them (more coverage; with the
        row_support filters below, 7.1 MP teapot views 0-7: mean coverage 0.609, RMS
        0.048 px, against 0.576 and 0.047 px without them and with the unsupported points;
        before those filters it cost RMS 0.071 instead of 0.057 px).
    dominance : float
        Gradient dominance of an edge point's class
        (:func:`~nurbscan.detect.edges.detect_edge_points`); below 1 edge pixels next to a
        crossing band's corner also join their lines, so more lines are traced through and
        labelled (7.1 MP teapot, with ``dominance=0.5, corner_keep=1, refit_residual=0.15``:
        coverage 53.3 -> 57.2 %, labels 99.88 %, RMS 0.054 -> 0.058 px; a few intersections
        of short lines go wrong). Default 1: one class per pixel, as before.
    corner_dominance : float
        Edge points found only with a gradient dominance below ``dominance`` and at least this
        (the corner pixels beside a crossing band, where the other family's gradient dominates
        but the edge's row (column) profile still peaks) are not traced. Where the bands are
        resolved (``FINE_BAND_PX``), after every filter and the grid intersections, those of at
        least ``min_strength`` extend the final lines they continue (:func:`extend_lines`), each
        kept when it lies within ``corner_residual`` camera px of the straight line through its
        line's other points within 6 chain positions. The lines, their labels and the
        intersections stay as they are. 1 disables (``nurbscan reconstruct`` does: with its
        point filters off they reached the curve fits unchecked, Gordon coverage 90.09 -> 89.86
        %; and the calibration, whose points are all fitted). 7.1 MP teapot view 0 at 1x noise:
        coverage 0.6666 -> 0.6863 (within 2 px of a crossing band 0.448 -> 0.531), RMS 0.0458 ->
        0.0468 px; demo scan views 0-7: coverage 0.6910 -> 0.7123, RMS 0.0442 -> 0.0453 px,
        labels unchanged; 1280 x 960 teapot: 0.542 -> 0.571 (``corner_residual`` 0.15: view 0
        0.6907, RMS 0.048 px). Tracing them instead (``dominance=0.5``: 0.6918 on view 0) let a
        squeezed spout side take a body edge's band across the depth step (two wrong lines over
        20 px in demo view 5).
    corner_residual : float
        See ``corner_dominance``.
    corner_keep : float
        A rising / falling pair counts as a band crossing (its points kept) only where both
        points' gradient across their edge is at least this times the one along it; 0 keeps
        all (with ``dominance < 1`` use 1: the corner pixels then serve only tracing and
        labelling).
    min_width : float
        (This and ``keep_unpaired``, ``partner_drops``, ``min_row_support``,
        ``max_row_residual``, ``keep_unsupported``, ``interpolation_rounds``,
        ``collinear_rounds`` and ``pool_gap`` apply where the bands are resolved, at least
        ``FINE_BAND_PX`` = 4 px wide; narrower bands use the plain rules: no unpaired points,
        no width, partner or row checks, no labels by interpolation, unknown colours or
        pooled votes.)
        Keep the points of band crossings at least this many ``sigma`` wide only: the edges
        of narrower (squeezed) bands are biased outwards (7.1 MP teapot, sigma 1.46 px: RMS
        0.16 px for bands 4-5 px wide, 0.085 px at 5-6 px, 0.05 px above 6 px); 0 keeps all.
    partner_drops : {"unmeasured", "all", "none"}
        After the refinement, drop a point whose crossing's other edge point (same row, same
        band) was dropped: "all" whatever dropped it, "unmeasured" only when it went for
        want of a clean re-measurement (``unrefined``), "none" never. A partner dropped as a
        kink off its re-measured neighbours (``refit_residual``, a disturbed corner on its
        side of the band) leaves the point alone with "unmeasured": 7.1 MP teapot view 0 at
        1x noise, coverage 0.7525 ("all") -> 0.7592, RMS 0.0394 -> 0.0398 px, intersections
        0.161 -> 0.174 px; demo views 0-7 0.7835 -> 0.7885, RMS 0.0383 -> 0.0388 px. "none" also
        keeps the points beside unmeasured partners, among them the turn of an edge into a
        crossing band of its colour (demo view 5: 14 points 6-19 px off, RMS 0.087 px).
    min_checked_length : float
        Drop lines shorter than this many pattern pitches (in camera px, from the measured
        band width; one point per px) that have no consistent grid intersection
        (:func:`grid_consistency`); 0 (default) keeps them. Half a pitch (about 12 px on
        the teapot views) once dropped a 9 px piece read as the other family's at the bottom
        of the teapot (demo scan view 4, RMS 0.0417 -> 0.0523 px without the check); the end
        test ``tail_residual`` and the grid runs (``read_along``) now keep such pieces out,
        and the check drops mostly exact short pieces (7.1 MP teapot view 0 at 1x noise:
        the 4,398 points it drops have p95 error 0.157 px against 0.099 px for the points
        kept, RMS 0.22 px from a few outliers; coverage 0.7841 -> 0.7942, RMS 0.0429 ->
        0.0437 px without it). Demo views 0-7 with 0.5 / 0: mean coverage 0.8029 / 0.8132, mean RMS
        0.0416 / 0.0421 px, worst view 0.0446 / 0.0449 px, no wrong line over 20 px.
    min_row_support : float
        Drop lines with a smaller share of points supported by labelled neighbours in their
        row or column (:func:`row_support`); 0 keeps them.
    max_row_residual : float
        Drop points farther than this (camera px) from the extrapolation of the two labelled
        edges beside them in their row (column) when they have no neighbour on the other
        side (:func:`row_support`); 0 keeps them. On the 7.1 MP teapot such points beyond
        1.2 px have an RMS error of 0.3 px. Also drop lines that no consistent grid
        intersection confirms and whose supported points lie, on median, farther than this
        across the line from their rows' prediction (:func:`row_disagreement`): demo scan
        view 4, a 14 px edge inside the crossing of two red bands, 0.4 -> 5 px off its
        labelled edge, took the RMS from 0.039 to 0.055 px; without it, 0.041 px (coverage
        0.7604 -> 0.7597; 7.1 MP teapot view 0: 0.7537 -> 0.7525).
    keep_unsupported : bool
        Keep points with no labelled neighbours within two pitches in their row or column
        (:func:`row_support`; 7.1 MP teapot: 2.6 % of the points, RMS 0.14-0.17 px).
    plane_radius, plane_k, plane_tol : float, int, float
        Before those three filters, a point without support in its row (column) or farther
        than ``max_row_residual`` from its row's extrapolation is supported after all when
        it lies within ``plane_tol`` camera px of the edge that a plane through the
        ``plane_k`` nearest points of other lines of its family, within ``plane_radius``
        pattern pitches, predicts (:func:`plane_support`): where the other family's bands
        slant across a surface (the teapot's lower body) they hide a piece's neighbours in
        most of its rows, and where the band spacing changes along a row its extrapolation
        is poor (a row's extrapolation a quarter pitch off or more is left to the row: the
        line's label is misread, and pieces of one misread edge would support each other).
        ``plane_radius=0`` disables. 7.1 MP teapot view 0: at 1x noise coverage 0.7282 ->
        0.7431, RMS 0.0375 -> 0.0391 px; at 0x 0.7645 -> 0.7781, 0.0263 -> 0.0269 px; at 3x
        0.6353 -> 0.6512, 0.0632 -> 0.0653 px; labels 100 %, no wrong line; demo scan views
        0-7: 0.7602 -> 0.7744, RMS 0.0366 -> 0.0396 px, no wrong line; 1280 x 960 view
        0.5803 -> 0.5944, 0.0534 -> 0.0559 px.
    interpolation_rounds : int
        Rounds of :func:`interpolate_labels` (unlabelled lines between labelled neighbours of
        their rows or columns take the band the interpolated projector coordinate points to),
        after the propagation and its checks; 0 disables. 7.1 MP teapot views 0-7, with the
        collinear propagation below: coverage 0.609 -> 0.629, labels still 99.999 % right
        with no wrong line over 20 px, RMS 0.048 -> 0.049 px. (Extrapolating beyond the last
        labelled edge of a row gained 1 point more but labelled 4 lines over 20 px wrongly.)
    interpolation_span, interpolation_tol : float
        Largest coordinate difference of the two labelled neighbours, and largest distance of
        the interpolated coordinate from the pattern edge, both in pattern pitches.
    require_colour : bool
        An interpolated label needs the line's own colour to be the band's (an unknown colour
        does not confirm it).
    collinear_rounds : int
        Further rounds of :func:`propagate_collinear` alone (labels carried along the pieces of
        one edge cut by crossing bands) after the propagation above.
    collinear_unknown : bool
        In those rounds, a piece of unknown colour also takes the label of the piece it
        continues (a contradicting colour still stops it).
    pool_gap, pool_tol : float
        Pool the window votes of the pieces of one edge before they are decided
        (:func:`pooled_labels`): pieces are joined across gaps up to ``pool_gap`` times
        ``join_gap`` whose end fits predict each other within ``pool_tol`` camera px (looser
        than the joins that carry labels: a wrong join here only mixes votes, which then
        disagree). ``pool_gap=0`` disables. On the teapot's lid the tilted vertical bands cut
        every horizontal edge into cell-long pieces, none with votes from three window
        positions. 7.1 MP teapot views 0-7 at 1x noise: coverage 0.6733 -> 0.6848, RMS 0.0419
        -> 0.0435 px (most of it one piece of an occluding contour in view 1, right label,
        2.5 px off), labels 99.998 %, no wrong line; demo Gordon coverage 53.2 -> 54.8 %.
        Only where the bands are resolved (``FINE_BAND_PX``): on 3 px bands the loose joins
        link neighbouring edges and wrong labels reach the calibration.
    fit_rounds : int
        Rounds of labels from the family's own camera-to-projector map, after the colour
        windows, their propagation and :func:`interpolate_labels`, where the bands are
        resolved: every point of an unlabelled line gets its projector coordinate from a
        local plane through the labelled points of its family within ``fit_radius`` camera
        pitches (:func:`family_coordinates`; none where their RMS residual exceeds
        ``fit_rms`` projector px or where it would extrapolate), the candidate edge must
        agree with the edge count of the point's row (column) towards its labelled
        neighbours (:func:`row_consistent`) or, with ``read_along`` "grid", of its grid run
        (a pixel column through slanted bands of the other family misses the edges hidden
        in them; 7.1 MP teapot view 0 at 1x: coverage 0.7942 -> 0.7980, RMS 0.0437 ->
        0.0439 px; 0x 0.8097 -> 0.8137; 3x 0.7100 -> 0.7153, 0.0716 -> 0.0740 px; demo
        scan views 0-7 0.8132 -> 0.8155, RMS 0.0421 -> 0.0424 px, worst view 0.0449 ->
        0.0456 px, no wrong line), and a line takes the band its points vote for
        within ``fit_tol`` pitches, with the points that fit no edge voting against
        (:func:`epipolar_labels` with ``dissent``) and its colour not contradicting it. 0
        disables (``nurbscan reconstruct`` does: with the rig the epipolar prediction labels
        these pieces, and the two together gave Gordon coverage 90.09 -> 90.01 %). 7.1 MP
        teapot view 0 at 1x noise: coverage 0.6588 -> 0.6677, RMS 0.0453 -> 0.0466 px; demo
        scan views 0-7: coverage 0.6848 -> 0.6917, RMS 0.0435 -> 0.0454 px, labels 99.998 %,
        no wrong line (without the row check, three rounds: 0.6981, but a handle's side
        squeezed between two surfaces took a band three pitches off: one wrong line over
        20 px); about 0.1 s per round on a 7.1 MP view (a third round: +0.001).
    fit_radius, fit_rms, fit_tol : float
        See ``fit_rounds``.
    fit_reach : float
        How far (pattern pitches) the plane of ``fit_rounds`` may predict beyond the least and
        largest coordinate of the labelled points it is fitted to, for the points of lines at
        least one pitch long (shorter ones must lie two projector px inside, the rule for
        all before); negative values demand that much inside. One pitch lets each round label
        the next edges beyond the last labelled row (column): where the bands of the other
        direction slant across a surface that turns away (the teapot's lower body) the colour
        windows fail on the outer rows, and the row check (:func:`row_consistent`) still counts
        the edges to the labelled neighbours. 7.1 MP teapot view 0 at 1x noise: coverage
        0.7240 -> 0.7278, RMS 0.0371 -> 0.0374 px; demo scan views 0-7: 0.7565 -> 0.7601, RMS
        0.0365 -> 0.0366 px, labels 100 %, no wrong line; 1280 x 960 teapot: 0.5780 -> 0.5803.
        For short lines too it gave 0.7320 on view 0, but on the 1280 x 960 view a 12 px
        piece of the lid's occluding contour took the hidden edge of the band beside it
        (its grid intersection 6 px off); with 4 rounds, one wrong line over 20 px.
    epipolar : callable, optional
        ``other_coordinate(pixels (N, 2), direction, coord (N,)) -> (N,)``: the other
        projector coordinate at camera pixels on projector edges, from a calibrated rig
        (:func:`nurbscan.reconstruct.light.other_coordinate`; ``nurbscan reconstruct`` passes
        it). With it, where the bands are resolved, each round (``epipolar_rounds``) predicts
        every edge point's projector coordinate from the other family's decoded points within
        ``epipolar_radius`` pitches (:func:`epipolar_coordinates`, every third point of a
        line), labels the lines the colour windows left unlabelled (:func:`epipolar_labels`)
        and unlabels the lines the prediction contradicts (:func:`epipolar_check`). Teapot
        scan (7.1 MP, 8 views, 1x noise, rig calibrated from the images): Gordon coverage
        54.8 -> 61.1 %, Table I unchanged (Gordon mean 0.0043 mm, max 0.018 mm); detection,
        views 0-7: coverage 0.685 -> 0.706, RMS 0.044 -> 0.057 px (the pieces it labels are
        the less exact ones: squeezed bands, grazing views), labels 99.997 %, 1 wrong line
        over 20 px (0 without); about 0.7 s more per view.
    tail_residual : float, optional
        Drop the tail points of chains that veer more than this (camera px) off the straight
        line through the chain before them (:func:`chain_tails`); default 1.0 with
        ``epipolar`` (the pieces it labels include tracer tails a few px off), else 3.0:
        with ``read_along="grid"`` a horizontal edge that the tracer carried on into a
        slanted crossing band of its own colour is labelled (demo scan view 5: 13 points
        4-19 px off, RMS 0.077 px; 3.0: 0.040 px, coverage 0.7955 -> 0.7940; 1.0: 0.7880).
    min_paired : int
        Fewest points of a labelled line that are one edge of a band crossing (a rising /
        falling pair of plausible width along the row or column); lines with fewer are
        dropped. Where a band is squeezed or half hidden its partner edge is often missing:
        ``nurbscan reconstruct`` keeps such lines (0) and leaves them to the network's
        crossing test (teapot demo scan: Gordon coverage 83.4 -> 84.2 %).
    oblique : bool
        Find and re-measure each family's edges by its own component of the gradient, the
        derivative along the other family's edges (``families``;
        :func:`~nurbscan.detect.edges.across_operators`), instead of the row and column
        derivatives, which the crossing bands' edges disturb where the two families are not
        upright (only with ``families``, where the bands are resolved). 7.1 MP teapot view
        (the other options at their defaults): coverage 0.690 -> 0.702 (within 2 px of a
        crossing band 0.551 -> 0.590), RMS 0.0449 -> 0.0400 px, intersections 0.156 ->
        0.137 px; teapot demo scan reconstruction: Gordon coverage 90.09 -> 90.24 %, Gordon
        mean 0.0128 -> 0.0122 mm.
    fit_line : {"balanced", "row"}
        With ``oblique``, the line along which each edge point's profile is fitted (first
        pass and re-measurement): "balanced", the line on which a crossing band's two shifts
        of the profile's peak cancel (:func:`~nurbscan.detect.edges.fit_slopes`, module notes
        of :mod:`~nurbscan.detect.edges`), or the pixel row (column). 7.1 MP teapot view 0,
        row -> balanced: at 1x noise coverage 0.7009 -> 0.7240 (within 2 px of a crossing
        band 0.588 -> 0.639), RMS 0.0398 -> 0.0371 px, intersections 0.138 -> 0.147 px; at 0x
        0.7390 -> 0.7555, 0.0294 -> 0.0260 px; at 3x 0.6040 -> 0.6291, 0.0646 -> 0.0623 px;
        demo scan views 0-7: coverage 0.7347 -> 0.7565, RMS 0.0396 -> 0.0365 px, no wrong
        line; 1280 x 960 teapot: 0.5590 -> 0.5780, 0.0528 -> 0.0532 px; calibration
        benchmark, held-out pose 0.0149 -> 0.0143 mm; demo reconstruction: Gordon mean
        0.01200 -> 0.01209 mm, coverage 90.05 -> 90.00 %.
    camera_blur : float
        The camera lens's blur, Gaussian sigma in camera px, used by the balanced fit line
        (part of the blur that mixes the two families; the simulator's default 0.5). 7.1 MP
        view at 1x noise, 0 -> 1 px: coverage 0.7235 -> 0.7277, RMS 0.0372 -> 0.0377 px.
    chroma_subsampled : bool
        The photograph is a JPEG with subsampled colour (4:2:2, 4:2:0:
        :func:`nurbscan.io.chroma_subsampled`; the readers of files, ``nurbscan detect``,
        ``reconstruct`` and ``calibrate``, pass it). Its colour channels' edges are blurred
        and displaced: the edge signal then weighs the channels as JPEG's own luma
        (``LUMA_601``, full resolution; :func:`~nurbscan.detect.normalize.normalize`'s
        ``weights``) and the points are not re-measured per channel (``refine`` False). 7.1 MP
        teapot view at 1x noise through JPEG 4:2:0 at quality 95: RMS 0.104 px (1 wrong
        line over 20 px) -> 0.080 px without the re-measurement -> 0.069 px with the luma
        weights too, no wrong line, coverage 0.668 -> 0.668 -> 0.666; 4:2:2: 0.078 -> 0.068
        -> 0.062 px, coverage 0.692 -> 0.673 -> 0.671. 1280 x 960 view, 4:2:0: 0.084 ->
        0.072 -> 0.065 px, coverage 0.526 -> 0.500 -> 0.471 (the price of accuracy in its
        narrow bands); 4:2:2: 1 wrong line -> none. JPEG 4:4:4 is a full-colour image
        (0.0497 px with the re-measurement, 0.058 px without).
    read_along : {"grid", "pixels"}
        The runs along which band crossings are paired and colour windows read (each
        family's "rows", :func:`~nurbscan.detect.decode.band_crossings`): "grid", along the
        other family's edges (:func:`~nurbscan.detect.decode.oblique_runs`, where the bands
        are resolved and the families told apart), or "pixels", the pixel rows (columns).
        Where the surface shears the grid the pixel column leaves each cell after one band
        and reads no window (the teapot's lid and the turning sides); along the grid the
        cells of one column line up. 7.1 MP teapot view 0, pixels -> grid: at 1x noise
        coverage 0.7592 -> 0.7841, RMS 0.0398 -> 0.0429 px, intersections 0.174 -> 0.165 px;
        at 0x 0.7824 -> 0.7986, 0.0275 -> 0.0284 px; at 3x 0.6800 -> 0.6966, 0.0687 -> 0.0701
        px; demo scan views 0-7: 0.7885 -> 0.8029, RMS 0.0388 -> 0.0416 px (at most 0.0446,
        with ``tail_residual`` 3), labels 100 %, no wrong line; a view sheared by 40 degrees
        (``tests/test_detect.py``): 0.717 -> 0.842 (0.722 -> 0.843 with the default
        ``min_checked_length``). About 0.2 s more on a 7.1 MP view.
    smooth_reach : int
        Half-width (camera px along the edge) of the local weighted line that smooths each
        final chain (:func:`~nurbscan.detect.lines.smooth_chains`); 0 keeps the points as
        measured. The intersections are fitted to the measured points. 7.1 MP teapot view:
        RMS 0.0468 -> 0.0427 px; demo scan views 0.0453 -> 0.0422 px (mean of 8).
    families : bool
        Tell vertical-band from horizontal-band edge pixels by the two families' local
        directions (:func:`~nurbscan.detect.edges.family_normals`) instead of by ``|g_x|``
        against ``|g_y|``: where the vertical bands tilt past 45 degrees (the teapot's lid)
        they are otherwise read as horizontal and spoil that family's decoding too. 7.1 MP
        teapot views 0-7, with the slope-following tracer and the tilt-aware refinement:
        coverage 0.625 -> 0.661, RMS 0.046 -> 0.042 px, labels 99.999 %, no wrong line
        (without it the refinement keeps the misread lid edges: RMS 0.093 px). Only where
        the bands are resolved (``FINE_BAND_PX``): bands 3 px wide give the gradient
        directions spurious modes (a 640 x 480 view of the calibration board has one at 45
        degrees).

    Returns
    -------
    DetectionResult
        Only lines labelled with confidence; empty (with ``warnings``) when no grid is found.
    """
    if not gamma > 0:
        raise NurbscanError(f"gamma={gamma!r}: must be positive")
    if tail_residual is None:
        tail_residual = 1.0 if epipolar is not None else 3.0
    if not 0 < dominance <= 1 or not corner_keep >= 0 or not 0 < corner_dominance <= 1:
        raise NurbscanError(f"dominance={dominance!r}, corner_keep={corner_keep!r}, "
                            f"corner_dominance={corner_dominance!r}: need 0 < dominance <= 1, "
                            "corner_keep >= 0 and 0 < corner_dominance <= 1")
    if fit_line not in ("balanced", "row"):
        raise NurbscanError(f"fit_line={fit_line!r}: must be 'balanced' or 'row'")
    if unrefined not in ("keep", "fit", "drop"):
        raise NurbscanError(f"unrefined={unrefined!r}: must be 'keep', 'fit' or 'drop'")
    if read_along not in ("grid", "pixels"):
        raise NurbscanError(f"read_along={read_along!r}: must be 'grid' or 'pixels'")
    if partner_drops not in ("unmeasured", "all", "none"):
        raise NurbscanError(f"partner_drops={partner_drops!r}: must be 'unmeasured', 'all' or "
                            "'none'")
    lin = as_float_planes(image, gamma=gamma)
    h, w = lin[0].shape
    wl = None
    if white is not None:
        wl = as_float_planes(white, "white image", gamma=gamma)
        if wl[0].shape != lin[0].shape:
            raise NurbscanError(f"white image: size {wl[0].shape[1]}x{wl[0].shape[0]} does "
                                f"not match the grid image's {w}x{h}")

    def give_up(msg: str) -> DetectionResult:
        _warnings.warn(msg, UserWarning, stacklevel=3)
        return DetectionResult.empty((w, h), (msg,))

    sub = np.maximum(np.maximum(lin[0][::4, ::4], lin[1][::4, ::4]), lin[2][::4, ::4])
    # (screening on a subsample)
    if np.percentile(sub, 99.5) < 0.08**gamma:
        return give_up("image: too dark (black), no grid found")
    if np.mean(sub > 0.98**gamma) > 0.5:
        return give_up("image: overexposed (more than half the pixels saturated), no grid found")
    if chroma_subsampled:
        refine = False
    nrm = normalize(lin, wl, window=window, weights=LUMA_601 if chroma_subsampled else None)
    del lin, wl
    sig = nrm.signal
    band_px_est = band_width_px(sig, pattern, nrm.valid)
    pitch_px_est = band_px_est * pattern.pitch / pattern.band  # one pattern pitch, camera px
    if sigma is None:
        per_band = sigma_per_band
        if per_band is None:
            per_band = per_band_for_noise(noise_level(sig, nrm.valid))
        sigma = auto_sigma(band_px_est, per_band)
    elif not sigma > 0:
        raise NurbscanError(f"sigma={sigma!r}: must be positive")
    # resolved bands (at least FINE_BAND_PX wide): the gaps beside a band can be sampled
    # clear of its edges' blur, and the stricter rules below pay (7.1 MP teapot: RMS 0.054 ->
    # 0.048 px, coverage +3 %). Narrower bands (small or distant images) keep the plain rules:
    # there the gap samples fall on the edges' blur and the strict rules drop most lines.
    fine = bool(np.isfinite(band_px_est) and band_px_est >= FINE_BAND_PX)
    if not fine:
        keep_unpaired, min_width, partner_drops = False, 0.0, "none"
        min_row_support, max_row_residual, keep_unsupported = 0.0, 0.0, True
        interpolation_rounds, collinear_rounds, pool_gap = 0, 0, 0.0
    pts = detect_edge_points(sig, sigma=sigma, threshold=threshold, valid=nrm.valid,
                             sigma_along=sigma_along,
                             dominance=min(dominance, corner_dominance) if fine else dominance,
                             families=families and fine, oblique=oblique,
                             fit_line=fit_line, camera_blur=camera_blur)
    corner_pts = None
    if fine and corner_dominance < dominance:
        # points found only below `dominance`: not traced, attached to the decoded lines
        main = pts.dominance >= dominance
        pts, corner_pts = pts.take(main), pts.take(~main)
    # a dark gap: well below the dimmest single-primary band (sum of channels ~1 in a band)
    dark_level = 0.35
    if len(pts.x) < 20:
        return give_up("image: blank (no edges), no grid found")
    order, line = trace_lines(pts, (h, w), min_length=min_length)
    if join_gap is None:
        join_gap = 1.5 * band_px_est + 4 * sigma if np.isfinite(band_px_est) else 0.0
    if join_gap > 0 and len(line):
        jsrc, jdst = join_collinear(pts.x[order], pts.y[order],
                                    pts.cls[order].astype(np.int64), line, max_gap=join_gap,
                                    pairs_only=True)
    else:
        jsrc = jdst = np.zeros(0, np.int64)
    nlines = int(line.max()) + 1 if len(line) else 0
    px, py = pts.x[order], pts.y[order]
    cls = pts.cls[order].astype(np.int64)
    ix, iy = pts.ix[order], pts.iy[order]
    op = pts.across[order]
    fit_sl = pts.slope[order]
    pstrength = pts.strength[order]
    ratio = pattern.band / pattern.pitch
    # a point is strict where its own gradient dominates the other direction's by corner_keep
    # (with dominance < 1 the others only help tracing and labelling)
    gxo, gyo = np.abs(pts.gx[order]), np.abs(pts.gy[order])
    strict = np.where(cls < 2, gxo, gyo) >= corner_keep * np.where(cls < 2, gyo, gxo)
    del gxo, gyo
    # band crossings along rows (vertical bands) and columns (horizontal bands)
    parts = []
    grid_rows = []  # the grid runs in row_order's form, for the family fit's count check
    # read along the other family's edges (where the bands are resolved and the families
    # told apart): the points' `across` vectors point along them
    along_grid = read_along == "grid" and fine and pts.across is not None
    acr = pts.across[order].astype(np.float64) if along_grid else None
    for d, name in ((0, "vertical"), (1, "horizontal")):
        sel = np.nonzero((cls // 2) == d)[0]
        # runs, the position along them, and the pixel of run coordinate c near point i:
        # base[i] + (c - across[i]) * step[i]; wscale turns a width along the run into the
        # width across the edge
        if along_grid and len(sel):
            la = np.hypot(acr[sel, 0], acr[sel, 1])
            step = acr[sel] / la[:, None]
            run, across = oblique_runs(px[sel], py[sel], step, line[sel], (h, w),
                                       1.5 * pitch_px_est)
            base = np.c_[px[sel], py[sel]]
            wscale = 1.0 / la
        else:
            across = px[sel] if d == 0 else py[sel]
            run = iy[sel] if d == 0 else ix[sel]
            base = np.c_[px[sel], iy[sel]] if d == 0 else np.c_[ix[sel], py[sel]]
            step = np.zeros((len(sel), 2))
            step[:, d] = 1.0
            wscale = np.ones(len(sel))
        o, st = band_crossings(across, run, cls[sel] % 2, ratio, tol=width_tol)
        if along_grid and len(sel) >= 3:
            grid_rows.append((d, sel[o], run[o], across[o]))  # o: by (run, across)
        a = across[o]
        mid = 0.5 * (a[st] + a[st + 1])
        qm = base[o[st]] + (mid - a[st])[:, None] * step[o[st]]
        samples = nrm.colour_at(qm[:, 0], qm[:, 1])
        if fine:
            # a crossing is clean when the gaps just outside both its edges are dark: it does
            # not lie inside a band of the other direction, whose colour would mix with its own
            clean = clean_crossings(sig, a, run[o], st, d, 2.5 * sigma, dark_level,
                                    base=base[o], step=step[o])
        else:
            # narrow bands: a gap beside the crossing is dark in its middle
            nxt = np.minimum(st + 2, len(a) - 1)
            gap_mid = 0.5 * (a[st + 1] + a[nxt])
            rr = run[o[st]].astype(np.float64)
            lev = bilinear(sig, gap_mid, rr) if d == 0 else bilinear(sig, rr, gap_mid)
            dark = (lev < dark_level) & (nxt == st + 2) & (run[o[nxt]] == run[o[st]])
            clean = dark | np.r_[False, dark[:-1]]
        parts.append((sel, across, run, o, st, samples, clean, name, wscale))
    allsamp = np.concatenate([q[5][q[6]] for q in parts]) if parts else np.zeros((0, 3))
    _, centres = classify_colours(allsamp, pattern.rgb)
    vp, vi, vj, spacing, props = [], [], [], [], []
    paired = np.zeros(len(px), bool)
    partner = np.full(len(px), -1, np.int64)  # the other edge point of a point's crossing
    for sel, across, run, o, st, samples, clean, name, wscale in parts:
        codes, _ = classify_colours(samples, pattern.rgb, iterations=0, centres=centres)
        # the colour of a band is a property of its edge lines: vote over the clean crossings
        lr, lf = line[sel[o[st]]], line[sel[o[st + 1]]]
        good = clean & (codes >= 0)
        lcode, _, _ = line_labels(np.r_[lr[good], lf[good]], None,
                                  np.r_[codes[good], codes[good]], nlines, min_votes=2,
                                  min_agreement=0.7, direct=True)
        cr, cf = lcode[lr], lcode[lf]
        ccode = np.where(cr < 0, cf, np.where((cf < 0) | (cf == cr), cr, -1))
        p_, i_, j_ = window_votes(o, st, run, across, ccode, pattern, name)
        a = across[o]
        props.append((lr, lf, st, run[o[st]], a[st], a[st + 1], lcode, name))
        # a band narrower than min_width sigma: its two edges' blurred profiles overlap and
        # the fitted peaks move apart (outward bias), so its points are not kept
        both = strict[sel[o[st]]] & strict[sel[o[st + 1]]] & \
            ((a[st + 1] - a[st]) * wscale[o[st]] >= min_width * sigma)
        paired[sel[o[st[both]]]] = True
        paired[sel[o[st[both] + 1]]] = True
        partner[sel[o[st[both]]]] = sel[o[st[both] + 1]]
        partner[sel[o[st[both] + 1]]] = sel[o[st[both]]]
        vp.append(sel[p_])
        vi.append(i_)
        vj.append(j_)
        if len(st) > 1:
            a = across[o]
            mids = 0.5 * (a[st] + a[st + 1])
            same = (st[1:] == st[:-1] + 2)
            spacing.append((mids[1:] - mids[:-1])[same])
    label, votes, agree = line_labels(line, np.concatenate(vp), np.concatenate(vi), nlines,
                                      min_votes=min_votes, min_agreement=min_agreement,
                                      vote_pos=np.concatenate(vj), min_positions=pattern.n)
    # a pattern that does not match the photograph still decodes every window (all windows of
    # the sequence exist), but neighbouring windows then rarely agree: reject the whole image
    with np.errstate(all="ignore"):
        total = np.where(agree > 0, votes / np.maximum(agree, 1e-12), 0.0)
    consensus = float(votes.sum() / total.sum()) if total.sum() > 0 else 0.0
    if total.sum() > 0 and consensus < min_consensus:
        return give_up(f"pattern: does not match the photograph (only {consensus:.0%} of the "
                       "colour windows agree with their neighbours)")
    seq = np.asarray(pattern.sequence)
    lcode_all = np.max(np.stack([q[6] for q in props]), axis=0)
    if pool_gap > 0 and join_gap > 0 and len(line):
        psrc, pdst = join_collinear(px, py, cls, line, max_gap=pool_gap * join_gap,
                                    tol=pool_tol, pairs_only=True)
        label = pooled_labels(label, psrc, pdst, line[np.concatenate(vp)], np.concatenate(vi),
                              np.concatenate(vj), lcode_all, seq, min_votes, min_agreement,
                              pattern.n)
    def propagate(label):
        for lr, lf, st, rw, ra, fa, lcode, name in props:
            label = propagate_labels(label, lr, lf, st, rw, ra, fa, lcode, seq,
                                     pattern.nbands(name), pattern.pitch / pattern.band)
            label = propagate_pairs(label, lr, lf, lcode, seq, min_votes=min_votes,
                                    min_agreement=min_agreement)
        return propagate_collinear(label, jsrc, jdst, lcode_all, seq)

    def check_all_adjacency(label):
        for lr, lf, st, rw, ra, fa, _, _ in props:
            label = check_adjacency(label, lr, lf, st, rw, ra, fa, pattern.pitch / pattern.band)
        return label

    label = _until_stable(propagate, label, propagation_rounds)
    label = _until_stable(lambda lab: propagate_collinear(lab, jsrc, jdst, lcode_all, seq,
                                                          unknown=collinear_unknown),
                          label, collinear_rounds)
    label = check_all_adjacency(label)
    if line_width_tol > 0:
        label = check_band_width(label, props, ratio, line_width_tol)
    if interpolation_rounds:
        rows = row_order(px, py, cls)
        label = _until_stable(
            lambda lab: interpolate_labels(lab, px, py, cls, line, lcode_all, pattern,
                                           span=interpolation_span * pattern.pitch,
                                           tol=interpolation_tol * pattern.pitch,
                                           min_votes=min_votes,
                                           require_colour=require_colour, rows=rows),
            label, interpolation_rounds)
        label = check_all_adjacency(label)
    if fit_rounds and fine:
        fit_r = fit_radius * pitch_px_est
        # lines of a pitch or more may be extrapolated to (fit_reach), shorter ones not
        long_line = np.bincount(line, minlength=len(label))[line] >= pitch_px_est
        reach_margin = np.where(long_line, -fit_reach * pattern.pitch, 2.0)
        rows = rows if interpolation_rounds else row_order(px, py, cls)

        def fit_round(lab):
            pred = family_coordinates(lab, px, py, cls, line, pattern, fit_r, max_rms=fit_rms,
                                      margin=reach_margin)
            # the edge count agrees along the pixel row (column) or along the grid run: a
            # pixel column through the slanted bands of the other family misses the edges
            # hidden in them (the bottom of the teapot), the grid run does not
            ok = row_consistent(lab, line, cls, pred, pattern, rows)
            if grid_rows:
                ok |= row_consistent(lab, line, cls, pred, pattern, grid_rows)
            pred = np.where(ok, pred, np.nan)
            return epipolar_labels(lab, pred, cls, line, lcode_all, pattern, tol=fit_tol,
                                   min_votes=min_votes, min_agreement=min_agreement,
                                   dissent=True)

        label = _until_stable(fit_round, label, fit_rounds)
        label = check_all_adjacency(label)
    if epipolar is not None and fine and epipolar_rounds:
        radius = epipolar_radius * pitch_px_est

        def epipolar_round(lab):
            pred = epipolar_coordinates(lab, px, py, cls, line, pattern, epipolar, radius,
                                        stride=3)
            lab = epipolar_labels(lab, pred, cls, line, lcode_all, pattern,
                                  min_votes=min_votes, min_agreement=min_agreement)
            return epipolar_check(lab, pred, cls, line, pattern)

        label = _until_stable(epipolar_round, label, epipolar_rounds)
        label = check_all_adjacency(label)
    ldir = np.zeros(nlines, np.int64)
    if len(line):
        ldir[line] = cls // 2
        ledge = np.zeros(nlines, np.int64)
        ledge[line] = cls % 2
    else:
        ledge = np.zeros(0, np.int64)
    good = label >= 0
    if not np.any(good):
        return give_up("image: no grid line could be decoded (unrelated image, or a pattern "
                       "file that does not match the photograph)")
    # keep the labelled lines, renumbered
    new_id = np.cumsum(good) - 1
    # keep the points of labelled lines that are one edge of a band crossing (a rising /
    # falling pair of plausible width along the row or column): an edge whose partner is
    # hidden lies inside a band of the other direction, near its corners, and is less exact
    # and whose edge is clear of the noise (low-contrast edges are the least exact)
    paired &= pstrength >= min_strength
    if max_residual > 0:
        along = np.where(cls < 2, py, px)
        across = np.where(cls < 2, px, py)
        paired &= local_residual(along, across, line) <= max_residual
    if crossing_margin > 0:
        # near a crossing band's edge the row (column) profile is disturbed by the corner
        for d in (0, 1):
            mask = np.full((h, w), 255, np.uint8)
            o_ = (cls // 2) == 1 - d
            mask[iy[o_], ix[o_]] = 0
            dist_o = cv2.distanceTransform(mask, cv2.DIST_L2, 3)
            sel_d = (cls // 2) == d
            paired[sel_d] &= dist_o[iy[sel_d], ix[sel_d]] >= crossing_margin
    good &= np.bincount(line[paired], minlength=nlines) >= min_paired
    new_id = np.cumsum(good) - 1
    keep = good[line] & (paired | (keep_unpaired & refine))
    paired_k = paired[keep]
    px, py, line = px[keep], py[keep], new_id[line[keep]]
    strength = pstrength[keep]
    lab = label[good]
    ldir, ledge = ldir[good], ledge[good]
    if refine:
        # second pass: re-measure each point in its band's clean colour channels
        chn = nrm.planes()
        colour = np.asarray(pattern.rgb)[seq[lab[line]]] > 127
        vk = cls[keep] < 2
        normal = None
        if fine:
            # a point is judged clean along its chain's normal, so that edges tilted past 14
            # degrees are re-measured too (narrow bands keep the x / y rule: there the extra
            # points cost accuracy, 640 x 480 calibration views)
            normal = chain_normals(px, py, vk, line)
        px, py, done = refine_by_channels(chn, ix[keep], iy[keep], cls[keep], colour, px, py,
                                          sigma, sigma_along, normal=normal,
                                          across=op[keep], slope=fit_sl[keep])
        del chn
        # points with no clean channel (their crossing band shares the band's channels) are
        # placed on the straight line through their re-measured chain neighbours
        c0, okf = neighbour_fit(*_along_across(px, py, vk), line, done,
                               both_sides=False)
        fix = okf & ~done
        px = np.where(fix & vk, c0, px)
        py = np.where(fix & ~vk, c0, py)
        # unpaired points (kept with keep_unpaired) only where re-measured
        kp = paired_k | done
        if unrefined == "fit":
            kp &= done | fix
        elif unrefined == "drop":
            kp &= done
        measured = kp.copy()
        if refit_residual > 0:
            # a point off the straight line through its re-measured neighbours (a kink where
            # the edge meets an occluding contour, a disturbed corner) is dropped
            res = local_residual(*_along_across(px, py, vk), line)
            kp &= res <= refit_residual
        if partner_drops != "none":
            # a point whose crossing partner was dropped is as disturbed (same row, same band);
            # with "unmeasured", not when the partner went as a kink (its own corner)
            kept = np.zeros(len(keep), bool)
            kidx = np.nonzero(keep)[0]
            kept[kidx[kp if partner_drops == "all" else measured]] = True
            pk = partner[kidx]
            kp &= (pk < 0) | kept[np.maximum(pk, 0)]
        px, py, line, strength = px[kp], py[kp], line[kp], strength[kp]
    if (end_residual > 0 or tail_residual > 0) and len(px):
        ke = np.ones(len(px), bool)
        if end_residual > 0:
            ke &= chain_end_residual(px, py, ldir[line], line) <= end_residual
        if tail_residual > 0:
            ke &= ~chain_tails(px, py, ldir[line], line, tail_residual)
        px, py, line, strength = px[ke], py[ke], line[ke], strength[ke]
    nl = len(lab)
    counts = np.bincount(line, minlength=nl)
    stop = np.cumsum(counts)
    start = stop - counts
    coord = np.where(ldir == 0, pattern.edge_coordinate("vertical", np.where(ldir == 0, lab, 0),
                                                        ledge),
                     pattern.edge_coordinate("horizontal", np.where(ldir == 1, lab, 0), ledge))
    sp = np.concatenate(spacing) if spacing else np.zeros(0)
    pitch_px = float(np.median(sp)) if len(sp) else 20.0
    band_px = pitch_px * pattern.band / pattern.pitch
    cam, proj, cb, ce, cl, fit_rms = _intersections(px, py, line, ldir, lab, ledge, coord,
                                                    max(2.0, 0.5 * band_px) + 1.5 * sigma, 8)
    # whole-grid consistency: intersections that disagree with their neighbours reveal a
    # wrongly labelled line; lines with more inconsistent than consistent crossings are dropped
    okc = grid_consistency(cam, proj, tol=0.5 * pattern.band)
    # all of them serve the checks of the lines; the result keeps the consistent ones whose
    # two fits are straight edges (grid_intersections' max_fit_rms)
    keep_i = okc & (fit_rms <= INTERSECTION_FIT_RMS)
    # (two lines' fits extrapolated to a crossing outside the photograph: no grid point)
    keep_i &= ((cam[:, 0] >= -0.5) & (cam[:, 0] <= w - 0.5) & (cam[:, 1] >= -0.5)
               & (cam[:, 1] <= h - 0.5))
    bad_n = np.bincount(cl[~okc].ravel(), minlength=nl)
    good_n = np.bincount(cl[okc].ravel(), minlength=nl)
    unconfirmed = good_n == 0  # lines without a consistent intersection
    # and lines left with fewer than min_length points after the point filters
    drop = ((bad_n >= 2) & (bad_n > good_n)) | (counts < min_length)
    keep_pt = np.ones(len(px), bool)
    if (min_row_support > 0 or max_row_residual > 0 or not keep_unsupported) and nl:
        # agreement with the labelled edges of the same row (column), row_support: lines
        # whose points are (almost) never accompanied by labelled neighbours are lone lines,
        # the least accurate; so are single points without support or far off the
        # extrapolation from their neighbours
        rres, kind = row_support(px, py, ldir[line], coord[line], 2.2 * pattern.pitch)
        if plane_radius > 0 and np.isfinite(pitch_px_est):
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
                                     plane_radius * pitch_px_est, k=plane_k, at=lone)
                kind[lone] = np.where(pres[lone] <= plane_tol, 3, kind[lone])  # 3: plane
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
            off = chain_end_residual(px[kk], py[kk], ldir[line[kk]], line[kk]) > new_end_residual
            if not np.any(off):
                break
            keep_pt[kk[off]] = False
    kept_n = np.bincount(line[keep_pt], minlength=nl)
    drop |= kept_n < min_length
    if min_checked_length > 0 and np.isfinite(pitch_px_est):
        # a short line (counted after the point filters) that no consistent intersection
        # confirms (a piece of an occluding contour or of a shadow edge that took a
        # neighbour's label) is dropped
        drop |= unconfirmed & (kept_n < min_checked_length * pitch_px_est)
    if np.any(drop) or not np.all(keep_pt):
        keepl = ~drop
        new_id = np.cumsum(keepl) - 1
        kp = keepl[line] & keep_pt
        px, py, strength, line = px[kp], py[kp], strength[kp], new_id[line[kp]]
        lab, ldir, ledge, coord = lab[keepl], ldir[keepl], ledge[keepl], coord[keepl]
        votes_k, agree_k = votes[good][keepl], agree[good][keepl]
        sel_i = keep_i & keepl[cl].all(axis=1)
        cam, proj, cb, ce = cam[sel_i], proj[sel_i], cb[sel_i], ce[sel_i]
        cl = new_id[cl[sel_i]]
        nl = len(lab)
        counts = np.bincount(line, minlength=nl)
        stop = np.cumsum(counts)
        start = stop - counts
    else:
        votes_k, agree_k = votes[good], agree[good]
        cam, proj, cb, ce, cl = cam[keep_i], proj[keep_i], cb[keep_i], ce[keep_i], cl[keep_i]
    if smooth_reach > 0 and len(px):
        # after every point filter (they judge the points as measured) and the intersections:
        # the points' noise is partly independent from row to row, and a local weighted line
        # along each chain lowers it (the squared strength is the inverse variance)
        vk = ldir[line] == 0
        a = smooth_chains(*_along_across(px, py, vk), line,
                          strength.astype(np.float64) ** 2, smooth_reach)
        px, py = np.where(vk, a, px), np.where(vk, py, a)
    if corner_pts is not None and len(px):
        # the corner pixels' points extend the final lines where they continue them (after
        # every filter and the intersections, which they leave as they are)
        px, py, strength, line = extend_lines(px, py, strength, line, ldir, ledge, corner_pts,
                                              (h, w), min_strength, corner_residual)
        counts = np.bincount(line, minlength=len(lab))
        stop = np.cumsum(counts)
        start = stop - counts
    return DetectionResult(
        image_size=(w, h), x=px, y=py, strength=strength.astype(np.float32), line=line,
        direction=ldir, band=lab, edge=ledge, coord=coord, start=start, stop=stop,
        votes=votes_k, agreement=agree_k, cam=cam, proj=proj, cross_band=cb,
        cross_edge=ce, cross_line=cl, warnings=())
