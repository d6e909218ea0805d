"""B-spline basis functions and knot-vector helpers, vectorised over parameters.

References: Piegl and Tiller, *The NURBS Book*, 2nd ed. (1997): A2.1 (span), A2.2 (basis
functions), A2.3 (basis functions and derivatives), eq. 9.5/9.6 (chord-length and centripetal
parameters), eq. 9.8 (averaging knots for interpolation), eq. 9.68/9.69 (knots for least-squares
approximation).

A knot vector ``U`` of a degree-``p`` B-spline with ``n + 1`` control points has
``m + 1 = n + p + 2`` non-decreasing values; the domain is ``[U[p], U[n + 1]]``.
"""

from __future__ import annotations

import numpy as np

from ..errors import NurbscanError

__all__ = [
    "averaging_knots",
    "approximation_knots",
    "basis_functions",
    "basis_function_derivatives",
    "basis_matrix",
    "chord_length_params",
    "find_span",
    "greville_abscissae",
    "knot_multiplicity",
    "uniform_knots",
    "validate_knots",
]


def validate_knots(knots, degree: int, n_ctrl: int, name: str = "knots") -> np.ndarray:
    """Check and return a knot vector as a float array of shape ``(n_ctrl + degree + 1,)``.

    Raises
    ------
    NurbscanError
        If the length does not match, values are not finite or decrease, an interior knot has
        or the domain is empty.
    """
    U = np.asarray(knots, dtype=float)
    if degree < 1:
        raise NurbscanError(f"{name}: degree must be >= 1, got {degree}")
    if U.ndim != 1 or U.size != n_ctrl + degree + 1:
        raise NurbscanError(
            f"{name}: expected {n_ctrl + degree + 1} knots for {n_ctrl} control points of degree "
            f"{degree}, got shape {U.shape}"
        )
    if not np.all(np.isfinite(U)):
        raise NurbscanError(f"{name}: knots must be finite")
    if np.any(np.diff(U) < 0):
        raise NurbscanError(f"{name}: knots must be non-decreasing")
    if not U[degree] < U[n_ctrl]:
        raise NurbscanError(f"{name}: empty domain [{U[degree]}, {U[n_ctrl]}]")
    return U


def find_span(n: int, p: int, u, U: np.ndarray) -> np.ndarray:
    """Knot span index ``i`` with ``U[i] <= u < U[i+1]`` (A2.1), vectorised.

    Parameters
    ----------
    n : int
        Index of the last control point (``n + 1`` control points).
    p : int
        Degree.
    u : array_like, shape (...)
        Parameters; values outside the domain are clamped to the first / last span.
    U : ndarray, shape (n + p + 2,)
        Knot vector.

    Returns
    -------
    ndarray of int, shape (...)
        Span indices in ``[p, n]``; ``u = U[n + 1]`` gets span ``n`` as in A2.1.
    """
    u = np.asarray(u, dtype=float)
    span = np.searchsorted(U, u, side="right") - 1
    # np.minimum / np.maximum rather than np.clip: the same integers without np.clip's
    # per-call argument checks (find_span runs thousands of times per view on short arrays)
    return np.minimum(np.maximum(span, p), n)


def basis_functions(span, u, p: int, U: np.ndarray) -> np.ndarray:
    """Non-vanishing basis functions ``N_{span-p..span, p}(u)`` (A2.2), vectorised.

    Parameters
    ----------
    span : array_like of int, shape (...)
        Span indices from :func:`find_span`.
    u : array_like, shape (...)
        Parameters.
    p : int
        Degree.
    U : ndarray
        Knot vector.

    Returns
    -------
    ndarray, shape (..., p + 1)
        ``N[..., j] = N_{span - p + j, p}(u)``; they sum to one.
    """
    u = np.asarray(u, dtype=float)
    span = np.asarray(span)
    N = [np.ones(u.shape)]  # contiguous 1-D arrays, stacked at the end
    left = [None] * (p + 1)
    right = [None] * (p + 1)
    for j in range(1, p + 1):
        left[j] = u - U[span + 1 - j]
        right[j] = U[span + j] - u
        saved = None
        for r in range(j):
            temp = N[r] / (right[r + 1] + left[j - r])
            val = right[r + 1] * temp
            N[r] = val if saved is None else val + saved
            saved = left[j - r] * temp
        N.append(saved)
    return np.stack(N, axis=-1)


def basis_function_derivatives(span, u, p: int, n_der: int, U: np.ndarray) -> np.ndarray:
    """Basis functions and their derivatives up to order ``n_der`` (A2.3), vectorised.

    Returns
    -------
    ndarray, shape (n_der + 1, ..., p + 1)
        ``D[k, ..., j] = d^k/du^k N_{span - p + j, p}(u)``; orders above ``p`` are zero.
    """
    u = np.asarray(u, dtype=float)
    span = np.asarray(span)
    shape = u.shape
    ndu = [[None] * (p + 1) for _ in range(p + 1)]
    ndu[0][0] = np.ones(shape)
    left = [None] * (p + 1)
    right = [None] * (p + 1)
    for j in range(1, p + 1):
        left[j] = u - U[span + 1 - j]
        right[j] = U[span + j] - u
        saved = np.zeros(shape)
        for r in range(j):
            ndu[j][r] = right[r + 1] + left[j - r]
            temp = ndu[r][j - 1] / ndu[j][r]
            ndu[r][j] = saved + right[r + 1] * temp
            saved = left[j - r] * temp
        ndu[j][j] = saved
    ders = np.zeros((n_der + 1,) + shape + (p + 1,))
    for j in range(p + 1):
        ders[0, ..., j] = ndu[j][p]
    kmax = min(n_der, p)
    for r in range(p + 1):
        a = [[None] * (p + 1), [None] * (p + 1)]
        s1, s2 = 0, 1
        a[0][0] = np.ones(shape)
        for k in range(1, kmax + 1):
            d = np.zeros(shape)
            rk = r - k
            pk = p - k
            if r >= k:
                a[s2][0] = a[s1][0] / ndu[pk + 1][rk]
                d = a[s2][0] * ndu[rk][pk]
            j1 = 1 if rk >= -1 else -rk
            j2 = k - 1 if r - 1 <= pk else p - r
            for j in range(j1, j2 + 1):
                a[s2][j] = (a[s1][j] - a[s1][j - 1]) / ndu[pk + 1][rk + j]
                d = d + a[s2][j] * ndu[rk + j][pk]
            if r <= pk:
                a[s2][k] = -a[s1][k - 1] / ndu[pk + 1][r]
                d = d + a[s2][k] * ndu[r][pk]
            ders[k, ..., r] = d
            s1, s2 = s2, s1
    fac = float(p)
    for k in range(1, kmax + 1):
        ders[k] *= fac
        fac *= p - k
    return ders


def basis_matrix(u, p: int, U: np.ndarray, n_ctrl: int) -> np.ndarray:
    """Dense collocation matrix ``A[k, i] = N_{i,p}(u_k)``, shape ``(len(u), n_ctrl)``."""
    u = np.asarray(u, dtype=float).ravel()
    span = find_span(n_ctrl - 1, p, u, U)
    N = basis_functions(span, u, p, U)
    A = np.zeros((u.size, n_ctrl))
    cols = span[:, None] - p + np.arange(p + 1)
    A[np.arange(u.size)[:, None], cols] = N
    return A


def knot_multiplicity(U: np.ndarray, u: float, tol: float = 0.0) -> int:
    """Number of knots equal to ``u`` (within ``tol``)."""
    return int(np.count_nonzero(np.abs(np.asarray(U) - u) <= tol))


def uniform_knots(n_ctrl: int, p: int, a: float = 0.0, b: float = 1.0) -> np.ndarray:
    """Clamped uniform knot vector on ``[a, b]`` for ``n_ctrl`` control points of degree ``p``.

    Returns
    -------
    ndarray, shape (n_ctrl + p + 1,)
        ``p + 1`` copies of ``a``, ``n_ctrl - p - 1`` equally spaced interior knots,
        ``p + 1`` copies of ``b``.
    """
    if n_ctrl < p + 1:
        raise NurbscanError(f"n_ctrl: need at least {p + 1} control points for degree {p}")
    inner = np.linspace(a, b, n_ctrl - p + 1)
    return np.concatenate([np.full(p, a), inner, np.full(p, b)])


def chord_length_params(points, centripetal: bool = False) -> np.ndarray:
    """Parameters of data points by chord length (eq. 9.5) or centripetal (eq. 9.6), in [0, 1].

    Parameters
    ----------
    points : array_like, shape (m, d)
        Data points (any unit).
    centripetal : bool
        Use square roots of the chord lengths (eq. 9.6).

    Returns
    -------
    ndarray, shape (m,)
        Non-decreasing, ``u[0] = 0``, ``u[-1] = 1``; uniform if the total length is zero.
    """
    Q = np.asarray(points, dtype=float)
    if Q.ndim != 2 or Q.shape[0] < 2:
        raise NurbscanError(f"points: expected shape (m >= 2, d), got {Q.shape}")
    d = np.linalg.norm(np.diff(Q, axis=0), axis=1)
    if centripetal:
        d = np.sqrt(d)
    total = d.sum()
    if not total > 0:
        return np.linspace(0.0, 1.0, Q.shape[0])
    u = np.concatenate([[0.0], np.cumsum(d) / total])
    u[-1] = 1.0
    return u


def averaging_knots(params, p: int) -> np.ndarray:
    """Knot vector for interpolating ``m`` points at ``params`` with degree ``p`` (eq. 9.8).

    Interior knots ``u_{j+p} = (1/p) sum_{i=j}^{j+p-1} params_i``, ``j = 1 .. m - p - 1``.
    """
    t = np.asarray(params, dtype=float)
    m = t.size
    if m < p + 1:
        raise NurbscanError(f"params: need at least {p + 1} values for degree {p}")
    c = np.concatenate([[0.0], np.cumsum(t)])
    inner = (c[p + 1 : m] - c[1 : m - p]) / p
    return np.concatenate([np.full(p + 1, t[0]), inner, np.full(p + 1, t[-1])])


def approximation_knots(params, p: int, n_ctrl: int) -> np.ndarray:
    """Knot vector for least-squares approximation with ``n_ctrl`` control points (eq. 9.68/9.69).

    ``d = (m + 1) / (n - p + 1)``, ``u_{p+j} = (1 - a) t_{i-1} + a t_i`` with ``i = int(j d)``,
    ``a = j d - i`` (``m + 1`` data parameters, ``n + 1 = n_ctrl``).
    """
    t = np.asarray(params, dtype=float)
    m1 = t.size
    n = n_ctrl - 1
    if n_ctrl < p + 1 or n_ctrl > m1:
        raise NurbscanError(f"n_ctrl: need {p + 1} <= n_ctrl <= {m1} (number of points)")
    d = m1 / (n - p + 1)
    j = np.arange(1, n - p + 1)
    jd = j * d
    i = np.floor(jd).astype(int)
    a = jd - i
    inner = (1.0 - a) * t[i - 1] + a * t[np.minimum(i, m1 - 1)]
    return np.concatenate([np.full(p + 1, t[0]), inner, np.full(p + 1, t[-1])])


def greville_abscissae(U: np.ndarray, p: int) -> np.ndarray:
    """Greville abscissae ``xi_i = (U[i+1] + ... + U[i+p]) / p``, shape ``(len(U) - p - 1,)``."""
    U = np.asarray(U, dtype=float)
    n1 = U.size - p - 1
    c = np.concatenate([[0.0], np.cumsum(U)])
    i = np.arange(n1)
    return (c[i + p + 1] - c[i + 1]) / p
