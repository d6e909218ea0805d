"""Calibration on real photographs: the shared projector-camera set (issue 31).

The set (``../shared/real/procam-colour-grid/`` beside the repository, or
``$NURBSCAN_REAL_PROCAM``; read its README) is laid out as scan folders by
``benchmarks/real_procam.py`` in a temporary folder (its images are symbolic links, never
copies into the repository). Tests that need it skip with the reason when it is absent.
The oracles: the set's own ``pattern.png`` (the line pattern rendered back), OpenCV's
``calibrateCamera`` on the same corners (the camera RMS it reaches with 5 distortion terms)
and the source project's decoded grid points (``reference/calibration.yml``; they lie on the
board's white part, which must hold them). The refusal to merge views with an uncalibrated
turntable is tested without the set.
"""

from __future__ import annotations

import importlib.util
import json
import os
from pathlib import Path

import cv2
import numpy as np
import pytest

from nurbscan.errors import NurbscanError

REPO = Path(__file__).resolve().parents[1]
REAL = Path(os.environ.get("NURBSCAN_REAL_PROCAM")
            or Path(__file__).resolve().parents[2] / "shared" / "real" / "procam-colour-grid")
HAVE_REAL = (REAL / "images" / "colorGrid01.png").is_file()
needs_real = pytest.mark.skipif(not HAVE_REAL, reason=f"real procam set not found at {REAL} "
                                "(set NURBSCAN_REAL_PROCAM)")


def _converter():
    spec = importlib.util.spec_from_file_location("real_procam",
                                                  REPO / "benchmarks" / "real_procam.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="module")
def real_scans(tmp_path_factory):
    if not HAVE_REAL:
        pytest.skip(f"real procam set not found at {REAL}")
    return _converter().lay_out(tmp_path_factory.mktemp("real"), REAL)


@pytest.fixture(scope="module")
def real_corners():
    from nurbscan.calibrate import detect_chessboard
    from nurbscan.io import read_image

    if not HAVE_REAL:
        pytest.skip(f"real procam set not found at {REAL}")
    whites = [read_image(REAL / "images" / f"lightGrid{k:02d}.png", as_float=False)
              for k in range(1, 9)]
    return whites, [detect_chessboard(w, (6, 9)) for w in whites]


@needs_real
def test_converter_lays_out_calibration_and_scene_scans(real_scans):
    from nurbscan.io import read_image
    from nurbscan.pattern import LinePattern, load_pattern

    calib = json.loads((real_scans["calib"] / "scan.json").read_text())
    assert calib["calibration"]["target"] == {"inner_corners": [6, 9], "square_mm": 24.0}
    poses = calib["calibration"]["poses"]
    assert [p["index"] for p in poses] == list(range(1, 9))
    assert {p["kind"] for p in poses} == {"free"}
    for p in poses:  # links into the set, not copies
        assert (real_scans["calib"] / p["white"]).is_symlink()
        assert (real_scans["calib"] / p["white"]).resolve() == \
            (REAL / "images" / f"lightGrid{p['index']:02d}.png").resolve()
    for k in (9, 10):
        doc = json.loads((real_scans[f"scene{k:02d}"] / "scan.json").read_text())
        assert len(doc["views"]) == 1 and "calibration" not in doc
        assert (real_scans[f"scene{k:02d}"] / doc["views"][0]["mask"]).resolve() == \
            (REAL / "images" / f"objectROI{k:02d}.png").resolve()
    pat = load_pattern(real_scans["calib"] / "pattern.json")
    assert isinstance(pat, LinePattern)
    assert (pat.width, pat.height, pat.window) == (800, 600, 3)
    assert (pat.vertical.count, pat.horizontal.count) == (28, 29)
    # the sidecar renders back to the projected image, pixel for pixel
    assert np.array_equal(pat.render(), read_image(REAL / "pattern.png", as_float=False))
    # README: horizontal lines use r, l, c, p (codes 0, 2, 4, 6), vertical y, g, b, m
    assert set(pat.horizontal.codes) == {0, 2, 4, 6}
    assert set(pat.vertical.codes) == {1, 3, 5, 7}


def test_converter_refuses_a_folder_inside_the_repository():
    if not HAVE_REAL:
        pytest.skip(f"real procam set not found at {REAL}")
    with pytest.raises(NurbscanError, match="inside the repository"):
        _converter().lay_out(REPO / "scratch-real", REAL)
    assert not (REPO / "scratch-real").exists()


@needs_real
def test_board_found_in_all_poses_and_camera_rms_as_opencv(real_corners):
    """8/8 poses; Tsai's one radial term reaches OpenCV's 5-term RMS (0.1558 px) within
    0.001 px on the same corners (measured 0.1564 px), under the issue's 0.16 px."""
    from nurbscan.calibrate import board_points, calibrate_camera

    _, corners = real_corners
    assert all(c is not None for c in corners)
    board = board_points((6, 9), 24.0)
    d = 3072 * 0.0023 / 640
    fit = calibrate_camera(corners, board, (640, 480), d, d)
    assert len(fit.corners.view) == 8 * 54  # no corner rejected
    rms_cv, K, _, _, _ = cv2.calibrateCamera([board.astype(np.float32)] * 8,
                                             [c.astype(np.float32) for c in corners],
                                             (640, 480), None, None)
    assert fit.rms <= 0.16
    assert fit.rms - rms_cv < 0.001
    fx, fy = fit.kc[0] * fit.kc[3] / d, fit.kc[0] / d
    assert abs(fx / K[0, 0] - 1) < 0.005 and abs(fy / K[1, 1] - 1) < 0.005


@needs_real
def test_white_area_holds_the_source_projects_grid_points(real_corners):
    """The board's white part found in each white-light image holds the grid points the
    source project decoded there (reference/calibration.yml, MATLAB 1-based pixels), and
    none of them lies in the checkerboard field."""
    from nurbscan.calibrate import white_area

    whites, corners = real_corners
    fs = cv2.FileStorage(str(REAL / "reference" / "calibration.yml"), cv2.FILE_STORAGE_READ)
    inside = total = 0
    for i, (w, c) in enumerate(zip(whites, corners, strict=True)):
        m = white_area(w, c, (6, 9), 24.0)
        assert 0.2 < m.mean() < 0.45  # measured 0.254-0.364
        ij = np.round(fs.getNode("camImgPts").at(i).mat() - 1.0).astype(int)
        inside += int(m[ij[:, 1], ij[:, 0]].sum())
        total += len(ij)
        # the field itself is out: a white square's centre is not in the mask
        centre = np.round(c[[0, 1, 6, 7]].mean(axis=0)).astype(int)
        assert not m[centre[1], centre[0]]
    assert inside / total >= 0.995  # measured 882 of 883


@needs_real
def test_board_not_found_is_one_line_naming_the_file(real_scans, tmp_path, capsys):
    from nurbscan.cli import main
    from nurbscan.io import write_image

    scan = tmp_path / "calib"
    (scan / "calibration").mkdir(parents=True)
    for f in ("scan.json", "pattern.json", "pattern.png"):
        (scan / f).symlink_to((real_scans["calib"] / f).resolve())
    for f in (real_scans["calib"] / "calibration").iterdir():
        (scan / "calibration" / f.name).symlink_to(f.resolve())
    bad = scan / "calibration" / "pose_01_white.png"
    bad.unlink()
    write_image(bad, np.full((480, 640, 3), 120, np.uint8))
    out = tmp_path / "calib.json"
    code = main(["calibrate", str(scan / "calibration"), "-o", str(out), "--require-all",
                 "-q", "--workers", "1"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2
    assert len(err) == 1 and str(bad) in err[0] and "target not found" in err[0]
    assert not out.exists()


def _line_pattern():
    from nurbscan.pattern import LineFamily, LinePattern

    v = LineFamily("vertical", (0, 0, 1, 1), (9.5, 29.5, 49.5, 69.5), (12.5, 32.5, 52.5, 72.5))
    h = LineFamily("horizontal", (2, 2, 3, 3), (9.5, 29.5, 49.5, 69.5), (12.5, 32.5, 52.5, 72.5))
    return LinePattern(80, 80, (("r", (255, 0, 0)), ("g", (0, 255, 0)), ("b", (0, 0, 255)),
                                ("w", (255, 255, 0))), 2, v, h, "max")


def test_reconstruct_refuses_to_merge_views_without_a_calibrated_turntable(tmp_path, capsys):
    """A rig from free poses only (turntable marked uncalibrated): two views are refused with
    one line and exit 2 before any image is read, nothing is written."""
    from nurbscan.calibrate import turntable_calibrated
    from nurbscan.cli import main
    from nurbscan.io import write_json
    from nurbscan.simulate.rig import default_rig

    rig = default_rig().to_dict()
    assert turntable_calibrated(rig)
    rig["turntable"] |= {"calibrated": False, "note": "free poses only"}
    assert not turntable_calibrated(rig)
    write_json(tmp_path / "rig.json", rig)
    scan = tmp_path / "scan"
    write_json(scan / "pattern.json", _line_pattern().to_dict())
    views = [{"index": k, "table_angle": 0.5 * k, "grid": f"views/view_{k:02d}_grid.png",
              "white": f"views/view_{k:02d}_white.png"} for k in range(2)]
    write_json(scan / "scan.json", {"type": "nurbscan.scan", "version": 1,
                                    "image_size": [rig["camera"]["width"],
                                                   rig["camera"]["height"]],
                                    "pattern": {"sidecar": "pattern.json"}, "views": views})
    out = tmp_path / "model"
    code = main(["reconstruct", str(scan), "--calib", str(tmp_path / "rig.json"), "-o",
                 str(out), "-q"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2
    assert len(err) == 1 and "2 views cannot be merged" in err[0] \
        and "turntable not calibrated" in err[0]
    assert not out.exists()


#: What was read from the poses' images (corners, decoded grid, white area), shared by the
#: calibrations of this module.
_POSES: dict = {}


@pytest.fixture(scope="module")
def real_calibration(real_scans, tmp_path_factory):
    """Poses 1-8 calibrated as ``nurbscan calibrate`` does (300 observations a pose, as the
    benchmark; the white part's shape fitted), with the rig file and residuals written."""
    from nurbscan.calibrate import calibrate_scan, write_outputs

    with pytest.warns(UserWarning, match="turntable not calibrated"):
        res = calibrate_scan(real_scans["calib"] / "calibration", max_points_per_view=300,
                             pose_cache=_POSES)
    out = tmp_path_factory.mktemp("real_calib") / "calib.json"
    write_outputs(res, out)
    return res, out


@pytest.fixture(scope="module")
def real_calibration_flat(real_scans):
    """The same calibration with the board's white part taken for the corners' plane."""
    from nurbscan.calibrate import calibrate_scan

    with pytest.warns(UserWarning, match="turntable not calibrated"):
        return calibrate_scan(real_scans["calib"] / "calibration", max_points_per_view=300,
                              pose_cache=_POSES, board_surface=False)


@needs_real
def test_real_calibration_free_poses_only(real_calibration):
    """8/8 poses; the camera-only fit under 0.16 px; the turntable said to be uncalibrated in
    the result, its warnings and the rig file, which still loads as a rig."""
    from nurbscan.calibrate import TURNTABLE_NOT_CALIBRATED, turntable_calibrated
    from nurbscan.camera import load_rig

    res, path = real_calibration
    f = res.figures
    assert f["views_used"] == f["views_given"] == 8
    assert f["camera_init_rms_px"] <= 0.16
    assert not res.turntable_calibrated and f["turntable"]["calibrated"] is False
    assert TURNTABLE_NOT_CALIBRATED in res.warnings
    doc = json.loads(path.read_text())
    assert not turntable_calibrated(doc)
    assert load_rig(path).camera.width == 640
    assert f["edge_bias_projector_px"] is None  # centre-lines only: no band-edge bias
    assert all(v["projector_observations"] >= 250 for v in f["per_view"])


@needs_real
def test_real_projector_agrees_with_opencv_on_the_same_points(real_calibration_flat,
                                                              real_calibration):
    """With the white part taken for the corners' plane, the projector's residual is that of
    OpenCV's own calibrateCamera (8 distortion terms) on the decoded grid intersections of
    the board's white part mapped onto that plane by the corner poses (measured 0.663-0.692
    px per coordinate with 1 to 8 terms): a lens model does not lower it. Its focal lengths
    agree within 5 %, and so do those of the calibration with the white part's shape."""
    from nurbscan.calibrate import board_points, calibrate_camera, detect_chessboard, white_area
    from nurbscan.calibrate._bundle import ProjObs
    from nurbscan.calibrate.projector import board_frame_points
    from nurbscan.detect import detect_lines
    from nurbscan.io import read_image

    res, _ = real_calibration
    pat = _converter().line_pattern(REAL / "pattern.png")
    board = board_points((6, 9), 24.0)
    whites, grids = [], []
    for k in range(1, 9):
        whites.append(read_image(REAL / "images" / f"lightGrid{k:02d}.png", as_float=False))
        grids.append(read_image(REAL / "images" / f"colorGrid{k:02d}.png", as_float=False))
    corners = [detect_chessboard(w, (6, 9)) for w in whites]
    d = 3072 * 0.0023 / 640
    cam = calibrate_camera(corners, board, (640, 480), d, d)
    obj, img = [], []
    for i in range(8):
        det = detect_lines(grids[i], pat, white=whites[i])
        m = white_area(whites[i], corners[i], (6, 9), 24.0)
        ij = np.clip(np.round(det.cam).astype(int), 0, [639, 479])
        c, p = det.cam[m[ij[:, 1], ij[:, 0]]], det.proj[m[ij[:, 1], ij[:, 0]]]
        z = np.zeros(len(c))
        xy = board_frame_points(cam.kc, cam.rvecs, cam.tvecs,
                                ProjObs(c, z, z.astype(int), np.full(len(c), i)), d, d)
        H, inl = cv2.findHomography(xy, p, cv2.RANSAC, 3.0)
        inl = inl.ravel() > 0
        obj.append(np.column_stack([xy[inl], np.zeros(inl.sum())]).astype(np.float32))
        img.append(p[inl].astype(np.float32))
    rms, K, _, _, _ = cv2.calibrateCamera(obj, img, (800, 600), None, None,
                                          flags=cv2.CALIB_RATIONAL_MODEL)
    per_coord = rms / np.sqrt(2)
    flat = real_calibration_flat
    assert flat.board_surface is None and flat.figures["board_surface"] is None
    assert abs(flat.figures["projector_rms_px"] - per_coord) < 0.1
    for r in (flat, res):
        prj = r.rig.projector
        assert abs(prj.f * prj.sx / prj.dx / K[0, 0] - 1) < 0.05
        assert abs(prj.f / prj.dy / K[1, 1] - 1) < 0.05


@needs_real
def test_real_board_shape_halves_the_projector_residual(real_calibration,
                                                        real_calibration_flat):
    """The white part is not the corners' plane: fitted as one height field shared by the 8
    poses (24 mm knots), it takes the projector RMS from 0.677 to 0.333 px per coordinate and
    frees the camera, whose corners the flat board pulled (joint-bundle camera RMS 0.260 ->
    0.190 px); the height field is a millimetre or so (measured RMS 1.38 mm, -2.5 to +4.3
    mm), the bow of a board a metre from the camera, not a degenerate fit."""
    res, flat = real_calibration[0], real_calibration_flat
    f, g = res.figures, flat.figures
    assert f["projector_rms_px"] < 0.36 and f["projector_rms_px"] < 0.55 * g["projector_rms_px"]
    assert f["camera_rms_px"] < 0.21 < g["camera_rms_px"]
    bs = f["board_surface"]
    assert 0.5 < bs["height_rms_mm"] < 3.0 and max(-bs["height_min_mm"], bs["height_max_mm"]) < 8
    assert bs["knot_spacing_mm"] == 24.0


@needs_real
@pytest.mark.xfail(strict=True, reason="issue 31 target 0.2 projector px not reached: 0.33 px "
                   "per coordinate with the board's shape fitted (0.68 px without); the "
                   "line centres scatter by 0.28 px RMS along each line (docs/accuracy.md)")
def test_real_projector_rms_target(real_calibration):
    assert real_calibration[0].figures["projector_rms_px"] <= 0.2


def _bench():
    spec = importlib.util.spec_from_file_location("bench_real_calibrate",
                                                  REPO / "benchmarks" / "bench_real_calibrate.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@needs_real
def test_real_held_out_pose_flat_and_to_scale(real_scans):
    """Pose 07 left out of the calibration: its decoded points on the white board lie within
    2 mm RMS of a plane (measured 1.41 mm at 1.07 m: the white board's own bow, which the
    calibration fits as its shape), and the 24 mm squares measured from its corner rays on
    that triangulated plane are 24 mm within 0.5 % (measured -0.003 %, RMS of the single
    squares 0.44 %)."""
    from nurbscan.calibrate import (
        calibrate_scan,
        detect_chessboard,
        triangulate_edges,
        white_area,
    )
    from nurbscan.detect import detect_lines
    from nurbscan.io import read_image

    b = _bench()
    with pytest.warns(UserWarning, match="turntable not calibrated"):
        res = calibrate_scan(real_scans["calib"] / "calibration", exclude=(7,),
                             max_points_per_view=300, pose_cache=_POSES)
    assert "calibration/pose_07_white.png" not in res.views
    white = read_image(REAL / "images" / "lightGrid07.png", as_float=False)
    grid = read_image(REAL / "images" / "colorGrid07.png", as_float=False)
    corners = detect_chessboard(white, (6, 9))
    det = detect_lines(grid, _converter().line_pattern(REAL / "pattern.png"), white=white)
    px, value, axis, _ = b._white_points(det, white_area(white, corners, (6, 9), 24.0))
    X = triangulate_edges(res.rig, px, value, axis)
    X = X[np.all(np.isfinite(X), axis=1)]
    assert len(X) > 5000
    c, n, d = b.fit_plane(X)
    assert np.sqrt(np.mean(d**2)) < 2.0
    sq = b.square_sizes(b._ray_plane(res.rig, corners, c, n), (6, 9))
    assert len(sq) == 5 * 9 + 6 * 8
    assert abs(sq.mean() / 24.0 - 1) < 0.005
    assert np.sqrt(np.mean((sq / 24.0 - 1)**2)) < 0.02


@needs_real
def test_real_scenes_plane_and_cylinder(real_scans, real_calibration):
    """Each scene from its one photograph with the calibration of poses 1-8, inside the
    source's mask: shot 09 (a flat sheet) within 2 mm RMS of a plane (measured 1.29 mm);
    shot 10 (a curved band) within 3 mm RMS of a cylinder (measured 2.40 mm, radius 207 mm)
    and far from any plane (measured 18.3 mm). Regression bounds, not the true shapes."""
    from nurbscan.calibrate import triangulate_edges
    from nurbscan.detect import detect_lines
    from nurbscan.io import read_image

    b = _bench()
    rig = real_calibration[0].rig
    pat = _converter().line_pattern(REAL / "pattern.png")
    out = {}
    for k in (9, 10):
        img = {n: read_image(REAL / "images" / f"{n}{k:02d}.png", as_float=False)
               for n in ("colorGrid", "lightGrid", "objectROI")}
        mask = img["objectROI"] if img["objectROI"].ndim == 2 else img["objectROI"][..., 0]
        det = detect_lines(img["colorGrid"], pat, white=img["lightGrid"])
        px, value, axis, _ = b._white_points(det, mask > 127)
        X = triangulate_edges(rig, px, value, axis)
        out[k] = X[np.all(np.isfinite(X), axis=1)]
    assert len(out[9]) > 5000 and len(out[10]) > 3000
    assert np.sqrt(np.mean(b.fit_plane(out[9])[2]**2)) < 2.0
    _, _, r, d = b.fit_cylinder(out[10])
    assert np.sqrt(np.mean(d**2)) < 3.0
    assert 100 < r < 400
    assert np.sqrt(np.mean(b.fit_plane(out[10])[2]**2)) > 10.0
