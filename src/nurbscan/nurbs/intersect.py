"""Intersections and closest points of NURBS curves and surfaces, vectorised.

Method (Piegl and Tiller, *The NURBS Book*, 2nd ed.; method.md section 3):

* Every curve / surface is decomposed into rational Bezier segments / patches (section 5.3,
  A5.6/A5.7 result; computed here by Bernstein collocation of the homogeneous polynomial on each
  knot span, which is exact up to rounding).
* Candidates are found by recursive subdivision (de Casteljau at 1/2, eq. 5.2 / section 5.3):
  a pair of pieces survives while the bounding boxes of their control polygons overlap (convex
  hull property, P4.x of chapter 4 for positive weights). All candidate pairs of all curves are
  processed level by level as numpy arrays.
* Each surviving candidate starts a Newton iteration on its parent Bezier piece (full Newton on
  the squared distance, Levenberg-damped, clamped to the piece), which converges quadratically at
  transversal intersections and still reaches tangential touches (where the Jacobian is singular)
  as the minimum of the distance. Solutions within ``tol`` are kept and duplicates (the same
  point found from several candidates or from both sides of a knot) are merged; consecutive
  solutions between which the two objects stay within ``tol`` of each other (the flat valley
  of a tangential touch) are one contact, reported at its smallest distance. Two true
  crossings closer than about ``2 sqrt(tol / curvature)`` are therefore reported as one touch.

Coincident (overlapping) curve pieces have infinitely many intersections; only isolated points
are reported there.
"""

from __future__ import annotations

from dataclasses import dataclass
from math import comb

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from ..errors import NurbscanError
from .basis import basis_functions
from .curve import NurbsCurve, rational_derivatives
from .surface import NurbsSurface

__all__ = [
    "CurveIntersections",
    "LineSurfaceHits",
    "intersect_curves",
    "intersect_curve_sets",
    "closest_points_curves",
    "closest_point_curve",
    "closest_point_surface",
    "intersect_line_surface",
    "intersect_lines_surface",
]

_MAX_CANDIDATES = 2_000_000

# ---------------------------------------------------------------------------- Bezier helpers


def _bernstein(p: int, t) -> np.ndarray:
    """Bernstein polynomials ``B_{j,p}(t)``, shape ``t.shape + (p + 1,)``."""
    t = np.asarray(t, dtype=float)
    tp = np.ones(t.shape + (p + 1,))
    sp = np.ones(t.shape + (p + 1,))
    for j in range(1, p + 1):
        tp[..., j] = tp[..., j - 1] * t
        sp[..., j] = sp[..., j - 1] * (1.0 - t)
    binom = np.array([comb(p, k) for k in range(p + 1)], dtype=float)
    return binom * tp * sp[..., ::-1]


def _collocation_inverse(p: int) -> np.ndarray:
    t = np.linspace(0.0, 1.0, p + 1)
    return np.linalg.inv(_bernstein(p, t))


def _elevation_matrix(p: int, P: int) -> np.ndarray:
    """Bezier degree elevation ``p -> P`` (eq. 5.36): ``Q = E @ Pw``, shape ``(P + 1, p + 1)``."""
    t = P - p
    E = np.zeros((P + 1, p + 1))
    for i in range(P + 1):
        for j in range(max(0, i - t), min(p, i) + 1):
            E[i, j] = comb(p, j) * comb(t, i - j) / comb(P, i)
    return E


def _curve_bezier(curve: NurbsCurve):
    """Rational Bezier segments of a curve on its non-empty knot spans.

    Returns
    -------
    Q : ndarray, shape (S, p + 1, d + 1)
        Homogeneous control points of the segments.
    u0, u1 : ndarray, shape (S,)
        Parameter range of each segment.
    """
    p, U, Pw = curve.degree, curve.knots, curve.homogeneous
    n = curve.n_ctrl - 1
    spans = np.arange(p, n + 1)
    spans = spans[U[spans + 1] > U[spans]]
    t = np.linspace(0.0, 1.0, p + 1)
    u0, u1 = U[spans], U[spans + 1]
    uu = u0[:, None] + t * (u1 - u0)[:, None]
    sp = np.broadcast_to(spans[:, None], uu.shape)
    N = basis_functions(sp, uu, p, U)  # (S, p+1 samples, p+1 funcs)
    idx = spans[:, None] - p + np.arange(p + 1)
    vals = np.einsum("skj,sjc->skc", N, Pw[idx])
    Q = np.einsum("jk,skc->sjc", _collocation_inverse(p), vals)
    return Q, u0.astype(float), u1.astype(float)


def _surface_bezier(surf: NurbsSurface):
    """Rational Bezier patches of a surface on its non-empty knot spans.

    Returns
    -------
    Q : ndarray, shape (S, p + 1, q + 1, d + 1)
    ranges : ndarray, shape (S, 4)
        ``(u0, u1, v0, v1)`` of each patch.
    """
    p, q = surf.degree_u, surf.degree_v
    Uu, Uv = surf.knots_u, surf.knots_v
    nu, nv = surf.shape
    su = np.arange(p, nu)
    su = su[Uu[su + 1] > Uu[su]]
    sv = np.arange(q, nv)
    sv = sv[Uv[sv + 1] > Uv[sv]]
    tu = np.linspace(0.0, 1.0, p + 1)
    tv = np.linspace(0.0, 1.0, q + 1)
    uu = Uu[su][:, None] + tu * (Uu[su + 1] - Uu[su])[:, None]
    vv = Uv[sv][:, None] + tv * (Uv[sv + 1] - Uv[sv])[:, None]
    Nu = basis_functions(np.broadcast_to(su[:, None], uu.shape), uu, p, Uu)  # (Su, p+1, p+1)
    Nv = basis_functions(np.broadcast_to(sv[:, None], vv.shape), vv, q, Uv)
    iu = su[:, None] - p + np.arange(p + 1)
    iv = sv[:, None] - q + np.arange(q + 1)
    Pw = surf.homogeneous
    net = Pw[iu[:, None, :, None], iv[None, :, None, :]]  # (Su, Sv, p+1, q+1, c)
    vals = np.einsum("aki,blj,abijc->abklc", Nu, Nv, net)
    Q = np.einsum("ik,jl,abklc->abijc", _collocation_inverse(p), _collocation_inverse(q), vals)
    S = Q.shape[0] * Q.shape[1]
    ranges = np.empty((Q.shape[0], Q.shape[1], 4))
    ranges[..., 0] = Uu[su][:, None]
    ranges[..., 1] = Uu[su + 1][:, None]
    ranges[..., 2] = Uv[sv][None, :]
    ranges[..., 3] = Uv[sv + 1][None, :]
    return Q.reshape((S,) + Q.shape[2:]), ranges.reshape(S, 4)


def _split_half(Q: np.ndarray, axis: int):
    """de Casteljau subdivision at 1/2 along ``axis`` of a batch of Bezier nets."""
    Q = np.moveaxis(Q, axis, 0)
    p = Q.shape[0] - 1
    left = [Q[0]]
    right = [Q[p]]
    R = Q
    for _ in range(p):
        R = 0.5 * (R[:-1] + R[1:])
        left.append(R[0])
        right.append(R[-1])
    L = np.moveaxis(np.stack(left), 0, axis)
    Rr = np.moveaxis(np.stack(right[::-1]), 0, axis)
    return L, Rr


def _boxes(Q: np.ndarray, n_param_axes: int):
    """Axis-aligned boxes of the projected control points, shapes ``(N, d)`` each."""
    X = Q[..., :-1] / Q[..., -1:]
    axes = tuple(range(1, 1 + n_param_axes))
    return X.min(axis=axes), X.max(axis=axes)


def _bez_curve_ders(Q: np.ndarray, t: np.ndarray, order: int) -> np.ndarray:
    """Point and derivatives of rational Bezier segments ``Q`` (N, p+1, k) at ``t`` (N,).

    Returns shape ``(order + 1, N, k - 1)`` (A4.2 applied to the Bezier derivative formula).
    """
    p = Q.shape[1] - 1
    out = np.zeros((order + 1, Q.shape[0], Q.shape[2]))
    D = Q
    fac = 1.0
    for r in range(order + 1):
        if p - r < 0:
            break
        out[r] = fac * np.einsum("nj,njc->nc", _bernstein(p - r, t), D)
        D = D[:, 1:] - D[:, :-1]
        fac *= p - r
    return rational_derivatives(out)


def _bez_surface_ders(Q: np.ndarray, u: np.ndarray, v: np.ndarray):
    """Point and first partials of rational Bezier patches ``Q`` (N, p+1, q+1, k) at (u, v)."""
    p, q = Q.shape[1] - 1, Q.shape[2] - 1
    Bu, Bv = _bernstein(p, u), _bernstein(q, v)
    Bu1, Bv1 = _bernstein(p - 1, u), _bernstein(q - 1, v)
    Qv = np.einsum("nj,nijc->nic", Bv, Q)  # contract v first (staged: far cheaper)
    A = np.einsum("ni,nic->nc", Bu, Qv)
    Au = p * np.einsum("ni,nic->nc", Bu1, Qv[:, 1:] - Qv[:, :-1])
    Qu = np.einsum("ni,nijc->njc", Bu, Q)
    Av = q * np.einsum("nj,njc->nc", Bv1, Qu[:, 1:] - Qu[:, :-1])
    w, wu, wv = A[:, -1:], Au[:, -1:], Av[:, -1:]
    S = A[:, :-1] / w
    Su = (Au[:, :-1] - wu * S) / w
    Sv = (Av[:, :-1] - wv * S) / w
    return S, Su, Sv


def _merge(group: np.ndarray, X: np.ndarray, score: np.ndarray, dist: float) -> np.ndarray:
    """Indices of one representative (lowest ``score``) per cluster of points closer than
    ``dist`` within the same ``group``."""
    if X.shape[0] == 0:
        return np.zeros(0, dtype=int)
    span = float(np.ptp(X)) + 1.0
    key = np.hstack([X, (group.astype(float) * 10.0 * (span + dist))[:, None]])
    pairs = cKDTree(key).query_pairs(dist, output_type="ndarray")
    n = X.shape[0]
    g = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    _, lab = connected_components(g, directed=False)
    order = np.lexsort((score, lab))
    first = np.ones(n, dtype=bool)
    first[1:] = lab[order][1:] != lab[order][:-1]
    return order[first]


def _scale_of(points: np.ndarray) -> float:
    s = float(np.max(np.ptp(points.reshape(-1, points.shape[-1]), axis=0)))
    return s if s > 0 else 1.0


# ---------------------------------------------------------------------------- curve / curve


@dataclass(frozen=True)
class CurveIntersections:
    """Intersections of curves ``A[ia]`` and ``B[ib]``.

    Attributes
    ----------
    ia, ib : ndarray of int, shape (k,)
        Indices of the curves in the two sets (0 for a single pair).
    u, v : ndarray, shape (k,)
        Parameters on ``A[ia]`` and ``B[ib]``.
    points : ndarray, shape (k, d)
        Intersection points (mean of the two curve points).
    distance : ndarray, shape (k,)
        ``|A(u) - B(v)|`` (<= tol; ~0 at a true intersection).
    """

    ia: np.ndarray
    ib: np.ndarray
    u: np.ndarray
    v: np.ndarray
    points: np.ndarray
    distance: np.ndarray

    def __len__(self) -> int:
        return int(self.u.size)

    def to_dict(self) -> dict:
        """JSON-ready dict with ``"type": "nurbscan.curve_intersections"``."""
        return {"type": "nurbscan.curve_intersections", "version": 1,
                "ia": self.ia.tolist(), "ib": self.ib.tolist(), "u": self.u.tolist(),
                "v": self.v.tolist(), "points": self.points.tolist(),
                "distance": self.distance.tolist()}

    @classmethod
    def from_dict(cls, d: dict) -> CurveIntersections:
        """Inverse of :meth:`to_dict`."""
        if not isinstance(d, dict) or d.get("type") != "nurbscan.curve_intersections":
            raise NurbscanError("curve intersections: expected type nurbscan.curve_intersections")
        dim = len(d["points"][0]) if d["points"] else 0
        return cls(np.asarray(d["ia"], int), np.asarray(d["ib"], int),
                   np.asarray(d["u"], float), np.asarray(d["v"], float),
                   np.asarray(d["points"], float).reshape(-1, dim),
                   np.asarray(d["distance"], float))


def _decompose_set(curves, name: str):
    if isinstance(curves, NurbsCurve):
        curves = [curves]
    curves = list(curves)
    for k, c in enumerate(curves):
        if not isinstance(c, NurbsCurve):
            raise NurbscanError(f"{name}[{k}]: expected a NurbsCurve, got {type(c).__name__}")
    return curves


def _segments_of(curves, P: int):
    Qs, u0s, u1s, owners = [], [], [], []
    for k, c in enumerate(curves):
        Q, u0, u1 = _curve_bezier(c)
        if c.degree < P:
            Q = np.einsum("ij,sjc->sic", _elevation_matrix(c.degree, P), Q)
        Qs.append(Q)
        u0s.append(u0)
        u1s.append(u1)
        owners.append(np.full(u0.size, k))
    return (np.concatenate(Qs), np.concatenate(u0s), np.concatenate(u1s),
            np.concatenate(owners))


def _newton_curve_pairs(QA, QB, ta, tb, iters: int = 60):
    """Minimise ``|A(ta) - B(tb)|^2`` over ``[0, 1]^2`` for batches of Bezier segment pairs.

    Full Newton (Hessian with the second-derivative terms), Levenberg-damped where it is not
    positive definite, steps clamped to the segments.
    """
    ta, tb = ta.copy(), tb.copy()
    active = np.ones(ta.size, dtype=bool)
    for _ in range(iters):
        if not active.any():
            break
        ia = np.nonzero(active)[0]
        DA = _bez_curve_ders(QA[ia], ta[ia], 2)
        DB = _bez_curve_ders(QB[ia], tb[ia], 2)
        F = DA[0] - DB[0]
        Ja, Jb = DA[1], -DB[1]
        ga = np.einsum("nc,nc->n", F, Ja)
        gb = np.einsum("nc,nc->n", F, Jb)
        h11 = np.einsum("nc,nc->n", Ja, Ja)
        h22 = np.einsum("nc,nc->n", Jb, Jb)
        h12 = np.einsum("nc,nc->n", Ja, Jb)
        f11 = h11 + np.einsum("nc,nc->n", F, DA[2])
        f22 = h22 - np.einsum("nc,nc->n", F, DB[2])
        det = f11 * f22 - h12**2
        pd = (f11 > 0) & (det > 1e-14 * (f11 + f22) ** 2)
        # Gauss-Newton with a small Levenberg term where the full Hessian is not usable
        mu = 1e-10 * (h11 + h22) + 1e-300
        g11 = np.where(pd, f11, h11 + mu)
        g22 = np.where(pd, f22, h22 + mu)
        det = g11 * g22 - h12**2
        da = -(g22 * ga - h12 * gb) / det
        db = -(g11 * gb - h12 * ga) / det
        bad = ~np.isfinite(da) | ~np.isfinite(db)
        da[bad] = 0.0
        db[bad] = 0.0
        lim = 0.5
        sc = np.minimum(1.0, lim / np.maximum(np.abs(da), np.abs(db)).clip(1e-300))
        na = np.clip(ta[ia] + sc * da, 0.0, 1.0)
        nb = np.clip(tb[ia] + sc * db, 0.0, 1.0)
        moved = np.maximum(np.abs(na - ta[ia]), np.abs(nb - tb[ia]))
        ta[ia], tb[ia] = na, nb
        active[ia[moved < 1e-12]] = False
    DA = _bez_curve_ders(QA, ta, 0)[0]
    DB = _bez_curve_ders(QB, tb, 0)[0]
    return ta, tb, DA, DB


def intersect_curve_sets(A, B, tol: float | None = None, merge_dist: float | None = None,
                         min_box: float | None = None, max_depth: int = 48,
                         same_set: bool = False) -> CurveIntersections:
    """All intersections of every curve of ``A`` with every curve of ``B`` (any dimension).

    Bounding-box subdivision of the Bezier segments, then Newton (module docstring). The
    segments of all curves are elevated to a common degree and every candidate pair of every
    curve pair is processed in the same numpy arrays, level by level, so that hundreds of
    horizontal x vertical image curves are intersected in one call. Curve pairs whose Bezier
    boxes do not meet are discarded at the first level.

    Parameters
    ----------
    A, B : sequence of NurbsCurve (or one curve)
        Curves of the same dimension ``d`` (2 for image curves in px; 3 in mm).
    tol : float, optional
        Largest accepted distance ``|A(u) - B(v)|`` (units of the curves). Boxes are inflated by
        it, so in 3-D it also accepts near-intersections ("the curves meet within tol").
        Default ``1e-9 * scale`` with scale the largest extent of the control points.
    merge_dist : float, optional
        Solutions of one curve pair closer than this are one intersection (default
        ``max(10 tol, 1e-7 scale)``).
    min_box : float, optional
        Subdivision stops when both pieces' boxes are smaller (default ``1e-4 * scale``).
    max_depth : int
        Maximum subdivision depth.
    same_set : bool
        ``A`` and ``B`` are the same list: only pairs ``ia < ib`` are intersected.

    Returns
    -------
    CurveIntersections
        Sorted by ``(ia, ib, u)``.
    """
    A = _decompose_set(A, "A")
    B = _decompose_set(B, "B")
    if not A or not B:
        z = np.zeros(0)
        return CurveIntersections(z.astype(int), z.astype(int), z, z, np.zeros((0, 2)), z)
    dims = {c.dimension for c in A + B}
    if len(dims) != 1:
        raise NurbscanError(f"A/B: curves of different dimensions {sorted(dims)}")
    P = max(c.degree for c in A + B)
    QA, a0, a1, oa = _segments_of(A, P)
    QB, b0, b1, ob = _segments_of(B, P)
    scale = _scale_of(np.concatenate([(QA[..., :-1] / QA[..., -1:]).reshape(-1, QA.shape[-1] - 1),
                                      (QB[..., :-1] / QB[..., -1:]).reshape(-1, QB.shape[-1] - 1)]))
    tol = 1e-9 * scale if tol is None else float(tol)
    merge_dist = max(10 * tol, 1e-7 * scale) if merge_dist is None else float(merge_dist)
    min_box = 1e-4 * scale if min_box is None else float(min_box)

    # initial candidate pairs: segment boxes overlapping (inflated by tol)
    loA, hiA = _boxes(QA, 1)
    loB, hiB = _boxes(QB, 1)
    sa_idx, sb_idx = _box_pairs(loA, hiA, loB, hiB, tol)
    if same_set:
        keep = oa[sa_idx] < ob[sb_idx]
        sa_idx, sb_idx = sa_idx[keep], sb_idx[keep]
    # per candidate: parent segment, sub-interval [lo, lo + w] in the parent, sub-Bezier nets
    ca_lo = np.zeros(sa_idx.size)
    cb_lo = np.zeros(sa_idx.size)
    cw_a = np.ones(sa_idx.size)
    cw_b = np.ones(sa_idx.size)
    SA, SB = QA[sa_idx], QB[sb_idx]
    starts = []
    d = QA.shape[-1] - 1
    for depth in range(max_depth + 1):
        if sa_idx.size == 0:
            break
        la, ha = _boxes(SA, 1)
        lb, hb = _boxes(SB, 1)
        ok = np.all((la <= hb + tol) & (lb <= ha + tol), axis=1)
        sa_idx, sb_idx, SA, SB = sa_idx[ok], sb_idx[ok], SA[ok], SB[ok]
        ca_lo, cb_lo, cw_a, cw_b = ca_lo[ok], cb_lo[ok], cw_a[ok], cw_b[ok]
        la, ha, lb, hb = la[ok], ha[ok], lb[ok], hb[ok]
        small = (np.max(ha - la, axis=1) <= min_box) & (np.max(hb - lb, axis=1) <= min_box)
        sta, stb = np.full(sa_idx.size, 0.5), np.full(sa_idx.size, 0.5)
        single = np.zeros(sa_idx.size, dtype=bool)
        if d == 2 and sa_idx.size:
            single, sta, stb = _single_crossing(SA, SB)
        done = small | single | (depth == max_depth)
        if done.any():
            starts.append((sa_idx[done], sb_idx[done], ca_lo[done] + sta[done] * cw_a[done],
                           cb_lo[done] + stb[done] * cw_b[done]))
        r = ~done
        sa_idx, sb_idx, SA, SB = sa_idx[r], sb_idx[r], SA[r], SB[r]
        ca_lo, cb_lo, cw_a, cw_b = ca_lo[r], cb_lo[r], cw_a[r], cw_b[r]
        if sa_idx.size * 4 > _MAX_CANDIDATES:
            raise NurbscanError(
                "A/B: too many intersection candidates (overlapping curves?); "
                f"{sa_idx.size} pairs at depth {depth}"
            )
        AL, AR = _split_half(SA, 1)
        BL, BR = _split_half(SB, 1)
        hw_a, hw_b = 0.5 * cw_a, 0.5 * cw_b
        SA = np.concatenate([AL, AL, AR, AR])
        SB = np.concatenate([BL, BR, BL, BR])
        ca_lo = np.concatenate([ca_lo, ca_lo, ca_lo + hw_a, ca_lo + hw_a])
        cb_lo = np.concatenate([cb_lo, cb_lo + hw_b, cb_lo, cb_lo + hw_b])
        cw_a = np.tile(hw_a, 4)
        cw_b = np.tile(hw_b, 4)
        sa_idx = np.tile(sa_idx, 4)
        sb_idx = np.tile(sb_idx, 4)

    if not starts:
        z = np.zeros(0)
        return CurveIntersections(z.astype(int), z.astype(int), z, z, np.zeros((0, d)), z)
    sa = np.concatenate([s[0] for s in starts])
    sb = np.concatenate([s[1] for s in starts])
    ta = np.concatenate([s[2] for s in starts])
    tb = np.concatenate([s[3] for s in starts])
    ta, tb, XA, XB = _newton_curve_pairs(QA[sa], QB[sb], ta, tb)
    dist = np.linalg.norm(XA - XB, axis=1)
    ok = dist <= tol
    sa, sb, ta, tb, XA, XB, dist = sa[ok], sb[ok], ta[ok], tb[ok], XA[ok], XB[ok], dist[ok]
    ia, ib = oa[sa], ob[sb]
    u = a0[sa] + ta * (a1[sa] - a0[sa])
    v = b0[sb] + tb * (b1[sb] - b0[sb])
    X = 0.5 * (XA + XB)
    group = ia.astype(np.int64) * (len(B) + 1) + ib
    keep = _merge(group, X, dist, merge_dist)
    order = np.lexsort((u[keep], ib[keep], ia[keep]))
    keep = keep[order]
    ia, ib, u, v, X, dist = ia[keep], ib[keep], u[keep], v[keep], X[keep], dist[keep]
    # one contact region = one intersection: consecutive hits of a pair between which the
    # curves stay within tol (a tangential touch reached from several starts)
    same = np.nonzero((ia[1:] == ia[:-1]) & (ib[1:] == ib[:-1]))[0]
    join = np.zeros(max(u.size - 1, 0), dtype=bool)
    for k in same:  # only curve pairs with several hits: is the chord midpoint on both?
        Xm = 0.5 * (X[k] + X[k + 1])[None]
        da = closest_point_curve(A[ia[k]], Xm, start=[u[k]])[2][0]
        db = closest_point_curve(B[ib[k]], Xm, start=[v[k]])[2][0]
        join[k] = max(da, db) <= tol
    sel = _best_of_runs(join, dist)
    return CurveIntersections(ia[sel], ib[sel], u[sel], v[sel], X[sel], dist[sel])


def _best_of_runs(join: np.ndarray, score: np.ndarray) -> np.ndarray:
    """Indices of the lowest ``score`` in each run of items chained by ``join[k]`` (k, k+1)."""
    if score.size == 0:
        return np.zeros(0, dtype=int)
    lab = np.concatenate([[0], np.cumsum(~join)])
    order = np.lexsort((score, lab))
    first = np.ones(score.size, dtype=bool)
    first[1:] = lab[order][1:] != lab[order][:-1]
    return np.sort(order[first])


def _box_pairs(loA, hiA, loB, hiB, tol, chunk: int = 2048):
    """Index pairs of overlapping boxes (inflated by ``tol``).

    Small sets: chunked broadcasting. Large sets: the boxes are hashed into a uniform grid over
    their first two coordinates (cell = median box size), pairs sharing a cell are tested.
    """
    nA, nB = loA.shape[0], loB.shape[0]
    if nA * nB <= 4_000_000:
        ia, ib = [], []
        for s in range(0, nA, chunk):
            la, ha = loA[s:s + chunk, None], hiA[s:s + chunk, None]
            ov = np.all((la <= hiB[None] + tol) & (loB[None] <= ha + tol), axis=2)
            i, j = np.nonzero(ov)
            ia.append(i + s)
            ib.append(j)
        return np.concatenate(ia), np.concatenate(ib)
    k = min(2, loA.shape[1])
    ext = np.concatenate([hiA - loA, hiB - loB])[:, :k]
    cell = max(float(np.median(ext.max(axis=1))), 1e-300) + 2 * tol
    origin = np.minimum(loA.min(axis=0), loB.min(axis=0))[:k] - tol

    def cells(lo, hi):
        c0 = np.floor((lo[:, :k] - tol - origin) / cell).astype(np.int64)
        c1 = np.floor((hi[:, :k] + tol - origin) / cell).astype(np.int64)
        n = c1 - c0 + 1
        cnt = np.prod(n, axis=1)
        owner = np.repeat(np.arange(lo.shape[0]), cnt)
        local = np.arange(cnt.sum()) - np.repeat(np.cumsum(cnt) - cnt, cnt)
        key = np.zeros(owner.size, dtype=np.int64)
        stride = 1
        for a in range(k):
            na = n[owner, a]
            key += (c0[owner, a] + local % na) * stride
            local //= na
            stride *= 1 << 21
        return key, owner

    kA, oA = cells(loA, hiA)
    kB, oB = cells(loB, hiB)
    order = np.argsort(kB, kind="stable")
    kB, oB = kB[order], oB[order]
    first = np.searchsorted(kB, kA, side="left")
    last = np.searchsorted(kB, kA, side="right")
    cnt = last - first
    ia = np.repeat(oA, cnt)
    pos = np.arange(cnt.sum()) - np.repeat(np.cumsum(cnt) - cnt, cnt) + np.repeat(first, cnt)
    ib = oB[pos]
    pair = np.unique(ia.astype(np.int64) * nB + ib)
    ia, ib = pair // nB, pair % nB
    ok = np.all((loA[ia] <= hiB[ib] + tol) & (loB[ib] <= hiA[ia] + tol), axis=1)
    return ia[ok], ib[ok]


def _single_crossing(SA: np.ndarray, SB: np.ndarray):
    """2-D pieces that cross at most once, and chord-intersection starts for them.

    Two planar curves meeting twice have parallel tangents somewhere (both have a tangent
    parallel to the chord through the two points). The tangents of a rational Bezier piece lie
    in the cone of its control-polygon legs; if the two cones (as directions modulo pi, each
    narrower than pi/4) are disjoint the pieces meet at most once, and the intersection of
    their chords is a good Newton start.
    """
    XA = SA[..., :2] / SA[..., 2:]
    XB = SB[..., :2] / SB[..., 2:]

    def cone(X):
        chord = X[:, -1] - X[:, 0]
        phi = np.arctan2(chord[:, 1], chord[:, 0])
        leg = np.diff(X, axis=1)
        ang = np.arctan2(leg[..., 1], leg[..., 0]) - phi[:, None]
        ang = (ang + np.pi / 2) % np.pi - np.pi / 2
        short = np.linalg.norm(leg, axis=2) <= 1e-14 * (np.abs(X).max(axis=(1, 2))[:, None]
                                                         + 1e-300)
        lo = np.where(short, np.inf, ang).min(axis=1)
        hi = np.where(short, -np.inf, ang).max(axis=1)
        ok = (np.linalg.norm(chord, axis=1) > 0) & (hi - lo < np.pi / 4)
        return phi, np.minimum(lo, 0.0), np.maximum(hi, 0.0), ok, chord

    pa, alo, ahi, oka, ca = cone(XA)
    pb, blo, bhi, okb, cb = cone(XB)
    dphi = (pb - pa + np.pi / 2) % np.pi - np.pi / 2
    b0, b1 = dphi + blo, dphi + bhi
    disjoint = ((b0 > ahi) & (b1 < alo + np.pi)) | ((b1 < alo) & (b0 > ahi - np.pi))
    single = oka & okb & disjoint
    # chord intersection XA0 + a ca = XB0 + b cb
    r = XB[:, 0] - XA[:, 0]
    den = ca[:, 0] * cb[:, 1] - ca[:, 1] * cb[:, 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        a = (r[:, 0] * cb[:, 1] - r[:, 1] * cb[:, 0]) / den
        b = (r[:, 0] * ca[:, 1] - r[:, 1] * ca[:, 0]) / den
    a = np.clip(np.nan_to_num(a, nan=0.5), 0.0, 1.0)
    b = np.clip(np.nan_to_num(b, nan=0.5), 0.0, 1.0)
    return single, np.where(single, a, 0.5), np.where(single, b, 0.5)


def intersect_curves(c1: NurbsCurve, c2: NurbsCurve, tol: float | None = None,
                     **kwargs) -> CurveIntersections:
    """All intersections of two curves (2-D, or within ``tol`` in 3-D).

    Same method and parameters as :func:`intersect_curve_sets` for the single pair; the result
    is sorted by the parameter ``u`` on ``c1``.
    """
    return intersect_curve_sets([c1], [c2], tol=tol, **kwargs)


# ---------------------------------------------------------------------------- closest points


def _sample_params(U: np.ndarray, p: int, n_ctrl: int, per_span: int) -> np.ndarray:
    k = np.unique(U[p:n_ctrl + 1])
    t = np.linspace(0.0, 1.0, per_span, endpoint=False)
    u = (k[:-1, None] + t * np.diff(k)[:, None]).ravel()
    return np.append(u, k[-1])


def closest_points_curves(c1: NurbsCurve, c2: NurbsCurve, per_span: int = 16, n_starts: int = 8):
    """Closest points of two curves (global minimum of ``|c1(u) - c2(v)|``), any dimension.

    Grid start (``per_span`` samples per knot span of each curve, the ``n_starts`` closest sample
    pairs), then clamped Newton on the squared distance (book section 6.1, eq. 6.4 for two
    curves) on the whole curves.

    Returns
    -------
    (u, v, distance) : float, float, float
    """
    u = _sample_params(c1.knots, c1.degree, c1.n_ctrl, per_span)
    v = _sample_params(c2.knots, c2.degree, c2.n_ctrl, per_span)
    X, Y = c1.evaluate(u), c2.evaluate(v)
    tree = cKDTree(Y)
    dd, jj = tree.query(X)
    best = np.argsort(dd)[:n_starts]
    s, t = u[best].copy(), v[jj[best]].copy()
    (a0, a1), (b0, b1) = c1.domain, c2.domain
    for _ in range(60):
        DA = c1.derivatives(s, 2)
        DB = c2.derivatives(t, 2)
        F = DA[0] - DB[0]
        Ja, Jb = DA[1], -DB[1]
        ga = np.einsum("nc,nc->n", F, Ja)
        gb = np.einsum("nc,nc->n", F, Jb)
        h11 = np.einsum("nc,nc->n", Ja, Ja)
        h22 = np.einsum("nc,nc->n", Jb, Jb)
        h12 = np.einsum("nc,nc->n", Ja, Jb)
        f11 = h11 + np.einsum("nc,nc->n", F, DA[2])
        f22 = h22 - np.einsum("nc,nc->n", F, DB[2])
        det = f11 * f22 - h12**2
        pd = (f11 > 0) & (det > 1e-14 * (f11 + f22) ** 2)
        mu = 1e-10 * (h11 + h22) + 1e-300
        g11 = np.where(pd, f11, h11 + mu)
        g22 = np.where(pd, f22, h22 + mu)
        det = g11 * g22 - h12**2
        ds = np.nan_to_num(-(g22 * ga - h12 * gb) / det)
        dt = np.nan_to_num(-(g11 * gb - h12 * ga) / det)
        ns = np.clip(s + ds, a0, a1)
        nt = np.clip(t + dt, b0, b1)
        if np.all(np.abs(ns - s) <= 1e-15 * (a1 - a0)) and np.all(
                np.abs(nt - t) <= 1e-15 * (b1 - b0)):
            s, t = ns, nt
            break
        s, t = ns, nt
    dist = np.linalg.norm(c1.evaluate(s) - c2.evaluate(t), axis=1)
    k = int(np.argmin(dist))
    return float(s[k]), float(t[k]), float(dist[k])


def _wrap(u, a, b):
    """Parameters of a closed curve / surface direction taken back into ``[a, b]``."""
    return np.where((u < a) | (u > b), a + np.mod(u - a, b - a), u)


def closest_point_curve(curve: NurbsCurve, points, per_span: int = 16, iters: int = 30,
                        start=None):
    """Closest points on a curve to many points (point inversion, book section 6.1, eq. 6.3).

    Start at the nearest of ``per_span`` samples per knot span (k-d tree), then Newton on
    ``f(u) = C'(u) . (C(u) - P) = 0`` (eq. 6.3), clamped to the domain (followed across the
    seam of a closed curve); vectorised over points.

    Parameters
    ----------
    curve : NurbsCurve
    points : array_like, shape (N, d)
    start : array_like, shape (N,), optional
        Start parameters (skip the sampled start).

    Returns
    -------
    (u, closest, distance) : ndarray (N,), ndarray (N, d), ndarray (N,)
    """
    Pt = np.asarray(points, dtype=float)
    if Pt.ndim != 2 or Pt.shape[1] != curve.dimension:
        raise NurbscanError(f"points: expected shape (N, {curve.dimension}), got {Pt.shape}")
    a, b = curve.domain
    if start is None:
        us = _sample_params(curve.knots, curve.degree, curve.n_ctrl, per_span)
        _, j = cKDTree(curve.evaluate(us)).query(Pt)
        u = us[j]
    else:
        u = np.clip(np.asarray(start, dtype=float).reshape(Pt.shape[0]), a, b)
    ends = curve.evaluate(np.array([a, b]))
    closed = np.linalg.norm(ends[0] - ends[1]) <= 1e-12 * _scale_of(curve.control_points)
    for _ in range(iters):
        D = curve.derivatives(u, 2)
        R = D[0] - Pt
        f = np.einsum("nc,nc->n", D[1], R)
        fp = np.einsum("nc,nc->n", D[2], R) + np.einsum("nc,nc->n", D[1], D[1])
        step = np.where(fp > 0, -f / np.where(fp > 0, fp, 1.0), -np.sign(f) * 1e-3 * (b - a))
        un = u + np.clip(step, -0.25 * (b - a), 0.25 * (b - a))
        # a closed curve is followed across its seam, an open one is clamped to its ends
        un = _wrap(un, a, b) if closed else np.clip(un, a, b)
        if np.all(np.abs(un - u) <= 1e-15 * (b - a)):
            u = un
            break
        u = un
    C = curve.evaluate(u)
    return u, C, np.linalg.norm(C - Pt, axis=1)


def closest_point_surface(surface: NurbsSurface, points, per_span: int | None = None,
                          iters: int = 30, start=None):
    """Closest points on a surface to many points (point inversion, book section 6.1, eq. 6.6).

    Start at the nearest sample of a grid with ``per_span`` samples per knot span in each
    direction (default: 8, fewer on surfaces with many spans, at least 3 and about 200 samples
    per direction), then Newton on ``f = S_u . r = 0``, ``g = S_v . r = 0`` with ``r = S - P``
    (eq. 6.6/6.7; Gauss-Newton with Levenberg damping where the Hessian is not positive
    definite), clamped to the domain (followed across the seams of closed directions);
    vectorised over points. ``start = (u0, v0)`` (arrays of shape (N,)) skips the grid.

    Returns
    -------
    (u, v, closest, distance) : ndarray (N,), ndarray (N,), ndarray (N, d), ndarray (N,)
    """
    Pt = np.asarray(points, dtype=float)
    if Pt.ndim != 2 or Pt.shape[1] != surface.dimension:
        raise NurbscanError(f"points: expected shape (N, {surface.dimension}), got {Pt.shape}")
    nu, nv = surface.shape

    def count(U, p, n):
        if per_span is not None:
            return int(per_span)
        spans = np.unique(U[p:n + 1]).size - 1
        return int(np.clip(np.ceil(200 / spans), 3, 8))

    (a0, a1), (b0, b1) = surface.domain
    if start is None:
        us = _sample_params(surface.knots_u, surface.degree_u, nu,
                            count(surface.knots_u, surface.degree_u, nu))
        vs = _sample_params(surface.knots_v, surface.degree_v, nv,
                            count(surface.knots_v, surface.degree_v, nv))
        G = surface.evaluate_grid(us, vs)
        _, j = cKDTree(G.reshape(-1, G.shape[-1])).query(Pt)
        u, v = us[j // vs.size], vs[j % vs.size]
    else:
        u = np.clip(np.asarray(start[0], dtype=float).reshape(Pt.shape[0]), a0, a1)
        v = np.clip(np.asarray(start[1], dtype=float).reshape(Pt.shape[0]), b0, b1)
    t = np.linspace(0.0, 1.0, 17)
    E = surface.evaluate_grid([a0, a1], b0 + t * (b1 - b0))
    F = surface.evaluate_grid(a0 + t * (a1 - a0), [b0, b1])
    sc = 1e-12 * _scale_of(surface.control_points)
    closed_u = bool(np.linalg.norm(E[0] - E[1], axis=-1).max() <= sc)
    closed_v = bool(np.linalg.norm(F[:, 0] - F[:, 1], axis=-1).max() <= sc)
    for _ in range(iters):
        D = surface.derivatives(u, v, 2)
        r = D[0, 0] - Pt
        Su, Sv = D[1, 0], D[0, 1]
        f = np.einsum("nc,nc->n", Su, r)
        g = np.einsum("nc,nc->n", Sv, r)
        h11 = np.einsum("nc,nc->n", Su, Su)
        h22 = np.einsum("nc,nc->n", Sv, Sv)
        h12 = np.einsum("nc,nc->n", Su, Sv)
        f11 = h11 + np.einsum("nc,nc->n", r, D[2, 0])
        f22 = h22 + np.einsum("nc,nc->n", r, D[0, 2])
        f12 = h12 + np.einsum("nc,nc->n", r, D[1, 1])
        det = f11 * f22 - f12**2
        pd = (f11 > 0) & (det > 1e-14 * (f11 + f22) ** 2)
        mu = 1e-10 * (h11 + h22) + 1e-300
        g11 = np.where(pd, f11, h11 + mu)
        g22 = np.where(pd, f22, h22 + mu)
        g12 = np.where(pd, f12, h12)
        det = g11 * g22 - g12**2
        du = np.nan_to_num(-(g22 * f - g12 * g) / det)
        dv = np.nan_to_num(-(g11 * g - g12 * f) / det)
        du = np.clip(du, -0.25 * (a1 - a0), 0.25 * (a1 - a0))
        dv = np.clip(dv, -0.25 * (b1 - b0), 0.25 * (b1 - b0))
        un = _wrap(u + du, a0, a1) if closed_u else np.clip(u + du, a0, a1)
        vn = _wrap(v + dv, b0, b1) if closed_v else np.clip(v + dv, b0, b1)
        if np.all(np.abs(un - u) <= 1e-15 * (a1 - a0)) and np.all(
                np.abs(vn - v) <= 1e-15 * (b1 - b0)):
            u, v = un, vn
            break
        u, v = un, vn
    S = surface.evaluate(u, v)
    return u, v, S, np.linalg.norm(S - Pt, axis=1)


# ---------------------------------------------------------------------------- line / surface


@dataclass(frozen=True)
class LineSurfaceHits:
    """Intersections of lines ``o_k + lam d_k`` with a surface.

    Attributes
    ----------
    line : ndarray of int, shape (h,)
        Index of the line of each hit.
    lam : ndarray, shape (h,)
        Line parameter (mm along the unit direction).
    u, v : ndarray, shape (h,)
        Surface parameters.
    points : ndarray, shape (h, 3)
        Hit points ``S(u, v)`` (mm).
    distance : ndarray, shape (h,)
        Distance of ``S(u, v)`` from the line (mm).
    """

    line: np.ndarray
    lam: np.ndarray
    u: np.ndarray
    v: np.ndarray
    points: np.ndarray
    distance: np.ndarray

    def __len__(self) -> int:
        return int(self.lam.size)

    def to_dict(self) -> dict:
        """JSON-ready dict with ``"type": "nurbscan.line_surface_hits"``."""
        return {"type": "nurbscan.line_surface_hits", "version": 1,
                "line": self.line.tolist(), "lam": self.lam.tolist(), "u": self.u.tolist(),
                "v": self.v.tolist(), "points": self.points.tolist(),
                "distance": self.distance.tolist()}

    @classmethod
    def from_dict(cls, d: dict) -> LineSurfaceHits:
        """Inverse of :meth:`to_dict`."""
        if not isinstance(d, dict) or d.get("type") != "nurbscan.line_surface_hits":
            raise NurbscanError("line surface hits: expected type nurbscan.line_surface_hits")
        return cls(np.asarray(d["line"], int), np.asarray(d["lam"], float),
                   np.asarray(d["u"], float), np.asarray(d["v"], float),
                   np.asarray(d["points"], float).reshape(-1, 3),
                   np.asarray(d["distance"], float))


def _perp_frames(D: np.ndarray):
    """Two unit vectors orthogonal to each unit direction, shapes (N, 3) each."""
    a = np.where((np.abs(D[:, 0]) < 0.9)[:, None], [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    e1 = np.cross(D, a)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    return e1, np.cross(D, e1)


def _injective(G: np.ndarray) -> np.ndarray:
    """Projected polynomial patches ``G`` (N, p+1, q+1, 3) whose map is one-to-one.

    For a non-rational patch the partials ``g_u`` / ``g_v`` lie in the cones of the control
    net's u- / v-legs. If each cone is narrower than pi/2 and no u-direction is parallel to a
    v-direction, ``g(q) - g(p) = du a + dv b`` (``a``, ``b`` in the cones) vanishes only for
    ``p = q``: the patch meets the line at most once and Newton from its centre finds it.
    Rational patches are not tested (returns False).
    """
    w = G[..., 2]
    flat = np.ptp(w.reshape(w.shape[0], -1), axis=1) <= 1e-14 * np.abs(w).max(axis=(1, 2))
    X = G[..., :2] / G[..., 2:]

    def cone(legs):
        legs = legs.reshape(legs.shape[0], -1, 2)
        mean = legs.sum(axis=1)
        phi = np.arctan2(mean[:, 1], mean[:, 0])
        ang = np.arctan2(legs[..., 1], legs[..., 0]) - phi[:, None]
        ang = (ang + np.pi) % (2 * np.pi) - np.pi
        short = np.linalg.norm(legs, axis=2) == 0
        lo = np.where(short, np.inf, ang).min(axis=1)
        hi = np.where(short, -np.inf, ang).max(axis=1)
        ok = (np.linalg.norm(mean, axis=1) > 0) & (hi - lo < np.pi / 2) & ~short.all(axis=1)
        return phi, lo, hi, ok

    pu, ulo, uhi, oku = cone(X[:, 1:] - X[:, :-1])
    pv, vlo, vhi, okv = cone(X[:, :, 1:] - X[:, :, :-1])
    d = (pv - pu + np.pi) % (2 * np.pi) - np.pi
    a, b = d + vlo - uhi, d + vhi - ulo
    sep = ((a > 0) & (b < np.pi)) | ((a > -np.pi) & (b < 0))
    return flat & oku & okv & sep


def _slab(o, d, lo, hi):
    """Does the line ``o + t d`` meet the box ``[lo, hi]`` (broadcast slab test)?"""
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (lo - o) / d
        t2 = (hi - o) / d
    inside = (o >= lo) & (o <= hi)
    tmin = np.where(d == 0, np.where(inside, -np.inf, np.inf), np.minimum(t1, t2))
    tmax = np.where(d == 0, np.where(inside, np.inf, -np.inf), np.maximum(t1, t2))
    return tmin.max(axis=-1) <= tmax.min(axis=-1)


def intersect_lines_surface(origins, directions, surface: NurbsSurface, tol: float | None = None,
                            min_box: float | None = None, max_depth: int = 40,
                            merge_dist: float | None = None) -> LineSurfaceHits:
    """Every intersection of each line ``o_k + lam d_k`` with a 3-D NURBS surface.

    Method (method.md section 3): the line is the zero set of ``g(X) = ((X - o).e1,
    (X - o).e2)`` with ``e1, e2`` orthogonal to ``d``. The surface is decomposed into rational
    Bezier patches; for each (line, patch) pair whose 3-D control box the line meets, the
    projected control net ``g(P_ij)`` (homogeneous: ``(w (P - o).e1, w (P - o).e2, w)``) is
    subdivided (de Casteljau in u and v) while its box contains the origin, until the patch is
    smaller than ``min_box``; every surviving piece starts a Newton iteration (Gauss-Newton with
    Levenberg damping, exact at transversal hits, minimising the distance at tangential ones) on
    its parent patch. Hits within ``tol`` of the line are kept, duplicates merged.

    Parameters
    ----------
    origins, directions : array_like, shape (N, 3) or (3,)
        Line points and directions (mm; directions are normalised).
    surface : NurbsSurface
        3-D surface (mm).
    tol : float, optional
        Accepted distance of a hit from the line (default ``1e-10 * scale``, scale = largest
        extent of the control net).
    min_box, max_depth, merge_dist : optional
        Subdivision stop size (default ``1e-3 * scale``), depth limit and duplicate distance
        (default ``max(10 tol, 1e-8 scale)``).

    Returns
    -------
    LineSurfaceHits
        Sorted by ``(line, lam)``.
    """
    if not isinstance(surface, NurbsSurface) or surface.dimension != 3:
        raise NurbscanError("surface: expected a 3-D NurbsSurface")
    O = np.atleast_2d(np.asarray(origins, dtype=float))
    D = np.atleast_2d(np.asarray(directions, dtype=float))
    if O.shape[1:] != (3,) or D.shape != O.shape:
        raise NurbscanError(f"origins/directions: expected matching (N, 3), got {O.shape}, "
                            f"{D.shape}")
    nd = np.linalg.norm(D, axis=1)
    if np.any(~(nd > 0)) or not np.all(np.isfinite(O)):
        raise NurbscanError("directions: must be finite and non-zero")
    D = D / nd[:, None]
    E1, E2 = _perp_frames(D)
    Q, rng = _surface_bezier(surface)
    X = Q[..., :3] / Q[..., 3:]
    scale = _scale_of(X)
    tol = 1e-10 * scale if tol is None else float(tol)
    min_box = 1e-3 * scale if min_box is None else float(min_box)
    merge_dist = max(10 * tol, 1e-8 * scale) if merge_dist is None else float(merge_dist)

    # initial (line, patch) pairs: the line meets the patch's control box (slab test), first
    # for blocks of up to 8 x 8 patches, then for the patches of the blocks that are met
    lo = X.min(axis=(1, 2)) - tol
    hi = X.max(axis=(1, 2)) + tol
    nsu = np.unique(rng[:, 0]).size
    nsv = Q.shape[0] // nsu
    bu, bv = np.arange(nsu) // 8, np.arange(nsv) // 8
    block = (bu[:, None] * (bv[-1] + 1) + bv[None, :]).ravel()  # block of each patch
    nb = int(block.max()) + 1
    blo = np.full((nb, 3), np.inf)
    bhi = np.full((nb, 3), -np.inf)
    np.minimum.at(blo, block, lo)
    np.maximum.at(bhi, block, hi)
    members = np.argsort(block, kind="stable")
    start = np.searchsorted(block[members], np.arange(nb))
    count = np.bincount(block, minlength=nb)
    lb, bb = [], []
    chunk = max(1, 200_000 // nb)
    for s0 in range(0, O.shape[0], chunk):
        i, j = np.nonzero(_slab(O[s0:s0 + chunk, None], D[s0:s0 + chunk, None], blo[None],
                                bhi[None]))
        lb.append(i + s0)
        bb.append(j)
    lb = np.concatenate(lb)
    bb = np.concatenate(bb)
    c = count[bb]
    li = np.repeat(lb, c)
    pi = members[np.repeat(start[bb], c) + np.arange(c.sum()) - np.repeat(np.cumsum(c) - c, c)]
    ok = _slab(O[li], D[li], lo[pi], hi[pi])
    li, pi = li[ok], pi[ok]

    def project(Qs, lines):
        o = O[lines][:, None, None, :]
        w = Qs[..., 3:]
        rel = Qs[..., :3] - w * o
        g1 = np.einsum("nijc,nc->nij", rel, E1[lines])
        g2 = np.einsum("nijc,nc->nij", rel, E2[lines])
        return np.stack([g1, g2, w[..., 0]], axis=-1)

    G = project(Q[pi], li)
    S3 = Q[pi]
    ulo = np.zeros(li.size)
    vlo = np.zeros(li.size)
    wid = np.ones(li.size)
    starts = []
    for depth in range(max_depth + 1):
        if li.size == 0:
            break
        gl, gh = _boxes(G, 2)
        ok = np.all((gl <= tol) & (gh >= -tol), axis=1)
        li, pi, G, S3, ulo, vlo, wid = li[ok], pi[ok], G[ok], S3[ok], ulo[ok], vlo[ok], wid[ok]
        xl, xh = _boxes(S3, 2)
        done = (np.max(xh - xl, axis=1) <= min_box) | (depth == max_depth) | _injective(G)
        if done.any():
            starts.append((li[done], pi[done], ulo[done] + 0.5 * wid[done],
                           vlo[done] + 0.5 * wid[done]))
        r = ~done
        li, pi, G, S3, ulo, vlo, wid = li[r], pi[r], G[r], S3[r], ulo[r], vlo[r], wid[r]
        if li.size * 4 > _MAX_CANDIDATES:
            raise NurbscanError(f"surface: too many line/surface candidates ({li.size}) at "
                                f"depth {depth} (a line lying in the surface?)")
        both = np.concatenate([G, S3], axis=-1)
        L, R = _split_half(both, 1)
        LL, LR = _split_half(L, 2)
        RL, RR = _split_half(R, 2)
        both = np.concatenate([LL, LR, RL, RR])
        G, S3 = both[..., :3], both[..., 3:]
        h = 0.5 * wid
        ulo = np.concatenate([ulo, ulo, ulo + h, ulo + h])
        vlo = np.concatenate([vlo, vlo + h, vlo, vlo + h])
        wid = np.tile(h, 4)
        li = np.tile(li, 4)
        pi = np.tile(pi, 4)

    if not starts:
        z = np.zeros(0)
        return LineSurfaceHits(z.astype(int), z, z, z, np.zeros((0, 3)), z)
    li = np.concatenate([s[0] for s in starts])
    pi = np.concatenate([s[1] for s in starts])
    tu = np.concatenate([s[2] for s in starts])
    tv = np.concatenate([s[3] for s in starts])
    Qp = Q[pi]
    o, e1, e2 = O[li], E1[li], E2[li]
    active = np.ones(li.size, dtype=bool)
    for _ in range(60):
        if not active.any():
            break
        k = np.nonzero(active)[0]
        S, Su, Sv = _bez_surface_ders(Qp[k], tu[k], tv[k])
        r = S - o[k]
        f = np.stack([np.einsum("nc,nc->n", r, e1[k]), np.einsum("nc,nc->n", r, e2[k])], 1)
        J = np.stack([np.stack([np.einsum("nc,nc->n", Su, e1[k]),
                                np.einsum("nc,nc->n", Sv, e1[k])], 1),
                      np.stack([np.einsum("nc,nc->n", Su, e2[k]),
                                np.einsum("nc,nc->n", Sv, e2[k])], 1)], 1)  # (n, 2, 2)
        JT = J.transpose(0, 2, 1)
        H = JT @ J
        g = np.einsum("nij,nj->ni", JT, f)
        mu = 1e-12 * (H[:, 0, 0] + H[:, 1, 1]) + 1e-300
        H[:, 0, 0] += mu
        H[:, 1, 1] += mu
        det = H[:, 0, 0] * H[:, 1, 1] - H[:, 0, 1] * H[:, 1, 0]
        du = np.nan_to_num(-(H[:, 1, 1] * g[:, 0] - H[:, 0, 1] * g[:, 1]) / det)
        dv = np.nan_to_num(-(H[:, 0, 0] * g[:, 1] - H[:, 1, 0] * g[:, 0]) / det)
        sc = np.minimum(1.0, 0.5 / np.maximum(np.abs(du), np.abs(dv)).clip(1e-300))
        nu_ = np.clip(tu[k] + sc * du, 0.0, 1.0)
        nv_ = np.clip(tv[k] + sc * dv, 0.0, 1.0)
        moved = np.maximum(np.abs(nu_ - tu[k]), np.abs(nv_ - tv[k]))
        tu[k], tv[k] = nu_, nv_
        active[k[moved < 1e-12]] = False
    S, _, _ = _bez_surface_ders(Qp, tu, tv)
    r = S - o
    lam = np.einsum("nc,nc->n", r, D[li])
    dist = np.linalg.norm(r - lam[:, None] * D[li], axis=1)
    ok = dist <= tol
    li, pi, tu, tv, S, lam, dist = li[ok], pi[ok], tu[ok], tv[ok], S[ok], lam[ok], dist[ok]
    rg = rng[pi]
    u = rg[:, 0] + tu * (rg[:, 1] - rg[:, 0])
    v = rg[:, 2] + tv * (rg[:, 3] - rg[:, 2])
    keep = _merge(li, S, dist, merge_dist)
    keep = keep[np.lexsort((lam[keep], li[keep]))]
    li, lam, u, v, S, dist = li[keep], lam[keep], u[keep], v[keep], S[keep], dist[keep]
    # one contact region = one hit: consecutive hits on a line between which the surface stays
    # within tol of the line (a tangential touch reached from several starts)
    join = np.zeros(max(lam.size - 1, 0), dtype=bool)
    k = np.nonzero((li[1:] == li[:-1]) & (lam[1:] - lam[:-1] <= 1e-3 * scale))[0]
    if k.size:  # is the midpoint on the line within tol of the surface?
        Xm = O[li[k]] + 0.5 * (lam[k] + lam[k + 1])[:, None] * D[li[k]]
        join[k] = closest_point_surface(surface, Xm, start=(u[k], v[k]))[3] <= tol
    sel = _best_of_runs(join, dist)
    return LineSurfaceHits(li[sel], lam[sel], u[sel], v[sel], S[sel], dist[sel])


def intersect_line_surface(origin, direction, surface: NurbsSurface, **kwargs) -> LineSurfaceHits:
    """Every intersection of one line with a surface (:func:`intersect_lines_surface`)."""
    return intersect_lines_surface(np.reshape(origin, (1, 3)), np.reshape(direction, (1, 3)),
                                   surface, **kwargs)
