"""Decoding a grid of thin coloured lines (any :class:`~nurbscan.pattern.LinePattern`).

:func:`detect_lines` reads a photograph of a projected grid of thin lines (2 to 4 camera px
wide) whose colours form a windowed code along each direction (a De Bruijn sequence, a PRMVS):

1. Line centres to sub-pixel (Steger's ridge detector on the largest channel, the one in which
   every colour of line stands out), split into vertical and horizontal lines by the ridge
   orientation and linked into chains (:mod:`.ridges`).
2. Each chain's colour class, learned from the photograph (:mod:`.colour_model`). Steps 2
   to 6 are :func:`.line_labels.decode_family`.
3. Windows: along each pixel row the vertical chains' centres, ordered by x, are the sequence
   of vertical lines that a horizontal line of the grid crosses (horizontal chains: along
   columns). ``pattern.window`` consecutive centres whose gaps are alike (no line missing
   between them: each gap within ``gap_ratio`` of the first) form a window; its colour codes
   looked up in the family (``LineFamily.lookup``) give the index of its first line, so a vote
   for the index of each of its chains (:func:`.line_labels._windows`). The assignment of
   colour classes to codes and the reading order (projector coordinate growing or falling with
   the camera coordinate) are those under which most windows occur in the code.
4. Each chain takes the index most of its votes agree on (``min_votes``, ``min_agreement``).
5. Consistency (:func:`.line_labels._consistent`): along the rows, labelled neighbours must
   hold consecutive indices in the reading order when their gap is one line pitch (two when it
   is two, ...; the pitch measured from the labelled neighbours themselves). Chains whose
   neighbour relations mostly fail are refused (label -1), the worst first, until all agree.
6. Propagation (:func:`.line_labels._propagate`): an unlabelled chain next to labelled chains
   in its rows, at the pitch of their labelled neighbours, takes the next index when its colour
   is that line's colour and enough rows agree; collinear pieces of a line share its label
   (:func:`.line_labels._collinear_labels`); chains between two decoded lines are labelled by
   counting (:func:`.line_labels._fill_between`); the result is checked again (step 5 and the
   order of the lines along the runs, :func:`.line_labels._ordered`), and finally against the
   smooth index field of each chain's neighbourhood (:func:`.line_labels._field_check`).
7. The decoded chains become centre-lines of a :class:`~nurbscan.detect.result.DetectionResult`
   (``edge = 2``, ``coord`` the line's centre coordinate in the projector), and their
   crossings (a vertical and a horizontal line fitted locally, intersected) its grid
   intersections (:func:`line_intersections`).

Bad input (documented behaviour, as :func:`~nurbscan.detect.detect_grid`): an image that is not a
2-D grey or colour array, holds non-finite values, or a white image of another size raises
:class:`~nurbscan.errors.NurbscanError`. A photograph in which no grid is found (blank, black,
unrelated, a pattern that does not match) gives an *empty* result whose ``warnings`` say why
(and a :class:`UserWarning`); the command line turns an empty result into a one-line error.
"""

from __future__ import annotations

import warnings as _warnings
from dataclasses import dataclass, replace

import numpy as np
from scipy.spatial import cKDTree

from ..errors import NurbscanError
from .colour_model import chromaticity, line_contrast
from .line_labels import DIRECTIONS, Chains, decode_family, family_chains, neighbours
from .neighbours import closest_pairs
from .normalize import colour_image
from .result import DetectionResult
from .ridges import link_ridges, ridge_points, split_directions


@dataclass(frozen=True)
class LineDetectOptions:
    """Options of :func:`detect_lines`, grouped by step.

    Ridges: ``sigma`` (px), ``threshold`` (share of the 99th percentile strength),
    ``max_angle`` (radians from the direction's mode), ``max_gap`` (runs bridged at crossings),
    ``min_length`` (centres per chain).

    Colour: ``background_offset`` (share of the direction's median line gap; the distance of
    the background samples, :func:`~nurbscan.detect.colour_model.line_contrast`, clipped to
    2.5 .. 8 px), ``min_class_share`` (share of a chain's centres in its colour class),
    ``colour_search`` (also try every other assignment of colour classes to codes,
    :func:`.line_labels._choose_codes`).

    Decoding: ``reading``: "forward" (the projector coordinate grows with the camera
    coordinate, as for an upright camera and projector), "backward" (mirrored) or "either"
    (the better-scoring); ``min_score`` (least share of windows reading in order,
    :func:`.line_labels._run_score`, below which a direction is taken not to show the pattern);
    ``gap_ratio`` (largest ratio of the gaps in a window); ``min_votes`` and
    ``min_agreement`` (of a chain's label); ``pitch_tol`` (largest difference of a
    neighbour's gap from a whole number of pitches, in pitches).

    Propagation: ``propagate_share`` (least share of a chain's centres in the colour of a
    label it takes from a neighbour or a collinear piece), ``propagation_rounds``,
    ``max_fill`` (most lines labelled by counting between two decoded ones; 0 or 1: none),
    ``piece_gap`` (longest gap, runs) and ``piece_offset`` (px, grown by 2 % of the gap)
    between collinear chains that must share a label.

    Field check: ``field_radius`` (neighbourhood, in line gaps) and ``field_tol`` (pitches; 0
    disables) of :func:`.line_labels._field_check`.

    Intersections: ``intersection_radius`` (px), ``intersection_k`` (points per fit),
    ``max_fit_rms`` (px).
    """

    sigma: float = 1.2
    threshold: float = 0.15
    max_angle: float = float(np.radians(30.0))
    max_gap: int = 9
    min_length: int = 8
    gap_ratio: float = 1.4
    min_votes: int = 4
    min_agreement: float = 0.8
    min_class_share: float = 0.6
    propagation_rounds: int = 6
    pitch_tol: float = 0.3
    intersection_radius: float = 8.0
    intersection_k: int = 16
    max_fit_rms: float = 0.5
    background_offset: float = 0.25
    reading: str = "forward"
    piece_gap: int = 40
    propagate_share: float = 0.3
    max_fill: int = 6
    min_score: float = 0.3
    colour_search: bool = False
    field_radius: float = 2.5
    field_tol: float = 0.5
    piece_offset: float = 1.2


def _as_float(image, what: str) -> np.ndarray:
    """(H, W, 3) float32 in [0, 1] from a grey or colour array (uint8, uint16 or float)."""
    a = colour_image(image, what)
    if a.dtype == np.uint8:
        return a.astype(np.float32) / 255.0
    if a.dtype == np.uint16:
        return a.astype(np.float32) / 65535.0
    a = a.astype(np.float32)
    if not np.all(np.isfinite(a)):
        raise NurbscanError(f"{what}: holds NaN or infinite values")
    return a


def line_intersections(x, y, line, direction, band, coord, radius: float, k: int = 10,
                       max_fit_rms: float = 0.5):
    """Crossings of decoded vertical and horizontal centre-lines.

    Vertical line i and horizontal line j cross once. Candidates are the (i, j) pairs with
    centres closer than ``radius`` px (at the crossing the ridge detector refuses the blob, so
    the two lines' chains end near it); around the closest pair, each line's ``k`` nearest
    centres (within ``2 radius``) are fitted by a straight line (least squares,
    x = a + b (y - y0) for the vertical line, y = c + d (x - x0) for the horizontal one) and
    the two lines intersected. Pairs whose intersection is farther than ``radius`` from the
    candidate, or whose fits' RMS residual exceeds ``max_fit_rms`` px, are dropped.

    Returns
    -------
    cam : (K, 2) camera px; proj : (K, 2) projector px (the two lines' coordinates);
    bands : (K, 2) int (vertical, horizontal) indices; lines : (K, 2) int line ids.
    """
    empty = (np.zeros((0, 2)), np.zeros((0, 2)), np.zeros((0, 2), np.int64),
             np.zeros((0, 2), np.int64))
    if not len(band) or not len(x):
        return empty
    pd, pb = direction[line], band[line]
    vi, hi = np.nonzero(pd == 0)[0], np.nonzero(pd == 1)[0]
    if len(vi) < 2 or len(hi) < 2:
        return empty
    # per (vertical line, horizontal line), the closest pair of their points
    ia, ib, _ = closest_pairs(np.c_[x[vi], y[vi]], pb[vi], np.c_[x[hi], y[hi]], pb[hi], radius)
    if not len(ia):
        return empty
    a, b = vi[ia], hi[ib]
    cx, cy = 0.5 * (x[a] + x[b]), 0.5 * (y[a] + y[b])
    span = float(max(x.max(), y.max()) + 10.0 * radius + 10.0)
    fits = []
    for sel, fam, along, across, centre in ((vi, pb[a], y, x, cy), (hi, pb[b], x, y, cx)):
        tree = cKDTree(np.c_[x[sel] + pb[sel] * span, y[sel]])
        kk = min(k, len(sel))
        dd, ii = tree.query(np.c_[cx + fam * span, cy], k=kk)
        dd, ii = dd.reshape(len(cx), kk), ii.reshape(len(cx), kk)
        ii = sel[np.minimum(ii, len(sel) - 1)]
        w = (np.isfinite(dd) & (dd < 2 * radius)).astype(np.float64)
        t = along[ii] - centre[:, None]
        v = across[ii]
        sw = w.sum(1)
        with np.errstate(all="ignore"):
            tm = (w * t).sum(1) / sw
            vm = (w * v).sum(1) / sw
            stt = (w * (t - tm[:, None]) ** 2).sum(1)
            slope = (w * (t - tm[:, None]) * (v - vm[:, None])).sum(1) / stt
            c0 = vm - slope * tm
            rms = np.sqrt((w * (v - c0[:, None] - slope[:, None] * t) ** 2).sum(1) / sw)
        fits.append((c0, slope, rms, sw))
    (av, bv, rv, wv), (ah, bh, rh, wh) = fits
    # x = av + bv (y - cy); y = ah + bh (x - cx)
    with np.errstate(all="ignore"):
        px = (av + bv * (ah - cy) - bv * bh * cx) / (1.0 - bv * bh)
        py = ah + bh * (px - cx)
    ok = np.isfinite(px) & np.isfinite(py) & (wv >= 4) & (wh >= 4)
    with np.errstate(invalid="ignore"):
        ok &= (np.hypot(px - cx, py - cy) < radius) & (rv <= max_fit_rms) & (rh <= max_fit_rms)
    lv, lh = line[a], line[b]
    return (np.c_[px, py][ok], np.c_[coord[lv], coord[lh]][ok], np.c_[band[lv], band[lh]][ok],
            np.c_[lv, lh][ok])


def _offset(ch: Chains, opts: LineDetectOptions) -> float:
    """Distance of the background samples from a line centre: ``background_offset`` times the
    direction's median gap between neighbouring centres, px, clipped to 2.5 .. 8."""
    _, gap = neighbours(ch)
    g = gap[np.isfinite(gap)]
    med = float(np.median(g)) if len(g) else 20.0
    return float(np.clip(opts.background_offset * med, 2.5, 8.0))


def _empty(size, why: str) -> DetectionResult:
    _warnings.warn(why, UserWarning, stacklevel=3)
    return DetectionResult.empty(size, (why,))


def detect_lines(image, pattern, white=None, options: LineDetectOptions = LineDetectOptions()
                 ) -> DetectionResult:
    """Find and decode the thin coloured lines of ``pattern`` in one photograph.

    Parameters
    ----------
    image : ndarray (H, W, 3) or (H, W), uint8, uint16 or float in [0, 1]
        The scene under the projected grid, as the camera wrote it (any gamma).
    pattern : nurbscan.pattern.LinePattern
        The projected pattern (its families' codes and centres, palette, window).
    white : ndarray like ``image``, optional
        The same view under white light: the line colours are divided by it (albedo).
    options : LineDetectOptions

    Returns
    -------
    DetectionResult
        Centre-lines (``edge = 2``, ``coord`` the line's projector centre coordinate, ``band``
        its index in the family, ``votes`` the windows that read its label and ``agreement``
        their share of its windows; 0 for a line labelled by its neighbours, a collinear
        piece or counting only) and the grid
        intersections of the decoded lines; empty with ``warnings`` when no grid is found.

    Notes
    -----
    Steps (module notes): ridges -> directions -> chains -> colour classes -> windows and
    votes -> consistency -> propagation -> centre-lines and intersections.
    """
    img = _as_float(image, "image")
    h, w = img.shape[:2]
    size = (w, h)
    wimg = None
    if white is not None:
        wimg = _as_float(white, "white image")
        if wimg.shape != img.shape:
            raise NurbscanError(f"white image: size {wimg.shape[1]} x {wimg.shape[0]} differs "
                                f"from the photograph's {w} x {h}")
    if float(img.max() - img.min()) < 1e-3:
        return _empty(size, "no grid found: the photograph is blank")
    pts = ridge_points(img.max(axis=2), options.sigma, options.threshold)
    if len(pts) < 50:
        return _empty(size, "no grid found: no thin lines in the photograph")
    direction, _ = split_directions(pts, options.max_angle)
    order, chain = link_ridges(pts, direction, max_gap=options.max_gap,
                               min_length=options.min_length)
    fams, labels, notes = [], [], []
    for d in (0, 1):
        ch = family_chains(pts, direction, order, chain, d)
        chroma = chromaticity(line_contrast(img, ch.pts, _offset(ch, options), wimg))
        if getattr(pattern, DIRECTIONS[d]) is None:
            lab = np.full(ch.nchains, -1, np.int64)
        else:
            lab, note = decode_family(ch, chroma, pattern, d, options)
            if note:
                notes.append(note)
        fams.append(ch)
        labels.append(lab)
    if not any((lab >= 0).any() for lab in labels):
        why = "no grid found: no line could be decoded"
        if notes:
            why += f" ({'; '.join(notes)})"
        return _empty(size, why)
    result = _result(size, fams, labels, pattern, options)
    if notes:
        for note in notes:
            _warnings.warn(note, UserWarning, stacklevel=2)
        result = replace(result, warnings=tuple(notes))
    return result


def _result(size, fams, labels, pattern, opts: LineDetectOptions) -> DetectionResult:
    """The decoded chains as centre-lines, ordered by (direction, index), and their crossings."""
    xs, ys, ss, lines = [], [], [], []
    ldir, lband, lcoord, lvotes, lagree = [], [], [], [], []
    nl = 0
    for d, (ch, lab) in enumerate(zip(fams, labels, strict=True)):
        if not (lab >= 0).any():
            continue
        centres = pattern.family(DIRECTIONS[d]).centres
        keep = np.nonzero(lab >= 0)[0]
        keep = keep[np.argsort(lab[keep], kind="stable")]
        for c in keep:
            sel = np.nonzero(ch.chain == c)[0]
            xs.append(ch.pts.x[sel])
            ys.append(ch.pts.y[sel])
            ss.append(ch.pts.strength[sel])
            lines.append(np.full(len(sel), nl, np.int64))
            ldir.append(d)
            lband.append(int(lab[c]))
            lcoord.append(float(centres[lab[c]]))
            if ch.votes is not None:
                lvotes.append(int(ch.votes[0][c]))
                lagree.append(float(ch.votes[1][c]))
            else:
                lvotes.append(0)
                lagree.append(0.0)
            nl += 1
    x, y = np.concatenate(xs), np.concatenate(ys)
    line = np.concatenate(lines)
    counts = np.bincount(line, minlength=nl)
    stop = np.cumsum(counts)
    start = stop - counts
    direction = np.asarray(ldir, np.int64)
    band = np.asarray(lband, np.int64)
    coord = np.asarray(lcoord, np.float64)
    cam, proj, cb, cl = line_intersections(x, y, line, direction, band, coord,
                                           opts.intersection_radius, opts.intersection_k,
                                           opts.max_fit_rms)
    return DetectionResult(
        image_size=tuple(int(v) for v in size), x=x, y=y,
        strength=np.concatenate(ss).astype(np.float32), line=line, direction=direction,
        band=band, edge=np.full(nl, 2, np.int64), coord=coord, start=start.astype(np.int64),
        stop=stop.astype(np.int64), votes=np.asarray(lvotes, np.int64),
        agreement=np.asarray(lagree, np.float64), cam=cam, proj=proj, cross_band=cb,
        cross_edge=np.full(cb.shape, 2, np.int64), cross_line=cl, warnings=())
