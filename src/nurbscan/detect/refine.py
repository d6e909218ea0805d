"""The refinement stage of :func:`~nurbscan.detect.detect_grid`: the labelled lines' points
selected, re-measured in their band's clean colour channels and filtered.

:func:`select_points` keeps the labelled chains and their points that are one edge of a band
crossing (and those only the re-measurement keeps); :func:`refine_points` re-measures them
(:func:`refine_by_channels`), places the points without a clean
channel on their neighbours' line, drops kinks, the partners of dropped points and the
disturbed chain ends and tails (:func:`~nurbscan.detect.chains.chain_end_residual`,
:func:`~nurbscan.detect.chains.chain_tails`). Returns :class:`Lines`.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ._pick import pick
from ._threads import parallel_map
from .chains import (
    SIGMA_ALONG,
    Chains,
    _along_across,
    by_family,
    chain_end_residual,
    chain_tails,
)
from .crossings import Reading
from .edges import _subpixel, gradient
from .labels import Labels
from .lines import chain_normals, local_residual, neighbour_fit
from .oblique import _along_line
from .prepare import NoGrid, Prepared

#: Drop edge points closer than this (camera px) to an edge pixel of the other direction; 0
#: keeps them (3 px halved the 95th percentile error at the cost of a fifth of the points).
CROSSING_MARGIN = 0.0
#: Also keep the points of labelled lines that are not one edge of a band crossing when the
#: re-measurement measured them (7.1 MP teapot views 0-7 with the row-support filters: mean
#: coverage 0.609, RMS 0.048 px, against 0.576 and 0.047 px without them).
KEEP_UNPAIRED = True
#: Points the re-measurement could not measure: "keep" them (moved onto their re-measured
#: neighbours' line where there are such), keep only those so moved ("fit"), or "drop" them.
UNREFINED = "keep"
#: Drop the tail points of chains that veer more than this (camera px) off the line through
#: the chain before them (:func:`~nurbscan.detect.chains.chain_tails`); demo scan view 5: 3.0
#: RMS 0.040 px, coverage 0.7955 -> 0.7940; 1.0: 0.7880. With ``epipolar`` 1.0 (the pieces it
#: labels include tracer tails a few px off).
TAIL_RESIDUAL, TAIL_RESIDUAL_EPIPOLAR = 3.0, 1.0


#: :func:`refine_by_channels` filters each channel in two bands of rows, side by side with
#: the other channels' (7 jobs on two threads instead of 4 of unequal length). The refine
#: stage of bench view 0, medians of 15 calls alternating with and without, three runs: 96.0,
#: 84.6, 75.5 ms without, 86.3, 78.1, 68.5 ms with (the values are the same).
SPLIT_ROWS = True


@dataclass(frozen=True)
class Lines:
    """Labelled edge lines (L) and their points (M), grouped by line.

    Attributes
    ----------
    x, y, strength : (M,) float
        Points, camera px, and their edge derivative, per px.
    line : (M,) int
        Line of each point, in [0, L), non-decreasing.
    band, direction, edge : (L,) int
        Band index, 0 vertical / 1 horizontal band, 0 rising / 1 falling.
    votes, agreement : (L,) int, float
        The colour windows' votes for the band and their share.
    """

    x: np.ndarray
    y: np.ndarray
    strength: np.ndarray
    line: np.ndarray
    band: np.ndarray
    direction: np.ndarray
    edge: np.ndarray
    votes: np.ndarray
    agreement: np.ndarray

    def coordinates(self, pattern) -> np.ndarray:
        """Projector coordinate of each line's edge (L,), px."""
        ldir, lab = self.direction, self.band
        return np.where(ldir == 0,
                        pattern.edge_coordinate("vertical", np.where(ldir == 0, lab, 0),
                                                self.edge),
                        pattern.edge_coordinate("horizontal", np.where(ldir == 1, lab, 0),
                                                self.edge))


@dataclass(frozen=True)
class Selection:
    """The points of the labelled lines before their re-measurement.

    Attributes
    ----------
    lines : Lines
        The labelled lines (renumbered) and their selected points.
    keep : (N,) bool
        Which chain points were selected.
    paired : (M,) bool
        The selected points that are one edge of a band crossing.
    """

    lines: Lines
    keep: np.ndarray
    paired: np.ndarray


def select_points(chains: Chains, reading: Reading, labels: Labels, prep: Prepared,
                  options, refine: bool) -> Selection:
    """The labelled chains (renumbered) with their points that are one edge of a band
    crossing, strong enough and on their chain's line, and with ``refine`` the others too
    where the bands are resolved (``options``: :class:`~nurbscan.detect.options.
    RefineOptions`). Raises :class:`NoGrid` when no chain is labelled."""
    px, py, cls, line, nlines = chains.x, chains.y, chains.cls, chains.line, chains.nlines
    label = labels.label
    ldir = np.zeros(nlines, np.int64)
    if len(line):
        ldir[line] = cls // 2
        ledge = np.zeros(nlines, np.int64)
        ledge[line] = cls % 2
    else:
        ledge = np.zeros(0, np.int64)
    good = label >= 0
    if not np.any(good):
        raise NoGrid("image: no grid line could be decoded (unrelated image, or a pattern "
                     "file that does not match the photograph)", prep.size)
    # keep the points of labelled lines that are one edge of a band crossing (a rising /
    # falling pair of plausible width along the row or column): an edge whose partner is
    # hidden lies inside a band of the other direction, near its corners, and is less exact
    # and whose edge is clear of the noise (low-contrast edges are the least exact)
    paired = reading.paired & (chains.strength >= options.min_strength)
    if options.max_residual > 0:
        along = np.where(cls < 2, py, px)
        across = np.where(cls < 2, px, py)
        at = np.nonzero(paired)[0]  # (the residuals that matter only)
        paired[at] = local_residual(along, across, line, at=at) <= options.max_residual
    if CROSSING_MARGIN > 0:
        # near a crossing band's edge the row (column) profile is disturbed by the corner
        w, h = prep.size
        ix, iy = chains.ix, chains.iy
        for d in (0, 1):
            mask = np.full((h, w), 255, np.uint8)
            o_ = (cls // 2) == 1 - d
            mask[iy[o_], ix[o_]] = 0
            dist_o = cv2.distanceTransform(mask, cv2.DIST_L2, 3)
            sel_d = (cls // 2) == d
            paired[sel_d] &= dist_o[iy[sel_d], ix[sel_d]] >= CROSSING_MARGIN
    good &= np.bincount(line[paired], minlength=nlines) >= options.min_paired
    new_id = np.cumsum(good) - 1
    keep_unpaired = KEEP_UNPAIRED and prep.fine
    keep = good[line] & (paired | (keep_unpaired & refine))
    kx, ky, ks, kl, kp = pick(keep, px, py, chains.strength, line, paired)
    lines = Lines(x=kx, y=ky, strength=ks, line=new_id[kl], band=label[good],
                  direction=ldir[good], edge=ledge[good], votes=labels.votes[good],
                  agreement=labels.agreement[good])
    return Selection(lines, keep, kp)


def refine_points(sel: Selection, chains: Chains, reading: Reading, prep: Prepared, pattern,
                  options, refine: bool, epipolar: bool) -> Lines:
    """Re-measure the selected points (with ``refine``) and filter them: kinks, partners
    of dropped points, disturbed chain ends and tails (``options``:
    :class:`~nurbscan.detect.options.RefineOptions`; ``epipolar``: the rig labelled some
    lines, whose tails are tested more tightly)."""
    lines, keep, paired_k = sel.lines, sel.keep, sel.paired
    px, py, line, strength = lines.x, lines.y, lines.line, lines.strength
    lab, ldir = lines.band, lines.direction
    cls = chains.cls
    fine, sigma = prep.fine, prep.sigma
    partner_drops = options.partner_drops if fine else "none"
    if refine:
        # second pass: re-measure each point in its band's clean colour channels
        seq = np.asarray(pattern.sequence)
        chn = prep.normalised.lazy_planes()
        colour = np.asarray(pattern.rgb)[seq[lab[line]]] > 127
        kix, kiy, kcls, kacross, kslope = pick(keep, chains.ix, chains.iy, cls, chains.across,
                                               chains.slope)
        vk = kcls < 2
        normal = None
        if fine:
            # a point is judged clean along its chain's normal, so that edges tilted past 14
            # degrees are re-measured too (narrow bands keep the x / y rule: there the extra
            # points cost accuracy, 640 x 480 calibration views)
            def normal(px=px, py=py, vk=vk, line=line):  # (computed beside the channels'
                # filters: _threads; of these points, whenever called)
                return chain_normals(px, py, vk, line)
        px, py, done = refine_by_channels(chn, kix, kiy, kcls, colour, px, py, sigma,
                                          SIGMA_ALONG, normal=normal, across=kacross,
                                          slope=kslope)
        del kix, kiy, kcls, kacross, kslope
        del chn
        # points with no clean channel (their crossing band shares the band's channels) are
        # placed on the straight line through their re-measured chain neighbours
        # (these fits and the chain filters below: the two families side by side, by_family)
        at = np.nonzero(~done)[0]  # (the fits that matter only)
        c0_at, okf = by_family(
            lambda along, across, use, ln, at: neighbour_fit(along, across, ln, use,
                                                             both_sides=False, at=at),
            vk, (*_along_across(px, py, vk), done), line, at=at)
        fix = np.zeros(len(px), bool)
        fix[at] = okf
        c0 = np.zeros(len(px))
        c0[at] = c0_at
        px = np.where(fix & vk, c0, px)
        py = np.where(fix & ~vk, c0, py)
        # unpaired points (kept with keep_unpaired) only where re-measured
        kp = paired_k | done
        if UNREFINED == "fit":
            kp &= done | fix
        elif UNREFINED == "drop":
            kp &= done
        measured = kp.copy()
        if options.refit_residual > 0:
            # a point off the straight line through its re-measured neighbours (a kink where
            # the edge meets an occluding contour, a disturbed corner) is dropped
            at = np.nonzero(kp)[0]  # (the residuals that matter only)
            kp[at] = by_family(local_residual, vk, _along_across(px, py, vk), line, at=at) \
                <= options.refit_residual
        if partner_drops != "none":
            # a point whose crossing partner was dropped is as disturbed (same row, same band);
            # with "unmeasured", not when the partner went as a kink (its own corner)
            kept = np.zeros(len(keep), bool)
            kidx = np.nonzero(keep)[0]
            kept[kidx[kp if partner_drops == "all" else measured]] = True
            pk = reading.partner[kidx]
            kp &= (pk < 0) | kept[np.maximum(pk, 0)]
        px, py, line, strength = px[kp], py[kp], line[kp], strength[kp]
    end_residual = options.end_residual
    tail_residual = TAIL_RESIDUAL_EPIPOLAR if epipolar else TAIL_RESIDUAL
    if (end_residual > 0 or tail_residual > 0) and len(px):
        ke = np.ones(len(px), bool)
        pdir = ldir[line]
        if end_residual > 0:
            ke &= by_family(chain_end_residual, pdir == 0, (px, py, pdir), line) <= end_residual
        if tail_residual > 0:
            ke &= ~by_family(chain_tails, pdir == 0, (px, py, pdir), line, tol=tail_residual)
        px, py, line, strength = px[ke], py[ke], line[ke], strength[ke]
    return Lines(x=px, y=py, strength=strength, line=line, band=lab, direction=ldir,
                 edge=lines.edge, votes=lines.votes, agreement=lines.agreement)


def refine_by_channels(channels, ix: np.ndarray, iy: np.ndarray, cls: np.ndarray,
                       colour: np.ndarray, x: np.ndarray, y: np.ndarray, sigma: float,
                       sigma_along: float | None = None, clean: float = 0.25,
                       normal: np.ndarray | None = None, across: np.ndarray | None = None,
                       slope: np.ndarray | None = None
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Second, per-channel sub-pixel pass for decoded edge points (method.md section 2).

    Where a band of the other direction crosses an edge, the crossing rule (channel-wise
    maximum) saturates the channels the two colours share, and near the crossing band's own edge
    those channels carry a corner structure whose gradient leaks into the row (column)
    derivative and shifts the fitted peak. A decoded point knows its band's colour (``colour``,
    (N, 3) bool): the edge is re-measured in the sum of the derivatives of those channels ``c``
    of the colour that are *clean* at the point, i.e. whose derivative along the edge is at most
    ``clean`` times the one across it (no crossing band edge passes there), with the same
    log-parabola fit across the edge as :func:`~nurbscan.detect.edges.detect_edge_points`. Using
    only the band's channels also leaves out the noise of the channels without an edge. The
    derivatives along and across the edge are taken along its tangent and normal (``normal``),
    so a tilted edge is judged as clean as an upright one.

    Parameters
    ----------
    channels : sequence of 3 ndarray (H, W) float32
        Normalised colour channels (each indexed once per band of rows, twice, from up to
        two threads at once, :mod:`~nurbscan.detect._threads`: a lazy sequence such as
        :meth:`~nurbscan.detect.normalize.Normalised.lazy_planes` holds one per thread).
    ix, iy : (N,) int
        Edge pixels; ``cls`` (N,) their classes (0..3, :data:`~nurbscan.detect.edges.CLASSES`).
    colour : (N, 3) bool
        Channels lit in the point's band.
    x, y : (N,) float
        The first pass's sub-pixel positions, kept where no channel is clean or the peak of the
        channel sum is not at the edge pixel.
    sigma, sigma_along : float
        Filter scales, px (as in :func:`~nurbscan.detect.edges.gradient`).
    clean : float
        Largest ratio of a channel's derivative along the edge to the one across it.
    normal : (N, 2) float, or a function returning them, optional
        Unit normal of each edge (the first pass's gradient direction; a function is called
        beside the channels' filters); default the row
        direction (1, 0) for vertical-band edges and the column direction (0, 1) otherwise.
    across : (N, 2) float, optional
        The edge derivative is ``g . across`` (:attr:`~nurbscan.detect.edges.EdgePoints.across`, the
        derivative along the other family's edges); default ``g_x`` for vertical-band edges and
        ``g_y`` otherwise.
    slope : (N,) float, optional
        The line of each point's fit (:attr:`~nurbscan.detect.edges.EdgePoints.slope`,
        :func:`~nurbscan.detect.oblique.fit_slopes`); default the row (column).

    Returns
    -------
    x, y : (N,) float64
        Refined positions, camera px.
    refined : (N,) bool
        Points re-measured.
    """
    n = len(ix)
    x = np.asarray(x, np.float64).copy()
    y = np.asarray(y, np.float64).copy()
    if n == 0:
        return x, y, np.zeros(0, bool)
    vert = cls < 2
    sgn = np.where(cls % 2 == 0, 1.0, -1.0)
    axes = np.where(vert[:, None], [1.0, 0.0], [0.0, 1.0])
    if normal is None:
        normal = axes
    # across-edge derivative samples at offsets -1, 0, +1, and the along-edge derivative
    acc = np.zeros((n, 3))
    used = np.zeros(n, np.int64)
    sl = np.zeros(n) if slope is None else np.asarray(slope, np.float64)
    ix, iy = np.asarray(ix, np.int64), np.asarray(iy, np.int64)
    mag = []
    if across is None:
        across = axes
    ux, uy = (np.asarray(across, np.float64).T[:, :, None] * sgn[None, :, None])

    # the filters over the points' window only (the same values there as over the image):
    # the reach of the filters and of the taps (a step and a cubic tap across) around them
    h, w = getattr(channels, "shape", None) or channels[0].shape
    m = max(int(np.ceil(4.0 * max(sigma, sigma_along or 0.0))), 1) + 8
    rows = slice(max(int(iy.min()) - m, 0), min(int(iy.max()) + m + 1, h))
    cols = slice(max(int(ix.min()) - m, 0), min(int(ix.max()) + m + 1, w))
    if hasattr(channels, "crop"):
        channels = channels.crop(rows, cols)
    else:
        channels = _Cropped(channels, rows, cols)
    jx, jy = ix - cols.start, iy - rows.start
    # (N, 2): the samples one step before and after each point along its fit line (the
    # centre sample is the pixel's own value: its taps' weights are 0, 1, 0, 0)
    search = np.where(vert, 0, 1)
    ux0, uy0 = ux[:, 0], uy[:, 0]

    # each channel in two bands of the window's rows, cut at its middle, each band reaching m
    # rows past the cut (the filters' and the taps' reach: the same values at its points)
    hw = rows.stop - rows.start
    cut = hw // 2
    parts = [(np.arange(n), slice(0, hw))] if hw < 4 * m or not SPLIT_ROWS else [
        (np.nonzero(jy < cut)[0], slice(0, cut + m)),
        (np.nonzero(jy >= cut)[0], slice(cut - m, hw))]

    def channel(c, idx, band):  # one channel's profiles at the points idx of one band
        img = channels[c][band]  # (a lazy sequence computes each plane here)
        gx, gy = gradient(img, sigma, sigma_along)
        del img
        bx, by, bs, bl = jx[idx], jy[idx] - band.start, search[idx], sl[idx]
        side = (_along_line(gx, bx, by, bs, bl, (-1.0, 1.0)) * ux[idx]
                + _along_line(gy, bx, by, bs, bl, (-1.0, 1.0)) * uy[idx])
        cx, cy = gx[by, bx], gy[by, bx]
        del gx, gy
        prof = np.empty((len(idx), 3))
        prof[:, 0], prof[:, 2] = side[:, 0], side[:, 1]
        prof[:, 1] = cx.astype(np.float64) * ux0[idx] + cy.astype(np.float64) * uy0[idx]
        return prof, cx, cy

    # the three channels' bands side by side (_threads), and the normals when they are to be
    # found
    jobs = [(c, *part) for c in range(3) for part in parts]
    jobs += [normal] if callable(normal) else []
    out = parallel_map(lambda job: job() if callable(job) else channel(*job), jobs)
    nx, ny = np.asarray(out[-1] if callable(normal) else normal, np.float64).T
    for c in range(3):  # (summed in the channels' order)
        prof, cx, cy = np.empty((n, 3)), np.empty(n, np.float32), np.empty(n, np.float32)
        for (idx, _), (p, x_, y_) in zip(parts, out[c * len(parts):(c + 1) * len(parts)],
                                          strict=True):
            prof[idx], cx[idx], cy[idx] = p, x_, y_
        along = nx * cy - ny * cx
        normal_d = nx * cx + ny * cy
        ok = colour[:, c] & (np.abs(along) <= clean * np.abs(normal_d)) & (prof[:, 1] > 0)
        mag.append(prof[:, 1])
        acc += np.where(ok[:, None], prof, 0.0)
        used += ok
    # (the channels' largest and the samples' least element by element: numpy reduces an
    # (N, 3) array along its short axis row by row, 3.7 instead of 0.1 ms each here)
    big = np.maximum(np.maximum(mag[0], mag[1]), mag[2])
    least = np.minimum(np.minimum(acc[:, 0], acc[:, 1]), acc[:, 2])
    peak = (used > 0) & (acc[:, 1] > 0.3 * big) & (acc[:, 1] >= acc[:, 0]) \
        & (acc[:, 1] >= acc[:, 2]) & (least > 0)
    la = np.log(np.maximum(acc, 1e-9))
    d = _subpixel(la[:, 0], la[:, 1], la[:, 2])  # |d| <= 0.5: the centre sample is the peak
    x = np.where(peak, np.where(vert, ix + d, ix + d * sl), x)
    y = np.where(peak, np.where(vert, iy + d * sl, iy + d), y)
    return x, y, peak


class _Cropped:
    """The window ``(rows, cols)`` of each of a sequence of images, taken when indexed."""

    def __init__(self, images, rows: slice, cols: slice):
        self._images, self._rows, self._cols = images, rows, cols

    def __getitem__(self, c: int) -> np.ndarray:
        return self._images[c][self._rows, self._cols]
