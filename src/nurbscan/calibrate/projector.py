"""Projector calibration as an inverse camera, from the grid projected on the planar target.

Input: in each target view, decoded camera points ``c`` (band-edge points or grid
intersections) with their exact projector coordinate ``v`` along axis ``a`` (0: x, from a
vertical band edge; 1: y, from a horizontal one).

1. Plane points: the camera ray of ``c`` meets the board plane of the calibrated view pose at
   ``X`` (Moreno and Taubin 2012 use local homographies; with the board pose known the exact
   intersection is used).
2. Per view, a plane -> projector homography ``H`` by the DLT on single-coordinate equations:
   a vertical-edge point gives ``h1 . X - v h3 . X = 0``, a horizontal one
   ``h2 . X - v h3 . X = 0`` (Hartley normalisation; Hartley and Zisserman 2004, alg. 4.2).
3. Initial projector: a grid of projector pixels is mapped through ``H^-1`` onto each board,
   and :func:`cv2.calibrateCamera` (Zhang 2000) gives the intrinsics and the board -> projector
   poses, hence the camera -> projector pose (chordal mean over views); converted to Tsai.
4. Joint refinement of camera, projector and board poses
   (:func:`nurbscan.calibrate._bundle.run_bundle`): camera corner residuals in camera px and,
   per observation, the one known projector coordinate's residual in projector px.
"""

from __future__ import annotations

import cv2
import numpy as np

from ..errors import NurbscanError
from ._bundle import ProjObs, plane_points
from ._tsai import rotmats, rotvecs
from .camera import single_thread_opencv, tsai_from_opencv


def _normaliser(pts: np.ndarray) -> np.ndarray:
    c = pts.mean(axis=0)
    s = np.sqrt(2) / max(np.mean(np.linalg.norm(pts - c, axis=1)), 1e-12)
    return np.array([[s, 0, -s * c[0]], [0, s, -s * c[1]], [0, 0, 1.0]])


def plane_homography(xy: np.ndarray, value: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """Plane -> projector homography from single-coordinate correspondences (DLT).

    Parameters
    ----------
    xy : ndarray, shape (K, 2)
        Points on the board plane (board frame, mm).
    value : ndarray, shape (K,)
        Known projector coordinate of each point (px).
    axis : ndarray, shape (K,)
        0 if ``value`` is the projector x, 1 if it is y.

    Returns
    -------
    ndarray, shape (3, 3)
        H with ``(x, y, 1) ~ H (X, Y, 1)``, normalised to ``H[2, 2] = 1``.
    """
    if np.sum(axis == 0) < 4 or np.sum(axis == 1) < 4:
        raise NurbscanError("projector calibration: a view needs decoded edges of both "
                            "directions (vertical and horizontal)")
    Tn = _normaliser(xy)
    Xh = np.column_stack([xy, np.ones(len(xy))]) @ Tn.T
    # normalise the projector coordinates per axis with one common similarity
    vmean = np.array([value[axis == 0].mean(), value[axis == 1].mean()])
    vs = np.sqrt(2) / max(np.std(value), 1e-12)
    vn = (value - vmean[axis]) * vs
    A = np.zeros((len(xy), 9))
    rows0 = axis == 0
    A[rows0, 0:3] = Xh[rows0]
    A[~rows0, 3:6] = Xh[~rows0]
    A[:, 6:9] = -vn[:, None] * Xh
    _, _, Vt = np.linalg.svd(A, full_matrices=False)
    Hn = Vt[-1].reshape(3, 3)
    Tv = np.array([[vs, 0, -vs * vmean[0]], [0, vs, -vs * vmean[1]], [0, 0, 1.0]])
    H = np.linalg.solve(Tv, Hn @ Tn)
    return H / H[2, 2]


def board_frame_points(kc, rvecs, tvecs, obs: ProjObs, dx, dy) -> np.ndarray:
    """Board-frame (X, Y) (K, 2) of each observation's camera point, via its view's pose."""
    X = plane_points(kc, rvecs, tvecs, obs.pixels, obs.view, dx, dy)
    R = rotmats(rvecs)[obs.view]
    Xb = np.einsum("kji,kj->ki", R, X - tvecs[obs.view])
    return Xb[:, :2]


def init_projector(kc, rvecs, tvecs, obs: ProjObs, dc, dp, size: tuple[int, int],
                   grid: int = 9):
    """Initial projector intrinsics (Tsai) and camera -> projector pose (steps 2 and 3).

    Parameters
    ----------
    kc, rvecs, tvecs : ndarray
        Calibrated camera intrinsics (5,) and board -> camera poses (P, 3), (P, 3).
    obs : ProjObs
        Decoded projector observations of all views.
    dc, dp : (float, float)
        Pixel pitch of camera and projector, mm.
    size : (int, int)
        Projector width and height, px.
    grid : int
        Projector pixels per side of the synthetic grid mapped onto each board.

    Returns
    -------
    kp : ndarray (5,), rp : ndarray (3,), tp : ndarray (3,)
    """
    xy = board_frame_points(kc, rvecs, tvecs, obs, *dc)
    P = len(rvecs)
    objs, imgs, views = [], [], []
    for i in range(P):
        m = obs.view == i
        if np.sum(m) < 20:
            continue
        H = plane_homography(xy[m], obs.value[m], obs.axis[m])
        v, a = obs.value[m], obs.axis[m]
        gx = np.linspace(*np.percentile(v[a == 0], [5, 95]), grid)
        gy = np.linspace(*np.percentile(v[a == 1], [5, 95]), grid)
        u = np.stack(np.meshgrid(gx, gy), axis=-1).reshape(-1, 2)
        b = np.column_stack([u, np.ones(len(u))]) @ np.linalg.inv(H).T
        b = b[:, :2] / b[:, 2:]
        objs.append(np.column_stack([b, np.zeros(len(b))]).astype(np.float32))
        imgs.append(u.astype(np.float32).reshape(-1, 1, 2))
        views.append(i)
    if len(views) < 3:
        raise NurbscanError(
            f"projector calibration: the grid was decoded in {len(views)} target view(s); "
            "at least 3 are needed")
    flags = cv2.CALIB_FIX_K2 | cv2.CALIB_FIX_K3 | cv2.CALIB_ZERO_TANGENT_DIST
    with single_thread_opencv():  # bit-identical from run to run
        _, K, dist, rv, tv = cv2.calibrateCamera(objs, imgs, tuple(int(s) for s in size), None,
                                                 None, flags=flags)
    kp = tsai_from_opencv(K, dist, *dp)
    Rb = rotmats(np.array(rv, float).reshape(-1, 3))  # board -> projector
    Rc = rotmats(rvecs[views])  # board -> camera
    Rcp = np.einsum("kab,kcb->kac", Rb, Rc)  # camera -> projector, per view
    U, _, Vt = np.linalg.svd(Rcp.sum(axis=0))
    R = U @ np.diag([1, 1, np.linalg.det(U @ Vt)]) @ Vt
    tcp = np.array(tv, float).reshape(-1, 3) - np.einsum("ab,kb->ka", R, tvecs[views])
    return kp, rotvecs(R), np.median(tcp, axis=0)
