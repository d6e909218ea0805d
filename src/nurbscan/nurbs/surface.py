"""Tensor-product NURBS surfaces: evaluation, derivatives, normals and knot operations.

``S(u, v) = sum_i sum_j N_ip(u) N_jq(v) w_ij P_ij / sum_i sum_j N_ip(u) N_jq(v) w_ij``
(Piegl and Tiller, *The NURBS Book*, 2nd ed., eq. 4.15), evaluated in homogeneous form.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from math import comb

import numpy as np

from ..errors import NurbscanError
from .basis import (
    basis_function_derivatives,
    basis_functions,
    basis_matrix,
    find_span,
    validate_knots,
)
from .curve import _CHUNK, NurbsCurve, _as_param, _readonly, elevate_degree_h, insert_knot_h

__all__ = ["NurbsSurface"]

SURFACE_TYPE = "nurbscan.nurbs_surface"


def _direction(direction: str) -> int:
    if direction not in ("u", "v"):
        raise NurbscanError(f"direction: expected 'u' or 'v', got {direction!r}")
    return 0 if direction == "u" else 1


@dataclass(frozen=True, eq=False)
class NurbsSurface:
    """A tensor-product NURBS surface (The NURBS Book eq. 4.15).

    Parameters
    ----------
    degree_u, degree_v : int
        Degrees ``p`` and ``q``.
    knots_u : array_like, shape (nu + p + 1,)
    knots_v : array_like, shape (nv + q + 1,)
    control_points : array_like, shape (nu, nv, d)
        Control net; ``control_points[i, j]`` multiplies ``N_ip(u) N_jq(v)`` (mm for 3-D).
    weights : array_like, shape (nu, nv), optional
        Positive weights; ones when omitted.
    """

    degree_u: int
    degree_v: int
    knots_u: np.ndarray
    knots_v: np.ndarray
    control_points: np.ndarray
    weights: np.ndarray | None = field(default=None)

    def __post_init__(self):
        P = np.asarray(self.control_points, dtype=float)
        if P.ndim != 3 or P.shape[0] < 2 or P.shape[1] < 2:
            raise NurbscanError(
                f"control_points: expected shape (nu >= 2, nv >= 2, d), got {P.shape}"
            )
        if not np.all(np.isfinite(P)):
            raise NurbscanError("control_points: must be finite")
        p, q = int(self.degree_u), int(self.degree_v)
        if not (1 <= p < P.shape[0] and 1 <= q < P.shape[1]):
            raise NurbscanError(
                f"degree: need 1 <= degree_u < {P.shape[0]} and 1 <= degree_v < {P.shape[1]}, "
                f"got ({p}, {q})"
            )
        Uu = validate_knots(self.knots_u, p, P.shape[0], "knots_u")
        Uv = validate_knots(self.knots_v, q, P.shape[1], "knots_v")
        if self.weights is None:
            w = np.ones(P.shape[:2])
        else:
            w = np.asarray(self.weights, dtype=float)
            if w.shape != P.shape[:2]:
                raise NurbscanError(f"weights: expected shape {P.shape[:2]}, got {w.shape}")
            if not np.all(np.isfinite(w)) or np.any(w <= 0):
                raise NurbscanError("weights: must be finite and positive")
        object.__setattr__(self, "degree_u", p)
        object.__setattr__(self, "degree_v", q)
        object.__setattr__(self, "knots_u", _readonly(Uu))
        object.__setattr__(self, "knots_v", _readonly(Uv))
        object.__setattr__(self, "control_points", _readonly(P))
        object.__setattr__(self, "weights", _readonly(w))

    # ------------------------------------------------------------------ properties
    @property
    def shape(self) -> tuple[int, int]:
        """Control net size ``(nu, nv)``."""
        return self.control_points.shape[:2]

    @property
    def dimension(self) -> int:
        return self.control_points.shape[2]

    @property
    def homogeneous(self) -> np.ndarray:
        """Homogeneous net ``(w P, w)``, shape ``(nu, nv, d + 1)``."""
        w = self.weights[..., None]
        return np.concatenate([self.control_points * w, w], axis=-1)

    @property
    def domain(self) -> tuple[tuple[float, float], tuple[float, float]]:
        """``((u0, u1), (v0, v1))``."""
        nu, nv = self.shape
        return (
            (float(self.knots_u[self.degree_u]), float(self.knots_u[nu])),
            (float(self.knots_v[self.degree_v]), float(self.knots_v[nv])),
        )

    @property
    def is_rational(self) -> bool:
        return bool(np.ptp(self.weights) > 0)

    @classmethod
    def from_homogeneous(cls, p: int, q: int, Uu, Uv, Pw) -> NurbsSurface:
        """Build from a homogeneous net ``(nu, nv, d + 1)``, weight last."""
        Pw = np.asarray(Pw, dtype=float)
        w = Pw[..., -1]
        if np.any(w <= 0):
            raise NurbscanError("Pw: homogeneous weights must be positive")
        return cls(p, q, Uu, Uv, Pw[..., :-1] / w[..., None], w)

    # ------------------------------------------------------------------ evaluation
    def _spans(self, u, v):
        u = _as_param(u, "u")
        v = _as_param(v, "v")
        if u.shape != v.shape:
            u, v = np.broadcast_arrays(u, v)
        nu, nv = self.shape
        su = find_span(nu - 1, self.degree_u, u, self.knots_u)
        sv = find_span(nv - 1, self.degree_v, v, self.knots_v)
        return u, v, su, sv

    def evaluate(self, u, v) -> np.ndarray:
        """Points ``S(u, v)``, shape ``(..., d)`` for ``u``, ``v`` of shape ``(...)`` (A4.3)."""
        u = _as_param(u, "u")
        v = _as_param(v, "v")
        if u.shape != v.shape:
            u, v = np.broadcast_arrays(u, v)
        if u.size > _CHUNK:  # cache-sized blocks
            fu, fv = u.ravel(), v.ravel()
            out = np.concatenate([
                self.evaluate(fu[i : i + _CHUNK], fv[i : i + _CHUNK])
                for i in range(0, fu.size, _CHUNK)
            ])
            return out.reshape(u.shape + (self.dimension,))
        u, v, su, sv = self._spans(u, v)
        p, q = self.degree_u, self.degree_v
        Nu = basis_functions(su, u, p, self.knots_u)
        Nv = basis_functions(sv, v, q, self.knots_v)
        iu = su[..., None, None] - p + np.arange(p + 1)[:, None]
        iv = sv[..., None, None] - q + np.arange(q + 1)[None, :]
        Sw = np.einsum("...i,...j,...ijc->...c", Nu, Nv, self.homogeneous[iu, iv])
        return Sw[..., :-1] / Sw[..., -1:]

    __call__ = evaluate

    def evaluate_grid(self, us, vs) -> np.ndarray:
        """Points on the grid ``us x vs``, shape ``(len(us), len(vs), d)``."""
        us = _as_param(us, "us").ravel()
        vs = _as_param(vs, "vs").ravel()
        nu, nv = self.shape
        Au = basis_matrix(us, self.degree_u, self.knots_u, nu)
        Av = basis_matrix(vs, self.degree_v, self.knots_v, nv)
        Sw = np.einsum("ai,ijc->ajc", Au, self.homogeneous)
        Sw = np.einsum("bj,ajc->abc", Av, Sw)
        return Sw[..., :-1] / Sw[..., -1:]

    def derivatives(self, u, v, order: int = 1) -> np.ndarray:
        """Partial derivatives ``d^{k+l} S / du^k dv^l`` for ``k, l <= order`` (A3.6, A4.4).

        Returns
        -------
        ndarray, shape (order + 1, order + 1, ..., d)
            ``D[k, l]``; ``D[0, 0]`` is the point.
        """
        if order < 0:
            raise NurbscanError(f"order: must be >= 0, got {order}")
        u, v, su, sv = self._spans(u, v)
        p, q = self.degree_u, self.degree_v
        Du = basis_function_derivatives(su, u, p, order, self.knots_u)
        Dv = basis_function_derivatives(sv, v, q, order, self.knots_v)
        iu = su[..., None, None] - p + np.arange(p + 1)[:, None]
        iv = sv[..., None, None] - q + np.arange(q + 1)[None, :]
        net = self.homogeneous[iu, iv]  # (..., p+1, q+1, d+1)
        Aders = np.einsum("k...i,l...j,...ijc->kl...c", Du, Dv, net)
        A = Aders[..., :-1]
        w = Aders[..., -1:]
        S = np.empty_like(A)
        for k in range(order + 1):
            for ll in range(order + 1):
                t = A[k, ll].copy()
                for j in range(1, ll + 1):
                    t -= comb(ll, j) * w[0, j] * S[k, ll - j]
                for i in range(1, k + 1):
                    t -= comb(k, i) * w[i, 0] * S[k - i, ll]
                    t2 = 0.0
                    for j in range(1, ll + 1):
                        t2 = t2 + comb(ll, j) * w[i, j] * S[k - i, ll - j]
                    t -= comb(k, i) * t2
                S[k, ll] = t / w[0, 0]
        return S

    def normal(self, u, v) -> np.ndarray:
        """Unit normals ``S_u x S_v / |S_u x S_v|``, shape ``(..., 3)`` (3-D surfaces only).

        Where a first partial vanishes (a row of control points collapsed to one point, as at
        the pole of a degenerate patch) the limit normal is used: ``S_u x S_uv`` (or
        ``S_uv x S_v``) with the sign of the one-sided limit, since ``S_v(u + h, v) ~ h S_uv``.
        Where that also vanishes the parameter is moved into the domain by ``1e-6`` of its width.
        """
        if self.dimension != 3:
            raise NurbscanError(f"normal: the surface must be 3-D, it is {self.dimension}-D")
        u, v, _, _ = self._spans(u, v)
        (u0, u1), (v0, v1) = self.domain
        n = self._normal_raw(u, v, (u0, u1), (v0, v1))
        bad = ~np.isfinite(n).all(axis=-1)
        if np.any(bad):
            du = 1e-6 * (u1 - u0)
            dv = 1e-6 * (v1 - v0)
            ub = np.where(u[bad] < 0.5 * (u0 + u1), u[bad] + du, u[bad] - du)
            vb = np.where(v[bad] < 0.5 * (v0 + v1), v[bad] + dv, v[bad] - dv)
            n2 = self._normal_raw(ub, vb, (u0, u1), (v0, v1))
            n[bad] = n2
        return n

    def _normal_raw(self, u, v, dom_u, dom_v) -> np.ndarray:
        D = self.derivatives(u, v, 1)
        Su, Sv, Suv = D[1, 0], D[0, 1], D[1, 1]
        lu = np.linalg.norm(Su, axis=-1, keepdims=True)
        lv = np.linalg.norm(Sv, axis=-1, keepdims=True)
        luv = np.linalg.norm(Suv, axis=-1, keepdims=True)
        n = np.cross(Su, Sv)
        ln = np.linalg.norm(n, axis=-1, keepdims=True)
        degenerate = ln <= 1e-9 * (lu + lv) ** 2
        # one-sided limits: S_v(u + h, v) ~ h S_uv where S_v vanishes, h > 0 at the low end
        sgn_u = np.where(u < 0.5 * (dom_u[0] + dom_u[1]), 1.0, -1.0)[..., None]
        sgn_v = np.where(v < 0.5 * (dom_v[0] + dom_v[1]), 1.0, -1.0)[..., None]
        alt = np.where(
            lv < lu, sgn_u * np.cross(Su, Suv), sgn_v * np.cross(Suv, Sv)
        )
        lalt = np.linalg.norm(alt, axis=-1, keepdims=True)
        alt_ok = lalt > 1e-9 * (lu + lv + luv) ** 2
        n = np.where(degenerate, np.where(alt_ok, alt, np.nan), n)
        ln = np.linalg.norm(n, axis=-1, keepdims=True)
        with np.errstate(invalid="ignore", divide="ignore"):
            return n / ln

    # ------------------------------------------------------------------ knot operations
    def _apply(self, direction: str, fn):
        """Apply a curve operation ``fn(p, U, Pw2d) -> (p', U', Pw2d')`` along a direction."""
        ax = _direction(direction)
        Pw = self.homogeneous
        if ax == 1:
            Pw = Pw.transpose(1, 0, 2)
        a, b, c = Pw.shape
        p = self.degree_u if ax == 0 else self.degree_v
        U = self.knots_u if ax == 0 else self.knots_v
        p2, U2, Q = fn(p, U, Pw.reshape(a, b * c))
        Q = Q.reshape(-1, b, c)
        if ax == 0:
            return NurbsSurface.from_homogeneous(p2, self.degree_v, U2, self.knots_v, Q)
        return NurbsSurface.from_homogeneous(
            self.degree_u, p2, self.knots_u, U2, Q.transpose(1, 0, 2)
        )

    def insert_knot(self, direction: str, t: float, r: int = 1) -> NurbsSurface:
        """Insert knot ``t`` ``r`` times in direction ``"u"`` or ``"v"`` (A5.3 = A5.1 per row)."""

        def fn(p, U, Pw):
            U2, Q = insert_knot_h(p, U, Pw, float(t), int(r))
            return p, U2, Q

        return self._apply(direction, fn)

    def insert_knots(self, direction: str, ts) -> NurbsSurface:
        """Insert each knot of ``ts`` once in the given direction."""
        s = self
        for t in np.atleast_1d(np.asarray(ts, dtype=float)):
            s = s.insert_knot(direction, float(t), 1)
        return s

    def elevate_degree(self, direction: str, t: int = 1) -> NurbsSurface:
        """Raise the degree in ``"u"`` or ``"v"`` by ``t``; the geometry is unchanged."""

        def fn(p, U, Pw):
            U2, Q = elevate_degree_h(p, U, Pw, int(t))
            return p + int(t), U2, Q

        return self._apply(direction, fn)

    def iso_curve(self, direction: str, t: float) -> NurbsCurve:
        """Exact iso-parametric curve.

        ``direction="u"``: the curve ``C(u) = S(u, t)`` running in u at ``v = t``;
        ``direction="v"``: the curve ``C(v) = S(t, v)`` running in v at ``u = t``.
        """
        ax = _direction(direction)
        Pw = self.homogeneous
        t = float(t)
        if ax == 0:
            q, Uv, n = self.degree_v, self.knots_v, self.shape[1]
            s = int(find_span(n - 1, q, t, Uv))
            N = basis_functions(s, t, q, Uv)
            Q = np.einsum("j,ijc->ic", N, Pw[:, s - q : s + 1])
            return NurbsCurve.from_homogeneous(self.degree_u, self.knots_u, Q)
        p, Uu, n = self.degree_u, self.knots_u, self.shape[0]
        s = int(find_span(n - 1, p, t, Uu))
        N = basis_functions(s, t, p, Uu)
        Q = np.einsum("i,ijc->jc", N, Pw[s - p : s + 1])
        return NurbsCurve.from_homogeneous(self.degree_v, self.knots_v, Q)

    def transpose(self) -> NurbsSurface:
        """Same surface with u and v swapped."""
        return NurbsSurface(
            self.degree_v,
            self.degree_u,
            self.knots_v,
            self.knots_u,
            self.control_points.transpose(1, 0, 2),
            self.weights.T,
        )

    # ------------------------------------------------------------------ serialisation
    def to_dict(self) -> dict:
        """JSON-ready dict with ``"type": "nurbscan.nurbs_surface"``."""
        return {
            "type": SURFACE_TYPE,
            "version": 1,
            "degree_u": self.degree_u,
            "degree_v": self.degree_v,
            "knots_u": self.knots_u.tolist(),
            "knots_v": self.knots_v.tolist(),
            "control_points": self.control_points.tolist(),
            "weights": self.weights.tolist(),
        }

    @classmethod
    def from_dict(cls, d: dict) -> NurbsSurface:
        """Inverse of :meth:`to_dict`."""
        if not isinstance(d, dict) or d.get("type") != SURFACE_TYPE:
            raise NurbscanError(f"nurbs surface: expected a dict with type {SURFACE_TYPE!r}")
        try:
            return cls(
                int(d["degree_u"]),
                int(d["degree_v"]),
                d["knots_u"],
                d["knots_v"],
                d["control_points"],
                d.get("weights"),
            )
        except KeyError as e:
            raise NurbscanError(f"nurbs surface: missing key {e.args[0]!r}") from None

    def __repr__(self) -> str:
        return (
            f"NurbsSurface(degree=({self.degree_u}, {self.degree_v}), shape={self.shape}, "
            f"dim={self.dimension}, rational={self.is_rational})"
        )
