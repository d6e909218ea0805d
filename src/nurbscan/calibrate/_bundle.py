"""Joint non-linear least squares (bundle adjustment) over camera, projector and board poses.

Unknowns (Tsai 1987 model, method.md section 4): the camera intrinsics ``kc = (f, cx, cy, sx,
k1)``; optionally the projector intrinsics ``kp`` (same form), the projector pose
``(rp, tp)`` (Rodrigues vector and translation, rig = camera frame -> projector frame) and
the band-edge bias ``shrink`` (2,) of the edge detector per axis (rising edges read
``-shrink``, falling ``+shrink`` projector px off their exact coordinate: a symmetric bias,
not confounded with the principal point); and one pose ``(r_i, t_i)`` per target view (board
frame -> camera frame).

Residuals, in pixels of the device that observes them:

* camera: each detected chessboard corner against the projection of its board point,
  ``P_c(R_i X + t_i) - c`` (2 per corner);
* projector: each decoded camera point ``c`` whose projector coordinate ``v`` along axis
  ``a`` (0 = x for vertical band edges, 1 = y for horizontal edges) is known exactly: the
  camera ray through ``c`` is intersected with the board plane of its view (Moreno and Taubin
  2012 map camera points onto the plane; here the plane is the board pose, exactly), the point is
  projected into the projector and its coordinate ``a`` compared with ``v`` (1 per observation:
  a band edge fixes only the coordinate across it; a grid intersection gives two observations).

A printed board's white part may be given a shape (:mod:`nurbscan.calibrate.surface`): the
camera rays of the projector observations then meet that height field over the board plane,
whose B-spline coefficients are unknowns shared by all views, with a roughness penalty on
their second differences as extra residual rows.

Solved with :func:`scipy.optimize.least_squares` (trust-region reflective, exact solves) and
a grouped central-difference Jacobian: a view's pose affects only its own residuals, so the
Jacobian needs 2 (6 + 16) function evaluations whatever the view count.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

from ..errors import NurbscanError
from ._tsai import back_project_local, project_local, rotmats
from .surface import BoardSurface, surface_points


@dataclass
class CornerObs:
    """Chessboard corners of all views: board points, pixels and the view of each corner."""

    board: np.ndarray  # (M, 3) board-frame points, mm
    pixels: np.ndarray  # (M, 2) camera px
    view: np.ndarray  # (M,) int view index


@dataclass
class ProjObs:
    """Projector observations: camera pixel, projector coordinate value and axis, view."""

    pixels: np.ndarray  # (K, 2) camera px
    value: np.ndarray  # (K,) projector px
    axis: np.ndarray  # (K,) 0 (x) or 1 (y)
    view: np.ndarray  # (K,) int view index
    sign: np.ndarray | None = None  # (K,) -1 rising edge, +1 falling edge, 0 unknown


@dataclass
class BundleState:
    """Parameters of the bundle (see the module docstring)."""

    kc: np.ndarray
    rvecs: np.ndarray  # (P, 3)
    tvecs: np.ndarray  # (P, 3)
    kp: np.ndarray | None = None
    rp: np.ndarray | None = None
    tp: np.ndarray | None = None
    shrink: np.ndarray | None = None  # (2,) band-edge bias per axis, projector px
    surface: BoardSurface | None = None  # the board's white part (None: the corners' plane)
    cost: dict = field(default_factory=dict)


def camera_residuals(kc, rvecs, tvecs, obs: CornerObs, dx, dy) -> np.ndarray:
    """Corner reprojection residuals (M, 2) in camera px."""
    R = rotmats(rvecs)[obs.view]
    xc = np.einsum("mij,mj->mi", R, obs.board) + tvecs[obs.view]
    return project_local(xc, kc, dx, dy) - obs.pixels


def plane_points(kc, rvecs, tvecs, pixels, view, dx, dy) -> np.ndarray:
    """Camera-frame points (K, 3) where the camera rays of ``pixels`` meet their view's board."""
    d = back_project_local(pixels, kc, dx, dy)
    R = rotmats(rvecs)[view]
    n = R[:, :, 2]
    t = tvecs[view]
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.einsum("ki,ki->k", n, t) / np.einsum("ki,ki->k", n, d)
    return d * s[:, None]


def projector_residuals(kc, rvecs, tvecs, kp, rp, tp, obs: ProjObs, dc, dp,
                        shrink=None, surface: BoardSurface | None = None,
                        offset: float = 0.0) -> np.ndarray:
    """Projector-coordinate residuals (K,) in projector px (see the module docstring).

    ``shrink`` (2,): a detected band-edge bias per axis (x, y), in projector px: rising edges
    read ``-shrink``, falling edges ``+shrink`` off their true coordinate (the edge detector
    narrows or widens the bands symmetrically); it is subtracted from the residual.
    ``surface``: the shape of the board's white part (:func:`surface_points`; ``offset`` mm
    added to its heights); None: the board plane.
    """
    if surface is None:
        X = plane_points(kc, rvecs, tvecs, obs.pixels, obs.view, *dc)
    else:
        X = surface_points(kc, rvecs, tvecs, obs.pixels, obs.view, *dc, surface,
                           offset=offset)[0]
    xp = X @ rotmats(rp).T + tp
    uv = project_local(xp, kp, *dp)
    r = np.take_along_axis(uv, obs.axis[:, None], axis=1)[:, 0] - obs.value
    if shrink is not None and obs.sign is not None:
        r = r - obs.sign * np.asarray(shrink)[obs.axis]
    return r


def run_bundle(
    state: BundleState,
    corners: CornerObs,
    proj: ProjObs | None,
    dc: tuple[float, float],
    dp: tuple[float, float] | None = None,
    fix_sx_proj: bool = False,
    proj_weight: float = 1.0,
    max_nfev: int = 200,
    corner_weight: np.ndarray | None = None,
    surface: BoardSurface | None = None,
    surface_weight: float = 0.3,
) -> BundleState:
    """Minimise the camera (and projector) reprojection residuals over all unknowns.

    Parameters
    ----------
    state : BundleState
        Initial values; ``kp``, ``rp``, ``tp`` are used (and fitted) only if ``proj`` is given.
    corners : CornerObs
        Chessboard corners (camera residuals).
    proj : ProjObs or None
        Projector observations; None fits the camera alone.
    dc, dp : (float, float)
        Pixel pitch (mm) of camera and projector.
    fix_sx_proj : bool
        Keep the projector's sx at its initial value.
    proj_weight : float
        Weight of the projector residuals relative to the camera's.
    max_nfev : int
        Iteration cap (function evaluations) of the solver.
    corner_weight : ndarray, shape (P,), optional
        Weight of each view's corner residuals (default 1 for all), e.g. the inverse of the
        view's corner error scale relative to the others' (inverse-variance weighting).
    surface : BoardSurface, optional
        Fit the shape of the board's white part, starting from these coefficients (only
        with ``proj``): its coefficients are unknowns shared by all views.
    surface_weight : float
        Weight of the roughness rows ``surface_weight * D c`` (projector px per mm of second
        difference of the coefficients, ``D`` :meth:`BoardSurface.roughness`).

    Returns
    -------
    BundleState
        The fitted parameters; ``cost`` holds the RMS of each residual block.
    """
    P = len(state.rvecs)
    use_p = proj is not None
    # the band-edge bias is fitted only when some observation is a signed band edge (the
    # centre-lines of thin lines, sign 0, leave it undetermined: it stays 0)
    fit_sh = use_p and proj.sign is not None and bool(np.any(proj.sign != 0))
    n_int = 5 + (10 + (0 if fix_sx_proj else 1) + (2 if fit_sh else 0) if use_p else 0)
    kp0 = None if state.kp is None else np.asarray(state.kp, float)
    surf = surface if use_p else None
    n_pose = n_int + 6 * P
    D = None if surf is None else surf.roughness() * float(surface_weight)

    def unpack(x):
        kc = x[:5]
        if use_p:
            i = 5
            if fix_sx_proj:
                kp = np.array([x[i], x[i + 1], x[i + 2], kp0[3], x[i + 3]])
                i += 4
            else:
                kp = x[i:i + 5]
                i += 5
            rp, tp = x[i:i + 3], x[i + 3:i + 6]
            sh = x[i + 6:i + 8] if fit_sh else np.zeros(2)
        else:
            kp = rp = tp = sh = None
        poses = x[n_int:n_pose].reshape(P, 6)
        return kc, kp, rp, tp, sh, poses[:, :3], poses[:, 3:]

    def shape_of(x):
        return None if surf is None else surf.with_coef(x[n_pose:])

    x0 = [np.asarray(state.kc, float)]
    if use_p:
        x0.append(kp0[[0, 1, 2, 4]] if fix_sx_proj else kp0)
        x0 += [np.asarray(state.rp, float), np.asarray(state.tp, float)]
        if fit_sh:
            x0.append(np.zeros(2) if state.shrink is None else np.asarray(state.shrink, float))
    x0.append(np.hstack([state.rvecs, state.tvecs]).ravel())
    if surf is not None:
        x0.append(np.asarray(surf.coef, float))
    x0 = np.concatenate(x0)

    M = len(corners.view)
    K = 0 if not use_p else len(proj.view)

    cw = None if corner_weight is None else np.repeat(
        np.asarray(corner_weight, float)[corners.view], 2)

    def fun(x):
        kc, kp, rp, tp, sh, rv, tv = unpack(x)
        r = camera_residuals(kc, rv, tv, corners, *dc).ravel()
        if cw is not None:
            r = r * cw
        if use_p:
            rpj = projector_residuals(kc, rv, tv, kp, rp, tp, proj, dc, dp, sh,
                                      shape_of(x)) * proj_weight
            r = np.concatenate([r, rpj])
        if D is not None:
            r = np.concatenate([r, D @ x[n_pose:]])
        return np.nan_to_num(r, nan=1e3)

    # Finite-difference Jacobian by column groups (Curtis, Powell and Reid 1974): a view's pose
    # affects only its own residuals, so parameter j of every view's pose is perturbed at once.
    steps = np.empty(len(x0))
    base_steps = {"f": 1e-6, "c": 1e-4, "sx": 1e-7, "k1": 1e-10}
    ks = [base_steps[k] for k in ("f", "c", "c", "sx", "k1")]
    steps[:5] = ks
    if use_p:
        kps = [s_ for s_, k in zip(ks, "fccsk", strict=True) if not (fix_sx_proj and k == "s")]
        steps[5:n_int] = kps + [1e-7] * 3 + [1e-5] * 3 + ([1e-4] * 2 if fit_sh else [])
    steps[n_int:n_pose] = np.tile([1e-7] * 3 + [1e-5] * 3, P)
    vrows = np.concatenate([np.repeat(corners.view, 2)] + ([proj.view] if use_p else []))
    n_pen = 0 if D is None else D.shape[0]

    def surface_columns(x):
        """(K, S) Jacobian of the projector residuals in the surface coefficients: the
        derivative of each residual in the height under its point (central difference of a
        common height offset) times the basis there; the point's drift in x, y with the
        height is of second order."""
        kc, kp, rp, tp, sh, rv, tv = unpack(x)
        s_ = shape_of(x)
        eps = 1e-3
        g = (projector_residuals(kc, rv, tv, kp, rp, tp, proj, dc, dp, sh, s_, eps)
             - projector_residuals(kc, rv, tv, kp, rp, tp, proj, dc, dp, sh, s_, -eps)) / (2 * eps)
        xy = surface_points(kc, rv, tv, proj.pixels, proj.view, *dc, s_)[1]
        B = s_.basis(np.nan_to_num(xy))
        return B.multiply(np.nan_to_num(g)[:, None] * proj_weight).toarray()

    def jac(x):
        J = np.zeros((2 * M + K + n_pen, len(x)))
        for j in range(n_int):
            e = np.zeros(len(x))
            e[j] = steps[j]
            J[:, j] = (fun(x + e) - fun(x - e)) / (2 * steps[j])
        for j in range(6):
            e = np.zeros(len(x))
            cols = n_int + 6 * np.arange(P) + j
            e[cols] = steps[cols]
            d = (fun(x + e) - fun(x - e)) / (2 * steps[cols][0])
            J[np.arange(len(vrows)), n_int + 6 * vrows + j] = d[:len(vrows)]
        if surf is not None:
            J[2 * M:2 * M + K, n_pose:] = surface_columns(x)
            J[2 * M + K:, n_pose:] = D.toarray()
        return J

    res = least_squares(fun, x0, jac=jac, x_scale="jac", method="trf", tr_solver="exact",
                        max_nfev=max_nfev, xtol=1e-10, ftol=1e-12, gtol=1e-10)
    if not np.all(np.isfinite(res.x)):
        raise NurbscanError("calibration: the least-squares fit diverged")
    kc, kp, rp, tp, sh, rv, tv = unpack(res.x)
    out = BundleState(kc=kc.copy(), rvecs=rv.copy(), tvecs=tv.copy(),
                      kp=None if kp is None else np.array(kp), rp=None if rp is None else rp.copy(),
                      tp=None if tp is None else tp.copy(),
                      shrink=None if sh is None else sh.copy(), surface=shape_of(res.x))
    rc = camera_residuals(kc, rv, tv, corners, *dc)
    out.cost["camera_rms_px"] = float(np.sqrt(np.nanmean(np.sum(rc**2, axis=1))))
    if use_p:
        rpj = projector_residuals(kc, rv, tv, kp, rp, tp, proj, dc, dp, sh, out.surface)
        out.cost["projector_rms_px"] = float(np.sqrt(np.nanmean(rpj**2)))
    out.cost["nfev"] = int(res.nfev)
    return out
