"""Sub-pixel centres of thin bright lines (Steger 1998) and their chains.

A line 2 to 4 camera px wide has two edges that the edge filter cannot separate; its centre is
measured instead, as a *ridge* of the smoothed intensity. The steps (Steger, "An unbiased
detector of curvilinear structures", IEEE PAMI 20(2), 1998, section 3):

1. Gaussian derivatives of the signal ``s`` at scale ``sigma`` (:func:`hessian`): ``r_x``,
   ``r_y``, ``r_xx``, ``r_xy``, ``r_yy``.
2. At each pixel the Hessian's most negative eigenvalue ``lambda`` and its unit eigenvector
   ``n = (n_x, n_y)``, the direction across the line (:func:`ridge_points`).
3. The second-order Taylor polynomial of ``s`` along ``n`` has its maximum (the zero of the
   first derivative) at ``t = -(r_x n_x + r_y n_y) / lambda``; the pixel holds a line centre
   when ``|t n_x| <= 1/2`` and ``|t n_y| <= 1/2``, at ``(x + t n_x, y + t n_y)``, and its
   strength ``-lambda`` is above a threshold. Pixels where the other eigenvalue is also
   strongly negative (a blob: the crossing of two lines) are not line centres.
4. The two directions of a grid are the two modes of the normals' orientation
   (:func:`split_directions`): lines of the family whose normal is nearer the image x axis are
   the *vertical* lines.
5. Centres of one direction are linked from each pixel row to the next (vertical lines; columns
   for horizontal ones) where they continue each other within a pixel, and the chains are
   joined across short gaps (the crossings of the other direction's lines, where step 3
   refuses the blob) when the extrapolated chains meet within a pixel (:func:`link_ridges`).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components


def derivative_kernels(sigma: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sampled Gaussian ``G``, ``G'`` and ``G''`` kernels (radius ceil(4 sigma)), float32.

    ``G'`` has unit response to a unit ramp and ``G''`` unit response to ``x^2 / 2``, both zero
    response to a constant (the sampled kernels are corrected for that).
    """
    r = max(int(np.ceil(4.0 * sigma)), 2)
    x = np.arange(-r, r + 1, dtype=np.float64)
    g = np.exp(-0.5 * (x / sigma) ** 2)
    g /= g.sum()
    d1 = -x / sigma**2 * g
    d1 -= d1.mean()
    d1 /= -(x * d1).sum()
    d2 = (x**2 / sigma**4 - 1.0 / sigma**2) * g
    d2 -= d2.mean()
    d2 /= (0.5 * x**2 * d2).sum()
    return g.astype(np.float32), d1.astype(np.float32), d2.astype(np.float32)


def hessian(signal: np.ndarray, sigma: float) -> tuple[np.ndarray, ...]:
    """Gaussian derivatives ``(r_x, r_y, r_xx, r_xy, r_yy)`` of ``signal`` (H, W), float32.

    Convolutions with the separable kernels of :func:`derivative_kernels` (OpenCV
    ``sepFilter2D``, which correlates: the odd kernel is flipped), per px and per px^2.
    """
    g, d1, d2 = derivative_kernels(sigma)
    d1c = d1[::-1].copy()
    s = np.ascontiguousarray(signal, dtype=np.float32)

    def sep(kx, ky):
        return cv2.sepFilter2D(s, cv2.CV_32F, kx, ky, borderType=cv2.BORDER_REFLECT)

    return sep(d1c, g), sep(g, d1c), sep(d2, g), sep(d1c, d1c), sep(g, d2)


@dataclass(frozen=True)
class RidgePoints:
    """Sub-pixel line centres, arrays (N,).

    Attributes
    ----------
    x, y : float64
        Centre, camera px (pixel centres at integers).
    ix, iy : int64
        The pixel that holds it.
    nx, ny : float64
        Unit normal across the line (the Hessian's eigenvector of its most negative
        eigenvalue), sign normalised so that the larger component is positive.
    strength : float32
        ``-lambda``, the second derivative across the line, signal units per px^2.
    """

    x: np.ndarray
    y: np.ndarray
    ix: np.ndarray
    iy: np.ndarray
    nx: np.ndarray
    ny: np.ndarray
    strength: np.ndarray

    def __len__(self) -> int:
        return len(self.x)

    def take(self, idx) -> RidgePoints:
        """The points ``idx`` (index or bool mask)."""
        return RidgePoints(*(getattr(self, f)[idx] for f in
                             ("x", "y", "ix", "iy", "nx", "ny", "strength")))


def ridge_points(signal: np.ndarray, sigma: float = 1.2, threshold: float = 0.15,
                 min_strength: float = 0.0, max_blob: float = 0.5,
                 valid: np.ndarray | None = None) -> RidgePoints:
    """Line centres of bright thin lines in ``signal`` (module notes, steps 1 to 3).

    Parameters
    ----------
    signal : ndarray (H, W)
        Grey signal in which the lines are brighter than their surroundings.
    sigma : float
        Gaussian scale, px. Steger's condition for a bar of width ``w`` to give one centre is
        ``sigma >= w / (2 sqrt 3)``; 1.2 px suits lines 2 to 4 px wide.
    threshold : float
        Least strength, as a share of the 99th percentile of the strength over all candidate
        pixels (the image's own contrast: no absolute scale is assumed).
    min_strength : float
        Least strength in signal units per px^2 (a floor for a blank image).
    max_blob : float
        Largest ratio ``lambda_2 / lambda`` (both negative at a blob, the crossing of two
        lines); 0.5 keeps a centre whose along-line curvature is at most half its
        across-line curvature.
    valid : ndarray (H, W) bool, optional
        Pixels that may hold centres.

    Returns
    -------
    RidgePoints
    """
    rx, ry, rxx, rxy, ryy = hessian(signal, sigma)
    half = 0.5 * (rxx + ryy)
    root = np.sqrt(0.25 * (rxx - ryy) ** 2 + rxy**2)
    lam = half - root  # most negative eigenvalue
    lam2 = half + root
    cand = lam < 0
    if valid is not None:
        cand &= valid
    # eigenvector of lam: (rxy, lam - rxx) or (lam - ryy, rxy), whichever is better conditioned
    ax, ay = rxy, lam - rxx
    bx, by = lam - ryy, rxy
    use_b = (bx * bx + by * by) > (ax * ax + ay * ay)
    nx = np.where(use_b, bx, ax)
    ny = np.where(use_b, by, ay)
    norm = np.hypot(nx, ny)
    iy, ix = np.nonzero(cand & (norm > 0))
    nx = (nx[iy, ix] / norm[iy, ix]).astype(np.float64)
    ny = (ny[iy, ix] / norm[iy, ix]).astype(np.float64)
    lv = lam[iy, ix].astype(np.float64)
    t = -(rx[iy, ix] * nx + ry[iy, ix] * ny) / lv
    strength = -lv
    if len(strength):
        level = max(threshold * float(np.percentile(strength, 99)), min_strength)
    else:
        level = np.inf
    keep = ((np.abs(t * nx) <= 0.5) & (np.abs(t * ny) <= 0.5) & (strength > level)
            & (lam2[iy, ix] < -max_blob * lv))
    flip = np.where(np.abs(nx) >= np.abs(ny), np.sign(nx), np.sign(ny))
    flip[flip == 0] = 1.0
    k = keep
    return RidgePoints(x=ix[k] + t[k] * nx[k], y=iy[k] + t[k] * ny[k],
                       ix=ix[k].astype(np.int64), iy=iy[k].astype(np.int64),
                       nx=nx[k] * flip[k], ny=ny[k] * flip[k],
                       strength=strength[k].astype(np.float32))


def split_directions(points: RidgePoints, max_angle: float = np.radians(30.0),
                     bins: int = 180) -> tuple[np.ndarray, np.ndarray]:
    """Direction of each centre: 0 vertical line, 1 horizontal line, -1 neither (step 4).

    The normals' orientations ``theta`` (mod pi) are histogrammed (doubled angle, weighted by
    strength, smoothed); the strongest mode and the strongest mode at least 45 degrees away
    from it are the two directions' normals. The mode nearer to the image x axis is the
    vertical lines' normal. A centre belongs to the mode nearer its own orientation when it
    is within ``max_angle`` radians of it.

    Returns
    -------
    direction : ndarray (N,) int64
    normals : ndarray (2, 2)
        Unit normal of the vertical and of the horizontal lines.
    """
    n = len(points)
    theta = np.mod(np.arctan2(points.ny, points.nx), np.pi)
    if n == 0:
        return np.zeros(0, np.int64), np.array([[1.0, 0.0], [0.0, 1.0]])
    hist, _ = np.histogram(theta, bins=bins, range=(0.0, np.pi), weights=points.strength)
    k = np.arange(-4, 5)
    kern = np.exp(-0.5 * (k / 2.0) ** 2)
    sm = np.convolve(np.r_[hist[-4:], hist, hist[:4]], kern, mode="same")[4:-4]
    centres = (np.arange(bins) + 0.5) * np.pi / bins
    a = centres[int(np.argmax(sm))]
    far = np.abs(np.angle(np.exp(2j * (centres - a)))) >= np.pi / 2  # >= 45 degrees away
    b = centres[int(np.argmax(np.where(far, sm, -1.0)))]
    modes = np.array([a, b])
    # the vertical lines' normal is the mode nearer the x axis (theta near 0 or pi)
    if np.abs(np.cos(b)) > np.abs(np.cos(a)):
        modes = modes[::-1]
    dev = np.abs(np.angle(np.exp(2j * (theta[:, None] - modes[None, :])))) / 2.0
    direction = np.argmin(dev, axis=1).astype(np.int64)
    direction[dev[np.arange(n), direction] > max_angle] = -1
    normals = np.c_[np.cos(modes), np.sin(modes)]
    normals *= np.where(np.abs(normals[:, :1]) >= np.abs(normals[:, 1:]),
                        np.sign(normals[:, :1]), np.sign(normals[:, 1:]))
    return direction, normals


def _run_across(points: RidgePoints, d: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Run index (pixel row for vertical lines, column for horizontal), across coordinate and
    the step across per unit run (the tangent's slope) of each point."""
    if d == 0:
        with np.errstate(divide="ignore", invalid="ignore"):
            slope = -points.ny / points.nx
        return points.iy, points.x, slope
    with np.errstate(divide="ignore", invalid="ignore"):
        slope = -points.nx / points.ny
    return points.ix, points.y, slope


def _dedupe(run: np.ndarray, acr: np.ndarray, strength: np.ndarray, tol: float) -> np.ndarray:
    """Indices of the points kept when, within one run, centres closer than ``tol`` px are one
    centre (the stronger is kept): a line can light two neighbouring pixels of a run."""
    o = np.lexsort((acr, run))
    keep = np.ones(len(o), bool)
    for _ in range(3):
        idx = o[keep[o]]
        r, a, s = run[idx], acr[idx], strength[idx]
        close = (r[1:] == r[:-1]) & (a[1:] - a[:-1] < tol)
        if not close.any():
            break
        # of each close pair drop the weaker
        drop = np.where(s[1:] >= s[:-1], idx[:-1], idx[1:])[close]
        keep[drop] = False
    return np.nonzero(keep)[0]


def _mutual(src: np.ndarray, dst: np.ndarray, cost: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pairs kept when each source and each destination keeps only its cheapest pair."""
    if not len(src):
        return src, dst
    o = np.argsort(cost, kind="stable")
    src, dst = src[o], dst[o]
    _, first_s = np.unique(src, return_index=True)
    ks = np.zeros(len(src), bool)
    ks[first_s] = True
    src, dst = src[ks], dst[ks]
    _, first_d = np.unique(dst, return_index=True)
    kd = np.zeros(len(dst), bool)
    kd[first_d] = True
    return src[kd], dst[kd]


def _components(n: int, src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """Connected components of the graph of ``n`` nodes with edges (src, dst)."""
    g = coo_matrix((np.ones(len(src)), (src, dst)), shape=(n, n))
    return connected_components(g, directed=False)[1]


def _step_links(run, acr, slope, max_offset: float) -> tuple[np.ndarray, np.ndarray]:
    """Links from each point to the point of the next run that continues it."""
    n = len(run)
    o = np.lexsort((acr, run))
    r_s, a_s = run[o], acr[o]
    src, dst, cost = [], [], []
    step = np.where(np.isfinite(slope), np.clip(slope, -1.5, 1.5), 0.0)
    pred = acr + step
    # candidates: the points of run + 1 nearest to the prediction (left and right of it)
    key_r = r_s.astype(np.float64) * 1e7 + a_s
    q = (run + 1).astype(np.float64) * 1e7 + pred
    pos = np.searchsorted(key_r, q)
    for off in (-1, 0):
        j = np.clip(pos + off, 0, n - 1)
        cand = o[j]
        ok = (run[cand] == run + 1) & (np.abs(acr[cand] - pred) <= max_offset)
        src.append(np.nonzero(ok)[0])
        dst.append(cand[ok])
        cost.append(np.abs(acr[cand] - pred)[ok])
    return _mutual(np.concatenate(src), np.concatenate(dst), np.concatenate(cost))


def _order(comp: np.ndarray, run: np.ndarray, acr: np.ndarray) -> tuple[np.ndarray, ...]:
    """Points ordered by chain and run; chain id of each ordered point, start and stop."""
    o = np.lexsort((acr, run, comp))
    c = comp[o]
    starts = np.r_[0, np.nonzero(c[1:] != c[:-1])[0] + 1]
    stops = np.r_[starts[1:], len(o)]
    return o, c, starts, stops


def _end_fits(run, acr, o, starts, stops, k: int):
    """Line fits ``acr = a + b run`` over the first and the last ``k`` points of each chain:
    (first run, first across, slope at the start, last run, last across, slope at the end)."""
    nch = len(starts)
    out = []
    for head in (True, False):
        idx = np.arange(k)[None, :] + (starts[:, None] if head else stops[:, None] - k)
        lo, hi = starts[:, None], stops[:, None]
        ok = (idx >= lo) & (idx < hi)
        idx = np.clip(idx, 0, len(o) - 1)
        p = o[idx]
        w = ok.astype(np.float64)
        t = run[p].astype(np.float64)
        v = acr[p]
        sw = w.sum(1)
        with np.errstate(all="ignore"):
            tm = (w * t).sum(1) / sw
            vm = (w * v).sum(1) / sw
            stt = (w * (t - tm[:, None]) ** 2).sum(1)
            b = np.where(stt > 0, (w * (t - tm[:, None]) * (v - vm[:, None])).sum(1) / stt, 0.0)
        end = o[starts] if head else o[stops - 1]
        r_end = run[end].astype(np.float64)
        a_end = vm + b * (r_end - tm)
        out.append((r_end, a_end, b))
    return out[0], out[1], nch


def gap_links(run, acr, o, starts, stops, max_gap: int, max_offset: float, k: int = 6,
              grow: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Pairs of chains (a, b) where chain b starts within ``max_gap`` runs after chain a ends
    and both chains' end fits (the last / first ``k`` centres), extrapolated to the middle of
    the gap, meet within ``max_offset + grow * gap`` px (the slopes agreeing within 0.3).

    ``run``, ``acr`` (N,): run index and across coordinate of the centres; ``o`` (M,) the
    centres ordered by chain and run, chain c being ``o[starts[c]:stops[c]]``. Each chain
    keeps at most one successor and one predecessor, the closest.
    """
    (r0, a0, b0), (r1, a1, b1), nch = _end_fits(run, acr, o, starts, stops, k)
    if nch < 2:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    ob = np.argsort(r0)
    src, dst, cost = [], [], []
    for gap in range(2, max_gap + 1):
        # chains starting exactly `gap` runs after the end of chain a
        lo = np.searchsorted(r0[ob], r1 + gap, side="left")
        hi = np.searchsorted(r0[ob], r1 + gap, side="right")
        width = int((hi - lo).max()) if len(lo) else 0
        for j in range(width):
            has = lo + j < hi
            a = np.nonzero(has)[0]
            b = ob[lo[a] + j]
            mid_r = 0.5 * (r1[a] + r0[b])
            pa = a1[a] + b1[a] * (mid_r - r1[a])
            pb = a0[b] + b0[b] * (mid_r - r0[b])
            err = np.abs(pa - pb)
            ok = (err <= max_offset + grow * gap) & (np.abs(b1[a] - b0[b]) < 0.3) & (a != b)
            src.append(a[ok])
            dst.append(b[ok])
            cost.append(err[ok] + 0.1 * gap)
    if not src:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    return _mutual(np.concatenate(src), np.concatenate(dst), np.concatenate(cost))


def link_ridges(points: RidgePoints, direction: np.ndarray, max_offset: float = 0.8,
                max_gap: int = 9, gap_offset: float = 1.0, min_length: int = 5
                ) -> tuple[np.ndarray, np.ndarray]:
    """Chains of line centres of each direction (module notes, step 5).

    Parameters
    ----------
    points : RidgePoints
    direction : ndarray (N,) int
        0 vertical, 1 horizontal, -1 neither (:func:`split_directions`).
    max_offset : float
        Largest distance across between a centre and the prediction from the previous run's
        centre and its tangent, px.
    max_gap : int
        Longest gap (runs) bridged between two chains (a crossing line, a dark square).
    gap_offset : float
        Largest distance across between the two chains' extrapolations in the gap, px.
    min_length : int
        Least number of centres of a chain.

    Returns
    -------
    order : ndarray (M,) int64
        Indices into ``points`` of the chained centres, grouped by chain and ordered along
        each chain (by run).
    chain : ndarray (M,) int64
        Chain id of each ordered centre, 0 .. C - 1; the vertical chains first.
    """
    orders, chains = [], []
    nxt = 0
    for d in (0, 1):
        sel = np.nonzero(direction == d)[0]
        if not len(sel):
            continue
        run, acr, slope = _run_across(points.take(sel), d)
        keep = _dedupe(run, acr, points.strength[sel], 1.0)
        sel, run, acr, slope = sel[keep], run[keep], acr[keep], slope[keep]
        s, t = _step_links(run, acr, slope, max_offset)
        comp = _components(len(sel), s, t)
        o, c, starts, stops = _order(comp, run, acr)
        if max_gap >= 2:
            a, b = gap_links(run, acr, o, starts, stops, max_gap, gap_offset)
            merged = _components(len(starts), a, b)
            comp = merged[comp]
            o, c, starts, stops = _order(comp, run, acr)
        # a chain is a path: a second centre in one run is a spur or two lines; keep chains
        # whose runs are distinct, drop the extra centres otherwise
        rr = run[o]
        dup = np.r_[False, (c[1:] == c[:-1]) & (rr[1:] == rr[:-1])]
        o, c = o[~dup], c[~dup]
        lengths = np.bincount(c)
        ok = lengths[c] >= min_length
        o, c = o[ok], c[ok]
        _, c = np.unique(c, return_inverse=True)
        orders.append(sel[o])
        chains.append(c + nxt)
        nxt += int(c.max()) + 1 if len(c) else 0
    if not orders:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    return np.concatenate(orders).astype(np.int64), np.concatenate(chains).astype(np.int64)
