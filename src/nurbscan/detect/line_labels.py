"""Labelling the chains of one direction of a thin-line grid (steps 2 to 6 of
:mod:`nurbscan.detect.line_grid`).

:func:`decode_family` takes one direction's chained line centres (:class:`Chains`) and their
chromaticities and gives each chain the index of its line in the pattern's family, or -1:

- colour classes learned from the photograph (:mod:`.colour_model`) and, per chain, the class
  most of its centres fall in;
- windows of ``pattern.window`` consecutive chains along the rows whose gaps are alike
  (:func:`_windows`), looked up in the family's code: a vote for each chain's index
  (:func:`_votes`), under the assignment of classes to codes and the reading order in which
  most windows occur in the code (:func:`_choose_codes`, :func:`_run_score`);
- each chain's majority label (:func:`_majority`), checked against its neighbours' pitch
  (:func:`_consistent`) and the order of the lines along the runs (:func:`_ordered`);
- propagation to unlabelled neighbours of the right colour (:func:`_propagate`), collinear
  pieces (:func:`_collinear_labels`), counting between two decoded lines
  (:func:`_fill_between`), and the check against the smooth index field of each chain's
  neighbourhood (:func:`_field_check`).

Hand-written: a windowed colour code read along the rows of a photograph, with gaps and
occlusions, is not in OpenCV's structured_light module (which reads its own Gray-code and
sinusoidal patterns) nor in any other library at hand.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from scipy.spatial import cKDTree

from .colour_model import ColourModel, all_assignments, chain_classes, fit_colour_model
from .ridges import RidgePoints, gap_links

if TYPE_CHECKING:
    from .line_grid import LineDetectOptions

DIRECTIONS = ("vertical", "horizontal")


@dataclass
class Chains:
    """Chained centres of one direction: points ``pts`` (ordered by chain), chain id ``chain``
    (0 .. C - 1), run and across coordinates, each chain's colour class."""

    pts: RidgePoints
    chain: np.ndarray
    run: np.ndarray
    across: np.ndarray
    nchains: int
    cls: np.ndarray | None = None
    votes: tuple | None = None  # (C,) windows for the final label, (C,) their share


def family_chains(points: RidgePoints, direction: np.ndarray, order: np.ndarray,
                   chain: np.ndarray, d: int) -> Chains:
    sel = direction[order] == d
    o, c = order[sel], chain[sel]
    _, c = np.unique(c, return_inverse=True)
    p = points.take(o)
    run = p.iy if d == 0 else p.ix
    acr = p.x if d == 0 else p.y
    return Chains(p, c.astype(np.int64), run.astype(np.int64), acr,
                   int(c.max()) + 1 if len(c) else 0)


def neighbours(ch: Chains) -> tuple[np.ndarray, np.ndarray]:
    """Consecutive centres of different chains along each run: (n - 1,) index pairs into the
    run-sorted order (``o``) and their gaps; returns (o, gap-after) with ``gap[i]`` the gap from
    ``o[i]`` to ``o[i + 1]`` (NaN where the run changes or the chain is the same)."""
    o = np.lexsort((ch.across, ch.run))
    r, a, c = ch.run[o], ch.across[o], ch.chain[o]
    gap = np.full(len(o), np.nan)
    same = (r[1:] == r[:-1]) & (c[1:] != c[:-1])
    gap[:-1] = np.where(same, a[1:] - a[:-1], np.nan)
    return o, gap


def _windows(ch: Chains, n: int, gap_ratio: float) -> tuple[np.ndarray, np.ndarray]:
    """Windows of ``n`` consecutive centres along the runs with alike gaps: (W, n) indices of
    the chains, in increasing across order, and each window's position in the run-sorted
    order (W,) (windows j and j + 1 of one run that overlap in n - 1 centres have positions
    differing by 1)."""
    o, gap = neighbours(ch)
    m = len(o)
    if m < n:
        return np.zeros((0, n), np.int64), np.zeros(0, np.int64)
    starts = np.arange(m - n + 1)
    ok = np.ones(len(starts), bool)
    g0 = gap[starts]
    ok &= np.isfinite(g0) & (g0 > 0)
    for j in range(1, n - 1):
        gj = gap[starts + j]
        with np.errstate(invalid="ignore"):
            ok &= np.isfinite(gj) & (gj < g0 * gap_ratio) & (gj * gap_ratio > g0)
    idx = starts[ok][:, None] + np.arange(n)[None, :]
    return ch.chain[o[idx]], starts[ok]


def _lookup(family, windows_codes: np.ndarray) -> np.ndarray:
    """``family.lookup`` with -1 for windows holding an unknown code (-1)."""
    if not len(windows_codes):
        return np.zeros(0, np.int64)
    out = np.asarray(family.lookup(np.where(windows_codes < 0, 0, windows_codes)), np.int64)
    out[(windows_codes < 0).any(1)] = -1
    return out


def _votes(wins: np.ndarray, codes: np.ndarray, family, reverse: bool
           ) -> tuple[np.ndarray, np.ndarray]:
    """(chain, index) votes of the windows under the chains' codes and a reading order."""
    n = wins.shape[1]
    w = wins[:, ::-1] if reverse else wins
    first = _lookup(family, codes[w])
    ok = first >= 0
    vc = w[ok].ravel()
    vi = (first[ok][:, None] + np.arange(n)[None, :]).ravel()
    return vc, vi


def _run_score(wins: np.ndarray, pos: np.ndarray, codes: np.ndarray, family, reverse: bool
               ) -> float:
    """Share of the windows with known codes that occur in the code *and* whose next window
    along the run (one centre on) occurs at the next index: a wrong assignment of colours to
    codes makes some windows occur by chance, but rarely two overlapping ones in order."""
    if not len(wins):
        return 0.0
    known = (codes[wins] >= 0).all(1)
    if not known.any():
        return 0.0
    w = wins[:, ::-1] if reverse else wins
    first = _lookup(family, codes[w])
    nxt = np.r_[pos[1:] == pos[:-1] + 1, False]
    step = -1 if reverse else 1
    follow = nxt & (first >= 0) & (np.r_[first[1:], -1] == first + step)
    prev = np.r_[False, follow[:-1]]
    return float((follow | prev).sum() / known.sum())


def _choose_codes(ch: Chains, model: ColourModel, wins: np.ndarray, pos: np.ndarray, family,
                  min_share: float, readings=(False,), prefer: float = 0.9,
                  search: bool = False):
    """Chain codes and reading order under which most windows read in order
    (:func:`_run_score`). Only the hue match is tried unless ``search``; then every
    assignment of classes to codes is, and the hue match is kept unless another scores more
    than 1 / ``prefer`` times as high. (On the real set the hue match won in all 20 families,
    but wrong assignments scored up to 0.79 of their windows in order - this code read
    backwards under a permutation of its colours is much like itself - so the search is off
    by default.)

    Returns the chain codes (C,), whether the windows read backwards, the score, the code of
    each colour class (K,), and the best score of the readings not tried (the other order;
    NaN when both were tried), which tells a mirrored image.
    """
    k = len(model.codes)
    cc, _ = chain_classes(ch.cls, ch.chain, ch.nchains, k, min_share)
    results, others = [], []
    for cand in (all_assignments(model) if search else (model,)):
        codes = np.where(cc >= 0, cand.codes[np.maximum(cc, 0)], -1)
        for rev in (False, True):
            score = _run_score(wins, pos, codes, family, rev)
            if rev in readings:
                results.append((score, codes, rev, cand.codes))
            else:
                others.append(score)
    other = max(others) if others else float("nan")
    best = max(results, key=lambda t: t[0])
    hue_first = max(results[:len(readings)], key=lambda t: t[0])
    pick = hue_first if hue_first[0] >= prefer * best[0] else best
    return pick[1], pick[2], pick[0], pick[3], other


def _majority(vc: np.ndarray, vi: np.ndarray, nchains: int, count: int, min_votes: int,
              min_agreement: float) -> np.ndarray:
    """Label (C,) of each chain: the index most of its votes give, -1 without a clear one."""
    label = np.full(nchains, -1, np.int64)
    ok = (vi >= 0) & (vi < count)
    if not ok.any():
        return label
    tab = np.zeros((nchains, count))
    np.add.at(tab, (vc[ok], vi[ok]), 1.0)
    tot = tab.sum(1)
    best = tab.argmax(1)
    top = tab.max(1)
    with np.errstate(all="ignore"):
        good = (top >= min_votes) & (top >= min_agreement * tot)
    label[good] = best[good]
    return label


def _pairs(ch: Chains) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Neighbouring centres along the runs: chains (left, right) and gap, px."""
    o, gap = neighbours(ch)
    i = np.nonzero(np.isfinite(gap))[0]
    return ch.chain[o[i]], ch.chain[o[i + 1]], gap[i]


def _consistent(label: np.ndarray, ch: Chains, reverse: bool, tol: float,
                rounds: int = 50) -> np.ndarray:
    """Refuse labels whose neighbours along the runs disagree (module notes, step 5).

    For each pair of labelled neighbours (a, b) along a run, the index step
    ``s = label[b] - label[a]`` (negated when reading backwards) must be a positive whole number
    and the gap must be ``s`` pitches, the pitch being the run-local median of ``gap / s`` over
    the labelled pairs of the same chains (a chain's median pitch); a chain with more failing
    than agreeing pairs loses its label, the worst first, until none is left.
    """
    label = label.copy()
    left, right, gap = _pairs(ch)
    sign = -1 if reverse else 1
    for _ in range(rounds):
        both = (label[left] >= 0) & (label[right] >= 0)
        a, b, g = left[both], right[both], gap[both]
        if not len(a):
            break
        step = sign * (label[b] - label[a])
        pos = step > 0
        with np.errstate(all="ignore"):
            per = np.where(pos, g / np.maximum(step, 1), np.nan)
        # pitch near each chain: the median per-step gap of its labelled pairs
        pitch = np.full(ch.nchains, np.nan)
        both_c = np.r_[a[pos], b[pos]]
        vals = np.r_[per[pos], per[pos]]
        if len(vals):
            o = np.lexsort((vals, both_c))
            bc, vv = both_c[o], vals[o]
            st = np.r_[0, np.nonzero(bc[1:] != bc[:-1])[0] + 1]
            en = np.r_[st[1:], len(bc)]
            pitch[bc[st]] = vv[(st + en - 1) // 2]
        ref = np.nanmin(np.c_[pitch[a], pitch[b]], axis=1)
        with np.errstate(all="ignore"):
            ratio = g / ref
            good = pos & (np.abs(ratio - step) <= tol * np.maximum(step, 1))
        bad_n = np.bincount(np.r_[a[~good], b[~good]], minlength=ch.nchains)
        good_n = np.bincount(np.r_[a[good], b[good]], minlength=ch.nchains)
        score = bad_n - good_n
        worst = int(np.argmax(np.where(label >= 0, score, -np.inf)))
        if score[worst] <= 0:
            break
        # drop every chain as bad as the worst at once when many fail (faster), else one
        drop = (label >= 0) & (score >= max(1, score[worst]))
        label[drop] = -1
    return label


def _run_order(ch: Chains, max_apart: int = 64
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Chain pairs (lo, hi), lo < hi, that share runs, with the number of runs in which lo lies
    before hi (smaller across) and after it: (P,) each. Any two centres of one run count, not
    only neighbours (up to ``max_apart`` centres apart in the run)."""
    o = np.lexsort((ch.across, ch.run))
    r, c = ch.run[o], ch.chain[o]
    aa, bb = [], []
    for k in range(1, max_apart + 1):
        same = r[k:] == r[:-k]
        if not same.any():
            break
        a, b = c[:-k][same], c[k:][same]
        ok = a != b
        aa.append(a[ok])
        bb.append(b[ok])
    z = np.zeros(0, np.int64)
    if not aa:
        return z, z, z, z
    a, b = np.concatenate(aa), np.concatenate(bb)
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    key = lo * ch.nchains + hi
    uk, inv = np.unique(key, return_inverse=True)
    nb = np.bincount(inv, (a == lo).astype(np.float64), minlength=len(uk)).astype(np.int64)
    nt = np.bincount(inv, minlength=len(uk)).astype(np.int64)
    return uk // ch.nchains, uk % ch.nchains, nb, nt - nb


def _ordered(label: np.ndarray, ch: Chains, reverse: bool, min_runs: int = 3,
             pairs=None) -> np.ndarray:
    """Refuse labels that contradict the order of the lines along the runs.

    Two chains that share at least ``min_runs`` runs lie in one order along them (the one most
    of their shared runs show); their indices must be in that order (growing in the reading
    direction). Misread colours over a whole region can make a run of windows that is
    consistent among itself but shifted (a block of lines read as another part of the code):
    its chains contradict the order of the correctly labelled chains beyond their own
    neighbours. The chain contradicting the most partners loses its label (ties: the one with
    fewer agreeing partners), until none contradicts any.
    """
    lo, hi, nb, na = _run_order(ch) if pairs is None else pairs
    keep = (nb + na >= min_runs) & (nb != na)
    lo, hi, lo_first = lo[keep], hi[keep], nb[keep] > na[keep]
    label = label.copy()
    sign = -1 if reverse else 1
    for _ in range(ch.nchains):
        both = (label[lo] >= 0) & (label[hi] >= 0)
        if not both.any():
            break
        d = sign * (label[hi] - label[lo])
        bad = both & np.where(lo_first, d <= 0, d >= 0)
        if not bad.any():
            break
        good = both & ~bad
        nbad = np.bincount(np.r_[lo[bad], hi[bad]], minlength=ch.nchains)
        ngood = np.bincount(np.r_[lo[good], hi[good]], minlength=ch.nchains)
        score = nbad * (ch.nchains + 1) - ngood
        worst = int(np.argmax(np.where(label >= 0, score, np.iinfo(np.int64).min)))
        label[worst] = -1
    return label


def _propagate(label: np.ndarray, colour_ok, ch: Chains, family, reverse: bool,
               opts: LineDetectOptions) -> np.ndarray:
    """Label unlabelled chains from labelled neighbours (module notes, step 6)."""
    left, right, gap = _pairs(ch)
    count = family.count
    fam_codes = np.asarray(family.codes, np.int64)
    sign = -1 if reverse else 1
    for _ in range(opts.propagation_rounds):
        # the labelled pairs' pitch per chain (median gap per index step)
        both = (label[left] >= 0) & (label[right] >= 0)
        step = sign * (label[right] - label[left])
        okp = both & (step > 0)
        pitch = np.full(ch.nchains, np.nan)
        if okp.any():
            per = gap[okp] / step[okp]
            cc = np.r_[left[okp], right[okp]]
            vv = np.r_[per, per]
            sums = np.bincount(cc, vv, minlength=ch.nchains)
            cnt = np.bincount(cc, minlength=ch.nchains)
            with np.errstate(all="ignore"):
                pitch = np.where(cnt > 0, sums / cnt, np.nan)
        vc, vi = [], []
        for src, dst, toward in ((left, right, sign), (right, left, -sign)):
            lab = label[src]
            ok = (lab >= 0) & (label[dst] < 0) & np.isfinite(pitch[src])
            with np.errstate(all="ignore"):
                ok &= np.abs(gap / pitch[src] - 1.0) <= opts.pitch_tol
            vc.append(dst[ok])
            vi.append(lab[ok] + toward)
        vc, vi = np.concatenate(vc), np.concatenate(vi)
        inside = (vi >= 0) & (vi < count)
        vc, vi = vc[inside], vi[inside]
        new = _majority(vc, vi, ch.nchains, count, opts.min_votes, opts.min_agreement)
        take = (new >= 0) & (label < 0)
        take &= colour_ok(np.arange(ch.nchains), fam_codes[np.clip(new, 0, count - 1)])
        if not take.any():
            break
        label = label.copy()
        label[take] = new[take]
        label = _consistent(label, ch, reverse, opts.pitch_tol)
    return label


def _fill_between(label: np.ndarray, ch: Chains, family, reverse: bool,
                  opts: LineDetectOptions) -> np.ndarray:
    """Label the chains between two labelled ones along the runs by counting.

    Along a run, two labelled centres i and j (indices ``l_i``, ``l_j``, reading order) with
    exactly ``l_j - l_i - 1`` centres between them, all gaps alike (within ``gap_ratio`` of
    each other), enclose lines ``l_i + 1 .. l_j - 1`` in order; each enclosed centre votes for
    its line, and an unlabelled chain takes the index most of its votes give (``min_votes``,
    ``min_agreement``). This needs no colour: where a region's colours are misread (saturated
    highlights) the windows fail, but the count of lines between two decoded ones does not.
    Gaps of at most ``max_fill`` lines are filled.
    """
    o = np.lexsort((ch.across, ch.run))
    r, a, c = ch.run[o], ch.across[o], ch.chain[o]
    lab = label[c]
    sign = -1 if reverse else 1
    li = np.nonzero(lab >= 0)[0]
    if len(li) < 2:
        return label
    p1, p2 = li[:-1], li[1:]
    d = sign * (lab[p2] - lab[p1])
    ok = (r[p1] == r[p2]) & (d >= 2) & (d <= opts.max_fill) & (p2 - p1 == d)
    p1, p2, d = p1[ok], p2[ok], d[ok]
    if not len(p1):
        return label
    gap = np.r_[np.diff(a), np.inf]
    # smallest and largest gap of each enclosed stretch [p1, p2)
    k = np.arange(int(d.max()))[None, :]
    idx = np.minimum(p1[:, None] + k, len(gap) - 1)
    inside = k < d[:, None]
    g = gap[idx]
    gmin = np.where(inside, g, np.inf).min(1)
    gmax = np.where(inside, g, 0.0).max(1)
    alike = gmax <= opts.gap_ratio * gmin
    p1, d = p1[alike], d[alike]
    if not len(p1):
        return label
    rep = np.repeat(np.arange(len(p1)), d - 1)
    step = np.arange(len(rep)) - np.repeat(np.cumsum(d - 1) - (d - 1), d - 1) + 1
    pos = p1[rep] + step
    vc = c[pos]
    vi = lab[p1[rep]] + sign * step
    free = label[vc] < 0
    new = _majority(vc[free], vi[free], ch.nchains, family.count, opts.min_votes,
                    opts.min_agreement)
    out = label.copy()
    take = (new >= 0) & (label < 0)
    out[take] = new[take]
    return out


def _field_residuals(label: np.ndarray, ch: Chains, coords: np.ndarray, radius: float,
                     samples: int = 5, min_labels: int = 2) -> np.ndarray:
    """Median distance (projector px) of each labelled chain's coordinate from the plane
    ``coord = a + b x + c y`` fitted (least squares) to the other labelled chains' centres
    within ``radius`` camera px of ``samples`` of its centres; NaN where fewer than
    ``min_labels`` other labels are near. (All samples' fits at once: the normal equations
    summed per sample with ``bincount``, solved batched.)"""
    res = np.full(ch.nchains, np.nan)
    lab_pt = label[ch.chain]
    sel = np.nonzero(lab_pt >= 0)[0][::3]  # every 3rd labelled centre
    if len(sel) < 3:
        return res
    starts = np.r_[0, np.nonzero(ch.chain[1:] != ch.chain[:-1])[0] + 1]
    stops = np.r_[starts[1:], len(ch.chain)]
    lc = np.nonzero(label >= 0)[0]
    frac = np.linspace(0.0, 1.0, samples)[None, :]
    smp = np.unique(np.round(starts[lc, None] + frac * (stops[lc, None] - 1 - starts[lc, None]))
                    .astype(np.int64).ravel())
    x, y = ch.pts.x, ch.pts.y
    tree = cKDTree(np.c_[x[sel], y[sel]])
    lists = tree.query_ball_point(np.c_[x[smp], y[smp]], radius)
    cnt = np.fromiter((len(v) for v in lists), np.int64, len(lists))
    if not cnt.sum():
        return res
    si = np.repeat(np.arange(len(smp)), cnt)
    nb = sel[np.concatenate([np.asarray(v, np.int64) for v in lists if len(v)])]
    keep = ch.chain[nb] != ch.chain[smp[si]]
    si, nb = si[keep], nb[keep]
    m = len(smp)
    # distinct labels per sample
    key = np.unique(si * (len(coords) + 1) + lab_pt[nb])
    nlab = np.bincount(key // (len(coords) + 1), minlength=m)
    dx, dy = x[nb] - x[smp[si]], y[nb] - y[smp[si]]
    v = coords[lab_pt[nb]]
    terms = (np.ones_like(dx), dx, dy, dx * dx, dx * dy, dy * dy, v, v * dx, v * dy)
    s_ = [np.bincount(si, t, minlength=m) for t in terms]
    ata = np.stack([np.stack([s_[0], s_[1], s_[2]], -1), np.stack([s_[1], s_[3], s_[4]], -1),
                    np.stack([s_[2], s_[4], s_[5]], -1)], -2)
    atb = np.stack([s_[6], s_[7], s_[8]], -1)
    ok = (nlab >= min_labels) & (np.linalg.det(ata) > 1e-6 * np.maximum(s_[0], 1) ** 3)
    if not ok.any():
        return res
    coef = np.linalg.solve(ata[ok] + 1e-9 * np.eye(3)[None], atb[ok][:, :, None])[:, 0, 0]
    sc = ch.chain[smp[ok]]
    err = np.abs(coef - coords[label[sc]])
    o = np.lexsort((err, sc))
    sc, err = sc[o], err[o]
    first = np.r_[0, np.nonzero(sc[1:] != sc[:-1])[0] + 1]
    last = np.r_[first[1:], len(sc)]
    lo, hi = (first + last - 1) // 2, (first + last) // 2
    res[sc[first]] = 0.5 * (err[lo] + err[hi])
    return res


def _field_check(label: np.ndarray, ch: Chains, family, radius: float, tol: float,
                 rounds: int = 20) -> np.ndarray:
    """Refuse labels off the smooth index field of their neighbourhood.

    On a surface the projector coordinate is a smooth function of the camera position, close to
    a plane over a few lines: the chain whose coordinate is farthest (more than ``tol``
    pitches) from the plane fitted to the other labelled chains around it
    (:func:`_field_residuals`) loses its label, until none is that far. This catches short
    chains labelled from a misread window or an interrupted run (inside a checkerboard), which
    the run checks see only along one row.
    """
    coords = np.asarray(family.centres, np.float64)
    pitch = float(np.median(np.diff(coords))) if len(coords) > 1 else 1.0
    label = label.copy()
    for _ in range(rounds):
        res = _field_residuals(label, ch, coords, radius)
        bad = np.nan_to_num(res, nan=0.0) > tol * pitch
        if not bad.any():
            break
        worst = np.nanmax(np.where(bad, res, np.nan))
        # drop the worst, and every chain nearly as bad (a round per chain is slow)
        label[bad & (res >= 0.75 * worst)] = -1
    return label


def _collinear(ch: Chains, max_gap: int, offset: float) -> tuple[np.ndarray, np.ndarray]:
    """Chain pairs (a, b) where b continues a along its line across a gap of up to ``max_gap``
    runs (a black square, a shadow; :func:`~nurbscan.detect.ridges.gap_links`)."""
    if ch.nchains < 2:
        z = np.zeros(0, np.int64)
        return z, z
    o = np.arange(len(ch.chain))  # ch's centres are grouped by chain and ordered by run
    starts = np.r_[0, np.nonzero(ch.chain[1:] != ch.chain[:-1])[0] + 1]
    stops = np.r_[starts[1:], len(o)]
    a, b = gap_links(ch.run, ch.across, o, starts, stops, max_gap, offset, k=8,
                     grow=0.02)
    return ch.chain[starts[a]], ch.chain[starts[b]]


def _collinear_labels(label: np.ndarray, colour_ok, ch: Chains, family, pairs,
                      ) -> np.ndarray:
    """Pieces of one line hold one label: of two collinear chains with different labels the
    shorter loses its label; an unlabelled chain continuing a labelled one takes its label
    when its colour is that line's colour (repeated along runs of pieces)."""
    a, b = pairs
    if not len(a):
        return label
    label = label.copy()
    length = np.bincount(ch.chain, minlength=ch.nchains)
    fam_codes = np.asarray(family.codes, np.int64)
    clash = (label[a] >= 0) & (label[b] >= 0) & (label[a] != label[b])
    short = np.where(length[a] < length[b], a, b)[clash]
    label[short] = -1
    for _ in range(8):
        changed = False
        for src, dst in ((a, b), (b, a)):
            ok = (label[src] >= 0) & (label[dst] < 0)
            ok &= colour_ok(dst, fam_codes[np.clip(label[src], 0, family.count - 1)])
            if ok.any():
                label[dst[ok]] = label[src[ok]]
                changed = True
        if not changed:
            break
    return label


def _label_votes(label: np.ndarray, vc: np.ndarray, vi: np.ndarray, nchains: int
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Windows voting for each chain's final label (C,) and their share of the chain's
    votes (C,) (0 for a chain without votes, labelled by its neighbours only)."""
    tot = np.bincount(vc, minlength=nchains).astype(np.float64)
    agree = np.bincount(vc[vi == label[vc]], minlength=nchains)
    with np.errstate(all="ignore"):
        share = np.where(tot > 0, agree / tot, 0.0)
    return agree.astype(np.int64), share


def decode_family(ch: Chains, chroma: np.ndarray, pattern, d: int,
                   opts: LineDetectOptions) -> tuple[np.ndarray, str | None]:
    """Labels (C,) of one direction's chains (module notes, steps 2 to 6), or a warning."""
    name = DIRECTIONS[d]
    family = pattern.family(name)
    model = fit_colour_model(chroma, pattern.rgb, pattern.codes_used(name))
    if model is None or ch.nchains == 0:
        return np.full(ch.nchains, -1, np.int64), f"too few {name} line centres"
    ch.cls = model.classify(chroma)
    wins, pos = _windows(ch, pattern.window, opts.gap_ratio)
    readings = (False, True) if opts.reading == "either" else (opts.reading == "backward",)
    codes, reverse, score, class_codes, other = _choose_codes(
        ch, model, wins, pos, family, opts.min_class_share, readings,
        search=opts.colour_search)
    none = np.full(ch.nchains, -1, np.int64)
    if score < opts.min_score and not (np.isfinite(other) and other > 1.5 * score
                                       and other >= opts.min_score):
        return none, (f"the {name} lines' colours do not read as the pattern's code (windows "
                      f"in order {score:.2f} < {opts.min_score})")
    if np.isfinite(other) and other > 1.5 * score:
        return none, (f"the {name} lines read backwards (windows in order {other:.2f} against "
                      f"{score:.2f}: a mirrored image? LineDetectOptions.reading)")
    vc, vi = _votes(wins, codes, family, reverse)
    label = _majority(vc, vi, ch.nchains, family.count, opts.min_votes, opts.min_agreement)
    # a chain's label must be a line of its own colour
    fam_codes = np.asarray(family.codes, np.int64)
    label[(label >= 0) & (codes != fam_codes[np.clip(label, 0, family.count - 1)])] = -1
    pairs = _run_order(ch)
    pieces = _collinear(ch, opts.piece_gap, opts.piece_offset)
    label = _ordered(_consistent(label, ch, reverse, opts.pitch_tol), ch, reverse, pairs=pairs)
    # a chain can take a neighbour's or a piece's label when a share propagate_share of its
    # centres have that line's colour (a line's colour drifts along it: the classes overlap)
    _, _, counts = chain_classes(ch.cls, ch.chain, ch.nchains, len(class_codes),
                                 opts.min_class_share, counts=True)
    frac = counts / np.maximum(counts.sum(1, keepdims=True), 1.0)
    code_frac = np.zeros((ch.nchains, len(pattern.colours)))
    code_frac[:, class_codes] = frac

    def colour_ok(chains, code):
        return code_frac[chains, code] >= opts.propagate_share

    label = _collinear_labels(label, colour_ok, ch, family, pieces)
    label = _propagate(label, colour_ok, ch, family, reverse, opts)
    label = _collinear_labels(label, colour_ok, ch, family, pieces)
    label = _ordered(_consistent(label, ch, reverse, opts.pitch_tol), ch, reverse, pairs=pairs)
    if opts.max_fill >= 2:
        label = _fill_between(label, ch, family, reverse, opts)
        label = _collinear_labels(label, colour_ok, ch, family, pieces)
        label = _ordered(_consistent(label, ch, reverse, opts.pitch_tol), ch, reverse,
                         pairs=pairs)
    if opts.field_tol > 0:
        _, gap = neighbours(ch)
        g = gap[np.isfinite(gap)]
        radius = opts.field_radius * (float(np.median(g)) if len(g) else 20.0)
        label = _field_check(label, ch, family, radius, opts.field_tol)
    ch.votes = _label_votes(label, vc, vi, ch.nchains)
    return label, None

