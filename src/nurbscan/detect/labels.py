"""The decoding-and-propagation stage of :func:`~nurbscan.detect.detect_grid`: band indices
of the chains from the colour windows' votes, carried to their neighbours and checked.

:func:`decode_labels` decides each chain's band from its window votes
(:func:`~nurbscan.detect.decode.line_labels`, pooled over the pieces of one edge,
:func:`pooled_labels`), rejects a pattern that does not match the photograph, propagates the
labels along the runs (:func:`propagate_labels`), between a band's two edges
(:func:`propagate_pairs`) and along the pieces of one edge (:func:`propagate_collinear`),
unlabels the chains their neighbours contradict (:func:`check_adjacency`,
:func:`check_band_width`) and labels more from the labelled neighbours of their rows
(:func:`interpolate_labels`). Returns :class:`Labels`.

No step after the windows' votes relates a chain to one of the other family (the runs' band
crossings, the band pairs, the pieces of one edge and the rows are each one family's), and a
step only labels unlabelled chains or unlabels its own: the two families' chains are decoded
side by side (:mod:`~nurbscan.detect._threads`; :func:`_families`), with the same labels as
all at once (7.1 MP teapot view: 75 -> 49 ms).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from ._threads import parallel_map
from .chains import Chains, family_cut
from .crossings import Reading
from .decode import line_labels, small_ints
from .lines import join_collinear, join_span
from .prepare import NoGrid, Prepared

#: Least share of all window votes that agree with their line's majority; below it the
#: pattern is taken not to match the photograph (empty result with a warning).
MIN_CONSENSUS = 0.85
#: Rounds of propagation (rows, band pairs, collinear pieces) after the windows: more label
#: more lines but carry a wrong label further; one has always been used.
PROPAGATION_ROUNDS = 1
#: In the collinear rounds (``collinear_rounds``), a piece of unknown colour also takes the
#: label of the piece it continues (a contradicting colour still stops it).
COLLINEAR_UNKNOWN = True
#: The pooling joins (``pool_gap``) need end fits predicting each other within this, camera px.
POOL_TOL = 2.0
#: Unlabel lines whose bands' median relative width is off by more than this
#: (:func:`check_band_width`, occluding contours).
LINE_WIDTH_TOL = 0.2
#: Rounds of :func:`interpolate_labels` where the bands are resolved. 7.1 MP teapot views
#: 0-7, with the collinear propagation: coverage 0.609 -> 0.629, labels still 99.999 % right
#: with no wrong line over 20 px, RMS 0.048 -> 0.049 px. (Extrapolating beyond the last
#: labelled edge of a row gained 1 point more but labelled 4 lines over 20 px wrongly.)
INTERPOLATION_ROUNDS = 3
#: :func:`interpolate_labels`' largest coordinate difference of the two labelled neighbours,
#: and largest distance of the interpolated coordinate from the pattern edge, pattern pitches.
INTERPOLATION_SPAN, INTERPOLATION_TOL = 2.2, 0.1
#: An interpolated label needs the line's own colour to be the band's (an unknown colour does
#: not confirm it).
REQUIRE_COLOUR = True


@dataclass(frozen=True)
class Labels:
    """Band index of every chain.

    Attributes
    ----------
    label : (L,) int
        Band index, -1 unlabelled.
    votes, agreement : (L,) int, (L,) float
        The colour windows' votes for it and their share (:func:`~nurbscan.detect.decode.
        line_labels`).
    rows : list or None
        :func:`row_order` of the chain points, when the decoding needed it.
    """

    label: np.ndarray
    votes: np.ndarray
    agreement: np.ndarray
    rows: list | None = None


def check_adjacencies(label: np.ndarray, props: tuple, pattern) -> np.ndarray:
    """:func:`check_adjacency` along the runs of the directions' crossings ``props``
    (:attr:`~nurbscan.detect.crossings.Reading.props`)."""
    for lr, lf, st, rw, ra, fa, _, _ in props:
        label = check_adjacency(label, lr, lf, st, rw, ra, fa, pattern.pitch / pattern.band)
    return label


def decode_labels(chains: Chains, reading: Reading, prep: Prepared, pattern,
                  options) -> Labels:
    """Labels from the colour windows, propagated and checked (``options``:
    :class:`~nurbscan.detect.options.DecodeOptions`). Raises :class:`NoGrid` when the
    windows disagree with their neighbours (a pattern that does not match)."""
    px, py, cls, line, nlines = chains.x, chains.y, chains.cls, chains.line, chains.nlines
    min_votes, min_agreement = options.min_votes, options.min_agreement
    fine = prep.fine
    label, votes, agree = line_labels(line, reading.vote_point, reading.vote_band, nlines,
                                      min_votes=min_votes, min_agreement=min_agreement,
                                      vote_pos=reading.vote_pos, min_positions=pattern.n)
    # a pattern that does not match the photograph still decodes every window (all windows of
    # the sequence exist), but neighbouring windows then rarely agree: reject the whole image
    with np.errstate(all="ignore"):
        total = np.where(agree > 0, votes / np.maximum(agree, 1e-12), 0.0)
    consensus = float(votes.sum() / total.sum()) if total.sum() > 0 else 0.0
    if total.sum() > 0 and consensus < MIN_CONSENSUS:
        raise NoGrid(f"pattern: does not match the photograph (only {consensus:.0%} of the "
                     "colour windows agree with their neighbours)", prep.size)
    seq = np.asarray(pattern.sequence)
    # the two families' lines are decoded side by side (_threads): no step below relates a
    # line to one of the other family (the runs, band pairs, joins, checks and rows are each
    # one family's), and a step only labels unlabelled lines or unlabels its own lines
    families = _families(chains, reading)
    if families is None:
        families = [_Family(px, py, cls, line, 0, nlines, reading.props, chains.join_src,
                            chains.join_dst, line[reading.vote_point], reading.vote_band,
                            reading.vote_pos, 0)]
    span = join_span(px, py)
    parts = parallel_map(lambda f: _propagated(label, f, reading.lcode, seq, pattern, options,
                                               fine, chains.join_gap, span), families)
    rows = None
    if len(parts) > 1:
        own = np.zeros(nlines, bool)
        own[families[1].first_line:families[1].first_line + families[1].nlines] = True
        label = np.where(own, parts[1][0], parts[0][0])
        if parts[0][1] is not None:
            rows = parts[0][1] + parts[1][1]
    else:
        label, rows = parts[0]
    return Labels(label, votes, agree, rows)


@dataclass(frozen=True)
class _Family:
    """The chains of one family (or of both) for :func:`_propagated`: their points (``x``,
    ``y``, ``cls``, ``line``: the chains' own ids), the ``nlines`` chains from
    ``first_line`` on, the runs' crossings (``props``), the collinear joins, the window
    votes (``vote_line``, ``vote_band``, ``vote_pos``) and the points' offset in the
    chains' arrays (``first_point``)."""

    x: np.ndarray
    y: np.ndarray
    cls: np.ndarray
    line: np.ndarray
    first_line: int
    nlines: int
    props: tuple
    join_src: np.ndarray
    join_dst: np.ndarray
    vote_line: np.ndarray
    vote_band: np.ndarray
    vote_pos: np.ndarray
    first_point: int


def _families(chains: Chains, reading: Reading) -> list[_Family] | None:
    """The vertical and the horizontal family's chains (:class:`_Family`), where the chains
    of each are consecutive (as :func:`~nurbscan.detect.lines.trace_lines` numbers them) and
    both have runs; None otherwise."""
    cls, line, nlines = chains.cls, chains.line, chains.nlines
    cut = family_cut(cls)
    if cut is None or [p[7] for p in reading.props] != ["vertical", "horizontal"]:
        return None
    first = int(line[cut])
    vline = line[reading.vote_point]
    jv = chains.join_src < first
    out = []
    for k, (pts, lines, joins, votes) in enumerate((
            (slice(0, cut), (0, first), jv, vline < first),
            (slice(cut, len(cls)), (first, nlines), ~jv, vline >= first))):
        out.append(_Family(chains.x[pts], chains.y[pts], cls[pts], line[pts], lines[0],
                           lines[1] - lines[0], (reading.props[k],), chains.join_src[joins],
                           chains.join_dst[joins], vline[votes], reading.vote_band[votes],
                           reading.vote_pos[votes], pts.start))
    return out


def _propagated(label: np.ndarray, f: _Family, lcode_all: np.ndarray, seq: np.ndarray,
                pattern, options, fine: bool, join_gap: float, span: float) -> tuple:
    """:func:`decode_labels` after the windows' labels ``label`` (L,), for the chains of
    ``f``: pooled over the pieces of an edge, propagated, checked and interpolated. Returns
    the labels (L,; the other chains' as given) and the rows (:func:`row_order`, indices of
    the chains' points) or None."""
    px, py, cls, line, props = f.x, f.y, f.cls, f.line, f.props
    min_votes, min_agreement = options.min_votes, options.min_agreement
    jsrc, jdst = f.join_src, f.join_dst
    pool_gap = options.pool_gap if fine else 0.0
    if pool_gap > 0 and join_gap > 0 and len(line):
        psrc, pdst = join_collinear(px, py, cls, line - f.first_line,
                                    max_gap=pool_gap * join_gap, tol=POOL_TOL,
                                    pairs_only=True, span=span)
        label = pooled_labels(label, psrc + f.first_line, pdst + f.first_line, f.vote_line,
                              f.vote_band, f.vote_pos, lcode_all, seq, min_votes,
                              min_agreement, pattern.n)

    def propagate(label):
        for lr, lf, st, rw, ra, fa, lcode, name in props:
            label = propagate_labels(label, lr, lf, st, rw, ra, fa, lcode, seq,
                                     pattern.nbands(name), pattern.pitch / pattern.band)
            label = propagate_pairs(label, lr, lf, lcode, seq, min_votes=min_votes,
                                    min_agreement=min_agreement)
        return propagate_collinear(label, jsrc, jdst, lcode_all, seq)

    label = _until_stable(propagate, label, PROPAGATION_ROUNDS)
    label = _until_stable(lambda lab: propagate_collinear(lab, jsrc, jdst, lcode_all, seq,
                                                          unknown=COLLINEAR_UNKNOWN),
                          label, options.collinear_rounds if fine else 0)
    label = check_adjacencies(label, props, pattern)
    label = check_band_width(label, props, pattern.band / pattern.pitch, LINE_WIDTH_TOL)
    rows = None
    if fine and INTERPOLATION_ROUNDS:
        rows = row_order(px, py, cls)
        label = _until_stable(
            lambda lab: interpolate_labels(lab, px, py, cls, line, lcode_all, pattern,
                                           span=INTERPOLATION_SPAN * pattern.pitch,
                                           tol=INTERPOLATION_TOL * pattern.pitch,
                                           min_votes=min_votes,
                                           require_colour=REQUIRE_COLOUR, rows=rows),
            label, INTERPOLATION_ROUNDS)
        label = check_adjacencies(label, props, pattern)
        rows = [(d, idx + f.first_point, run, acr) for d, idx, run, acr in rows]
    return label, rows


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
        o = np.lexsort((acr, small_ints(run)))
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
    k = np.flatnonzero(known)  # (a gather by index: faster than by the mask)
    c[k] = pattern.edge_coordinate(("vertical", "horizontal")[d], lab[k], cls[idx[k]] % 2)
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
    neighbours = [_row_neighbours(label, line, cls, pattern, d, idx) for d, idx, _, _ in rows]
    for (_, idx, run, acr), (known, c, prv, nxt) in zip(rows, neighbours, strict=True):
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
    consistent = row_consistent(label, line, cls, ci, pattern, rows, neighbours)
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


def row_consistent(label, line, cls, pred, pattern, rows: list,
                   neighbours: list | None = None) -> np.ndarray:
    """Whether each point's predicted edge agrees with the edge count of its row.

    ``pred`` (N,) is a predicted projector coordinate for points of unlabelled lines (NaN
    elsewhere); its candidate is the nearest pattern edge of the point's kind (rising /
    falling). Along the point's pixel row (column for horizontal-band edges; ``rows`` is
    :func:`row_order`), between it and the nearest labelled point on each side, there must
    lie as many edge points as there are pattern edges between their coordinates and the
    candidate (no edge missed or spurious between them, as in :func:`interpolate_labels`).
    A point passes when it has a labelled neighbour in its row on at least one side and
    every such side agrees: a surface squeezed between two others (a handle's side) holds
    more edges than a plane through its neighbours allows. ``neighbours``: the rows'
    :func:`_row_neighbours` for ``label``, when the caller has them. Returns bool (N,).
    """
    out = np.zeros(len(line), bool)

    def one_run(job):  # one family's rows (the families side by side: _threads)
        (d, idx, run, _), nb = job
        known, c, prv, nxt = nb if nb is not None else _row_neighbours(label, line, cls,
                                                                         pattern, d, idx)
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
        out[idx[k]] = (has1 | has2) & (~has1 | ok1) & (~has2 | ok2)  # (disjoint per family)

    parallel_map(one_run, list(zip(rows, neighbours or [None] * len(rows), strict=True)))
    return out


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
    o = np.lexsort((v, small_ints(g)))
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
