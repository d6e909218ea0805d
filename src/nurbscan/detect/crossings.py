"""The colour-reading stage of :func:`~nurbscan.detect.detect_grid`: band crossings along the
runs of each family, the colours read on them, and the colour windows' votes.

Along each run (a pixel row for vertical-band edges, a column for horizontal ones, or a run
along the other family's edges, :func:`~nurbscan.detect.decode.oblique_runs`) a rising and a
falling edge point of plausible width are one band crossing
(:func:`~nurbscan.detect.decode.band_crossings`). Its colour is sampled in its middle and
classified (:func:`~nurbscan.detect.decode.classify_colours`, on the clean crossings,
:func:`clean_crossings`), each chain takes the colour its crossings agree on, and the
windows of consecutive colours vote for band indices
(:func:`~nurbscan.detect.decode.window_votes`). :func:`read_colours` returns a
:class:`Reading`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ._threads import parallel_map
from .chains import Chains
from .decode import (
    band_crossings,
    bilinear,
    classify_colours,
    line_labels,
    oblique_runs,
    window_votes,
)
from .orientation import window_spans
from .prepare import Prepared

#: Relative tolerance of a band's width against the local pitch times band / pitch for a
#: rising / falling pair to count as a band crossing (partly occluded or squeezed bands give
#: inexact edges and misleading colours); nothing has needed another.
WIDTH_TOL = 0.35

#: Largest edge signal of a dark gap: well below the dimmest single-primary band (sum of
#: channels ~1 in a band).
DARK_LEVEL = 0.35


@dataclass(frozen=True)
class Reading:
    """Band crossings, colours and window votes of the chains (N points, L chains).

    Attributes
    ----------
    props : tuple
        Per direction (vertical, horizontal), the crossings (K,): ``(lr, lf, st, row,
        rising, falling, lcode, name)``, the chains of the rising / falling point, the
        crossing's position in the sorted run, its run, the rising / falling coordinate
        along the run, the colour code of every chain (L,) (-1 unknown) and "vertical" /
        "horizontal".
    paired : (N,) bool
        The point is one edge of a band crossing at least ``min_width`` sigma wide whose
        points' gradients are strict (``corner_keep``).
    partner : (N,) int
        The other edge point of that crossing (-1: none).
    lcode : (L,) int
        Colour code of each chain (-1 unknown).
    vote_point, vote_band, vote_pos : (V,) int
        The colour windows' votes: chain point, band index, window position.
    pitch_px : float
        Median distance of neighbouring crossings along the runs, camera px (20 without).
    grid_rows : tuple
        With ``read_along`` "grid", the grid runs in
        :func:`~nurbscan.detect.labels.row_order`'s form (empty otherwise).
    spans : (2, 2, 3) int
        Per family (vertical, horizontal), the spans of agreeing windows read forwards and
        backwards (:func:`~nurbscan.detect.orientation.window_spans`), for the orientation.
    """

    props: tuple
    paired: np.ndarray
    partner: np.ndarray
    lcode: np.ndarray
    vote_point: np.ndarray
    vote_band: np.ndarray
    vote_pos: np.ndarray
    pitch_px: float
    grid_rows: tuple
    spans: np.ndarray | None = None


def _runs(chains: Chains, prep: Prepared, pattern, along_grid: bool, strict: np.ndarray):
    """Per direction, the band crossings along the runs, their colour samples and whether
    they are clean: ``(sel, across, run, o, st, samples, clean, name, wscale)``; and the
    grid runs (with ``along_grid``)."""
    px, py, cls, line = chains.x, chains.y, chains.cls, chains.line
    ix, iy = chains.ix, chains.iy
    w, h = prep.size
    nrm, sigma, fine = prep.normalised, prep.sigma, prep.fine
    sig = nrm.signal
    ratio = pattern.band / pattern.pitch
    acr = chains.across.astype(np.float64) if along_grid else None

    def direction(dn):  # the crossings of one direction
        d, name = dn
        sel = np.nonzero((cls // 2) == d)[0]
        # runs, the position along them, and the pixel of run coordinate c near point i:
        # base[i] + (c - across[i]) * step[i]; wscale turns a width along the run into the
        # width across the edge
        if along_grid and len(sel):
            la = np.hypot(acr[sel, 0], acr[sel, 1])
            step = acr[sel] / la[:, None]
            run, across = oblique_runs(px[sel], py[sel], step, line[sel], (h, w),
                                       1.5 * prep.pitch_px)
            base = np.c_[px[sel], py[sel]]
            wscale = 1.0 / la
        else:
            across = px[sel] if d == 0 else py[sel]
            run = iy[sel] if d == 0 else ix[sel]
            base = np.c_[px[sel], iy[sel]] if d == 0 else np.c_[ix[sel], py[sel]]
            step = np.zeros((len(sel), 2))
            step[:, d] = 1.0
            wscale = np.ones(len(sel))
        o, st = band_crossings(across, run, cls[sel] % 2, ratio, tol=WIDTH_TOL)
        row = (d, sel[o], run[o], across[o]) if along_grid and len(sel) >= 3 else None
        a = across[o]
        mid = 0.5 * (a[st] + a[st + 1])
        qm = base[o[st]] + (mid - a[st])[:, None] * step[o[st]]
        samples = nrm.colour_at(qm[:, 0], qm[:, 1])
        if fine:
            # a crossing is clean when the gaps just outside both its edges are dark: it does
            # not lie inside a band of the other direction, whose colour would mix with its own
            clean = clean_crossings(sig, a, run[o], st, d, 2.5 * sigma, DARK_LEVEL,
                                    base=base[o], step=step[o])
        else:
            # narrow bands: a gap beside the crossing is dark in its middle
            nxt = np.minimum(st + 2, len(a) - 1)
            gap_mid = 0.5 * (a[st + 1] + a[nxt])
            rr = run[o[st]].astype(np.float64)
            lev = bilinear(sig, gap_mid, rr) if d == 0 else bilinear(sig, rr, gap_mid)
            dark = (lev < DARK_LEVEL) & (nxt == st + 2) & (run[o[nxt]] == run[o[st]])
            clean = dark | np.r_[False, dark[:-1]]
        return (sel, across, run, o, st, samples, clean, name, wscale), row

    # (the two directions side by side: _threads)
    out = parallel_map(direction, ((0, "vertical"), (1, "horizontal")))
    parts = [p for p, _ in out]
    grid_rows = tuple(r for _, r in out if r is not None)  # o: by (run, across)
    return parts, grid_rows


def read_colours(chains: Chains, prep: Prepared, pattern, options) -> Reading:
    """Band crossings, their colours and the colour windows' votes (``options``:
    :class:`~nurbscan.detect.options.ReadingOptions`)."""
    px, cls, line, nlines = chains.x, chains.cls, chains.line, chains.nlines
    sigma = prep.sigma
    min_width = options.min_width if prep.fine else 0.0
    # a point is strict where its own gradient dominates the other direction's by corner_keep
    # (with dominance < 1 the others only help tracing and labelling)
    gxo, gyo = np.abs(chains.gx), np.abs(chains.gy)
    strict = np.where(cls < 2, gxo, gyo) >= options.corner_keep * np.where(cls < 2, gyo, gxo)
    del gxo, gyo
    # read along the other family's edges (where the bands are resolved and the families
    # told apart): the points' `across` vectors point along them
    along_grid = options.read_along == "grid" and prep.fine and chains.across is not None
    parts, grid_rows = _runs(chains, prep, pattern, along_grid, strict)
    allsamp = np.concatenate([q[5][q[6]] for q in parts]) if parts else np.zeros((0, 3))
    _, centres = classify_colours(allsamp, pattern.rgb)
    paired = np.zeros(len(px), bool)
    partner = np.full(len(px), -1, np.int64)  # the other edge point of a point's crossing

    def votes(part):  # one direction's colours and votes (the two side by side: _threads)
        sel, across, run, o, st, samples, clean, name, wscale = part
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
        span = window_spans(o, st, run, ccode, pattern)
        a = across[o]
        prop = (lr, lf, st, run[o[st]], a[st], a[st + 1], lcode, name)
        # a band narrower than min_width sigma: its two edges' blurred profiles overlap and
        # the fitted peaks move apart (outward bias), so its points are not kept
        both = strict[sel[o[st]]] & strict[sel[o[st + 1]]] & \
            ((a[st + 1] - a[st]) * wscale[o[st]] >= min_width * sigma)
        rising, falling = sel[o[st[both]]], sel[o[st[both] + 1]]
        gaps = None
        if len(st) > 1:
            mids = 0.5 * (a[st] + a[st + 1])
            same = (st[1:] == st[:-1] + 2)
            gaps = (mids[1:] - mids[:-1])[same]
        return prop, span, rising, falling, sel[p_], i_, j_, gaps

    vp, vi, vj, spacing, props, spans = [], [], [], [], [], []
    for prop, span, rising, falling, p_, i_, j_, gaps in parallel_map(votes, parts):
        props.append(prop)
        spans.append(span)
        paired[rising] = True
        paired[falling] = True
        partner[rising] = falling
        partner[falling] = rising
        vp.append(p_)
        vi.append(i_)
        vj.append(j_)
        if gaps is not None:
            spacing.append(gaps)
    sp = np.concatenate(spacing) if spacing else np.zeros(0)
    return Reading(props=tuple(props), paired=paired, partner=partner,
                   lcode=np.max(np.stack([q[6] for q in props]), axis=0),
                   vote_point=np.concatenate(vp), vote_band=np.concatenate(vi),
                   vote_pos=np.concatenate(vj),
                   pitch_px=float(np.median(sp)) if len(sp) else 20.0, grid_rows=grid_rows,
                   spans=np.stack(spans))


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
