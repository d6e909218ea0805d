"""Vectorised Tsai (1987) projection and back-projection on plain parameter arrays.

The calibration fits evaluate the camera and projector models millions of times with
parameters that change at every step; these functions take the intrinsic parameters as plain
numbers (no :class:`nurbscan.camera.Camera` object is built per evaluation) and act on whole
point arrays at once. They implement exactly the model of method.md section 4 and
docs/conventions.md, which :mod:`nurbscan.camera` also implements (the tests check that the two
agree):

    x = R X + T,  Xu = f x / z,  Yu = f y / z                      (pinhole, mm)
    Xu = Xd (1 + k1 r^2),  Yu = Yd (1 + k1 r^2),  r^2 = Xd^2 + Yd^2  (distorted -> undistorted)
    Xf = sx Xd / dx + Cx,  Yf = Yd / dy + Cy                       (pixels)

The intrinsic vector used throughout this package is ``k = (f, cx, cy, sx, k1)`` with the pixel
pitch ``(dx, dy)`` fixed (f, dx and dy are not separately identifiable).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from ..camera import distortion_scale


def rotmats(rvecs: np.ndarray) -> np.ndarray:
    """Rotation matrices from Rodrigues vectors.

    Parameters
    ----------
    rvecs : ndarray, shape (..., 3)
        Axis times angle (radians).

    Returns
    -------
    ndarray, shape (..., 3, 3)
    """
    rvecs = np.asarray(rvecs, dtype=float)
    flat = rvecs.reshape(-1, 3)
    return Rotation.from_rotvec(flat).as_matrix().reshape(rvecs.shape[:-1] + (3, 3))


def rotvecs(mats: np.ndarray) -> np.ndarray:
    """Rodrigues vectors (..., 3) of rotation matrices (..., 3, 3)."""
    mats = np.asarray(mats, dtype=float)
    flat = mats.reshape(-1, 3, 3)
    return Rotation.from_matrix(flat).as_rotvec().reshape(mats.shape[:-2] + (3,))


def undistorted_to_distorted(xu: np.ndarray, yu: np.ndarray, k1: float):
    """Invert Tsai's radial model: (Xd, Yd) with Xu = Xd (1 + k1 r^2), r = |(Xd, Yd)|.

    Uses :func:`nurbscan.camera.distortion_scale` (the cubic ``k1 rd^3 + rd - ru = 0`` in
    closed form); points beyond the model's fold come back as NaN.

    Parameters
    ----------
    xu, yu : ndarray, shape (N,)
        Undistorted sensor coordinates (mm).
    k1 : float
        Radial coefficient (mm^-2).

    Returns
    -------
    xd, yd : ndarray, shape (N,)
        Distorted sensor coordinates (mm).
    """
    s = distortion_scale(k1 * (xu * xu + yu * yu))
    return xu * s, yu * s


def project_local(xc: np.ndarray, k: np.ndarray, dx: float, dy: float) -> np.ndarray:
    """Project points given in the model's own frame to pixels (Tsai 1987, eq. 1-5).

    Parameters
    ----------
    xc : ndarray, shape (N, 3)
        Points in the camera (or projector) frame, mm; z > 0 in front.
    k : array_like, shape (5,)
        Intrinsics ``(f, cx, cy, sx, k1)``: f in mm, (cx, cy) in px, sx unitless, k1 in mm^-2.
    dx, dy : float
        Pixel pitch (mm per px).

    Returns
    -------
    ndarray, shape (N, 2)
        Pixel coordinates (x right, y down); NaN where z <= 0 or beyond the distortion fold.
    """
    f, cx, cy, sx, k1 = (float(v) for v in k)
    z = xc[:, 2]
    with np.errstate(invalid="ignore", divide="ignore"):
        zz = np.where(z > 0, z, np.nan)
        xu = f * xc[:, 0] / zz
        yu = f * xc[:, 1] / zz
    xd, yd = undistorted_to_distorted(xu, yu, k1)
    return np.stack([sx * xd / dx + cx, yd / dy + cy], axis=1)


def back_project_local(px: np.ndarray, k: np.ndarray, dx: float, dy: float) -> np.ndarray:
    """Directions (not normalised) of the rays through pixels, in the model's frame.

    Closed form (method.md section 4, the paper's eq. 6-8): pixel -> (Xd, Yd) -> (Xu, Yu) ->
    the ray through the optical centre and (Xu, Yu, f).

    Parameters
    ----------
    px : ndarray, shape (N, 2)
        Pixel coordinates.
    k : array_like, shape (5,)
        Intrinsics ``(f, cx, cy, sx, k1)``.
    dx, dy : float
        Pixel pitch (mm per px).

    Returns
    -------
    ndarray, shape (N, 3)
        Ray directions ``(Xu / f, Yu / f, 1)`` (unit z component).
    """
    f, cx, cy, sx, k1 = (float(v) for v in k)
    xd = (px[:, 0] - cx) * dx / sx
    yd = (px[:, 1] - cy) * dy
    s = 1.0 + k1 * (xd**2 + yd**2)
    return np.stack([xd * s / f, yd * s / f, np.ones_like(xd)], axis=1)


def transform(rvec: np.ndarray, tvec: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Apply ``x = R(rvec) X + t`` to points (N, 3)."""
    return pts @ rotmats(rvec).T + np.asarray(tvec, dtype=float)


def ray_plane(dirs: np.ndarray, rvec: np.ndarray, tvec: np.ndarray) -> np.ndarray:
    """Intersect rays from the origin with the plane z = 0 of a board frame.

    The board frame maps to the ray's frame by ``x = R X + t``; its plane z_board = 0 has normal
    ``n = R e3`` and passes through ``t``. The ray ``s d`` meets it at ``s = (n . t) / (n . d)``.

    Parameters
    ----------
    dirs : ndarray, shape (N, 3)
        Ray directions from the origin.
    rvec, tvec : ndarray, shape (3,)
        Board pose.

    Returns
    -------
    ndarray, shape (N, 3)
        Intersection points in the ray's frame (mm).
    """
    R = rotmats(rvec)
    n = R[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        s = float(n @ np.asarray(tvec, dtype=float)) / (dirs @ n)
    return dirs * s[:, None]
