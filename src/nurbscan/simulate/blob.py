"""A smooth freeform scene without symmetry: a star-shaped "blob" (issue 33).

The surface is a sphere whose radius varies smoothly with the direction,
``S(u, v) = c + f(n) n`` with ``n = (sin u cos v, sin u sin v, cos u)`` (``u`` polar angle
from +z in [0, pi], ``v`` azimuth in [0, 2 pi)) and ``f`` a polynomial in the components of the
unit vector ``n``:

``f(n) = R (1 + a1 nx + a2 ny nz + a3 (nx^2 - ny^2) + a4 nz^3 + a5 nx ny)``.

A polynomial in ``n`` is smooth on the sphere (also at the poles), ``f > 0`` keeps the surface
star-shaped about ``c`` (no self-intersection), and the mixed terms leave it without any
rotation or mirror symmetry, so that two scans of it in different poses can be aligned
unambiguously. Its derivatives follow from the chain rule through ``n(u, v)``; the generic
Newton ray refinement and closest-point search of :class:`~nurbscan.simulate.scenes.Scene`
work on it. The default centre puts its lowest point on the table top (``z = 0``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .scenes import Scene, _arc_steps, _positive, _vec3

__all__ = ["Blob"]

#: The shape's coefficients a1..a5 (relative to the mean radius).
_COEF = (0.18, 0.30, 0.15, -0.12, 0.16)


def _poly(n: np.ndarray, a=_COEF):
    """``f / R`` (N,), its gradient (N, 3) and Hessian (N, 3, 3) in ``n``."""
    x, y, z = n[:, 0], n[:, 1], n[:, 2]
    a1, a2, a3, a4, a5 = a
    f = 1 + a1 * x + a2 * y * z + a3 * (x * x - y * y) + a4 * z ** 3 + a5 * x * y
    g = np.column_stack([a1 + 2 * a3 * x + a5 * y, a2 * z - 2 * a3 * y + a5 * x,
                         a2 * y + 3 * a4 * z * z])
    H = np.zeros((len(n), 3, 3))
    H[:, 0, 0] = 2 * a3
    H[:, 1, 1] = -2 * a3
    H[:, 2, 2] = 6 * a4 * z
    H[:, 0, 1] = H[:, 1, 0] = a5
    H[:, 1, 2] = H[:, 2, 1] = a2
    return f, g, H


@dataclass(frozen=True)
class Blob(Scene):
    """The blob of mean radius ``radius`` mm about ``center`` (module notes); one surface."""

    radius: float = 50.0
    center: tuple = (-8.9174, -1.5111, 57.6620)  # lowest point on z = 0, box on the axis
    name = "blob"

    def __post_init__(self):
        object.__setattr__(self, "radius", _positive(self.radius, "blob radius"))
        object.__setattr__(self, "center", _vec3(self.center, "blob center"))

    @property
    def n_surfaces(self):
        return 1

    def _domain(self, k):
        return (0.0, math.pi, 0.0, 2 * math.pi)

    def _periodic(self, k):
        return (False, True)

    def _eval(self, k, u, v, order=1):
        u, v = np.asarray(u, float), np.asarray(v, float)
        su, cu, sv, cv = np.sin(u), np.cos(u), np.sin(v), np.cos(v)
        z0 = 0 * u
        n = np.column_stack([su * cv, su * sv, cu])
        nu = np.column_stack([cu * cv, cu * sv, -su])
        nv = np.column_stack([-su * sv, su * cv, z0])
        f, g, H = _poly(n)
        R = self.radius
        f, g, H = R * f, R * g, R * H
        c = np.array(self.center)
        out = [c + f[:, None] * n]
        if order < 1:
            return out
        fu = np.einsum("ij,ij->i", g, nu)
        fv = np.einsum("ij,ij->i", g, nv)
        out += [fu[:, None] * n + f[:, None] * nu, fv[:, None] * n + f[:, None] * nv]
        if order >= 2:
            nuu = -n
            nuv = np.column_stack([-cu * sv, cu * cv, z0])
            nvv = np.column_stack([-su * cv, -su * sv, z0])
            fuu = np.einsum("ni,nij,nj->n", nu, H, nu) + np.einsum("ij,ij->i", g, nuu)
            fuv = np.einsum("ni,nij,nj->n", nu, H, nv) + np.einsum("ij,ij->i", g, nuv)
            fvv = np.einsum("ni,nij,nj->n", nv, H, nv) + np.einsum("ij,ij->i", g, nvv)
            out += [fuu[:, None] * n + 2 * fu[:, None] * nu + f[:, None] * nuu,
                    fuv[:, None] * n + fu[:, None] * nv + fv[:, None] * nu + f[:, None] * nuv,
                    fvv[:, None] * n + 2 * fv[:, None] * nv + f[:, None] * nvv]
        return out

    def _grid_size(self, k, tol):
        # a grid as fine as for a sphere of twice the radius: the bumps' chord error is then
        # below tol (measured in the tests)
        n = _arc_steps(2.0 * self.radius, math.pi, tol)
        return n, 2 * n

    def _bounds(self):
        uu, vv = np.meshgrid(np.linspace(0, math.pi, 401), np.linspace(0, 2 * math.pi, 801))
        p = self._eval(0, uu.ravel(), vv.ravel(), 0)[0]
        pad = 1e-3 * self.radius  # the grid's chord error
        return np.array([p.min(0) - pad, p.max(0) + pad])
