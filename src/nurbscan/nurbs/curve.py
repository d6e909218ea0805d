"""NURBS curves: evaluation, derivatives and knot operations in homogeneous form.

A NURBS curve of degree ``p`` with control points ``P_i`` (shape ``(n + 1, d)``), weights ``w_i``
and knot vector ``U`` is ``C(u) = sum N_ip(u) w_i P_i / sum N_ip(u) w_i`` (the paper's eq. 1-4).
Every operation works on the homogeneous points ``P^w_i = (w_i P_i, w_i)`` where
``C^w(u) = sum N_ip(u) P^w_i`` is a polynomial B-spline (Piegl and Tiller, *The NURBS Book*,
2nd ed., section 4.2).

The module-level ``*_h`` functions act on homogeneous control arrays of shape ``(n + 1, k)``
(any ``k``) so that :mod:`nurbscan.nurbs.surface` can apply them to rows or columns of a net.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from math import comb

import numpy as np
from scipy.linalg import solve_banded

from ..errors import NurbscanError
from .basis import (
    basis_function_derivatives,
    basis_functions,
    basis_matrix,
    find_span,
    greville_abscissae,
    validate_knots,
)

__all__ = [
    "NurbsCurve",
    "evaluate_many",
    "evaluate_pieces",
    "insert_knot_h",
    "elevate_degree_h",
    "remove_knot_h",
    "rational_derivatives",
]

CURVE_TYPE = "nurbscan.nurbs_curve"
_CHUNK = 1 << 14  # parameters evaluated per block


def _readonly(a: np.ndarray) -> np.ndarray:
    a = np.array(a, dtype=float)
    a.setflags(write=False)
    return a


def _as_param(u, name: str = "u") -> np.ndarray:
    u = np.asarray(u, dtype=float)
    if not np.all(np.isfinite(u)):
        raise NurbscanError(f"{name}: parameters must be finite")
    return u


def insert_knot_h(p: int, U: np.ndarray, Pw: np.ndarray, u: float, r: int = 1):
    """Insert knot ``u`` ``r`` times into a B-spline with control array ``Pw`` (A5.1).

    Parameters
    ----------
    p : int
        Degree.
    U : ndarray, shape (n + p + 2,)
        Knot vector.
    Pw : ndarray, shape (n + 1, k)
        Homogeneous control points (or any values attached to the basis).
    u : float
        Knot to insert, strictly inside the domain or equal to an interior knot.
    r : int
        Number of insertions; the multiplicity ``s`` of ``u`` must satisfy ``s + r <= p``.

    Returns
    -------
    (U_new, Pw_new) : ndarray (n + p + 2 + r,), ndarray (n + 1 + r, k)
    """
    n = Pw.shape[0] - 1
    if not (U[p] < u < U[n + 1]):
        raise NurbscanError(f"u: knot {u} is not inside the domain ({U[p]}, {U[n + 1]})")
    s = int(np.count_nonzero(U == u))
    if r < 0 or s + r > p:
        raise NurbscanError(f"r: cannot insert {u} {r} times (multiplicity {s}, degree {p})")
    if r == 0:
        return U.copy(), Pw.copy()
    k = int(find_span(n, p, u, U))
    UQ = np.concatenate([U[: k + 1], np.full(r, u), U[k + 1 :]])
    Q = np.empty((n + 1 + r,) + Pw.shape[1:])
    Q[: k - p + 1] = Pw[: k - p + 1]
    Q[k - s + r :] = Pw[k - s :]
    R = Pw[k - p : k - s + 1].copy()
    L = k - p
    for j in range(1, r + 1):
        L = k - p + j
        i = np.arange(p - j - s + 1)
        alpha = (u - U[L + i]) / (U[i + k + 1] - U[L + i])
        alpha = alpha.reshape((-1,) + (1,) * (Pw.ndim - 1))
        R[: p - j - s + 1] = alpha * R[1 : p - j - s + 2] + (1.0 - alpha) * R[: p - j - s + 1]
        Q[L] = R[0]
        Q[k + r - j - s] = R[p - j - s]
    for i in range(L + 1, k - s):
        Q[i] = R[i - L]
    return UQ, Q


def remove_knot_h(p: int, U: np.ndarray, Pw: np.ndarray, u: float, num: int, tol: float):
    """Remove knot ``u`` up to ``num`` times within tolerance ``tol`` (A5.8).

    Each removal is accepted when the removal bound (the distance of eq. 5.28/5.29 checked in
    A5.8, the paper's eq. 5) between the control point computed from the left and from the right
    is at most ``tol`` (a distance in the space of ``Pw``).

    Returns
    -------
    (U_new, Pw_new, t) : knots, control array and the number ``t`` of removals done.
    """
    U = np.array(U, dtype=float)
    P = np.array(Pw, dtype=float)
    n = P.shape[0] - 1
    m = U.size - 1
    s = int(np.count_nonzero(U == u))
    if s == 0 or not (U[p] < u < U[n + 1]):
        raise NurbscanError(f"u: {u} is not an interior knot")
    num = min(int(num), s)
    r = int(np.nonzero(U == u)[0][-1])
    order = p + 1
    fout = (2 * r - s - p) // 2
    last = r - s
    first = r - p
    temp = np.zeros((2 * p + 1,) + P.shape[1:])
    t = 0
    while t < num:
        off = first - 1
        temp[0] = P[off]
        temp[last + 1 - off] = P[last + 1]
        i, j = first, last
        ii, jj = 1, last - off
        while j - i > t:
            alfi = (u - U[i]) / (U[i + order + t] - U[i])
            alfj = (u - U[j - t]) / (U[j + order] - U[j - t])
            temp[ii] = (P[i] - (1.0 - alfi) * temp[ii - 1]) / alfi
            temp[jj] = (P[j] - alfj * temp[jj + 1]) / (1.0 - alfj)
            i += 1
            ii += 1
            j -= 1
            jj -= 1
        if j - i < t:
            ok = np.linalg.norm(temp[ii - 1] - temp[jj + 1]) <= tol
        else:
            alfi = (u - U[i]) / (U[i + order + t] - U[i])
            blend = alfi * temp[ii + t + 1] + (1.0 - alfi) * temp[ii - 1]
            ok = np.linalg.norm(P[i] - blend) <= tol
        if not ok:
            break
        i, j = first, last
        while j - i > t:
            P[i] = temp[i - off]
            P[j] = temp[j - off]
            i += 1
            j -= 1
        first -= 1
        last += 1
        t += 1
    if t == 0:
        return U, P, 0
    U = np.concatenate([U[: r + 1 - t], U[r + 1 :]])
    j = fout
    i = j
    for k in range(1, t):
        if k % 2 == 1:
            i += 1
        else:
            j -= 1
    P = np.concatenate([P[:j], P[i + 1 :]])
    assert U.size == m + 1 - t and P.shape[0] == n + 1 - t
    return U, P, t


def elevate_degree_h(p: int, U: np.ndarray, Pw: np.ndarray, t: int):
    """Raise the degree of a B-spline by ``t`` (The NURBS Book section 5.5).

    The elevated curve lives in the spline space of degree ``p + t`` whose knot vector repeats
    every distinct knot ``t`` more times; its control points are found exactly by collocation at
    the Greville abscissae of that space (Schoenberg-Whitney holds there, so the banded system is
    regular and well conditioned). The result is the same as A5.9's up to rounding.

    Returns
    -------
    (U_new, Pw_new)
    """
    if t < 0:
        raise NurbscanError(f"t: degree elevation must be >= 0, got {t}")
    if t == 0:
        return U.copy(), Pw.copy()
    vals, counts = np.unique(U, return_counts=True)
    Unew = np.repeat(vals, counts + t)
    q = p + t
    n_new = Unew.size - q - 1
    xi = greville_abscissae(Unew, q)
    n = Pw.shape[0] - 1
    span = find_span(n, p, xi, U)
    N = basis_functions(span, xi, p, U)
    idx = span[:, None] - p + np.arange(p + 1)
    flat = Pw.reshape(Pw.shape[0], -1)
    rhs = np.einsum("kj,kjc->kc", N, flat[idx])
    Q = collocation_solve(xi, q, Unew, n_new, rhs)
    # the end points are interpolated exactly; keep them bit-exact
    Q[0] = flat[0]
    Q[-1] = flat[-1]
    return Unew, Q.reshape((n_new,) + Pw.shape[1:])


def collocation_solve(x, p: int, U: np.ndarray, n_ctrl: int, rhs: np.ndarray) -> np.ndarray:
    """Control values ``P`` with ``sum_i N_ip(x_k) P_i = rhs_k`` (square, banded system).

    ``x`` must have ``n_ctrl`` values with ``|k - span(x_k) + p/2|`` small, as the Greville
    abscissae do (then ``N_ip(x_k) = 0`` for ``|k - i| > p``); solved with a banded LU.
    """
    span = find_span(n_ctrl - 1, p, x, U)
    N = basis_functions(span, x, p, U)
    k = np.arange(x.size)[:, None]
    cols = span[:, None] - p + np.arange(p + 1)
    band = k - cols
    if np.any(np.abs(band) > p):
        A = basis_matrix(x, p, U, n_ctrl)
        return np.linalg.solve(A, rhs)
    ab = np.zeros((2 * p + 1, n_ctrl))
    ab[p + band, cols] = N
    return solve_banded((p, p), ab, rhs, check_finite=False)


def rational_derivatives(Aders: np.ndarray) -> np.ndarray:
    """Derivatives of ``C = A / w`` from those of the homogeneous curve ``(A, w)`` (A4.2, eq. 4.8).

    Parameters
    ----------
    Aders : ndarray, shape (order + 1, ..., d + 1)
        Derivatives of the homogeneous curve, the weight last.

    Returns
    -------
    ndarray, shape (order + 1, ..., d)
    """
    A = Aders[..., :-1]
    w = Aders[..., -1:]
    CK = np.empty_like(A)
    for k in range(Aders.shape[0]):
        v = A[k].copy()
        for i in range(1, k + 1):
            v -= comb(k, i) * w[i] * CK[k - i]
        CK[k] = v / w[0]
    return CK


@dataclass(frozen=True, eq=False)
class NurbsCurve:
    """A NURBS curve ``C(u) = sum N_ip(u) w_i P_i / sum N_ip(u) w_i`` (paper eq. 1-4).

    Parameters
    ----------
    degree : int
        Degree ``p >= 1``.
    knots : array_like, shape (n + p + 2,)
        Non-decreasing knot vector ``U``.
    control_points : array_like, shape (n + 1, d)
        Control points in any dimension ``d >= 1`` (units of the data: px for image curves,
        mm for 3-D curves).
    weights : array_like, shape (n + 1,), optional
        Positive weights; ones (a non-rational B-spline) when omitted.
    """

    degree: int
    knots: np.ndarray
    control_points: np.ndarray
    weights: np.ndarray | None = field(default=None)

    def __post_init__(self):
        P = np.asarray(self.control_points, dtype=float)
        if P.ndim != 2 or P.shape[0] < 2 or P.shape[1] < 1:
            raise NurbscanError(f"control_points: expected shape (n + 1 >= 2, d), got {P.shape}")
        if not np.all(np.isfinite(P)):
            raise NurbscanError("control_points: must be finite")
        p = int(self.degree)
        if p < 1 or p >= P.shape[0]:
            raise NurbscanError(
                f"degree: need 1 <= degree < {P.shape[0]} (control points), got {p}"
            )
        U = validate_knots(self.knots, p, P.shape[0])
        if self.weights is None:
            w = np.ones(P.shape[0])
        else:
            w = np.asarray(self.weights, dtype=float)
            if w.shape != (P.shape[0],):
                raise NurbscanError(f"weights: expected shape ({P.shape[0]},), got {w.shape}")
            if not np.all(np.isfinite(w)) or np.any(w <= 0):
                raise NurbscanError("weights: must be finite and positive")
        object.__setattr__(self, "degree", p)
        object.__setattr__(self, "knots", _readonly(U))
        object.__setattr__(self, "control_points", _readonly(P))
        object.__setattr__(self, "weights", _readonly(w))

    # ------------------------------------------------------------------ properties
    @property
    def n_ctrl(self) -> int:
        """Number of control points ``n + 1``."""
        return self.control_points.shape[0]

    @property
    def dimension(self) -> int:
        """Dimension ``d`` of the control points."""
        return self.control_points.shape[1]

    @property
    def homogeneous(self) -> np.ndarray:
        """Homogeneous control points ``P^w_i = (w_i P_i, w_i)``, shape ``(n + 1, d + 1)``."""
        w = self.weights[:, None]
        return np.hstack([self.control_points * w, w])

    @property
    def domain(self) -> tuple[float, float]:
        """Parameter domain ``(U[p], U[n + 1])``."""
        return float(self.knots[self.degree]), float(self.knots[self.n_ctrl])

    @property
    def is_rational(self) -> bool:
        """True when the weights are not all equal."""
        return bool(np.ptp(self.weights) > 0)

    @classmethod
    def from_homogeneous(cls, degree: int, knots, Pw) -> NurbsCurve:
        """Build a curve from homogeneous control points ``(n + 1, d + 1)``, weight last."""
        Pw = np.asarray(Pw, dtype=float)
        w = Pw[:, -1]
        if np.any(w <= 0):
            raise NurbscanError("Pw: homogeneous weights must be positive")
        return cls(degree, knots, Pw[:, :-1] / w[:, None], w)

    # ------------------------------------------------------------------ evaluation
    def evaluate(self, u) -> np.ndarray:
        """Points ``C(u)``, shape ``(..., d)`` for ``u`` of shape ``(...)`` (A4.1, vectorised).

        Parameters outside the domain are evaluated on the end spans (polynomial extension).
        """
        u = _as_param(u)
        if u.size > _CHUNK:  # cache-sized blocks: about twice as fast for 10^6 parameters
            flat = u.ravel()
            out = np.concatenate(
                [self.evaluate(flat[i : i + _CHUNK]) for i in range(0, flat.size, _CHUNK)]
            )
            return out.reshape(u.shape + (self.dimension,))
        p, U = self.degree, self.knots
        span = find_span(self.n_ctrl - 1, p, u, U)
        N = basis_functions(span, u, p, U)
        idx = span[..., None] - p + np.arange(p + 1)
        Pw = self.homogeneous
        Cw = np.einsum("...j,...jc->...c", N, Pw[idx])
        return Cw[..., :-1] / Cw[..., -1:]

    __call__ = evaluate

    def derivatives(self, u, order: int = 1) -> np.ndarray:
        """Point and derivatives ``d^k C / du^k`` for ``k = 0 .. order`` (A3.2 and A4.2).

        Returns
        -------
        ndarray, shape (order + 1, ..., d)
        """
        u = _as_param(u)
        if order < 0:
            raise NurbscanError(f"order: must be >= 0, got {order}")
        p, U = self.degree, self.knots
        span = find_span(self.n_ctrl - 1, p, u, U)
        D = basis_function_derivatives(span, u, p, order, U)
        idx = span[..., None] - p + np.arange(p + 1)
        Aders = np.einsum("k...j,...jc->k...c", D, self.homogeneous[idx])
        return rational_derivatives(Aders)

    def tangent(self, u) -> np.ndarray:
        """Unit tangent vectors ``C'(u) / |C'(u)|``, shape ``(..., d)``."""
        d1 = self.derivatives(u, 1)[1]
        nrm = np.linalg.norm(d1, axis=-1, keepdims=True)
        return d1 / np.where(nrm > 0, nrm, 1.0)

    # ------------------------------------------------------------------ knot operations
    def insert_knot(self, u: float, r: int = 1) -> NurbsCurve:
        """Insert knot ``u`` ``r`` times (A5.1); the geometry is unchanged."""
        U, Q = insert_knot_h(self.degree, self.knots, self.homogeneous, float(u), int(r))
        return NurbsCurve.from_homogeneous(self.degree, U, Q)

    def insert_knots(self, us) -> NurbsCurve:
        """Insert each knot of ``us`` once, in turn (knot refinement as repeated A5.1)."""
        U, Q = np.array(self.knots), self.homogeneous
        for u in np.atleast_1d(np.asarray(us, dtype=float)):
            U, Q = insert_knot_h(self.degree, U, Q, float(u), 1)
        return NurbsCurve.from_homogeneous(self.degree, U, Q)

    def remove_knot(self, u: float, num: int = 1, tol: float = 1e-9) -> tuple[NurbsCurve, int]:
        """Remove knot ``u`` up to ``num`` times while the curve moves by at most ``tol`` (A5.8).

        The removal test of A5.8 compares homogeneous points. For a non-rational curve the
        tolerance is used as it is; for a rational curve it becomes
        ``tol * w_min / (1 + |P|_max)`` (eq. 5.30), which bounds the deviation of the curve by
        ``tol`` (in the units of the control points).

        Returns
        -------
        (curve, removed) : the new curve and the number of removals done (0 .. num).
        """
        if self.is_rational:
            wmin = float(self.weights.min())
            pmax = float(np.linalg.norm(self.control_points, axis=1).max())
            TOL = tol * wmin / (1.0 + pmax)
        else:
            TOL = tol
        U, Q, t = remove_knot_h(self.degree, self.knots, self.homogeneous, float(u), num, TOL)
        if t == 0:
            return self, 0
        return NurbsCurve.from_homogeneous(self.degree, U, Q), t

    def elevate_degree(self, t: int = 1) -> NurbsCurve:
        """Raise the degree by ``t`` without changing the geometry (section 5.5)."""
        U, Q = elevate_degree_h(self.degree, self.knots, self.homogeneous, int(t))
        return NurbsCurve.from_homogeneous(self.degree + int(t), U, Q)

    def split(self, u: float) -> tuple[NurbsCurve, NurbsCurve]:
        """Split at interior parameter ``u`` into curves on ``[a, u]`` and ``[u, b]`` (A5.1).

        The knot is inserted until its multiplicity is ``p``; the common control point is
        ``C(u)``.
        """
        a, b = self.domain
        u = float(u)
        if not a < u < b:
            raise NurbscanError(f"u: split parameter {u} is not inside ({a}, {b})")
        p = self.degree
        s = int(np.count_nonzero(self.knots == u))
        U, Q = insert_knot_h(p, self.knots, self.homogeneous, u, max(p - s, 0))
        k = int(np.nonzero(U == u)[0][-1])
        left = NurbsCurve.from_homogeneous(p, np.append(U[: k + 1], u), Q[: k - p + 1])
        right = NurbsCurve.from_homogeneous(p, np.insert(U[k - p + 1 :], 0, u), Q[k - p :])
        return left, right

    def reparametrize(self, a: float = 0.0, b: float = 1.0) -> NurbsCurve:
        """Same curve with the knots mapped linearly so that the domain is ``[a, b]``."""
        if not b > a:
            raise NurbscanError(f"reparametrize: need b > a, got [{a}, {b}]")
        u0, u1 = self.domain
        U = a + (np.asarray(self.knots) - u0) * ((b - a) / (u1 - u0))
        U[self.degree] = a
        U[self.n_ctrl] = b
        U[: self.degree] = np.minimum(U[: self.degree], a)
        U[self.n_ctrl :] = np.maximum(U[self.n_ctrl :], b)
        return NurbsCurve(self.degree, U, self.control_points, self.weights)

    def reverse(self) -> NurbsCurve:
        """Same point set traversed backwards: ``C_r(u) = C(a + b - u)`` on the same domain."""
        a, b = self.domain
        U = (a + b) - np.asarray(self.knots)[::-1]
        return NurbsCurve(
            self.degree, U, self.control_points[::-1], self.weights[::-1]
        )

    # ------------------------------------------------------------------ serialisation
    def to_dict(self) -> dict:
        """JSON-ready dict with ``"type": "nurbscan.nurbs_curve"``."""
        return {
            "type": CURVE_TYPE,
            "version": 1,
            "degree": self.degree,
            "knots": self.knots.tolist(),
            "control_points": self.control_points.tolist(),
            "weights": self.weights.tolist(),
        }

    @classmethod
    def from_dict(cls, d: dict) -> NurbsCurve:
        """Inverse of :meth:`to_dict`."""
        if not isinstance(d, dict) or d.get("type") != CURVE_TYPE:
            raise NurbscanError(f"nurbs curve: expected a dict with type {CURVE_TYPE!r}")
        try:
            return cls(int(d["degree"]), d["knots"], d["control_points"], d.get("weights"))
        except KeyError as e:
            raise NurbscanError(f"nurbs curve: missing key {e.args[0]!r}") from None

    def __repr__(self) -> str:
        return (
            f"NurbsCurve(degree={self.degree}, n_ctrl={self.n_ctrl}, dim={self.dimension}, "
            f"domain={self.domain}, rational={self.is_rational})"
        )


def evaluate_many(degree: int, knots, control_points, u, weights=None) -> np.ndarray:
    """Evaluate many curves sharing degree and knot vector at the same parameters.

    The basis functions are computed once and applied to every curve (A2.2 + A4.1).

    Parameters
    ----------
    degree : int
    knots : array_like, shape (n + p + 2,)
    control_points : array_like, shape (c, n + 1, d)
        Control points of ``c`` curves.
    u : array_like, shape (k,)
        Parameters.
    weights : array_like, shape (c, n + 1), optional

    Returns
    -------
    ndarray, shape (c, k, d)
    """
    P = np.asarray(control_points, dtype=float)
    if P.ndim != 3:
        raise NurbscanError(f"control_points: expected shape (c, n + 1, d), got {P.shape}")
    p = int(degree)
    U = validate_knots(knots, p, P.shape[1])
    u = _as_param(u).ravel()
    A = basis_matrix(u, p, U, P.shape[1])  # (k, n+1), dense but cheap for moderate n
    if weights is None:
        return np.einsum("ki,cid->ckd", A, P)
    w = np.asarray(weights, dtype=float)
    if w.shape != P.shape[:2]:
        raise NurbscanError(f"weights: expected shape {P.shape[:2]}, got {w.shape}")
    num = np.einsum("ki,cid->ckd", A, P * w[..., None])
    den = np.einsum("ki,ci->ck", A, w)
    return num / den[..., None]


def evaluate_pieces(curves, params) -> list[np.ndarray]:
    """Points of several curves of one degree, each at its own parameters, in one pass.

    The same arithmetic as :meth:`NurbsCurve.evaluate` (A2.1 span search per curve, A2.2
    basis functions and the A4.1 weighted sum over all parameters at once), so each curve's
    points are bit for bit those of ``curve.evaluate(u)``: the knot vectors and homogeneous
    control points of the curves are concatenated and every parameter indexes its own curve's
    part. The curves may differ in knots, control point count and weights.

    Parameters
    ----------
    curves : sequence of NurbsCurve
        ``c >= 1`` curves of one degree and one dimension ``d``.
    params : sequence of array_like
        ``c`` parameter arrays, shapes ``(k_i,)`` (any shape is flattened).

    Returns
    -------
    list of ndarray
        ``c`` arrays of shapes ``(k_i, d)``, units of the control points.
    """
    curves = list(curves)
    us = [_as_param(u).ravel() for u in params]
    if len(us) != len(curves) or not curves:
        raise NurbscanError(f"evaluate_pieces: {len(curves)} curves, {len(us)} parameter sets")
    p = curves[0].degree
    if any(c.degree != p or c.dimension != curves[0].dimension for c in curves):
        raise NurbscanError("evaluate_pieces: the curves must share degree and dimension")
    sizes = np.array([u.size for u in us])
    koff = np.cumsum([0] + [len(c.knots) for c in curves[:-1]])
    coff = np.cumsum([0] + [c.n_ctrl for c in curves[:-1]])
    span = [find_span(c.n_ctrl - 1, p, u, c.knots) for c, u in zip(curves, us, strict=True)]
    u = np.concatenate(us)
    local = np.concatenate(span)
    N = basis_functions(local + np.repeat(koff, sizes), u, p,
                        np.concatenate([c.knots for c in curves]))
    idx = (local + np.repeat(coff, sizes))[:, None] - p + np.arange(p + 1)
    Pw = np.concatenate([c.homogeneous for c in curves])
    Cw = np.einsum("...j,...jc->...c", N, Pw[idx])
    return np.split(Cw[:, :-1] / Cw[:, -1:], np.cumsum(sizes)[:-1])
