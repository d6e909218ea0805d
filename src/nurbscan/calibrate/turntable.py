"""Turntable axis from views of the target standing on the table at several known angles.

A target fixed to the table and seen at table angle theta_i has the board -> camera pose

    R_i = Rot(a, theta_i) R_0,   t_i = p + Rot(a, theta_i) (t_0 - p)            (1)

(docs/conventions.md: the table turns by theta about the axis through p with direction a, by
the right-hand rule), where (R_0, t_0) is the board pose at theta = 0.

1. Direction: the relative rotations ``R_j R_i^T = Rot(a, theta_j - theta_i)`` of every pair of
   views give ``a`` (their rotation vectors, signed by theta_j - theta_i so that ``a`` turns by
   the right-hand rule with increasing table angle; a weighted mean over all pairs).
2. Point: with ``a`` known, (1) is linear in ``p`` and ``t_0``:
   ``(I - Rot_i) p + Rot_i t_0 = t_i``; least squares over all views.
3. Refinement (maximum likelihood): the poses (1), parametrised by ``a``, ``p``, ``R_0``, ``t_0``,
   are fitted to the detected chessboard corners by :func:`scipy.optimize.least_squares` on the
   camera reprojection error (the camera intrinsics fixed).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from ..errors import NurbscanError
from ._tsai import project_local, rotmats, rotvecs


def _axis_rot(a: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """Rotations (N, 3, 3) by angles theta (N,) about the unit axis a (3,)."""
    return rotmats(np.asarray(theta, float)[:, None] * a[None, :])


def _wrap(x):
    return (np.asarray(x, float) + np.pi) % (2 * np.pi) - np.pi


def _perp_basis(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    h = np.array([1.0, 0, 0]) if abs(a[0]) < 0.9 else np.array([0, 1.0, 0])
    e1 = np.cross(a, h)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(a, e1)


@dataclass
class TurntableFit:
    """Result of :func:`fit_turntable`."""

    point: np.ndarray  # (3,) mm, rig frame, a point of the axis
    direction: np.ndarray  # (3,) unit, up (right-hand rule with increasing table angle)
    rvec0: np.ndarray  # board pose at table angle 0
    tvec0: np.ndarray
    rms_px: float  # reprojection RMS of the constrained poses, camera px
    angle_rms_deg: float  # RMS between given and measured relative table angles, degrees


def initial_axis(rvecs: np.ndarray, tvecs: np.ndarray, angles: np.ndarray):
    """Closed-form axis direction and point (steps 1 and 2 of the module notes).

    Parameters
    ----------
    rvecs, tvecs : ndarray, shape (P, 3)
        Board -> camera poses of the views on the table.
    angles : ndarray, shape (P,)
        Table angles, radians.

    Returns
    -------
    a : ndarray (3,), p : ndarray (3,), rvec0 : ndarray (3,), tvec0 : ndarray (3,)
    """
    R = rotmats(rvecs)
    P = len(R)
    i, j = np.triu_indices(P, 1)
    dth = _wrap(angles[j] - angles[i])
    keep = np.abs(dth) > np.radians(1.0)
    if not np.any(keep):
        raise NurbscanError(
            "calibration: turntable views need at least two different table angles")
    i, j, dth = i[keep], j[keep], dth[keep]
    rel = rotvecs(np.einsum("kab,kcb->kac", R[j], R[i]))
    a = np.sum(rel * np.sign(dth)[:, None], axis=0)
    a /= np.linalg.norm(a)
    Rot = _axis_rot(a, angles)
    A = np.zeros((3 * P, 6))
    A[:, :3] = (np.eye(3)[None] - Rot).reshape(3 * P, 3)
    A[:, 3:] = Rot.reshape(3 * P, 3)
    sol = np.linalg.lstsq(A, np.asarray(tvecs, float).ravel(), rcond=None)[0]
    p, t0 = sol[:3], sol[3:]
    R0 = np.einsum("kba,kbc->kac", Rot, R)  # Rot_i^T R_i, one estimate of R_0 per view
    U, _, Vt = np.linalg.svd(R0.sum(axis=0))
    R0m = U @ np.diag([1, 1, np.linalg.det(U @ Vt)]) @ Vt
    return a, p, rotvecs(R0m), t0


def fit_turntable(rvecs, tvecs, angles, board, corners, kc, dx, dy,
                  ref: np.ndarray | None = None) -> TurntableFit:
    """Fit the turntable axis to the views of the target on the table.

    Parameters
    ----------
    rvecs, tvecs : ndarray, shape (P, 3)
        Calibrated board -> camera poses of the turntable views (initial values).
    angles : ndarray, shape (P,)
        The table angle of each view, radians.
    board : ndarray, shape (N, 3)
        Board-frame corner coordinates, mm.
    corners : list of ndarray (N, 2)
        Detected corners of each turntable view, camera px (NaN rows are left out).
    kc : ndarray, shape (5,)
        Camera intrinsics (fixed).
    dx, dy : float
        Camera pixel pitch, mm.
    ref : ndarray, shape (3,), optional
        The returned ``point`` is the axis point closest to ``ref`` (default: the centroid of
        the board corners at table angle 0).

    Returns
    -------
    TurntableFit
    """
    angles = np.asarray(angles, float)
    if len(angles) < 2:
        raise NurbscanError(
            f"calibration: {len(angles)} turntable view(s); at least 2 table angles are needed")
    a0, p0, r0, t0 = initial_axis(rvecs, tvecs, angles)
    e1, e2 = _perp_basis(a0)
    px = np.concatenate(corners)
    N = len(board)
    P = len(angles)
    view = np.repeat(np.arange(P), N)
    Xb = np.tile(board, (P, 1))
    ok = np.all(np.isfinite(px), axis=1)  # corners marked NaN are left out
    px, view, Xb = px[ok], view[ok], Xb[ok]

    def model(x):
        a = a0 + x[0] * e1 + x[1] * e2
        a = a / np.linalg.norm(a)
        p = p0 + x[2] * e1 + x[3] * e2
        Rot = _axis_rot(a, angles)
        R = np.einsum("kab,bc->kac", Rot, rotmats(x[4:7]))
        t = p + np.einsum("kab,b->ka", Rot, x[7:10] - p)
        return a, p, R, t

    def fun(x):
        _, _, R, t = model(x)
        xc = np.einsum("mij,mj->mi", R[view], Xb) + t[view]
        return np.nan_to_num((project_local(xc, kc, dx, dy) - px).ravel(), nan=1e3)

    x0 = np.concatenate([[0, 0, 0, 0], r0, t0])
    res = least_squares(fun, x0, x_scale="jac", method="lm", xtol=1e-12, ftol=1e-12)
    a, p, R, t = model(res.x)
    r = fun(res.x).reshape(-1, 2)
    # Measured table angles (about the fitted axis) against the given ones.
    Rm = rotmats(rvecs)
    rel = rotvecs(np.einsum("kab,cb->kac", Rm, Rm[0]))
    meas = rel @ a
    angle_rms = float(np.degrees(np.sqrt(np.mean(_wrap(meas - (angles - angles[0]))**2))))
    if ref is None:
        ref = (board @ rotmats(res.x[4:7]).T + res.x[7:10]).mean(axis=0)
    p = p + a * float(a @ (np.asarray(ref, float) - p))
    return TurntableFit(point=p, direction=a, rvec0=res.x[4:7].copy(), tvec0=res.x[7:10].copy(),
                        rms_px=float(np.sqrt(np.mean(np.sum(r**2, axis=1)))),
                        angle_rms_deg=angle_rms)
