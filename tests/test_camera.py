"""Tests of nurbscan.camera: Tsai's model (Tsai 1987; method.md section 4), turntable, rig.

Ground truth and oracles: Tsai's equations written out by hand, OpenCV's ``projectPoints``
(k1 = 0), exact round trips (back-project -> project, distort <-> undistort, JSON), and the
turntable's geometry (fixed axis, full turn).
"""

from __future__ import annotations

import json
import math

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from nurbscan.camera import (
    Camera,
    Projector,
    Rig,
    Turntable,
    distortion_scale,
    load_rig,
)
from nurbscan.errors import NurbscanError

W, H = 3072, 2304
F, PITCH, SX = 14.0, 0.0023, 1.0031
CX, CY = 1530.25, 1160.75
POSE_R = Rotation.from_rotvec([0.21, -0.33, 0.12]).as_matrix()
POSE_T = np.array([31.0, -22.5, 480.0])
K1_STRONG = 6.0e-4  # mm^-2: moves the image corners by about 22 px (asserted below)


def camera(k1: float = 0.0, cls=Camera, **kw) -> Camera:
    args = dict(width=W, height=H, f=F, cx=CX, cy=CY, dx=PITCH, dy=PITCH, sx=SX, k1=k1,
                R=POSE_R, T=POSE_T)
    args.update(kw)
    return cls(**args)


def corner_shift_px(cam: Camera) -> float:
    """Pixel distance between the distorted and the undistorted image of the corner (0, 0)."""
    xd, yd = cam.pixel_to_sensor([-0.5, -0.5])
    xu, yu = cam.undistort(xd, yd)
    return float(np.hypot((xu - xd) * cam.sx / cam.dx, (yu - yd) / cam.dy))


# ----------------------------------------------------------------------------- projection
@pytest.mark.parametrize("k1", [K1_STRONG, -K1_STRONG])
def test_project_returns_the_back_projected_pixel(k1):
    cam = camera(k1)
    assert corner_shift_px(cam) >= 20.0
    rng = np.random.default_rng(11)
    px = rng.uniform([-0.5, -0.5], [W - 0.5, H - 0.5], (1_000_000, 2))
    origin, d = cam.back_project(px)
    np.testing.assert_allclose(np.linalg.norm(d, axis=-1), 1.0, atol=1e-15)
    pts = origin + d * rng.uniform(50.0, 5000.0, (len(px), 1))
    back, valid = cam.project(pts, return_valid=True)
    assert valid.all()
    err = np.max(np.abs(back - px))
    assert err < 1e-6, err


@pytest.mark.parametrize("k1", [K1_STRONG, -K1_STRONG, 0.0])
def test_project_satisfies_tsai_equations(k1):
    """The pixel of a point, read back through Tsai's equations, gives f x / z exactly."""
    cam = camera(k1)
    rng = np.random.default_rng(12)
    X = np.column_stack([rng.uniform(-300, 300, (5000, 2)), rng.uniform(200, 900, 5000)])
    px = cam.project(X)
    x = X @ POSE_R.T + POSE_T
    xu, yu = F * x[:, 0] / x[:, 2], F * x[:, 1] / x[:, 2]
    xd = (px[:, 0] - CX) * PITCH / SX  # Xf = sx Xd / dx + Cx
    yd = (px[:, 1] - CY) * PITCH
    s = 1.0 + k1 * (xd**2 + yd**2)  # Xu = Xd (1 + k1 r^2)
    assert np.max(np.abs(xd * s - xu)) < 1e-12
    assert np.max(np.abs(yd * s - yu)) < 1e-12


def test_behind_camera_and_outside_domain_are_flagged():
    cam = camera(K1_STRONG)
    c = cam.center
    ahead = c + 500.0 * cam.axis
    behind = c - 500.0 * cam.axis
    at_centre = c
    px, valid = cam.project([ahead, behind, at_centre, [np.nan, 0, 0]], return_valid=True)
    assert valid.tolist() == [True, False, False, False]
    assert np.all(np.isfinite(px[0])) and np.all(np.isnan(px[1:]))
    # k1 < 0: the undistorted radius has a maximum ru* = (2/3) / sqrt(-3 k1)
    k1 = -0.05
    neg = camera(k1, R=np.eye(3), T=np.zeros(3))
    ru_max = (2.0 / 3.0) / math.sqrt(-3.0 * k1)
    assert neg.max_undistorted_radius == pytest.approx(ru_max, rel=1e-15)
    ru = ru_max * np.array([0.5, 0.99, 0.999999, 1.000001, 1.5, 10.0])
    ang = np.linspace(0.1, 2.0, len(ru))
    X = np.column_stack([ru * np.cos(ang) / F, ru * np.sin(ang) / F, np.ones(len(ru))]) * 700
    px, valid = neg.project(X, return_valid=True)
    assert valid.tolist() == [True, True, True, False, False, False]
    assert np.all(np.isnan(px[~valid]))
    # inside, Tsai's equation holds even close to the fold (rd -> rd* = 1 / sqrt(-3 k1))
    xd, yd = neg.pixel_to_sensor(px[valid]).T
    xu, yu = neg.undistort(xd, yd)
    np.testing.assert_allclose(xu, (X[valid, 0] / X[valid, 2]) * F, atol=1e-9)
    np.testing.assert_allclose(yu, (X[valid, 1] / X[valid, 2]) * F, atol=1e-9)
    # past the fold of the model a pixel has no ray
    rd_star = neg.max_distorted_radius
    pix = neg.sensor_to_pixel([[0.9 * rd_star, 0.0], [1.1 * rd_star, 0.0]])
    _, d = neg.back_project(pix)
    assert np.all(np.isfinite(d[0])) and np.all(np.isnan(d[1]))


def test_k1_zero_matches_opencv_project_points():
    cam = camera(0.0)
    rng = np.random.default_rng(13)
    X = np.column_stack([rng.uniform(-400, 400, (20000, 2)), rng.uniform(300, 3000, 20000)])
    K = np.array([[F / PITCH * SX, 0, CX], [0, F / PITCH, CY], [0, 0, 1.0]])
    ref = cv2.projectPoints(X.reshape(-1, 1, 3), cv2.Rodrigues(POSE_R)[0], POSE_T, K,
                            np.zeros(5))[0].reshape(-1, 2)
    assert np.max(np.abs(cam.project(X) - ref)) < 1e-9


@pytest.mark.parametrize("k1", [K1_STRONG, -K1_STRONG, 3e-3, -3e-3])
def test_distort_and_undistort_are_inverses(k1):
    cam = camera(k1)
    rng = np.random.default_rng(14)
    xd = rng.uniform(-3.6, 3.6, 200000)
    yd = rng.uniform(-2.7, 2.7, 200000)
    xu, yu = cam.undistort(xd, yd)
    x2, y2 = cam.distort(xu, yu)
    assert max(np.max(np.abs(x2 - xd)), np.max(np.abs(y2 - yd))) < 1e-12
    xu2, yu2 = cam.undistort(*cam.distort(xd, yd))
    assert max(np.max(np.abs(xu2 - xd)), np.max(np.abs(yu2 - yd))) < 1e-12


def test_distortion_scale_solves_the_cubic():
    c = np.concatenate([np.linspace(-4 / 27, 2.0, 100001), [0.0, 1e-9, -1e-9, 1e-8, -1e-8]])
    s = distortion_scale(c)
    assert np.max(np.abs(c * s**3 + s - 1.0)) < 4e-16
    assert s[0] == pytest.approx(1.5, rel=1e-7)  # the fold: s = 3/2 at c = -4/27
    assert np.isnan(distortion_scale(-4 / 27 * 1.0001))
    assert np.all(np.diff(s[:100001]) < 0)  # s decreases with c (one branch)


def test_pixel_sensor_and_pose_helpers():
    cam = camera(K1_STRONG)
    px = np.array([[CX, CY], [CX + 100, CY - 50]])
    xy = cam.pixel_to_sensor(px)
    np.testing.assert_allclose(xy, [[0, 0], [100 * PITCH / SX, -50 * PITCH]], atol=1e-15)
    np.testing.assert_allclose(cam.sensor_to_pixel(xy), px, atol=1e-9)
    np.testing.assert_allclose(cam.to_camera(cam.center), 0.0, atol=1e-12)
    moved = cam.with_pose(np.eye(3), [1.0, 2.0, 3.0])
    assert isinstance(moved, Camera) and moved.f == cam.f and moved.k1 == cam.k1
    np.testing.assert_allclose(moved.center, [-1.0, -2.0, -3.0])
    # the ray of the principal point runs along the optical axis
    o, d = cam.back_project([CX, CY])
    np.testing.assert_allclose(d, cam.axis, atol=1e-15)
    assert not cam.R.flags.writeable and not cam.T.flags.writeable


@pytest.mark.parametrize(
    ("kw", "match"),
    [
        (dict(f=-1.0), "camera f: must be positive"),
        (dict(dx=0.0), "camera dx: must be positive"),
        (dict(width=0), "camera width"),
        (dict(height=10.5), "camera height"),
        (dict(R=np.diag([1.0, 1.0, -1.0])), "determinant"),
        (dict(R=np.eye(3) * 1.001), "not orthonormal"),
        (dict(T=[1.0, 2.0]), "camera T: expected shape"),
        (dict(k1=float("nan")), "camera k1: must be finite"),
    ],
)
def test_camera_validation(kw, match):
    with pytest.raises(NurbscanError, match=match):
        camera(**kw)


# ----------------------------------------------------------------------------- OpenCV
@pytest.mark.parametrize("k1", [K1_STRONG, -K1_STRONG])
def test_to_opencv_matches_project(k1):
    cam = camera(k1)
    K, dist, R, tvec, err = cam.to_opencv()
    assert dist.shape == (5,) and dist[2] == 0 and dist[3] == 0
    np.testing.assert_allclose(K, [[F * SX / PITCH, 0, CX], [0, F / PITCH, CY], [0, 0, 1]])
    assert err < 1e-3  # measured: 4.6e-5 px (k1 > 0), 5.0e-5 px (k1 < 0) at 22 px corner shift
    rng = np.random.default_rng(15)
    px = rng.uniform([-0.5, -0.5], [W - 0.5, H - 0.5], (100000, 2))
    o, d = cam.back_project(px)
    X = o + d * rng.uniform(100, 2000, (len(px), 1))
    ref = cv2.projectPoints(X.reshape(-1, 1, 3), cv2.Rodrigues(R)[0], tvec, K,
                            dist)[0].reshape(-1, 2)
    diff = np.max(np.hypot(*(ref - cam.project(X)).T))
    assert diff <= err * 1.001 + 1e-9
    assert diff > 0.5 * err  # the returned figure is the real disagreement, not a loose bound
    # the fit is not a trivial match: OpenCV without distortion is off by the corner shift
    plain = cv2.projectPoints(X.reshape(-1, 1, 3), cv2.Rodrigues(R)[0], tvec, K,
                              np.zeros(5))[0].reshape(-1, 2)
    assert np.max(np.hypot(*(plain - cam.project(X)).T)) > 15.0


def test_to_opencv_strong_distortion_error_is_reported():
    cam = camera(3e-3)  # about 110 px at the corners
    K, dist, R, tvec, err = cam.to_opencv()
    assert 1e-3 < err < 0.05  # measured 0.025 px
    g = cam._grid_pixels()
    o, d = cam.back_project(g)
    X = o + d * 800.0
    ref = cv2.projectPoints(X.reshape(-1, 1, 3), cv2.Rodrigues(R)[0], tvec, K,
                            dist)[0].reshape(-1, 2)
    assert np.max(np.hypot(*(ref - cam.project(X)).T)) == pytest.approx(err, rel=1e-6)


@pytest.mark.parametrize("k1", [K1_STRONG, -K1_STRONG])
def test_from_opencv_round_trip(k1):
    cam = camera(k1, cls=Projector, name="p")
    K, dist, R, tvec, _ = cam.to_opencv()
    back, err = Projector.from_opencv(K, dist, cv2.Rodrigues(R)[0], tvec, W, H, dx=PITCH,
                                      name="p")
    assert isinstance(back, Projector)
    assert back.f == pytest.approx(F, rel=1e-14) and back.sx == pytest.approx(SX, rel=1e-14)
    assert back.k1 == pytest.approx(k1, rel=1e-6)
    np.testing.assert_allclose(back.R, POSE_R, atol=1e-14)
    assert err < 1e-3


def test_from_opencv_of_a_real_opencv_model():
    """OpenCV's k1, k2 (not Tsai's model): the fitted k1 and the documented error."""
    K = np.array([[6000.0, 0, 1536.0], [0, 6010.0, 1150.0], [0, 0, 1]])
    dist = np.array([-0.1, 0.05, 0, 0, 0])
    cam, err = Camera.from_opencv(K, dist, np.zeros(3), np.zeros(3), W, H, dx=PITCH)
    assert 0.01 < err < 0.3  # measured 0.15 px: one Tsai term cannot hold OpenCV's k2
    # barrel distortion in OpenCV (k1_cv < 0) is Tsai k1 > 0, about -k1_cv / f^2
    assert cam.k1 == pytest.approx(0.1 / cam.f**2, rel=0.2)
    rng = np.random.default_rng(16)
    X = np.column_stack([rng.uniform(-0.25, 0.25, (50000, 1)), rng.uniform(-0.19, 0.19,
                                                                          (50000, 1)),
                         np.ones((50000, 1))]) * 600.0
    ref = cv2.projectPoints(X.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K,
                            dist)[0].reshape(-1, 2)
    ours = cam.project(X)
    inside = (ref[:, 0] > -0.5) & (ref[:, 0] < W - 0.5) & (ref[:, 1] > -0.5) & (
        ref[:, 1] < H - 0.5)
    assert inside.sum() > 40000
    assert np.max(np.hypot(*(ref - ours)[inside].T)) <= err * 1.001


# ----------------------------------------------------------------------------- turntable
def turntable() -> Turntable:
    return Turntable(point=[5.0, 80.0, 600.0], direction=[0.05, -2.0, -0.6])


def test_turntable_geometry():
    tt = turntable()
    a = tt.direction
    assert np.linalg.norm(a) == pytest.approx(1.0, abs=1e-15)
    np.testing.assert_allclose(tt.rotation(2 * np.pi), np.eye(3), atol=1e-14)
    np.testing.assert_allclose(tt.rotation(0.7) @ tt.rotation(-0.7), np.eye(3), atol=1e-15)
    Fm = tt.frame()
    np.testing.assert_allclose(Fm.T @ Fm, np.eye(3), atol=1e-15)
    assert np.linalg.det(Fm) == pytest.approx(1.0, abs=1e-14)
    np.testing.assert_allclose(Fm[:, 2], a, atol=1e-15)
    # x_t points from the table towards the camera (at the rig origin), across the axis
    assert Fm[:, 0] @ (np.zeros(3) - tt.point) > 0
    assert abs(Fm[:, 0] @ a) < 1e-15
    # right-hand rule: a quarter turn takes x_t to y_t
    np.testing.assert_allclose(tt.rotation(np.pi / 2) @ Fm[:, 0], Fm[:, 1], atol=1e-15)
    rng = np.random.default_rng(17)
    P = rng.uniform(-60, 60, (1000, 3))
    for ang in (0.0, 0.4, -2.5, 7.0):
        rig = tt.to_rig(P, ang)
        np.testing.assert_allclose(tt.from_rig(rig, ang), P, atol=1e-12)
        # distances to the axis point are kept; the axis is fixed
        np.testing.assert_allclose(np.linalg.norm(rig - tt.point, axis=1),
                                   np.linalg.norm(P, axis=1), rtol=1e-13)
        axis_pts = np.column_stack([np.zeros(5), np.zeros(5), np.linspace(-50, 90, 5)])
        np.testing.assert_allclose(tt.to_rig(axis_pts, ang),
                                   tt.point + axis_pts[:, 2:] * a, atol=1e-12)
    # the table origin at angle 0 maps x_t exactly
    np.testing.assert_allclose(tt.to_rig([1.0, 0.0, 0.0], 0.0), tt.point + Fm[:, 0], atol=1e-13)
    with pytest.raises(NurbscanError, match="turntable direction"):
        Turntable(point=[0, 0, 0], direction=[0, 0, 0])
    with pytest.raises(NurbscanError, match="optical axis"):
        Turntable(point=[0, 0, 500], direction=[0, 0, -1])


# ----------------------------------------------------------------------------- JSON
def rig() -> Rig:
    proj = camera(-3e-5, cls=Projector, width=1920, height=1080, f=24.0, cx=960.1, cy=999.9,
                  dx=0.00756, dy=0.00756, sx=1.0)
    cam = camera(1e-4, R=np.eye(3), T=np.zeros(3), name="cam 1")
    return Rig(camera=cam, projector=proj, turntable=turntable())


def test_json_round_trips_are_exact(tmp_path):
    r = rig()
    for obj in (r.camera, r.projector, r.turntable, r):
        d = json.loads(json.dumps(obj.to_dict()))
        back = type(obj).from_dict(d)
        assert back == obj and type(back) is type(obj)
        assert back.to_dict() == obj.to_dict()
    assert r.camera.to_dict()["type"] == "nurbscan.camera"
    assert r.projector.to_dict()["type"] == "nurbscan.projector"
    assert r.projector.name == "projector"
    assert r.turntable.to_dict()["type"] == "nurbscan.turntable"
    back = Camera.from_dict(json.loads(json.dumps(r.camera.to_dict())))
    assert np.array_equal(back.R, r.camera.R) and np.array_equal(back.T, r.camera.T)
    assert back.k1 == r.camera.k1 and back.sx == r.camera.sx
    path = r.save(tmp_path / "sub" / "rig.json")
    loaded = load_rig(path)
    assert loaded == r
    X = np.array([[10.0, -20.0, 600.0], [-50.0, 30.0, 550.0]])
    assert np.array_equal(loaded.projector.project(X), r.projector.project(X))
    assert [p.name for p in tmp_path.joinpath("sub").iterdir()] == ["rig.json"]


def test_load_rig_errors(tmp_path):
    with pytest.raises(NurbscanError, match="file not found"):
        load_rig(tmp_path / "nope.json")
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(NurbscanError, match="not valid JSON"):
        load_rig(bad)
    d = rig().to_dict()
    del d["projector"]["k1"]
    p = tmp_path / "missing.json"
    p.write_text(json.dumps(d))
    with pytest.raises(NurbscanError, match=r"missing\.json projector: missing key 'k1'"):
        load_rig(p)
    d = rig().to_dict()
    d["camera"]["type"] = "nurbscan.projector"
    p.write_text(json.dumps(d))
    with pytest.raises(NurbscanError, match="expected 'nurbscan.camera'"):
        load_rig(p)
    d = rig().to_dict()
    d["camera"]["f"] = -3
    p.write_text(json.dumps(d))
    with pytest.raises(NurbscanError, match="camera f: must be positive"):
        load_rig(p)
    with pytest.raises(NurbscanError, match="rig projector: expected a Projector"):
        Rig(camera=rig().camera, projector=rig().camera, turntable=turntable())
