"""Chaining edge points into ordered sub-pixel edge lines (method.md section 2).

The edge pixels of each class (vertical rising / falling, horizontal rising / falling) are
grouped into 8-connected components (``cv2.connectedComponents``). A vertical edge meets each
pixel row at most once, so a component that holds two pixels of one row has a junction or a
spur there: those pixels are removed and the components are formed again, which splits the
chain at the junction. (Horizontal edges: the same with columns.) Chains are therefore split at
junctions, at gaps (a missing pixel breaks 8-connectivity) and at depth discontinuities (a jump
of more than one pixel across the edge between neighbouring rows). Each chain is ordered along
its run (by row for vertical edges, by column for horizontal ones); chains shorter than
``min_length`` points are dropped.
"""

from __future__ import annotations

import cv2
import numpy as np

from .edges import EdgePoints


def _components(iy: np.ndarray, ix: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    mask = np.zeros(shape, np.uint8)
    mask[iy, ix] = 1
    _, lab = cv2.connectedComponents(mask, connectivity=8, ltype=cv2.CV_32S)
    return lab[iy, ix]


def trace_lines(pts: EdgePoints, shape: tuple[int, int], min_length: int = 4
                ) -> tuple[np.ndarray, np.ndarray]:
    """Group edge points into ordered chains.

    Parameters
    ----------
    pts : EdgePoints
        Edge points (N,) from :func:`~nurbscan.detect.edges.detect_edge_points`.
    shape : (H, W)
        Image size, px.
    min_length : int
        Fewest points of a kept chain.

    Returns
    -------
    order : ndarray int64 (M,)
        Indices into ``pts`` of the kept points, grouped by chain and ordered along each chain.
    line : ndarray int64 (M,)
        Chain id 0 .. L - 1 of each kept point (non-decreasing).
    """
    n = len(pts.x)
    keep = np.zeros(n, bool)
    comp = np.full(n, -1, np.int64)
    offset = 0
    for cls in range(4):
        sel = np.nonzero(pts.cls == cls)[0]
        if not len(sel):
            continue
        iy, ix = pts.iy[sel], pts.ix[sel]
        along = iy if cls < 2 else ix
        lab = _components(iy, ix, shape)
        key = lab.astype(np.int64) * (max(shape) + 1) + along
        _, inv, cnt = np.unique(key, return_inverse=True, return_counts=True)
        single = cnt[inv] == 1
        sel, iy, ix, along = sel[single], iy[single], ix[single], along[single]
        lab = _components(iy, ix, shape).astype(np.int64)
        comp[sel] = lab + offset
        keep[sel] = True
        offset += int(lab.max()) + 1 if len(lab) else 0
    idx = np.nonzero(keep)[0]
    along = np.where(pts.cls[idx] < 2, pts.iy[idx], pts.ix[idx])
    o = np.lexsort((along, comp[idx]))
    idx = idx[o]
    c = comp[idx]
    uniq, inv, cnt = np.unique(c, return_inverse=True, return_counts=True)
    good = cnt[inv] >= min_length
    idx, inv = idx[good], inv[good]
    _, line = np.unique(inv, return_inverse=True)
    return idx, line.astype(np.int64)


def local_residual(along: np.ndarray, across: np.ndarray, line: np.ndarray, reach: int = 4
                   ) -> np.ndarray:
    """Distance of each point from the straight line fitted to its chain neighbours.

    For point i of a chain, the points i - reach .. i + reach of the same chain, i itself left
    out, are fitted by least squares with ``across = c0 + c1 (along - along_i)``; the residual
    is ``|across_i - c0|`` px (0 where fewer than 3 neighbours exist). A point off its own
    chain by more than the noise is an outlier (a disturbed profile at a crossing's corner).
    Arrays (M,) ordered by chain as returned by :func:`trace_lines`.
    """
    n = len(along)
    if n == 0:
        return np.zeros(0)
    i = np.arange(n)
    counts = np.bincount(line)
    stop = np.cumsum(counts)
    first = (stop - counts)[line]
    last = stop[line] - 1
    offs = np.r_[np.arange(-reach, 0), np.arange(1, reach + 1)]
    j = i[:, None] + offs[None, :]
    wts = ((j >= first[:, None]) & (j <= last[:, None])).astype(np.float64)
    j = np.clip(j, 0, n - 1)
    t = along[j] - along[:, None]
    v = across[j]
    sw = wts.sum(1)
    st = (wts * t).sum(1)
    stt = (wts * t * t).sum(1)
    sv = (wts * v).sum(1)
    stv = (wts * t * v).sum(1)
    det = sw * stt - st * st
    with np.errstate(all="ignore"):
        c1 = (sw * stv - st * sv) / det
        c0 = (sv - c1 * st) / sw
    res = np.abs(across - c0)
    return np.where((sw >= 3) & np.isfinite(res), res, 0.0)

