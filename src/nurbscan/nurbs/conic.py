"""Conic arcs, circles and ellipses as exact rational quadratic NURBS curves.

A conic arc is the rational quadratic Bezier curve (Piegl and Tiller, *The NURBS Book*, 2nd ed.,
section 7.2, eq. 7.1; the paper's eq. 9)::

    C(u) = ((1-u)^2 P0 + 2 u (1-u) w1 P1 + u^2 P2) / ((1-u)^2 + 2 u (1-u) w1 + u^2)

with ``w0 = w2 = 1``, end points ``P0``, ``P2`` and ``P1`` the intersection of the end tangent
lines. ``w1`` is fixed by one more point ``P`` on the arc (the paper's eq. 10; book section 7.3).
Circles and ellipses are joined arcs of at most 90 degrees (A7.1 MakeNurbsCircle); an ellipse is
the affine image of a circle, so its arcs are exact too (section 7.4).
"""

from __future__ import annotations

import numpy as np

from ..errors import NurbscanError
from .curve import NurbsCurve

__all__ = ["conic_arc", "conic_weight", "tangent_intersection", "circle", "ellipse", "elliptic_arc"]


def _vec(x, name: str, dim: int | None = None) -> np.ndarray:
    a = np.asarray(x, dtype=float)
    if a.ndim != 1 or a.size < 2 or (dim is not None and a.size != dim):
        want = f"({dim},)" if dim is not None else "(2,) or (3,)"
        raise NurbscanError(f"{name}: expected a point/vector of shape {want}, got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise NurbscanError(f"{name}: must be finite")
    return a


def tangent_intersection(P0, T0, P2, T2, tol: float = 1e-9) -> np.ndarray:
    """Intersection ``P1`` of the lines ``P0 + a T0`` and ``P2 + b T2`` (A7.2 Intersect3DLines).

    Parameters
    ----------
    P0, P2 : array_like, shape (d,)
        Points on the lines (d = 2 or 3, any length unit).
    T0, T2 : array_like, shape (d,)
        Line directions (need not be unit).
    tol : float
        Relative tolerance for parallel or skew lines.

    Returns
    -------
    ndarray, shape (d,)
        ``P1`` (least-squares solution of ``P0 + a T0 = P2 + b T2``).

    Raises
    ------
    NurbscanError
        If the tangents are parallel (``P1`` at infinity) or the lines are skew.
    """
    P0, T0 = _vec(P0, "P0"), _vec(T0, "T0")
    P2, T2 = _vec(P2, "P2", P0.size), _vec(T2, "T2", P0.size)
    A = np.stack([T0, -T2], axis=1)
    n0, n2 = np.linalg.norm(T0), np.linalg.norm(T2)
    if n0 == 0 or n2 == 0:
        raise NurbscanError("T0/T2: tangent vectors must be non-zero")
    s = np.linalg.svd(A / np.array([n0, n2]), compute_uv=False)
    if s[-1] < tol:
        raise NurbscanError("T0/T2: end tangents are parallel, P1 is at infinity")
    ab, *_ = np.linalg.lstsq(A, P2 - P0, rcond=None)
    X0 = P0 + ab[0] * T0
    X2 = P2 + ab[1] * T2
    scale = max(np.linalg.norm(P2 - P0), np.linalg.norm(X0 - P0), 1e-300)
    if np.linalg.norm(X0 - X2) > tol * scale * 1e3:
        raise NurbscanError("T0/T2: the end tangent lines are skew (not coplanar)")
    return 0.5 * (X0 + X2)


def conic_weight(P0, P1, P2, P) -> tuple[float, float]:
    """Middle weight ``w1`` of the conic through ``P`` and the parameter of ``P`` (book 7.3).

    ``P - P1 = a (P0 - P1) + b (P2 - P1)`` with ``a = (1-u)^2 / D``, ``b = u^2 / D`` and
    ``D = (1-u)^2 + 2u(1-u) w1 + u^2`` (from eq. 7.1 with ``w0 = w2 = 1``), so
    ``u = sqrt(b) / (sqrt(a) + sqrt(b))`` and ``w1 = (D - (1-u)^2 - u^2) / (2 u (1-u))``. This is
    the book's shoulder-point construction (the line P1 P meets the chord P0 P2 at ratio
    ``b : a``) and the paper's eq. 10.

    Returns
    -------
    (w1, u) : float, float
        The weight (> 0 for an arc inside the triangle P0 P1 P2) and the parameter of ``P``.

    Raises
    ------
    NurbscanError
        If ``P`` is not inside the angle at ``P1`` or the weight is not positive.
    """
    P0, P1, P2, P = (np.asarray(x, dtype=float) for x in (P0, P1, P2, P))
    A = np.stack([P0 - P1, P2 - P1], axis=1)
    ab, *_ = np.linalg.lstsq(A, P - P1, rcond=None)
    a, b = float(ab[0]), float(ab[1])
    scale = max(np.linalg.norm(P0 - P1), np.linalg.norm(P2 - P1))
    if np.linalg.norm(A @ ab - (P - P1)) > 1e-9 * scale:
        raise NurbscanError("P: the point is not in the plane of P0, P1, P2")
    if not (a > 0 and b > 0):
        raise NurbscanError("P: the point is not inside the angle of the end tangents at P1")
    u = np.sqrt(b) / (np.sqrt(a) + np.sqrt(b))
    D = (1.0 - u) ** 2 / a
    w1 = (D - (1.0 - u) ** 2 - u**2) / (2.0 * u * (1.0 - u))
    if not w1 > 0:
        raise NurbscanError(f"P: gives a non-positive middle weight w1 = {w1:.6g}")
    return float(w1), float(u)


def conic_arc(P0, T0, P2, T2, P) -> NurbsCurve:
    """Conic arc through ``P0``, ``P`` and ``P2`` with end tangent directions ``T0``, ``T2``.

    The rational quadratic Bezier curve of the paper's eq. 9-10 (book section 7.3, MakeOneArc of
    A7.3 for non-parallel tangents): ``P1`` is the intersection of the tangent lines,
    ``w0 = w2 = 1`` and ``w1`` from :func:`conic_weight`. ``w1 < 1`` gives an ellipse, ``= 1`` a
    parabola, ``> 1`` a hyperbola.

    Parameters
    ----------
    P0, P2 : array_like, shape (d,)
        End points (d = 2 or 3, mm or px).
    T0, T2 : array_like, shape (d,)
        Tangent directions at ``P0`` and ``P2`` (any length; the arc leaves ``P0`` along ``T0``).
    P : array_like, shape (d,)
        A point on the arc, inside the triangle ``P0 P1 P2``.

    Returns
    -------
    NurbsCurve
        Degree 2, knots ``[0, 0, 0, 1, 1, 1]``, 3 control points, weights ``(1, w1, 1)``.
    """
    P0 = _vec(P0, "P0")
    P2, P = _vec(P2, "P2", P0.size), _vec(P, "P", P0.size)
    P1 = tangent_intersection(P0, T0, P2, T2)
    if np.dot(P1 - P0, np.asarray(T0, float)) <= 0:
        raise NurbscanError("T0: the tangent at P0 points away from the tangent intersection")
    w1, _ = conic_weight(P0, P1, P2, P)
    return NurbsCurve(2, [0, 0, 0, 1, 1, 1], np.stack([P0, P1, P2]), [1.0, w1, 1.0])


def elliptic_arc(center, x_axis, y_axis, rx: float, ry: float, start: float = 0.0,
                 end: float = 2 * np.pi) -> NurbsCurve:
    """Elliptic (or circular) arc ``O + rx cos(t) X + ry sin(t) Y``, ``t`` in [start, end].

    A7.1 (MakeNurbsCircle) generalised by the affine map ``(cos t, sin t) -> (rx cos t, ry sin t)``:
    ``n = ceil(angle / 90 deg)`` rational quadratic arcs of equal angle ``dt``, end control points
    on the ellipse, middle points ``O + (rx cos(tm) X + ry sin(tm) Y) / cos(dt / 2)`` with weight
    ``cos(dt / 2)``, double interior knots at ``k / n``. Exact: every point lies on the ellipse up
    to rounding.

    Parameters
    ----------
    center : array_like, shape (d,)
        Centre ``O`` (d = 2 or 3).
    x_axis, y_axis : array_like, shape (d,)
        Orthonormal directions of the two semi-axes (normalised here; ``y_axis`` is made
        orthogonal to ``x_axis``).
    rx, ry : float
        Semi-axis lengths (> 0, units of ``center``).
    start, end : float
        Angles in radians, ``0 < end - start <= 2 pi``.

    Returns
    -------
    NurbsCurve
        Degree 2 on the domain [0, 1], ``2 n + 1`` control points.
    """
    O = _vec(center, "center")
    X = _vec(x_axis, "x_axis", O.size)
    Y = _vec(y_axis, "y_axis", O.size)
    nx = np.linalg.norm(X)
    if nx == 0:
        raise NurbscanError("x_axis: must be non-zero")
    X = X / nx
    Y = Y - np.dot(Y, X) * X
    ny = np.linalg.norm(Y)
    if ny < 1e-12 * max(1.0, np.linalg.norm(_vec(y_axis, "y_axis"))):
        raise NurbscanError("y_axis: must not be parallel to x_axis")
    Y = Y / ny
    if not (rx > 0 and ry > 0 and np.isfinite(rx) and np.isfinite(ry)):
        raise NurbscanError(f"rx/ry: radii must be finite and positive, got {rx}, {ry}")
    theta = float(end) - float(start)
    if not 0 < theta <= 2 * np.pi + 1e-12:
        raise NurbscanError(f"start/end: need 0 < end - start <= 2 pi, got {theta}")
    narcs = int(np.clip(np.ceil(theta / (np.pi / 2) - 1e-12), 1, 4))
    dt = theta / narcs
    t_end = start + dt * np.arange(narcs + 1)
    t_mid = t_end[:-1] + 0.5 * dt
    wm = np.cos(dt / 2)

    def pt(t, scale=1.0):
        return O + scale * (rx * np.cos(t)[:, None] * X + ry * np.sin(t)[:, None] * Y)

    P = np.empty((2 * narcs + 1, O.size))
    P[0::2] = pt(t_end)
    P[1::2] = pt(t_mid, 1.0 / wm)
    if abs(theta - 2 * np.pi) < 1e-12:
        P[-1] = P[0]
    w = np.ones(2 * narcs + 1)
    w[1::2] = wm
    inner = np.repeat(np.arange(1, narcs) / narcs, 2)
    U = np.concatenate([[0.0, 0.0, 0.0], inner, [1.0, 1.0, 1.0]])
    return NurbsCurve(2, U, P, w)


def _plane_axes(normal, x_axis, dim: int):
    if dim == 2:
        X = np.array([1.0, 0.0]) if x_axis is None else _vec(x_axis, "x_axis", 2)
        X = X / np.linalg.norm(X)
        return X, np.array([-X[1], X[0]])
    N = np.array([0.0, 0.0, 1.0]) if normal is None else _vec(normal, "normal", 3)
    nn = np.linalg.norm(N)
    if nn == 0:
        raise NurbscanError("normal: must be non-zero")
    N = N / nn
    if x_axis is None:
        e = np.eye(3)[int(np.argmin(np.abs(N)))]
        X = e - np.dot(e, N) * N
    else:
        X = _vec(x_axis, "x_axis", 3)
        X = X - np.dot(X, N) * N
        if np.linalg.norm(X) < 1e-12:
            raise NurbscanError("x_axis: must not be parallel to the normal")
    X = X / np.linalg.norm(X)
    return X, np.cross(N, X)


def circle(center, radius: float, normal=None, x_axis=None) -> NurbsCurve:
    """Full circle of ``radius`` about ``center`` as 4 rational quadratic arcs (A7.1).

    Parameters
    ----------
    center : array_like, shape (2,) or (3,)
        Centre (mm or px).
    radius : float
        Radius (> 0, same unit).
    normal : array_like, shape (3,), optional
        Plane normal for a 3-D circle (default +z); the circle runs counter-clockwise about it.
        Ignored in 2-D (the circle runs from +x towards +y).
    x_axis : array_like, shape (d,), optional
        Direction of the start point ``C(0) - center`` (projected into the plane).

    Returns
    -------
    NurbsCurve
        Degree 2, 9 control points, knots ``[0,0,0,1/4,1/4,1/2,1/2,3/4,3/4,1,1,1]``, weights
        ``1, sqrt(2)/2, 1, ...``; ``C(0) = C(1)``.
    """
    O = _vec(center, "center")
    X, Y = _plane_axes(normal, x_axis, O.size)
    return elliptic_arc(O, X, Y, radius, radius)


def ellipse(center, rx: float, ry: float, normal=None, x_axis=None) -> NurbsCurve:
    """Full ellipse ``O + rx cos(t) X + ry sin(t) Y`` as 4 rational quadratic arcs (A7.1, 7.4).

    Parameters as :func:`circle`; ``rx`` is the semi-axis along ``x_axis``, ``ry`` the one along
    ``normal x x_axis`` (2-D: along +90 degrees from ``x_axis``).
    """
    O = _vec(center, "center")
    X, Y = _plane_axes(normal, x_axis, O.size)
    return elliptic_arc(O, X, Y, rx, ry)
