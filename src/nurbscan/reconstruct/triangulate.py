"""From labelled image edge lines to 3-D points and 3-D NURBS curves (method.md section 5).

For every labelled edge line of a view (a detection result: ordered sub-pixel points, the
direction of its band, the exact projector coordinate of its edge):

1. a 2-D cubic B-spline is fitted to the points by linear least squares (Piegl and Tiller
   section 9.4.1, eq. 9.63-9.67), parametrised by the coordinate *along* the line (the image row
   for an edge of a vertical band, the column for a horizontal one: such an edge meets each
   row, or column, once), with uniform knots ``knot_spacing`` px apart; the fit smooths the
   edge noise and its residual is reported;
2. the 2-D curve is sampled at every along-coordinate of the data, each sample is
   back-projected (Tsai, the paper's eq. 6-8) and the ray is intersected with the edge's exact
   light surface (:func:`nurbscan.reconstruct.light.intersect_exact`), which also gives the
   other projector coordinate ``w`` of every 3-D point;
3. the 3-D points are parametrised by ``w`` (projector px): the chains of one edge are joined
   and fitted with 3-D curves in :mod:`nurbscan.reconstruct.network`, so that curves of one
   family meet those of the other at known parameters (a vertical edge ``x = c_i`` meets a
   horizontal edge ``y = c_j`` at ``w = c_j`` on the first and ``w = c_i`` on the second).

All chains are fitted together (:mod:`nurbscan.reconstruct._batch`), with one pass of outlier
removal (3 robust sigmas).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import NurbscanError
from ..nurbs import NurbsCurve
from ..nurbs.basis import basis_matrix
from ._batch import fit_chains, uniform_knots01
from .light import intersect_exact

DIRECTIONS = ("vertical", "horizontal")


def _normal_matrix(params, knots, degree: int, smooth: float):
    """Basis matrix ``A`` (m, n_ctrl) and penalised normal matrix ``A^T A + s D^T D`` of the
    least-squares fits (:func:`lstsq_spline`)."""
    n_ctrl = len(knots) - degree - 1
    A = basis_matrix(params, degree, knots, n_ctrl)
    M = A.T @ A
    if n_ctrl > 2:
        D = np.diff(np.eye(n_ctrl), 2, axis=0)
        M = M + smooth * max(len(params), 1) / n_ctrl * (D.T @ D)
    return A, M


def lstsq_spline(params: np.ndarray, points: np.ndarray, knots: np.ndarray, degree: int = 3,
                 smooth: float = 1e-6) -> NurbsCurve:
    """Least-squares B-spline with a given knot vector (Piegl and Tiller eq. 9.63-9.67).

    A small second-difference penalty on the control points (``smooth`` times the data
    weight) keeps spans without data well posed.

    Parameters
    ----------
    params : ndarray (m,)
        Data parameters inside the knot domain.
    points : ndarray (m, d)
    knots : ndarray (n + p + 2,)

    Returns
    -------
    NurbsCurve
        Non-rational, ``len(knots) - degree - 1`` control points.
    """
    A, M = _normal_matrix(params, knots, degree, smooth)
    P = np.linalg.solve(M, A.T @ points)
    return NurbsCurve(degree, knots, P)


def lstsq_splines(params: np.ndarray, points: np.ndarray, knots: np.ndarray, degree: int = 3,
                  smooth: float = 1e-6) -> np.ndarray:
    """Control points of several least-squares B-splines on shared parameters and knots.

    :func:`lstsq_spline` for ``c`` data sets sampled at the same ``params`` (Piegl and Tiller
    eq. 9.63-9.67 with the same penalty): the basis matrix and the normal matrix are built
    once and the ``c`` normal equations are solved as one stacked solve (one matrix, the
    right-hand sides batched). Each fit is bit for bit that of :func:`lstsq_spline`.

    Parameters
    ----------
    params : ndarray (m,)
        Data parameters inside the knot domain.
    points : ndarray (c, m, d)
        The ``c`` data sets.
    knots : ndarray (n + p + 2,)

    Returns
    -------
    ndarray (c, n_ctrl, d)
        Control points, ``n_ctrl = len(knots) - degree - 1``, units of ``points``.
    """
    points = np.asarray(points, dtype=float)
    A, M = _normal_matrix(params, knots, degree, smooth)
    c = points.shape[0]
    return np.linalg.solve(np.broadcast_to(M, (c,) + M.shape), A.T @ points)


@dataclass(frozen=True)
class Line3D:
    """One labelled edge chain of a view, in 2-D and in 3-D.

    Attributes
    ----------
    direction : str
        ``"vertical"`` or ``"horizontal"`` (of the projector band).
    band, edge : int
        Band index and edge (0 rising, 1 falling).
    coord : float
        Exact projector coordinate of the edge, px.
    knots2d, ctrl2d : ndarray
        The 2-D curve (camera px): clamped cubic knots over the along-coordinate (row or
        column, px) and control points (n, 2); :attr:`curve2d` builds the NurbsCurve.
    rms2d : float
        RMS residual of the 2-D fit (inliers), px: the edge noise.
    w : ndarray (m,)
        Other projector coordinate of each triangulated sample, px (sorted).
    points : ndarray (m, 3)
        Triangulated 3-D points (rig frame, mm), in the order of ``w``.
    """

    direction: str
    band: int
    edge: int
    coord: float
    knots2d: np.ndarray
    ctrl2d: np.ndarray
    rms2d: float
    w: np.ndarray
    points: np.ndarray

    @property
    def curve2d(self) -> NurbsCurve:
        """The 2-D curve as a NurbsCurve (parameter: the along-coordinate, px)."""
        return NurbsCurve(3, self.knots2d, self.ctrl2d)


def fit_line_2d(pixels: np.ndarray, direction: str, knot_spacing: float = 12.0):
    """Fit the 2-D curve of one edge line; return (curve, along-params of inliers, rms px).

    The single-line form of the batched fit in :func:`triangulate_lines`.
    """
    px = np.asarray(pixels, float)
    ax = 1 if direction == "vertical" else 0
    along = px[:, ax]
    o = np.argsort(along, kind="stable")
    px, along = px[o], along[o]
    a, b = float(along[0]), float(along[-1])
    if not b > a:
        raise NurbscanError("edge line: fewer than two distinct points")
    n = _n_spans(b - a, len(along), knot_spacing)
    t = (along - a) / (b - a)
    ctrl, inl, rms = fit_chains(t, px[:, 1 - ax:2 - ax], np.zeros(len(t), int),
                                np.array([n]), robust=0.1)
    knots, C = _curve2d(a, b, n, ctrl[0][:, 0], ax)
    return NurbsCurve(3, knots, C), along[inl], float(rms[0])


def _n_spans(length: float, n_points: int, spacing: float) -> int:
    """Knot spans of a chain: about ``spacing`` apart, at most ``n_points - 4``, at least 1."""
    return int(max(1, min(np.ceil(length / spacing), max(n_points - 4, 1))))


def _curve2d(a: float, b: float, n: int, other_ctrl: np.ndarray, ax: int):
    """Knots and 2-D control points of a chain fitted as ``other(along)`` on [a, b].

    The along-coordinate is linear in the parameter, so its control points are the Greville
    abscissae (linear precision of B-splines, Piegl and Tiller eq. 9.8 ff.).
    """
    knots01 = uniform_knots01(n)
    g = (knots01[1:-3] + knots01[2:-2] + knots01[3:-1]) / 3.0
    along_ctrl = a + (b - a) * g
    C = np.empty((len(g), 2))
    C[:, ax] = along_ctrl
    C[:, 1 - ax] = other_ctrl
    return a + (b - a) * knots01, C


def triangulate_lines(det, rig, knot_spacing: float = 12.0, min_points: int = 4,
                      robust: float = 0.1) -> list[Line3D]:
    """2-D curves and triangulated 3-D points of every labelled chain of a detection result.

    Parameters
    ----------
    det : detection result
        Anything with the arrays of :class:`nurbscan.detect.result.DetectionResult`: ``x, y``
        (N,), ``direction, band, edge, coord, start, stop`` (L,).
    rig : Rig
        Camera and projector (Tsai fields), rig frame = camera frame.
    knot_spacing : float
        Knot spacing of the 2-D fits, camera px.
    min_points : int
        Chains with fewer points are skipped.
    robust : float
        Floor (px) of the outlier limit of the 2-D fits (3 robust sigmas otherwise).

    Returns
    -------
    list of Line3D
        One per kept chain; its samples are the 2-D curve at the along-coordinates of the
        chain's inlier points, triangulated on the exact light surface.
    """
    cam, proj = rig.camera, rig.projector
    start = np.asarray(det.start, np.int64)
    stop = np.asarray(det.stop, np.int64)
    coord = np.asarray(det.coord, float)
    dirn = np.asarray(det.direction, np.int64)
    n = stop - start
    keep = np.nonzero((n >= min_points) & np.isfinite(coord))[0]
    if len(keep) == 0:
        return []
    cid = np.repeat(np.arange(len(keep)), n[keep])
    pidx = np.concatenate([np.arange(start[i], stop[i]) for i in keep])
    x = np.asarray(det.x, float)[pidx]
    y = np.asarray(det.y, float)[pidx]
    ax = np.where(dirn[keep] == 0, 1, 0)[cid]  # along axis: y for vertical edges
    along = np.where(ax == 1, y, x)
    other = np.where(ax == 1, x, y)
    o = np.lexsort((along, cid))
    cid, along, other, ax = cid[o], along[o], other[o], ax[o]
    first = np.r_[0, np.nonzero(np.diff(cid))[0] + 1]
    lo = along[first]
    hi = np.maximum.reduceat(along, first)
    good = hi > lo
    nsp = np.array([_n_spans(h - lw, c, knot_spacing)
                    for h, lw, c in zip(hi, lo, np.diff(np.r_[first, len(cid)]), strict=True)])
    t = (along - lo[cid]) / np.where(good, hi - lo, 1.0)[cid]
    ctrl, inl, rms, fitted = fit_chains(t, other[:, None], cid, nsp, robust=robust,
                                        return_fitted=True)
    inl &= good[cid]
    fitted = fitted[:, 0]
    S = np.where((ax == 1)[:, None], np.stack([fitted, along], 1), np.stack([along, fitted], 1))
    S, cid_s = S[inl], cid[inl]
    C = coord[keep][cid_s]
    Dn = dirn[keep][cid_s]
    origin, rays = cam.back_project(S)
    pts = np.full((len(S), 3), np.nan)
    w = np.full(len(S), np.nan)
    for k, name in enumerate(DIRECTIONS):
        sel = Dn == k
        if np.any(sel):
            pts[sel], w[sel], _ = intersect_exact(proj, origin, rays[sel], name, C[sel])
    ok = np.isfinite(w)
    order = np.lexsort((w, cid_s))
    order = order[ok[order]]
    cid_o, w_o, p_o = cid_s[order], w[order], pts[order]
    bounds = np.searchsorted(cid_o, np.arange(len(keep) + 1))
    out = []
    for c, i in enumerate(keep):
        if not good[c]:
            continue
        s0, s1 = bounds[c], bounds[c + 1]
        knots, C2 = _curve2d(float(lo[c]), float(hi[c]), int(nsp[c]), ctrl[c][:, 0],
                             1 if dirn[i] == 0 else 0)
        out.append(Line3D(direction=DIRECTIONS[int(dirn[i])], band=int(det.band[i]),
                          edge=int(det.edge[i]), coord=float(coord[i]), knots2d=knots,
                          ctrl2d=C2, rms2d=float(rms[c]), w=w_o[s0:s1], points=p_o[s0:s1]))
    return out


def drop_occluded(lines: list[Line3D], camera, radius: float = 3.0, depth: float = 1.0,
                  min_points: int = 2) -> list[Line3D]:
    """Drop the samples that lie in the image beside a nearer surface (an occluding contour).

    A sample is dropped when, within ``radius`` camera px of its pixel, lies a sample of
    another chain that is more than ``depth`` mm nearer the camera: the camera sees a contour
    of a surface in front there, whose blur mixes into the edge's profile and shifts it
    (the sub-pixel edge is a weighted mean over the edge filter's support, which reaches a
    few pixels across the contour), and the nearly grazing triangulation of an edge there
    turns that shift into depth. All pairs closer than ``radius`` come from one k-d tree
    query (:meth:`scipy.spatial.cKDTree.query_pairs`). Chains left with fewer than
    ``min_points`` samples are dropped.

    Teapot demo scan at 1024 x 768 px (docs/accuracy.md, "Where the worst edge points
    are"): the worst CAD cell's own edge points lie at the end of a horizontal edge's chain
    2.2-2.9 px from the spout's contour in front, 0.82 mm off at the chain's end and 0.24 mm
    5 px further in.

    Parameters
    ----------
    lines : list of Line3D
        A view's triangulated chains (:func:`triangulate_lines`, rig = camera frame).
    camera : Camera
        The view's camera (projects the samples, gives the viewpoint).
    radius : float
        Largest image distance to the nearer sample, camera px.
    depth : float
        Smallest depth difference (distance to the camera centre) of an occluding sample, mm.
    min_points : int
        Chains left with fewer samples are dropped.

    Returns
    -------
    list of Line3D
        The chains without their occluded samples (unchanged chains are the same objects).
    """
    from dataclasses import replace

    from scipy.spatial import cKDTree

    if not lines:
        return []
    n = np.array([len(ln.w) for ln in lines])
    if n.sum() == 0:
        return list(lines)
    P = np.concatenate([ln.points for ln in lines])
    cid = np.repeat(np.arange(len(lines)), n)
    px = camera.project(P)
    dist = np.linalg.norm(P - camera.center, axis=1)
    ok = np.isfinite(px).all(1) & np.isfinite(dist)
    idx = np.nonzero(ok)[0]
    pairs = cKDTree(px[idx]).query_pairs(radius, output_type="ndarray")
    i, j = idx[pairs[:, 0]], idx[pairs[:, 1]]
    other = cid[i] != cid[j]
    i, j = i[other], j[other]
    drop = np.zeros(len(P), bool)
    drop[i[dist[i] > dist[j] + depth]] = True
    drop[j[dist[j] > dist[i] + depth]] = True
    if not drop.any():
        return list(lines)
    out = []
    for ln, keep in zip(lines, np.split(~drop, np.cumsum(n)[:-1]), strict=True):
        if keep.all():
            out.append(ln)
        elif keep.sum() >= min_points:
            out.append(replace(ln, w=ln.w[keep], points=ln.points[keep]))
    return out
