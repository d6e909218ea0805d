"""Tsai's camera model (Tsai 1987) for the camera and, used as an inverse camera, the projector.

The model is exactly the one of method.md section 4 and docs/conventions.md:

* world (rig) to camera frame: ``x = R X + T`` (mm);
* pinhole: ``Xu = f x / z``, ``Yu = f y / z`` (undistorted sensor point, mm);
* one radial term, written from *distorted* to *undistorted* (Tsai's eq. 5b):
  ``Xu = Xd (1 + k1 r^2)``, ``Yu = Yd (1 + k1 r^2)``, ``r^2 = Xd^2 + Yd^2`` (``k1`` in mm^-2);
* pixels: ``Xf = sx Xd / dx + Cx``, ``Yf = Yd / dy + Cy`` (pixel centres at integers).

Back-projection of a pixel (the paper's eq. 6-8) is closed form. Projection inverts the radial
term: with the scale ``s = Xd / Xu = rd / ru`` and ``c = k1 ru^2`` the cubic
``k1 rd^3 + rd - ru = 0`` becomes ``c s^3 + s - 1 = 0``, solved in closed form
(hyperbolic / trigonometric form of Cardano's formula, see :func:`distortion_scale`) and
polished by one Newton step, vectorised, to full double precision.

For ``k1 < 0`` the map ``rd -> ru = rd (1 + k1 rd^2)`` rises only up to ``rd* = 1 / sqrt(-3 k1)``
where ``ru`` reaches its maximum ``ru* = (2/3) rd*``: undistorted points beyond ``ru*`` have no
image (NaN, flagged invalid) and distorted points beyond ``rd*`` (past the fold of the model)
have no ray (NaN directions).

OpenCV's radial model goes the other way (undistorted -> distorted, a polynomial in the
normalised radius); :meth:`Camera.to_opencv` and :meth:`Camera.from_opencv` convert by a least
squares fit over the image and return the largest disagreement in pixels.

Also here: the :class:`Turntable` (an axis in the rig frame and the object frame of
docs/conventions.md) and the :class:`Rig` (camera, projector, turntable) with JSON files.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from .errors import NurbscanError

__all__ = [
    "Camera",
    "Projector",
    "Rig",
    "Turntable",
    "distortion_scale",
    "load_rig",
    "rotation_about",
    "rotation_matrix",
]

FORMAT_VERSION = 1
_CHUNK = 1 << 17  # points per block in project/back_project (keeps temporaries in cache)
_ORTHO_TOL = 1e-9


# ----------------------------------------------------------------------------- helpers
def _float(value: Any, what: str, *, positive: bool = False) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise NurbscanError(f"{what}: expected a number, got {value!r}") from None
    if not math.isfinite(v):
        raise NurbscanError(f"{what}: must be finite, got {v}")
    if positive and not v > 0:
        raise NurbscanError(f"{what}: must be positive, got {v}")
    return v


def _int(value: Any, what: str) -> int:
    if isinstance(value, bool):
        raise NurbscanError(f"{what}: expected a positive integer, got {value!r}")
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise NurbscanError(f"{what}: expected a positive integer, got {value!r}") from None
    if not (math.isfinite(v) and v == int(v) and v > 0):
        raise NurbscanError(f"{what}: expected a positive integer, got {value!r}")
    return int(v)


def _array(value: Any, shape: tuple[int, ...], what: str) -> np.ndarray:
    try:
        a = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise NurbscanError(f"{what}: expected an array of shape {shape}") from None
    if a.shape != shape:
        raise NurbscanError(f"{what}: expected shape {shape}, got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise NurbscanError(f"{what}: contains non-finite values")
    a.setflags(write=False)
    return a


def _rotation(value: Any, what: str) -> np.ndarray:
    R = _array(value, (3, 3), what)
    err = float(np.max(np.abs(R.T @ R - np.eye(3))))
    if err > _ORTHO_TOL:
        raise NurbscanError(f"{what}: not orthonormal (max |R^T R - I| = {err:.3g})")
    det = float(np.linalg.det(R))
    if abs(det - 1.0) > _ORTHO_TOL:
        raise NurbscanError(f"{what}: determinant {det:.12g}, expected +1 (a proper rotation)")
    return R


def _points(points: Any, what: str, dim: int) -> np.ndarray:
    try:
        p = np.asarray(points, dtype=float)
    except (TypeError, ValueError):
        raise NurbscanError(f"{what}: expected a numeric array of shape (..., {dim})") from None
    if p.ndim == 0 or p.shape[-1] != dim:
        raise NurbscanError(f"{what}: expected shape (..., {dim}), got {p.shape}")
    return p


def _check_type(d: Any, expected: str, source: str) -> None:
    if not isinstance(d, dict):
        raise NurbscanError(f"{source}: expected a JSON object, got {type(d).__name__}")
    t = d.get("type")
    if t != expected:
        raise NurbscanError(f"{source}: \"type\" is {t!r}, expected {expected!r}")
    v = d.get("version", FORMAT_VERSION)
    if not isinstance(v, int) or v > FORMAT_VERSION:
        raise NurbscanError(f"{source}: unsupported version {v!r} (this reads {FORMAT_VERSION})")


def _get(d: dict, key: str, source: str) -> Any:
    if key not in d:
        raise NurbscanError(f"{source}: missing key {key!r}")
    return d[key]


def rotation_about(axis: Any, angle: float) -> np.ndarray:
    """Rotation matrix by ``angle`` (radians, right-hand rule) about the unit vector ``axis``.

    Rodrigues' formula ``R = cos(a) I + sin(a) [u]_x + (1 - cos(a)) u u^T``; shape (3, 3).
    """
    u = np.asarray(axis, float)
    u = u / np.linalg.norm(u)
    c, s = math.cos(angle), math.sin(angle)
    ux = np.array([[0.0, -u[2], u[1]], [u[2], 0.0, -u[0]], [-u[1], u[0], 0.0]])
    return c * np.eye(3) + s * ux + (1.0 - c) * np.outer(u, u)


rotation_matrix = rotation_about  # the name used by the first version of this module


def distortion_scale(c: Any) -> np.ndarray:
    """Root ``s`` of ``c s^3 + s - 1 = 0`` on the branch with ``s -> 1`` as ``c -> 0``.

    With ``c = k1 ru^2`` this is the ratio ``s = rd / ru`` of distorted to undistorted radius of
    Tsai's radial model ``ru = rd (1 + k1 rd^2)`` (the cubic ``k1 rd^3 + rd - ru = 0`` with
    ``rd = s ru``, divided by ``ru``). Closed form (Cardano's formula in hyperbolic /
    trigonometric form), with ``u = sqrt(3 |c|)``:

    * ``c > 0``: ``s = 2 sinh(asinh(3u/2) / 3) / u`` (the only real root);
    * ``c < 0``: ``s = 2 sin(asin(3u/2) / 3) / u``, defined for ``3u/2 <= 1`` i.e.
      ``c >= -4/27`` (beyond, the undistorted radius exceeds the model's maximum: NaN);
    * ``|c| < 1e-8``: the series ``1 - c + 3c^2 - 12c^3 + 55c^4`` (Fuss-Catalan numbers).

    One Newton step on ``c s^3 + s - 1`` then brings the result to full double precision
    (skipped near the fold ``c = -4/27``, where the derivative vanishes).

    Parameters
    ----------
    c : array_like
        ``k1 ru^2`` (dimensionless), any shape.

    Returns
    -------
    ndarray
        ``s``, same shape; NaN where ``c < -4/27`` or ``c`` is not finite.
    """
    c = np.asarray(c, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        if not np.any(c < 0):  # k1 >= 0 (NaN entries stay NaN): the hyperbolic form only
            s = _scale_branch(c, np.sinh, np.arcsinh)
        elif not np.any(c > 0):  # k1 <= 0: the trigonometric form only
            s = _scale_branch(c, np.sin, np.arcsin)
        else:
            s = np.where(c > 0, _scale_branch(c, np.sinh, np.arcsinh),
                         _scale_branch(c, np.sin, np.arcsin))
        small = np.abs(c) < 1e-8
        if np.any(small):
            series = 1.0 + c * (-1.0 + c * (3.0 + c * (-12.0 + 55.0 * c)))
            s = np.where(small, series, s)
        # one Newton step (the closed form is within a few ulp; this removes the rest)
        s2 = s * s
        d = 1.0 + 3.0 * c * s2
        step = (s + c * s2 * s - 1.0) / d
        s = np.where(d > 0.25, s - step, s)
    return s


def _scale_branch(c: np.ndarray, fun, inverse) -> np.ndarray:
    """``2 fun(inverse(3u/2) / 3) / u`` with ``u = sqrt(3 |c|)`` (see :func:`distortion_scale`)."""
    u = np.sqrt(3.0 * np.abs(c))
    t = inverse(1.5 * u)
    t /= 3.0
    t = fun(t)
    t *= 2.0
    t /= u
    return t


# ----------------------------------------------------------------------------- camera
@dataclass(frozen=True, eq=False)
class Camera:
    """Tsai's camera model (Tsai 1987; method.md section 4; docs/conventions.md).

    Parameters
    ----------
    width, height : int
        Image size, px.
    f : float
        Focal length (effective), mm.
    cx, cy : float
        Principal point ``(Cx, Cy)``, px (pixel centres at integer coordinates).
    dx, dy : float
        Pixel pitch, mm/px.
    sx : float
        Horizontal scale factor (Tsai's ``sx``).
    k1 : float
        Radial distortion, mm^-2, distorted -> undistorted: ``Xu = Xd (1 + k1 r^2)``.
    R : array_like, shape (3, 3)
        World -> camera rotation (orthonormal, det +1 within 1e-9). Stored read-only.
    T : array_like, shape (3,)
        World -> camera translation, mm: ``x = R X + T``. Stored read-only.
    name : str
        A label.

    Notes
    -----
    Equality compares the JSON form (:meth:`to_dict`) exactly.
    """

    width: int
    height: int
    f: float
    cx: float
    cy: float
    dx: float = 0.0025
    dy: float = 0.0025
    sx: float = 1.0
    k1: float = 0.0
    R: np.ndarray = field(default_factory=lambda: np.eye(3))
    T: np.ndarray = field(default_factory=lambda: np.zeros(3))
    name: str = "camera"

    TYPE: ClassVar[str] = "nurbscan.camera"

    def __post_init__(self) -> None:
        kind = type(self).__name__.lower()
        set_ = object.__setattr__
        set_(self, "width", _int(self.width, f"{kind} width"))
        set_(self, "height", _int(self.height, f"{kind} height"))
        for key in ("f", "dx", "dy", "sx"):
            set_(self, key, _float(getattr(self, key), f"{kind} {key}", positive=True))
        for key in ("cx", "cy", "k1"):
            set_(self, key, _float(getattr(self, key), f"{kind} {key}"))
        set_(self, "R", _rotation(self.R, f"{kind} R"))
        set_(self, "T", _array(self.T, (3,), f"{kind} T"))
        set_(self, "name", str(self.name))

    # ------------------------------------------------------------------ identity
    def __eq__(self, other: object) -> bool:
        if type(other) is not type(self):
            return NotImplemented
        return self.to_dict() == other.to_dict()

    def __hash__(self) -> int:
        return hash(json.dumps(self.to_dict(), sort_keys=True))

    # ------------------------------------------------------------------ frames
    @property
    def center(self) -> np.ndarray:
        """Optical centre in the world (rig) frame, ``-R^T T``, mm, shape (3,)."""
        c = -self.R.T @ self.T
        c.setflags(write=False)
        return c

    @property
    def axis(self) -> np.ndarray:
        """Unit optical axis (the camera's +z) in the world frame, ``R^T (0, 0, 1)``, (3,)."""
        return self.R[2].copy()

    @property
    def max_undistorted_radius(self) -> float:
        """Largest undistorted sensor radius the model can image, mm (``inf`` for ``k1 >= 0``).

        For ``k1 < 0``: ``ru* = (2/3) / sqrt(-3 k1)``, reached at ``rd* = 1 / sqrt(-3 k1)``.
        """
        return math.inf if self.k1 >= 0 else (2.0 / 3.0) / math.sqrt(-3.0 * self.k1)

    @property
    def max_distorted_radius(self) -> float:
        """Largest distorted sensor radius with a ray, mm (``inf`` for ``k1 >= 0``).

        For ``k1 < 0`` the fold ``rd* = 1 / sqrt(-3 k1)`` where ``d ru / d rd = 0``.
        """
        return math.inf if self.k1 >= 0 else 1.0 / math.sqrt(-3.0 * self.k1)

    def to_camera(self, points: Any) -> np.ndarray:
        """World (rig) points to this device's frame, ``x = R X + T``.

        Parameters
        ----------
        points : array_like, shape (..., 3)
            mm, world frame.

        Returns
        -------
        ndarray, shape (..., 3)
            mm, camera frame.
        """
        p = _points(points, "points", 3)
        return p @ self.R.T + self.T

    def with_pose(self, R: Any, T: Any) -> Camera:
        """A copy with another pose (``x = R X + T``); same class, intrinsics and name."""
        return dataclasses.replace(self, R=R, T=T)

    # ------------------------------------------------------------------ sensor <-> pixel
    def pixel_to_sensor(self, pixels: Any) -> np.ndarray:
        """Pixels to distorted sensor coordinates ``Xd = (Xf - Cx) dx / sx``, ``Yd = (Yf - Cy) dy``.

        Parameters
        ----------
        pixels : array_like, shape (..., 2)
            px.

        Returns
        -------
        ndarray, shape (..., 2)
            ``(Xd, Yd)``, mm.
        """
        p = _points(pixels, "pixels", 2)
        out = np.empty(p.shape)
        out[..., 0] = (p[..., 0] - self.cx) * (self.dx / self.sx)
        out[..., 1] = (p[..., 1] - self.cy) * self.dy
        return out

    def sensor_to_pixel(self, xy: Any) -> np.ndarray:
        """Distorted sensor coordinates to pixels ``Xf = sx Xd / dx + Cx``, ``Yf = Yd / dy + Cy``.

        Parameters
        ----------
        xy : array_like, shape (..., 2)
            ``(Xd, Yd)``, mm.

        Returns
        -------
        ndarray, shape (..., 2)
            px.
        """
        p = _points(xy, "sensor points", 2)
        out = np.empty(p.shape)
        out[..., 0] = p[..., 0] * (self.sx / self.dx) + self.cx
        out[..., 1] = p[..., 1] / self.dy + self.cy
        return out

    # ------------------------------------------------------------------ distortion
    def undistort(self, xd: Any, yd: Any) -> tuple[np.ndarray, np.ndarray]:
        """Distorted to undistorted sensor point, ``Xu = Xd (1 + k1 r^2)``, ``r^2 = Xd^2 + Yd^2``.

        Tsai's eq. 5b, closed form. For ``k1 < 0`` points past the fold
        (``r > max_distorted_radius``) give NaN.

        Parameters
        ----------
        xd, yd : array_like
            Distorted sensor coordinates, mm (broadcast together).

        Returns
        -------
        xu, yu : ndarray
            Undistorted sensor coordinates, mm.
        """
        xd = np.asarray(xd, float)
        yd = np.asarray(yd, float)
        k = self.k1 * (xd * xd + yd * yd)
        s = 1.0 + k
        if self.k1 < 0:
            s = np.where(k >= -1.0 / 3.0, s, np.nan)
        return xd * s, yd * s

    def distort(self, xu: Any, yu: Any, return_valid: bool = False):
        """Undistorted to distorted sensor point: the inverse of :meth:`undistort`.

        Solves ``k1 rd^3 + rd - ru = 0`` per point by :func:`distortion_scale` (closed form and
        a Newton step). For ``k1 < 0`` points with ``ru > max_undistorted_radius`` give NaN.

        Parameters
        ----------
        xu, yu : array_like
            Undistorted sensor coordinates, mm (broadcast together).

        return_valid : bool
            Also return the mask of finite results.

        Returns
        -------
        xd, yd : ndarray
            Distorted sensor coordinates, mm.
        valid : ndarray of bool
            Only with ``return_valid``.
        """
        xu = np.asarray(xu, float)
        yu = np.asarray(yu, float)
        if self.k1 == 0.0:
            xd, yd = xu + 0.0, yu + 0.0
        else:
            s = distortion_scale(self.k1 * (xu * xu + yu * yu))
            xd, yd = xu * s, yu * s
        if return_valid:
            return xd, yd, np.isfinite(xd) & np.isfinite(yd)
        return xd, yd

    # ------------------------------------------------------------------ projection
    def project(self, points: Any, return_valid: bool = False):
        """Pixels of world points (Tsai's forward model).

        ``x = R X + T``; ``Xu = f x / z``, ``Yu = f y / z``; ``(Xd, Yd) = s (Xu, Yu)`` with
        ``s`` the root of ``c s^3 + s - 1 = 0``, ``c = k1 (Xu^2 + Yu^2)``
        (:func:`distortion_scale`); ``Xf = sx Xd / dx + Cx``, ``Yf = Yd / dy + Cy``.
        Pixels outside the image are returned as computed (not flagged).

        Parameters
        ----------
        points : array_like, shape (..., 3)
            World (rig) points, mm.
        return_valid : bool
            Also return the validity mask.

        Returns
        -------
        pixels : ndarray, shape (..., 2)
            px; NaN for points at or behind the centre (``z <= 0``), outside the distortion
            model's domain (``k1 < 0`` and ``ru > max_undistorted_radius``) or not finite.
        valid : ndarray of bool, shape (...)
            Only with ``return_valid``: where ``pixels`` is finite.
        """
        p = _points(points, "points", 3)
        shape = p.shape[:-1]
        flat = p.reshape(-1, 3)
        n = flat.shape[0]
        out = np.empty((n, 2))
        valid = np.empty(n, dtype=bool)
        (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = self.R.tolist()
        t0, t1, t2 = self.T.tolist()
        ax, ay = self.sx / self.dx, 1.0 / self.dy
        for a in range(0, n, _CHUNK):
            b = min(n, a + _CHUNK)
            X, Y, Z = flat[a:b, 0], flat[a:b, 1], flat[a:b, 2]
            # camera frame x = R X + T, written out (no BLAS call on a thin matrix)
            z = r20 * X + r21 * Y + r22 * Z + t2
            with np.errstate(divide="ignore", invalid="ignore"):
                iz = self.f / z
                iz[~(z > 0)] = np.nan
                xu = r00 * X + r01 * Y + r02 * Z + t0
                xu *= iz
                yu = r10 * X + r11 * Y + r12 * Z + t1
                yu *= iz
                if self.k1 != 0.0:
                    s = distortion_scale(self.k1 * (xu * xu + yu * yu))
                    xu *= s
                    yu *= s
            o = out[a:b]
            xu *= ax
            xu += self.cx
            yu *= ay
            yu += self.cy
            ok = np.isfinite(xu) & np.isfinite(yu)
            xu[~ok] = np.nan
            yu[~ok] = np.nan
            o[:, 0] = xu
            o[:, 1] = yu
            valid[a:b] = ok
        out = out.reshape(*shape, 2)
        if return_valid:
            return out, valid.reshape(shape)
        return out

    def back_project(self, pixels: Any) -> tuple[np.ndarray, np.ndarray]:
        """Rays of pixels, closed form (the paper's eq. 6-8; Tsai 1987).

        Pixel -> distorted sensor ``Xd = (Xf - Cx) dx / sx``, ``Yd = (Yf - Cy) dy`` ->
        undistorted ``Xu = Xd (1 + k1 r^2)``, ``Yu = Yd (1 + k1 r^2)`` -> the ray through the
        optical centre and ``(Xu, Yu, f)`` (camera frame), in the world ``d = R^T (Xu, Yu, f)``.

        Parameters
        ----------
        pixels : array_like, shape (..., 2)
            px.

        Returns
        -------
        origin : ndarray, shape (3,)
            The optical centre (:attr:`center`), mm, world frame.
        directions : ndarray, shape (..., 3)
            Unit ray directions, world frame; NaN for pixels past the fold of the model
            (``k1 < 0`` and ``r > max_distorted_radius``) or not finite.
        """
        p = _points(pixels, "pixels", 2)
        shape = p.shape[:-1]
        flat = p.reshape(-1, 2)
        n = flat.shape[0]
        out = np.empty((n, 3))
        bx, by = self.dx / self.sx, self.dy
        # d_world = R^T d_cam, written out; d_cam = (Xu, Yu, f)
        (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = self.R.tolist()
        f = self.f
        fold = -1.0 / 3.0
        for a in range(0, n, _CHUNK):
            b = min(n, a + _CHUNK)
            xu = flat[a:b, 0] - self.cx
            xu *= bx
            yu = flat[a:b, 1] - self.cy
            yu *= by
            if self.k1 != 0.0:
                k = xu * xu
                k += yu * yu
                k *= self.k1
                if self.k1 < 0:
                    k[k < fold] = np.nan
                k += 1.0
                xu *= k
                yu *= k
            wx = r00 * xu + r10 * yu + r20 * f
            wy = r01 * xu + r11 * yu + r21 * f
            wz = r02 * xu + r12 * yu + r22 * f
            nrm = wx * wx + wy * wy + wz * wz
            np.sqrt(nrm, out=nrm)
            o = out[a:b]
            o[:, 0] = wx / nrm
            o[:, 1] = wy / nrm
            o[:, 2] = wz / nrm
        return self.center.copy(), out.reshape(*shape, 3)

    # ------------------------------------------------------------------ JSON
    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dictionary (``"type"``, ``"version"``, every field; arrays as lists)."""
        return {
            "type": self.TYPE,
            "version": FORMAT_VERSION,
            "name": self.name,
            "width": self.width,
            "height": self.height,
            "f": self.f,
            "cx": self.cx,
            "cy": self.cy,
            "dx": self.dx,
            "dy": self.dy,
            "sx": self.sx,
            "k1": self.k1,
            "R": self.R.tolist(),
            "T": self.T.tolist(),
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any], source: str | None = None) -> Camera:
        """Inverse of :meth:`to_dict` (exact); ``source`` names the input in error messages."""
        source = source or cls.TYPE
        _check_type(d, cls.TYPE, source)
        keys = ("width", "height", "f", "cx", "cy", "dx", "dy", "sx", "k1", "R", "T")
        kw = {k: _get(d, k, source) for k in keys}
        if "name" in d:
            kw["name"] = d["name"]
        try:
            return cls(**kw)
        except NurbscanError as exc:
            raise NurbscanError(f"{source}: {exc}") from None

    # ------------------------------------------------------------------ OpenCV
    def _grid_pixels(self, n: int = 64, radial: int = 400) -> np.ndarray:
        """Pixels over the whole image where two models are compared, px, shape (M, 2).

        A regular grid of about ``n`` points along the longer side (edges and corners
        included) and, because radial models differ most at large radii, ``radial`` points on
        each of the 8 segments from the principal point to the image corners and edge middles.
        """
        w, h = self.width - 0.5, self.height - 0.5
        nx = max(2, int(round(n * self.width / max(self.width, self.height))) + 1)
        ny = max(2, int(round(n * self.height / max(self.width, self.height))) + 1)
        grid = np.stack(np.meshgrid(np.linspace(-0.5, w, nx), np.linspace(-0.5, h, ny)), -1)
        c = np.array([min(max(self.cx, -0.5), w), min(max(self.cy, -0.5), h)])
        ends = np.array([[-0.5, -0.5], [w, -0.5], [-0.5, h], [w, h],
                         [-0.5, c[1]], [w, c[1]], [c[0], -0.5], [c[0], h]])
        t = np.linspace(0.0, 1.0, radial)[:, None, None]
        lines = c + t * (ends - c)
        return np.concatenate([grid.reshape(-1, 2), lines.reshape(-1, 2)])

    def opencv_matrix(self) -> np.ndarray:
        """OpenCV's camera matrix ``K = [[f sx / dx, 0, Cx], [0, f / dy, Cy], [0, 0, 1]]``."""
        return np.array([[self.f * self.sx / self.dx, 0.0, self.cx],
                         [0.0, self.f / self.dy, self.cy],
                         [0.0, 0.0, 1.0]])

    def to_opencv(self, grid: int = 64):
        """OpenCV's pinhole model fitted to this camera: ``(K, dist, R, tvec, max_error_px)``.

        ``K`` is exact (:meth:`opencv_matrix`). OpenCV's radial model maps *undistorted* to
        *distorted* normalised coordinates, ``x'' = x' (1 + k1 r^2 + k2 r^4 + k3 r^6)``; Tsai's
        maps the other way, so the two are not the same model. OpenCV's ``k1, k2, k3``
        (``p1 = p2 = 0``) are fitted by linear least squares over a grid of about
        ``grid`` x ``grid * height / width`` pixels covering the whole image (corners and
        edges included): each grid pixel is back-projected exactly (Tsai's closed form) and
        the fit minimises the squared pixel distance between OpenCV's image of that ray and
        the pixel (the residual is linear in ``k1, k2, k3``).

        Returns
        -------
        K : ndarray, shape (3, 3)
        dist : ndarray, shape (5,)
            ``(k1, k2, p1, p2, k3)`` in OpenCV's order, with ``p1 = p2 = 0``.
        R : ndarray, shape (3, 3)
            The rotation (``cv2.Rodrigues(R)[0]`` gives OpenCV's ``rvec``).
        tvec : ndarray, shape (3,)
            mm.
        max_error_px : float
            Largest distance, px, between ``cv2.projectPoints`` with these parameters and
            :meth:`project` over the grid (measured with OpenCV). Measured on a 3072 x 2304
            camera (tests/test_camera.py): 5e-5 px when distortion moves the image corners by
            22 px, 0.025-0.037 px at 112 px; it grows with stronger distortion, which the
            three-term polynomial cannot follow. Grid pixels past the fold (``k1 < 0``) are
            left out.
        """
        import cv2

        px = self._grid_pixels(grid)
        xd = (px[:, 0] - self.cx) * self.dx / self.sx
        yd = (px[:, 1] - self.cy) * self.dy
        xu, yu = self.undistort(xd, yd)
        ok = np.isfinite(xu)
        px, xd, yd, xu, yu = px[ok], xd[ok], yd[ok], xu[ok], yu[ok]
        rho2 = (xu * xu + yu * yu) / (self.f * self.f)
        ax, ay = self.sx / self.dx, 1.0 / self.dy
        basis = np.stack([rho2, rho2**2, rho2**3], -1)
        A = np.concatenate([ax * xu[:, None] * basis, ay * yu[:, None] * basis])
        rhs = np.concatenate([ax * (xd - xu), ay * (yd - yu)])
        scale = np.maximum(np.abs(A).max(axis=0), 1e-300)
        sol = np.linalg.lstsq(A / scale, rhs, rcond=None)[0] / scale
        dist = np.array([sol[0], sol[1], 0.0, 0.0, sol[2]])
        K = self.opencv_matrix()
        # the grid rays, at depth z = 1 m, in the world frame; OpenCV against Tsai
        xc = np.stack([xu / self.f, yu / self.f, np.ones_like(xu)], -1) * 1000.0
        world = (xc - self.T) @ self.R
        rvec = cv2.Rodrigues(self.R)[0]
        cv_px = cv2.projectPoints(world.reshape(-1, 1, 3), rvec, self.T.reshape(3, 1), K,
                                  dist)[0].reshape(-1, 2)
        err = float(np.max(np.hypot(*(cv_px - self.project(world)).T)))
        return K, dist, np.array(self.R), np.array(self.T), err

    @classmethod
    def from_opencv(cls, K: Any, dist: Any, R: Any, tvec: Any, width: int, height: int,
                    dx: float = 0.0025, dy: float | None = None, name: str | None = None,
                    grid: int = 64):
        """Tsai's model fitted to an OpenCV pinhole camera: ``(camera, max_error_px)``.

        ``f = K[1,1] dy``, ``sx = K[0,0] dx / f``, ``(Cx, Cy) = (K[0,2], K[1,2])`` (exact; the
        pixel pitch ``dx, dy`` is not in ``K`` and must be given, ``dy`` defaults to ``dx``).
        Tsai's one radial term ``k1`` is fitted to OpenCV's distortion (any of its
        coefficient sets; tangential and higher terms are approximated by the radial one)
        over a grid covering the whole image: rays of the grid pixels (``cv2.undistortPoints``)
        are imaged by ``cv2.projectPoints`` and ``k1`` minimises the squared pixel distance
        of Tsai's projection of the same rays to those pixels (linear least squares on the
        back-projection residual, then Gauss-Newton on the pixel residual).

        Parameters
        ----------
        K : array_like, shape (3, 3)
            OpenCV camera matrix (no skew).
        dist : array_like or None
            OpenCV distortion coefficients (4, 5, 8, 12 or 14 values).
        R : array_like, shape (3, 3) or (3,)
            Rotation matrix or Rodrigues vector (world -> camera).
        tvec : array_like, shape (3,)
            mm.
        width, height : int
            Image size, px.
        dx, dy : float
            Pixel pitch, mm/px.
        name : str, optional
            Defaults to the class's default name.
        grid : int
            Grid pixels along the longer image side.

        Returns
        -------
        camera : Camera (or the class it is called on)
        max_error_px : float
            Largest distance, px, between :meth:`project` of the fitted camera and
            ``cv2.projectPoints`` over the grid. Measured (tests/test_camera.py): 5e-5 px for
            an OpenCV model made by :meth:`to_opencv` (k1 recovered to 1e-6), 0.15 px for a
            genuine OpenCV ``k1 = -0.1, k2 = 0.05`` on a 3072 x 2304 image (one Tsai term
            cannot hold ``k2``); tangential terms add their own share.
        """
        import cv2

        dy = dx if dy is None else dy
        K = _array(K, (3, 3), "K")
        lower = (K[1, 0], K[2, 0], K[2, 1], K[2, 2] - 1.0)
        if abs(K[0, 1]) > 1e-9 * abs(K[0, 0]) or any(v != 0 for v in lower):
            raise NurbscanError("K: expected [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] (no skew)")
        dist = np.zeros(5) if dist is None else np.asarray(dist, float).ravel()
        if dist.size == 0:
            dist = np.zeros(5)
        if dist.size not in (4, 5, 8, 12, 14) or not np.all(np.isfinite(dist)):
            raise NurbscanError(f"dist: expected 4, 5, 8, 12 or 14 finite values, got {dist}")
        Rm = np.asarray(R, float)
        if Rm.shape in ((3,), (3, 1), (1, 3)):
            Rm = cv2.Rodrigues(Rm.reshape(3, 1))[0]
        dx = _float(dx, "dx", positive=True)
        dy = _float(dy, "dy", positive=True)
        fx, fy = _float(K[0, 0], "K[0,0]", positive=True), _float(K[1, 1], "K[1,1]",
                                                                  positive=True)
        f = fy * dy
        kw = dict(width=width, height=height, f=f, cx=K[0, 2], cy=K[1, 2], dx=dx, dy=dy,
                  sx=fx * dx / f, R=Rm, T=tvec)
        if name is not None:
            kw["name"] = name
        cam0 = cls(k1=0.0, **kw)
        # grid pixels -> OpenCV's normalised rays -> OpenCV's exact images of those rays
        px = cam0._grid_pixels(grid)
        crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-14)
        if hasattr(cv2, "undistortPointsIter"):  # OpenCV 4
            norm = cv2.undistortPointsIter(px.reshape(-1, 1, 2), K, dist, None, None, crit)
        else:  # OpenCV 5: criteria on undistortPoints
            norm = cv2.undistortPoints(px.reshape(-1, 1, 2), K, dist, None, None, None, crit)
        norm = norm.reshape(-1, 2)
        rays = np.column_stack([norm, np.ones(len(norm))])
        target = cv2.projectPoints(rays.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K,
                                   dist)[0].reshape(-1, 2)
        xu, yu = f * norm[:, 0], f * norm[:, 1]
        xd = (target[:, 0] - K[0, 2]) * dx / kw["sx"]
        yd = (target[:, 1] - K[1, 2]) * dy
        # linear start: Xu - Xd = k1 Xd rd^2, residual in px
        r2 = xd * xd + yd * yd
        a = np.concatenate([xd * r2 / dx, yd * r2 / dy])
        b = np.concatenate([(xu - xd) / dx, (yu - yd) / dy])
        k1 = float(a @ b / (a @ a)) if a @ a > 0 else 0.0

        def residual(k: float) -> np.ndarray:
            cam = dataclasses.replace(cam0, k1=k, R=np.eye(3), T=np.zeros(3))
            return (cam.project(rays) - target).ravel()

        for _ in range(8):
            r = residual(k1)
            h = 1e-6 * max(abs(k1), 1e-6)
            J = (residual(k1 + h) - residual(k1 - h)) / (2 * h)
            ok = np.isfinite(r) & np.isfinite(J)
            if not np.any(ok) or J[ok] @ J[ok] == 0:
                break
            step = float(J[ok] @ r[ok] / (J[ok] @ J[ok]))
            k1 -= step
            if abs(step) <= 1e-12 * max(abs(k1), 1e-300):
                break
        cam = dataclasses.replace(cam0, k1=k1)
        world = (rays * 1000.0 - cam.T) @ cam.R
        cv_px = cv2.projectPoints(world.reshape(-1, 1, 3), cv2.Rodrigues(cam.R)[0],
                                  cam.T.reshape(3, 1), K, dist)[0].reshape(-1, 2)
        e = np.hypot(*(cv_px - cam.project(world)).T)
        err = float(np.max(e)) if np.all(np.isfinite(e)) else math.inf
        return cam, err


@dataclass(frozen=True, eq=False)
class Projector(Camera):
    """The projector: Tsai's model used as an inverse camera (method.md section 4).

    :meth:`project` gives the projector pixel that lights a world point; :meth:`back_project`
    gives the light ray of a projector pixel. Same fields and units as :class:`Camera`.
    """

    name: str = "projector"

    TYPE: ClassVar[str] = "nurbscan.projector"


# ----------------------------------------------------------------------------- turntable
@dataclass(frozen=True, eq=False)
class Turntable:
    """A turntable axis and its object (table) frame (docs/conventions.md).

    Parameters
    ----------
    point : array_like, shape (3,)
        A point of the axis, mm, rig frame (the object frame's origin, on the table top).
    direction : array_like, shape (3,)
        Axis direction, up out of the table top; normalised on creation. It must not be
        parallel to the camera's z axis (the object frame's x axis would be undefined).

    A table angle ``theta`` turns the table by ``Rot(direction, theta)`` (right-hand rule);
    a point ``X_obj`` of the object is at ``point + Rot(direction, theta) F X_obj`` in the rig
    frame, ``F = [x_t y_t z_t]`` (:meth:`frame`).
    """

    point: np.ndarray
    direction: np.ndarray

    TYPE: ClassVar[str] = "nurbscan.turntable"

    def __post_init__(self) -> None:
        object.__setattr__(self, "point", _array(self.point, (3,), "turntable point"))
        d = np.array(_array(self.direction, (3,), "turntable direction"))
        n = float(np.linalg.norm(d))
        if not n > 0:
            raise NurbscanError("turntable direction: must be a non-zero vector")
        if abs(n - 1.0) > 1e-15:  # a unit vector is kept as is (exact JSON round trips)
            d /= n
        if np.linalg.norm(np.cross(d, [0.0, 0.0, 1.0])) < 1e-9:
            raise NurbscanError("turntable direction: parallel to the camera's optical axis, "
                                "the object frame is undefined")
        d.setflags(write=False)
        object.__setattr__(self, "direction", d)

    def __eq__(self, other: object) -> bool:
        if type(other) is not type(self):
            return NotImplemented
        return self.to_dict() == other.to_dict()

    def __hash__(self) -> int:
        return hash(json.dumps(self.to_dict(), sort_keys=True))

    def rotation(self, angle: float) -> np.ndarray:
        """``Rot(direction, angle)``, right-hand rule (Rodrigues' formula), shape (3, 3)."""
        return rotation_about(self.direction, _float(angle, "table angle"))

    def frame(self) -> np.ndarray:
        """Object-frame axes as columns ``[x_t y_t z_t]`` in the rig frame, shape (3, 3).

        ``z_t = direction``; ``x_t`` = the component of ``(0, 0, -1)`` (from the table towards
        the camera) perpendicular to ``z_t``, normalised; ``y_t = z_t x x_t``.
        """
        z = self.direction
        x = np.array([0.0, 0.0, -1.0]) - z * (-z[2])
        x /= np.linalg.norm(x)
        return np.column_stack([x, np.cross(z, x), z])

    def to_rig(self, points_obj: Any, angle: float) -> np.ndarray:
        """Object-frame points to the rig frame at table angle ``angle`` (radians).

        ``X_rig = point + Rot(direction, angle) F X_obj``; shapes (..., 3) -> (..., 3), mm.
        """
        p = _points(points_obj, "object points", 3)
        M = self.rotation(angle) @ self.frame()
        return p @ M.T + self.point

    def from_rig(self, points_rig: Any, angle: float) -> np.ndarray:
        """Inverse of :meth:`to_rig`: ``X_obj = F^T Rot^T (X_rig - point)``; (..., 3), mm."""
        p = _points(points_rig, "rig points", 3)
        M = self.rotation(angle) @ self.frame()
        return (p - self.point) @ M

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dictionary (``"type": "nurbscan.turntable"``)."""
        return {"type": self.TYPE, "version": FORMAT_VERSION, "point": self.point.tolist(),
                "direction": self.direction.tolist()}

    @classmethod
    def from_dict(cls, d: dict[str, Any], source: str | None = None) -> Turntable:
        """Inverse of :meth:`to_dict` (exact)."""
        source = source or cls.TYPE
        _check_type(d, cls.TYPE, source)
        try:
            return cls(point=_get(d, "point", source), direction=_get(d, "direction", source))
        except NurbscanError as exc:
            if str(exc).startswith(source):
                raise
            raise NurbscanError(f"{source}: {exc}") from None


# ----------------------------------------------------------------------------- rig
@dataclass(frozen=True, eq=False)
class Rig:
    """A calibrated scanner: camera (defines the rig frame), projector and turntable."""

    camera: Camera
    projector: Projector
    turntable: Turntable

    TYPE: ClassVar[str] = "nurbscan.rig"

    def __post_init__(self) -> None:
        if not isinstance(self.camera, Camera) or isinstance(self.camera, Projector):
            raise NurbscanError(f"rig camera: expected a Camera, got {type(self.camera).__name__}")
        if not isinstance(self.projector, Projector):
            raise NurbscanError("rig projector: expected a Projector, got "
                                f"{type(self.projector).__name__}")
        if not isinstance(self.turntable, Turntable):
            raise NurbscanError("rig turntable: expected a Turntable, got "
                                f"{type(self.turntable).__name__}")

    def __eq__(self, other: object) -> bool:
        if type(other) is not type(self):
            return NotImplemented
        return self.to_dict() == other.to_dict()

    def __hash__(self) -> int:
        return hash(json.dumps(self.to_dict(), sort_keys=True))

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dictionary (``"type": "nurbscan.rig"``) holding the three parts."""
        return {"type": self.TYPE, "version": FORMAT_VERSION, "camera": self.camera.to_dict(),
                "projector": self.projector.to_dict(), "turntable": self.turntable.to_dict()}

    @classmethod
    def from_dict(cls, d: dict[str, Any], source: str | None = None) -> Rig:
        """Inverse of :meth:`to_dict` (exact); ``source`` names the input in error messages."""
        source = source or cls.TYPE
        _check_type(d, cls.TYPE, source)
        return cls(
            camera=Camera.from_dict(_get(d, "camera", source), f"{source} camera"),
            projector=Projector.from_dict(_get(d, "projector", source), f"{source} projector"),
            turntable=Turntable.from_dict(_get(d, "turntable", source), f"{source} turntable"),
        )

    def save(self, path: str | os.PathLike) -> Path:
        """Write the rig as JSON, atomically (:func:`nurbscan.io.write_json`); return the path."""
        from .io.atomic import write_json

        return write_json(path, self.to_dict())


def load_rig(path: str | os.PathLike) -> Rig:
    """Read a rig written by :meth:`Rig.save`.

    Raises
    ------
    NurbscanError
        One line naming the file: not found, not valid JSON, wrong type, missing keys or
        invalid values.
    """
    from .io.atomic import read_json

    return Rig.from_dict(read_json(path), str(path))
