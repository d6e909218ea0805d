"""Calibration of camera, projector and turntable (issue 6).

Two kinds of tests:

* synthetic correspondences (no images): Tsai projection against nurbscan.camera, the camera
  fit, the projector homography, the turntable axis and the failure cases, against the exact
  parameters they were made from;
* one small simulated scan (camera 768 x 576, the default rig's field of view; the figures of
  issue 6 in camera px scale by 3072 / 768 = 4 here): the whole calibration against the
  simulator's true rig, and the command line.
"""

from __future__ import annotations

import json
import shutil
import warnings
from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from nurbscan.calibrate import (
    board_points,
    calibrate_camera,
    compare_rigs,
    fit_turntable,
    plane_homography,
)
from nurbscan.calibrate._tsai import back_project_local, project_local, rotmats
from nurbscan.errors import NurbscanError

DC = (0.0023, 0.0023)
KC = np.array([12.5, 1539.3, 1148.6, 1.0, 1.0e-4])
SIZE = (3072, 2304)
BOARD = board_points((9, 7), 20.0)


def _views(n, rng, tilt=25.0, noise=0.05):
    """Random board poses in front of the camera and their noisy corner pixels."""
    out, poses = [], []
    for _ in range(n):
        R = Rotation.from_euler("xyz", rng.uniform(-tilt, tilt, 3), degrees=True).as_matrix()
        t = np.array([-80.0, -60.0, 600.0]) + rng.uniform(-30, 30, 3)
        out.append(project_local(BOARD @ R.T + t, KC, *DC) + rng.normal(0, noise, (63, 2)))
        poses.append((R, t))
    return out, poses


# ------------------------------------------------------------------ model


def test_tsai_projection_inverts_back_projection_and_distortion():
    rng = np.random.default_rng(1)
    px = rng.uniform([0, 0], SIZE, (500, 2))
    d = back_project_local(px, KC, *DC)
    X = d * rng.uniform(300, 900, (500, 1))
    np.testing.assert_allclose(project_local(X, KC, *DC), px, atol=1e-9)
    # the distortion model itself, written forward: Xu = Xd (1 + k1 r^2) at pixel (0, 0)
    xd, yd = (0 - KC[1]) * DC[0], (0 - KC[2]) * DC[1]
    s = 1 + KC[4] * (xd**2 + yd**2)
    np.testing.assert_allclose(back_project_local(np.zeros((1, 2)), KC, *DC)[0],
                               [xd * s / KC[0], yd * s / KC[0], 1.0], rtol=1e-12)


def test_tsai_projection_agrees_with_nurbscan_camera():
    camera = pytest.importorskip("nurbscan.camera")
    rng = np.random.default_rng(2)
    R = Rotation.from_rotvec([0.1, -0.2, 0.05]).as_matrix()
    T = np.array([10.0, -5.0, 20.0])
    cam = camera.Camera(width=SIZE[0], height=SIZE[1], f=KC[0], cx=KC[1], cy=KC[2], dx=DC[0],
                        dy=DC[1], sx=1.002, k1=KC[4], R=R, T=T, name="c")
    X = np.column_stack([rng.uniform(-150, 150, (400, 2)), rng.uniform(450, 800, 400)])
    k = np.array([KC[0], KC[1], KC[2], 1.002, KC[4]])
    ours = project_local(X @ R.T + T, k, *DC)
    theirs = np.asarray(cam.project(X), float)
    np.testing.assert_allclose(ours, theirs, atol=1e-6)


# ------------------------------------------------------------------ camera


def test_camera_fit_recovers_tsai_parameters_from_noisy_corners():
    rng = np.random.default_rng(3)
    corners, poses = _views(12, rng)
    fit = calibrate_camera(corners, BOARD, SIZE, *DC)
    assert fit.rms == pytest.approx(0.05 * np.sqrt(2), rel=0.15)  # the noise, 2-D
    assert abs(fit.kc[0] / KC[0] - 1) < 1e-3
    assert np.hypot(*(fit.kc[1:3] - KC[1:3])) < 1.0
    assert abs(fit.kc[3] - 1) < 1e-4
    assert abs(fit.kc[4] / KC[4] - 1) < 0.05
    assert len(fit.per_view_rms) == 12
    np.testing.assert_allclose(fit.tvecs, [p[1] for p in poses], atol=0.5)


@pytest.mark.parametrize("size", [(1024, 768), (3072, 2304)])
def test_chessboard_corners_against_exact_homography(size):
    """Corners of a board warped by a known homography (small images: the sector-based
    detector at full size; large ones: found reduced, refined at full size)."""
    from nurbscan.calibrate import detect_chessboard

    w, h = size
    nx, ny, sq = 9, 7, 40  # inner corners; square side in the source image, px
    # source board: (nx + 1) x (ny + 1) squares, first square dark, a white margin of one square
    ii, jj = np.meshgrid(np.arange((nx + 3) * sq), np.arange((ny + 3) * sq))
    cell = (ii // sq - 1) + (jj // sq - 1)
    inside = (ii >= sq) & (jj >= sq) & (ii < (nx + 2) * sq) & (jj < (ny + 2) * sq)
    src = np.where(inside & (cell % 2 == 0), 25, 220).astype(np.uint8)
    # inner corner (i, j) of the source at pixel edge ((i + 2) sq - 0.5, (j + 2) sq - 0.5)
    gi, gj = np.meshgrid(np.arange(nx), np.arange(ny))
    corners_src = np.stack([(gi.ravel() + 2) * sq - 0.5, (gj.ravel() + 2) * sq - 0.5], 1)
    quad_src = np.float32([[0, 0], [src.shape[1], 0], [src.shape[1], src.shape[0]],
                           [0, src.shape[0]]]) - np.float32(0.5)
    quad_dst = (np.float32([[0.18, 0.15], [0.80, 0.12], [0.86, 0.83], [0.14, 0.90]])
                * np.float32([w, h]))
    M = cv2.getPerspectiveTransform(quad_src, quad_dst)
    img = cv2.warpPerspective(src, M, (w, h), flags=cv2.INTER_LINEAR, borderValue=128)
    img = cv2.GaussianBlur(img.astype(np.float32), (0, 0), 1.0)
    img = np.clip(img + np.random.default_rng(1).normal(0, 1.0, img.shape), 0, 255)
    truth = cv2.perspectiveTransform(corners_src[None].astype(np.float64), M)[0]
    found = detect_chessboard(img.astype(np.uint8), (nx, ny), first_square_dark=True)
    assert found is not None
    # 9 + 7 is even: the board looks the same turned by 180 degrees, either order is right
    err = min((np.hypot(*(c - truth).T) for c in (found, found[::-1])), key=np.max)
    assert np.sqrt(np.mean(err**2)) < 0.05 and err.max() < 0.15
    # a blank image has no board
    assert detect_chessboard(np.full((h, w), 128, np.uint8), (nx, ny)) is None


def test_smoothed_refinement_lowers_corner_error_on_rendered_boards():
    """Three simulated 1536 x 1152 poses (noise free): corners refined on the image smoothed
    by 1.5 px land within 0.035 px RMS of the truth, and at least 15 % closer than refined
    on the image itself (cornerSubPix's sub-pixel phase bias on sharp edges)."""
    from _board_fixtures import free_board
    from nurbscan.calibrate import detect_chessboard
    from nurbscan.simulate import RenderSettings, render_view
    from nurbscan.simulate.rig import default_rig, scale_camera
    from nurbscan.simulate.scan import default_pattern

    rig = scale_camera(default_rig(), 1536, 1152)
    pat = default_pattern(rig.projector)
    errs = {0.0: [], 1.5: []}
    for k in (1, 2, 3):
        board, scene, r_b, t_b = free_board(rig, k)
        white = render_view(scene, rig, pat, 0.0, RenderSettings(table=False, noise=0.0),
                            albedo=scene.albedo, albedo_cell=scene.albedo_cell).white
        truth = rig.camera.project(board.corners() @ r_b.T + t_b)
        for sigma, e in errs.items():
            c = detect_chessboard(white, (board.cols, board.rows), refine_sigma=sigma)
            if np.linalg.norm(c[0] - truth[0]) > np.linalg.norm(c[0] - truth[-1]):
                c = c[::-1]
            e.append(np.sum((c - truth) ** 2, axis=1))
    sharp, smooth = (np.sqrt(np.mean(np.concatenate(errs[k]))) for k in (0.0, 1.5))
    assert smooth < 0.035 and smooth < 0.85 * sharp


def test_camera_refuses_too_few_and_parallel_views():
    rng = np.random.default_rng(4)
    corners, _ = _views(2, rng)
    with pytest.raises(NurbscanError, match="at least 3"):
        calibrate_camera(corners, BOARD, SIZE, *DC)
    par = []
    for k in range(5):  # same orientation, moved around
        t = np.array([-80.0 + 15 * k, -60.0 + 7 * k, 600.0 + 20 * k])
        R = Rotation.from_euler("x", 20, degrees=True).as_matrix()
        par.append(project_local(BOARD @ R.T + t, KC, *DC))
    with pytest.raises(NurbscanError, match="parallel"):
        calibrate_camera(par, BOARD, SIZE, *DC)


# ------------------------------------------------------------------ projector, turntable


def test_plane_homography_from_single_coordinates():
    rng = np.random.default_rng(5)
    H = np.array([[3.1, 0.2, 400.0], [-0.1, 2.9, 300.0], [1e-4, -2e-4, 1.0]])
    xy = rng.uniform(0, 200, (300, 2))
    uv = np.column_stack([xy, np.ones(300)]) @ H.T
    uv = uv[:, :2] / uv[:, 2:]
    axis = rng.integers(0, 2, 300)
    Hf = plane_homography(xy, uv[np.arange(300), axis], axis)
    np.testing.assert_allclose(Hf / Hf[2, 2], H, rtol=1e-6, atol=1e-8)
    with pytest.raises(NurbscanError, match="both"):
        plane_homography(xy, uv[:, 0], np.zeros(300, int))


def test_corner_weights_downweight_views_worse_than_the_median():
    """Views with corner RMS above the median get median / rms (inverse-variance weighting),
    the others 1; a zero RMS is not a division by zero."""
    from nurbscan.calibrate.pipeline import corner_weights

    w = corner_weights(np.array([0.04, 0.05, 0.05, 0.10, 0.20, 0.0]))
    # median of the six: 0.05
    np.testing.assert_allclose(w, [1.0, 1.0, 1.0, 0.5, 0.25, 1.0], rtol=1e-12)


def test_turntable_axis_point_and_sense():
    rng = np.random.default_rng(6)
    a = np.array([0.0, -np.cos(0.35), -np.sin(0.35)])
    p = np.array([3.0, 55.0, 620.0])
    R0 = Rotation.from_euler("x", -40, degrees=True).as_matrix()
    t0 = np.array([-90.0, -40.0, 560.0])
    th = np.radians([-40, -20, 0, 20, 40])
    corners, rv, tv = [], [], []
    for ang in th:
        Rt = rotmats(ang * a)
        R, t = Rt @ R0, p + Rt @ (t0 - p)
        corners.append(project_local(BOARD @ R.T + t, KC, *DC) + rng.normal(0, 0.02, (63, 2)))
        rv.append(Rotation.from_matrix(R).as_rotvec() + rng.normal(0, 1e-3, 3))
        tv.append(t + rng.normal(0, 0.3, 3))
    fit = fit_turntable(np.array(rv), np.array(tv), th, BOARD, corners, KC, *DC)
    assert np.degrees(np.arccos(fit.direction @ a)) < 0.02
    d = fit.point - p
    assert np.linalg.norm(d - (d @ a) * a) < 0.1
    # reversed angles reverse the sense of the axis
    fit2 = fit_turntable(np.array(rv), np.array(tv), -th, BOARD, corners, KC, *DC)
    assert fit2.direction @ a < -0.999
    with pytest.raises(NurbscanError, match="at least 2"):
        fit_turntable(np.array(rv[:1]), np.array(tv[:1]), th[:1], BOARD, corners[:1], KC, *DC)


def test_held_out_error_against_exact_synthetic_edges():
    """Exact edge points made from the true rig: the triangulation error is zero, a known
    symmetric band-edge bias is found and removed, and the point selection keeps exactly the
    white-square points."""
    from types import SimpleNamespace

    from nurbscan.calibrate import Target, held_out_error
    from nurbscan.calibrate.pipeline import _cam_params

    sim_rig = pytest.importorskip("nurbscan.simulate.rig")
    rig = sim_rig.default_rig()
    target = Target(9, 7, 20.0)
    R = Rotation.from_euler("xyz", [20.0, -15.0, 5.0], degrees=True).as_matrix()
    T = np.array([-80.0, -60.0, 600.0])
    # square centres (i, j) in -1..8 x -1..6: white where i + j is odd; two points per centre
    ij = np.stack(np.meshgrid(np.arange(-1, 9), np.arange(-1, 6)), axis=-1).reshape(-1, 2)
    xy = np.concatenate([(ij + 0.5) * 20.0, (ij + 0.3) * 20.0])
    white = np.concatenate([(ij.sum(axis=1) % 2 == 1)] * 2)
    X = np.column_stack([xy, np.zeros(len(xy))]) @ R.T + T
    px = np.asarray(rig.camera.project(X), float)
    kp, dp = _cam_params(rig.projector)
    uv = project_local(X @ np.asarray(rig.projector.R).T + rig.projector.T, kp, *dp)
    K = len(xy)
    axis = np.arange(K) % 2
    edge = (np.arange(K) // 2) % 2  # 0 rising, 1 falling
    bias = np.array([0.3, 0.2])
    value = uv[np.arange(K), axis] - (2.0 * edge - 1.0) * bias[axis]  # inward: falling - bias
    det = SimpleNamespace(x=px[:, 0], y=px[:, 1], line=np.arange(K), direction=axis,
                          coord=value, edge=edge)
    exact = held_out_error(rig, rig, det, R, T, edge_bias=bias)
    assert exact["points"] == K and exact["gross_errors"] == 0
    assert exact["rms_mm"] < 1e-6 and exact["aligned_rms_mm"] < 1e-6
    raw = held_out_error(rig, rig, det, R, T)
    ce = raw["coord_error_px"]
    assert ce["x_rising"]["mean"] == pytest.approx(0.3, abs=1e-6)
    assert ce["x_falling"]["mean"] == pytest.approx(-0.3, abs=1e-6)
    assert ce["y_rising"]["mean"] == pytest.approx(0.2, abs=1e-6)
    assert ce["y_falling"]["mean"] == pytest.approx(-0.2, abs=1e-6)
    # one projector px is about 0.17 mm on the board at 600 mm, and the rays cross at about
    # 20 degrees: 0.2 to 0.3 projector px move the points about a quarter of a mm in depth
    assert 0.1 < raw["rms_mm"] < 0.5
    assert raw["plane_rms_mm"] < raw["rms_mm"]
    sel = held_out_error(rig, rig, det, R, T, edge_bias=bias, target=target)
    assert sel["points"] == int(np.sum(white))


# ------------------------------------------------------------------ simulated scan

#: Free poses kept for the quick scan (indices into nurbscan.simulate.target.FREE_POSES) and
#: table angles (degrees); the last free pose is held out of the calibration.
QUICK_FREE = (1, 2, 3, 4, 7, 11)
QUICK_TABLE = (-40.0, 0.0, 40.0)


@pytest.fixture(scope="module")
def quick_scan(tmp_path_factory):
    """A small simulated scan (camera 640 x 480): 6 free poses and 3 table poses."""
    sim_scan = pytest.importorskip("nurbscan.simulate.scan")
    from nurbscan.simulate import Plane
    from nurbscan.simulate import target as sim_target
    from nurbscan.simulate.rig import default_rig, scale_camera

    mp = pytest.MonkeyPatch()
    mp.setattr(sim_target, "FREE_POSES", tuple(sim_target.FREE_POSES[i] for i in QUICK_FREE))
    mp.setattr(sim_scan, "TABLE_POSE_ANGLES", QUICK_TABLE)
    try:
        out = tmp_path_factory.mktemp("calib") / "scan"
        sim_scan.simulate_scan(Plane(), out, views=1, rig=scale_camera(default_rig(), 640, 480))
    finally:
        mp.undo()
    return out


@pytest.fixture(scope="module")
def quick_result(quick_scan):
    from nurbscan.calibrate import calibrate_scan

    held = len(QUICK_FREE) - 1
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = calibrate_scan(quick_scan / "calibration", exclude=(held,))
    return res


def _held_out_pose(quick_scan):
    """The held-out pose's detected grid, its true board -> rig pose and the target."""
    from nurbscan.calibrate import Target
    from nurbscan.detect import detect_grid
    from nurbscan.io import read_image
    from nurbscan.pattern import load_pattern

    held = len(QUICK_FREE) - 1
    truth = json.loads((quick_scan / "truth" / "calibration.json").read_text())
    pose = next(p for p in truth["poses"] if p["index"] == held)
    g = quick_scan / "calibration" / f"pose_{held:02d}_grid.png"
    w = quick_scan / "calibration" / f"pose_{held:02d}_white.png"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        det = detect_grid(read_image(g), load_pattern(quick_scan / "pattern.json"),
                          white=read_image(w))
    target = Target.from_dict(json.loads((quick_scan / "scan.json").read_text())
                              ["calibration"]["target"], "scan.json")
    return det, np.array(pose["board_to_rig"]["R"]), np.array(pose["board_to_rig"]["T"]), target


def test_calibration_of_simulated_scan_against_truth(quick_scan, quick_result):
    from nurbscan.calibrate import held_out_error
    from nurbscan.camera import load_rig

    true = load_rig(quick_scan / "truth" / "rig.json")
    c = compare_rigs(quick_result.rig, true)
    f = quick_result.figures
    # camera px here are 4.8 times the full-size camera's: the figures scale accordingly
    assert f["camera_rms_px"] < 0.15
    assert f["projector_rms_px"] < 0.4
    # the detector's band-edge bias at this size (0.3 to 0.6 projector px, depending on the
    # detector's version) is fitted, not absorbed elsewhere: it stays a plausible size
    assert abs(f["edge_bias_projector_px"]["x"]) < 1.5
    assert abs(f["edge_bias_projector_px"]["y"]) < 1.5
    assert c["camera"]["f_rel_err"] < 0.005
    assert c["camera"]["principal_point_err_px"] < 3.0
    assert c["projector"]["f_rel_err"] < 0.005
    assert c["projector"]["principal_point_err_px"] < 8.0
    assert c["projector"]["k1_rel_err"] < 0.2
    assert c["relative_translation_err_mm"] < 1.0
    assert c["relative_rotation_err_deg"] < 0.1
    assert c["turntable_direction_err_deg"] < 0.3
    assert c["turntable_axis_distance_mm"] < 2.0
    # held-out pose triangulated with the calibrated rig
    det, R, T, target = _held_out_pose(quick_scan)
    bias = [f["edge_bias_projector_px"]["x"], f["edge_bias_projector_px"]["y"]]
    ho = held_out_error(quick_result.rig, true, det, R, T, edge_bias=bias, target=target)
    assert ho["points"] > 1000
    # the detector's bias, measured with the true rig, is removed in the main by the
    # calibration's estimate of it: the detection floor drops
    floor_raw = held_out_error(true, true, det, R, T, target=target)
    floor = held_out_error(true, true, det, R, T, edge_bias=bias, target=target)
    assert floor["rms_mm"] < floor_raw["rms_mm"] or floor_raw["rms_mm"] < 0.05
    # at 640 px one camera px is 0.5 mm on the target: the principal point error alone
    # (< 1 px) moves the rays by a few tenths of a mm. With 8 poses this small the figures
    # depend on the noise: over seeds 0-4 the RMS was 0.32-0.51 mm and the distance to the
    # plane 0.29-0.48 mm (the detection floor 0.11-0.12 mm; full size: bench_calibrate)
    assert ho["rms_mm"] < 0.7
    assert ho["plane_rms_mm"] < 0.55
    # the true rig compared with itself: zero errors (compare_rigs is not vacuous)
    z = compare_rigs(true, true)
    assert z["relative_translation_err_mm"] == 0 and z["camera"]["f_rel_err"] == 0


def test_cli_writes_rig_residuals_and_picture(quick_scan, quick_result, tmp_path):
    """The command line (poses read in two processes) gives the API's rig (one process)."""
    from nurbscan.camera import load_rig
    from nurbscan.cli import main

    out = tmp_path / "calib.json"
    held = len(QUICK_FREE) - 1
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rc = main(["calibrate", str(quick_scan / "calibration"), "--pattern",
                   str(quick_scan / "pattern.json"), "-o", str(out), "--exclude", str(held),
                   "--workers", "2", "-q"])
    assert rc == 0
    rig = load_rig(out)
    # the same up to rounding (threaded OpenCV and BLAS sums): far below the rig's errors
    same = compare_rigs(rig, quick_result.rig)
    assert same["camera"]["f_rel_err"] < 1e-7 and same["projector"]["f_rel_err"] < 1e-7
    assert same["relative_translation_err_mm"] < 1e-4
    assert same["turntable_axis_distance_mm"] < 1e-4
    res = json.loads((tmp_path / "calib_residuals.json").read_text())
    assert res["type"] == "nurbscan.calibration_residuals"
    assert len(res["per_view"]) == res["views_used"] == len(QUICK_FREE) + len(QUICK_TABLE) - 1
    assert (tmp_path / "calib_residuals.png").stat().st_size > 1000


def test_opencv_calibrated_rig_triangulates_like_nurbscans_own(quick_scan, quick_result,
                                                               tmp_path):
    """A rig calibrated by OpenCV alone (benchmarks/opencv_calibrate.py: calibrateCamera for
    camera and projector, stereoCalibrate, radial k1 only; the turntable from OpenCV's poses),
    written by cv2.FileStorage and read by read_opencv as a user's would be: on the held-out
    pose it triangulates about as well as nurbscan's own rig, against the true board."""
    import importlib.util

    from nurbscan.calibrate import held_out_error
    from nurbscan.calibrate.opencv import read_opencv
    from nurbscan.camera import load_rig

    path = Path(__file__).resolve().parents[1] / "benchmarks" / "opencv_calibrate.py"
    spec = importlib.util.spec_from_file_location("opencv_calibrate", path)
    oc = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(oc)
    held = len(QUICK_FREE) - 1
    flags = oc.MODELS["k1"]  # Tsai's model; with 8 poses this small k2 is not determined
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fig = oc.opencv_calibration(quick_scan / "calibration", tmp_path / "cv.yml", workers=1,
                                    progress=lambda m: None, camera_flags=flags,
                                    projector_flags=flags, exclude=(held,))
    assert fig["poses"] == len(QUICK_FREE) + len(QUICK_TABLE) - 1
    assert fig["turntable_poses"] == len(QUICK_TABLE)
    rep = read_opencv(tmp_path / "cv.yml")
    assert rep.camera_max_px < 0.1 and rep.projector_max_px < 0.1  # Tsai k1 <-> OpenCV's
    true = load_rig(quick_scan / "truth" / "rig.json")
    det, R, T, target = _held_out_pose(quick_scan)
    f = quick_result.figures
    bias = [f["edge_bias_projector_px"]["x"], f["edge_bias_projector_px"]["y"]]
    own = held_out_error(quick_result.rig, true, det, R, T, edge_bias=bias, target=target)
    cv = held_out_error(rep.rig, true, det, R, T, target=target)
    print(f"held-out pose: OpenCV rig {cv['rms_mm']:.4f} mm RMS ({cv['plane_rms_mm']:.4f} to "
          f"the plane), nurbscan's {own['rms_mm']:.4f} mm ({own['plane_rms_mm']:.4f})")
    assert cv["points"] > 1000 and own["points"] > 1000
    assert cv["rms_mm"] < 1.3 * own["rms_mm"]
    assert cv["plane_rms_mm"] < 1.3 * own["plane_rms_mm"]
    c = compare_rigs(rep.rig, true)
    print(f"OpenCV rig against the truth: {c}")
    # 640 px and 8 poses: OpenCV's projector principal point is off by 18 px, balanced by a
    # pose off by 0.23 degrees and 2.1 mm (nurbscan's own: < 8 px, < 0.1 degrees, < 1 mm);
    # what the pair costs in 3-D is the held-out triangulation above (0.47 against 0.58 mm)
    assert c["relative_translation_err_mm"] < 3.0 and c["relative_rotation_err_deg"] < 0.4
    assert c["turntable_direction_err_deg"] < 0.3 and c["turntable_axis_distance_mm"] < 2.0


def test_missing_target_is_named_and_skipped_and_too_few_refused(quick_scan, tmp_path):
    from nurbscan.calibrate import calibrate_scan

    scan = tmp_path / "scan"
    shutil.copytree(quick_scan, scan, ignore=shutil.ignore_patterns("views", "truth"))
    blank = np.full((480, 640, 3), 200, np.uint8)
    from nurbscan.io import write_image

    write_image(scan / "calibration" / "pose_00_white.png", blank)
    with pytest.warns(UserWarning, match="pose_00_white.png: calibration target not found"):
        res = calibrate_scan(scan / "calibration", max_points_per_view=300)
    assert "calibration/pose_00_white.png" not in res.views
    # too few poses
    doc = json.loads((scan / "scan.json").read_text())
    doc["calibration"]["poses"] = doc["calibration"]["poses"][:2]
    (scan / "scan.json").write_text(json.dumps(doc))
    with pytest.raises(NurbscanError, match="at least 3"):
        calibrate_scan(scan / "calibration")
    with pytest.raises(NurbscanError, match="not found"):
        calibrate_scan(tmp_path / "nowhere")
