"""The shape of a printed board's white part: a smooth height field over the board's plane.

A checkerboard printed on paper and glued on a larger white board is flat where the squares
are (its corners define the board frame, ``z = 0``), but the white board around it, where the
projected grid is read, need not be: foam or card bows and cockles by a millimetre or more,
and the paper adds its thickness. With the white part taken as the plane of the corners, the
projector residuals carry that shape: on the shared real set (benchmarks/real_procam.py) one
height field common to all eight poses, fitted in the board frame, explains most of them and
predicts the residuals of a pose left out of its fit (docs/accuracy.md, "Real photographs").
Huang, Ozdemir, Tang, Liao and Ling ("A single-shot-per-pose camera-projector calibration
system for imperfect planar targets", ISMAR 2018 adjunct, arXiv:1803.09058) free each grid
point's 3-D position in their bundle; here the white part is one
smooth surface shared by all poses, fitted in the bundle with the rig
(:func:`nurbscan.calibrate._bundle.run_bundle`):

    z = h(x, y) = sum_ij c_ij B_i(x) B_j(y)          (board frame, mm)

a tensor-product cubic B-spline (de Boor, A practical guide to splines, 1978) on uniform knots
over the board points' extent, with a roughness penalty on the second differences of its
coefficients (P-splines: Eilers and Marx, Statistical Science 11(2), 1996), whose null space is
the planes, so that data and not the penalty fix the surface's offset and tilt.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import sparse
from scipy.interpolate import BSpline

from ._tsai import back_project_local, rotmats

DEGREE = 3


def _knots(lo: float, hi: float, spacing: float) -> np.ndarray:
    """Uniform knots with spans of at most ``spacing`` whose basis covers [lo, hi], extended
    by ``DEGREE`` spans on each side (Eilers and Marx: with equal spans the coefficients'
    Greville abscissae are equally spaced, so a plane has zero second differences)."""
    n = max(int(np.ceil((hi - lo) / spacing)), 1)
    h = (hi - lo) / n
    return lo + h * np.arange(-DEGREE, n + DEGREE + 1)


@dataclass(frozen=True)
class BoardSurface:
    """Height field of the board's white part over the board plane (module notes).

    Attributes
    ----------
    tx, ty : ndarray
        Uniform knot vectors along the board's x and y, mm (:func:`_knots`); the surface is
        defined over ``[tx[3], tx[-4]] x [ty[3], ty[-4]]``.
    coef : ndarray, shape (nx * ny,)
        B-spline coefficients, mm (x index slow, y index fast); zero: the plane of the corners.
    """

    tx: np.ndarray
    ty: np.ndarray
    coef: np.ndarray

    @property
    def shape(self) -> tuple[int, int]:
        """Coefficients along x and along y."""
        return len(self.tx) - DEGREE - 1, len(self.ty) - DEGREE - 1

    @classmethod
    def spanning(cls, xy: np.ndarray, spacing: float, pad: float = 1.0) -> BoardSurface:
        """A flat surface (zero coefficients) whose knots span the board points ``xy`` (K, 2),
        mm, widened by ``pad`` mm, with knot spans of at most ``spacing`` mm."""
        xy = np.asarray(xy, float)
        lo, hi = xy.min(axis=0) - pad, xy.max(axis=0) + pad
        tx, ty = _knots(lo[0], hi[0], spacing), _knots(lo[1], hi[1], spacing)
        n = (len(tx) - DEGREE - 1) * (len(ty) - DEGREE - 1)
        return cls(tx, ty, np.zeros(n))

    def with_coef(self, coef: np.ndarray) -> BoardSurface:
        """The same knots with other coefficients."""
        return BoardSurface(self.tx, self.ty, np.asarray(coef, float).copy())

    def greville(self) -> tuple[np.ndarray, np.ndarray]:
        """Greville abscissae along x and y (mm): the coefficients ``a + b x_i + c y_j``
        reproduce the plane ``a + b x + c y`` exactly."""
        gx = np.convolve(self.tx[1:-1], np.ones(DEGREE) / DEGREE, mode="valid")
        gy = np.convolve(self.ty[1:-1], np.ones(DEGREE) / DEGREE, mode="valid")
        return gx, gy

    def basis(self, xy: np.ndarray) -> sparse.csr_matrix:
        """Basis matrix (K, nx * ny): row k holds ``B_i(x_k) B_j(y_k)`` (points outside the
        surface's span are clamped to its edge)."""
        xy = np.asarray(xy, float)
        k = DEGREE
        x = np.clip(xy[:, 0], self.tx[k], np.nextafter(self.tx[-k - 1], -np.inf))
        y = np.clip(xy[:, 1], self.ty[k], np.nextafter(self.ty[-k - 1], -np.inf))
        bx = BSpline.design_matrix(x, self.tx, DEGREE).tocsr()
        by = BSpline.design_matrix(y, self.ty, DEGREE).tocsr()
        # row-wise Kronecker product of the two sparse rows (4 x 4 non-zeros a row)
        nx, ny = bx.shape[1], by.shape[1]
        bxc, byc = bx.tocoo(), by.tocoo()
        ox = np.argsort(bxc.row, kind="stable")
        oy = np.argsort(byc.row, kind="stable")
        k = DEGREE + 1
        rx, cx, vx = (a[ox].reshape(-1, k) for a in (bxc.row, bxc.col, bxc.data))
        cy, vy = (a[oy].reshape(-1, k) for a in (byc.col, byc.data))
        rows = np.repeat(rx[:, 0], k * k)
        cols = (cx[:, :, None] * ny + cy[:, None, :]).ravel()
        vals = (vx[:, :, None] * vy[:, None, :]).ravel()
        return sparse.csr_matrix((vals, (rows, cols)), shape=(len(xy), nx * ny))

    def height(self, xy: np.ndarray) -> np.ndarray:
        """``h(x, y)`` (K,) mm at board points ``xy`` (K, 2) mm."""
        return self.basis(xy) @ self.coef

    def roughness(self) -> sparse.csr_matrix:
        """Second differences of the coefficient grid along x and along y (the P-spline
        penalty matrix, rows: differences, columns: coefficients)."""
        nx, ny = self.shape
        rows = []
        for n, other, first in ((nx, ny, True), (ny, nx, False)):
            if n < 3:
                continue
            d = sparse.diags([1.0, -2.0, 1.0], [0, 1, 2], shape=(n - 2, n))
            eye = sparse.identity(other)
            rows.append(sparse.kron(d, eye) if first else sparse.kron(eye, d))
        if not rows:
            return sparse.csr_matrix((0, nx * ny))
        return sparse.vstack(rows).tocsr()


def surface_points(kc, rvecs, tvecs, pixels, view, dx, dy, surface: BoardSurface | None,
                   iterations: int = 3, offset: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Where the camera rays of ``pixels`` (K, 2) meet their view's board surface.

    The ray meets the plane ``z = 0`` of its view's board (pose ``rvecs[view]``,
    ``tvecs[view]``: board frame -> camera frame), then, ``iterations`` times, the plane
    ``z = h(x, y)`` at the height of the surface under the last point (a fixed-point iteration
    that converges at once for heights of millimetres and slopes of a few per cent).
    ``offset`` (mm) is added to every height (the derivative of a residual with respect to
    the height under its point, for the bundle's Jacobian).

    Returns
    -------
    X : ndarray (K, 3)
        Camera-frame points, mm.
    xy : ndarray (K, 2)
        Their board-frame x, y, mm.
    """
    d = back_project_local(np.asarray(pixels, float), kc, dx, dy)
    R = rotmats(rvecs)[view]
    n = R[:, :, 2]
    t = tvecs[view]
    nt = np.einsum("ki,ki->k", n, t)
    nd = np.einsum("ki,ki->k", n, d)
    h = np.zeros(len(d))
    steps = 1 + (iterations if surface is not None else 0)
    for i in range(steps):
        with np.errstate(divide="ignore", invalid="ignore"):
            X = d * ((nt + h) / nd)[:, None]
        xy = np.einsum("kji,kj->ki", R, X - t)[:, :2]
        if i < steps - 1:
            h = surface.height(np.nan_to_num(xy)) + offset
    return X, xy
