"""The shape of a printed board's white part in the calibration bundle (issue 31).

Oracles: scipy's own B-spline basis elements, exact planes (which a cubic B-spline reproduces
from its Greville abscissae), the camera rays themselves, and a synthetic rig whose board's
white part is bowed by a known height field: the bundle with the surface recovers that field
and leaves no projector residual, the flat bundle cannot.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.interpolate import BSpline
from scipy.spatial.transform import Rotation

from nurbscan.calibrate._bundle import (
    BundleState,
    CornerObs,
    ProjObs,
    projector_residuals,
    run_bundle,
)
from nurbscan.calibrate._tsai import project_local, rotvecs
from nurbscan.calibrate.camera import board_points
from nurbscan.calibrate.surface import BoardSurface, surface_points

RNG = np.random.default_rng(7)


def test_surface_basis_matches_scipy_and_reproduces_planes():
    xy = RNG.uniform([-100.0, -50.0], [200.0, 300.0], (300, 2))
    s = BoardSurface.spanning(xy, 24.0)
    nx, ny = s.shape
    assert nx * ny == len(s.coef) and np.all(np.diff(s.tx) <= 24.0 + 1e-9)
    B = s.basis(xy)
    assert np.allclose(np.asarray(B.sum(axis=1)).ravel(), 1.0)  # partition of unity
    c = RNG.normal(size=len(s.coef))
    ref = []
    for x, y in xy[:25]:
        v = 0.0
        for i in range(nx):
            bi = BSpline.basis_element(s.tx[i:i + 5], extrapolate=False)(x)
            if not np.isfinite(bi) or bi == 0:
                continue
            for j in range(ny):
                bj = BSpline.basis_element(s.ty[j:j + 5], extrapolate=False)(y)
                if np.isfinite(bj):
                    v += c[i * ny + j] * bi * bj
        ref.append(v)
    assert np.allclose(s.with_coef(c).height(xy[:25]), ref, atol=1e-12)
    gx, gy = s.greville()
    plane = (1.5 + 0.01 * gx[:, None] - 0.02 * gy[None, :]).ravel()
    assert np.allclose(s.with_coef(plane).height(xy), 1.5 + 0.01 * xy[:, 0] - 0.02 * xy[:, 1],
                       atol=1e-12)
    assert np.abs(s.roughness() @ plane).max() < 1e-12  # the penalty leaves planes free
    assert np.abs(s.roughness() @ c).max() > 0.1


def test_surface_points_lie_on_the_rays_and_the_raised_board():
    kc, dc = np.array([12.5, 320.0, 240.0, 1.0, 1e-4]), (0.0023 * 4.8, 0.0023 * 4.8)
    R = Rotation.from_euler("xyz", [20.0, -15.0, 5.0], degrees=True).as_matrix()
    t = np.array([-80.0, -60.0, 600.0])
    px = RNG.uniform([50, 50], [590, 430], (200, 2))
    s = BoardSurface.spanning(np.array([[-400.0, -400.0], [400.0, 400.0]]), 50.0)
    s = s.with_coef(np.full(len(s.coef), 2.5))  # a constant height: the plane z = 2.5 mm
    X, xy = surface_points(kc, rotvecs(R)[None], t[None], px, np.zeros(200, int), *dc, s)
    zb = (X - t) @ R[:, 2]
    assert np.abs(zb - 2.5).max() < 1e-9
    assert np.abs(project_local(X, kc, *dc) - px).max() < 1e-6  # on the pixels' rays
    assert np.allclose(xy, ((X - t) @ R)[:, :2])


def _bowed_board_data(height):
    """Corners and projector observations of a synthetic rig (nurbscan's default rig) seeing
    a 9 x 7 board of 20 mm squares whose white part has the height field ``height``."""
    from nurbscan.calibrate.pipeline import _cam_params

    sim_rig = pytest.importorskip("nurbscan.simulate.rig")
    rig = sim_rig.default_rig()
    kc, dc = _cam_params(rig.camera)
    kp, dp = _cam_params(rig.projector)
    rp, tp = rotvecs(np.asarray(rig.projector.R)), np.asarray(rig.projector.T, float)
    board = board_points((9, 7), 20.0)
    rv, tv, cpx, cview, obs = [], [], [], [], []
    for i, ang in enumerate(([18, -12, 4], [-15, 20, -6], [8, 25, 10], [-22, -8, 2],
                             [12, 5, -12])):
        R = Rotation.from_euler("xyz", ang, degrees=True).as_matrix()
        t = np.array([-80.0, -60.0, 620.0]) + RNG.uniform(-20, 20, 3)
        rv.append(rotvecs(R))
        tv.append(t)
        cpx.append(project_local(board @ R.T + t, kc, *dc) + RNG.normal(0, 0.02, (63, 2)))
        cview.append(np.full(63, i))
        xy = RNG.uniform([-100.0, -80.0], [260.0, 200.0], (1200, 2))
        xy = xy[~((xy[:, 0] > -25) & (xy[:, 0] < 185) & (xy[:, 1] > -25) & (xy[:, 1] < 145))]
        X = np.column_stack([xy, height(xy)]) @ R.T + t
        px = project_local(X, kc, *dc)
        uv = project_local(X @ Rotation.from_rotvec(rp).as_matrix().T + tp, kp, *dp)
        axis = np.arange(len(xy)) % 2
        obs.append(ProjObs(px, uv[np.arange(len(xy)), axis], axis, np.full(len(xy), i),
                           np.zeros(len(xy))))
    corners = CornerObs(np.tile(board, (5, 1)), np.concatenate(cpx), np.concatenate(cview))
    proj = ProjObs(*(np.concatenate([getattr(o, k) for o in obs])
                     for k in ("pixels", "value", "axis", "view", "sign")))
    state = BundleState(kc=kc, rvecs=np.array(rv), tvecs=np.array(tv), kp=kp, rp=rp, tp=tp)
    return state, corners, proj, dc, dp


def test_bundle_recovers_a_bowed_white_board():
    """A white part bowed by up to 2 mm (a paraboloid, which cubic B-splines hold exactly):
    the flat bundle is left with projector residuals of tenths of a px, the bundle with the
    surface recovers the heights within 0.05 mm and the residuals vanish (noise-free
    projector coordinates, corners with 0.02 px noise)."""

    def height(xy):
        return 2.0 - 2.0 * (((xy[:, 0] - 80.0) / 190.0) ** 2 + ((xy[:, 1] - 60.0) / 150.0) ** 2)

    st, corners, proj, dc, dp = _bowed_board_data(height)
    flat = run_bundle(st, corners, proj, dc, dp)
    assert flat.cost["projector_rms_px"] > 0.1
    X, xy = surface_points(st.kc, st.rvecs, st.tvecs, proj.pixels, proj.view, *dc, None)
    surf = BoardSurface.spanning(xy, 20.0)
    fit = run_bundle(st, corners, proj, dc, dp, surface=surf)
    assert fit.cost["projector_rms_px"] < 0.02
    r = projector_residuals(fit.kc, fit.rvecs, fit.tvecs, fit.kp, fit.rp, fit.tp, proj, dc, dp,
                            surface=fit.surface)
    assert np.sqrt(np.mean(r**2)) == pytest.approx(fit.cost["projector_rms_px"])
    _, xy_fit = surface_points(fit.kc, fit.rvecs, fit.tvecs, proj.pixels, proj.view, *dc,
                               fit.surface)
    err = fit.surface.height(xy_fit) - height(xy_fit)
    assert np.sqrt(np.mean(err**2)) < 0.05
    assert fit.cost["camera_rms_px"] < 0.05
