"""Tests of the synthetic scanner's image formation, rig, calibration target and scan folder.

Most checks run on the default rig with its camera scaled down (same field of view, fewer
pixels) to stay fast; each compares the renderer's output with an independent computation
(the camera and projector models, the exact surface, ray casts, OpenCV's corner finder).
"""

from __future__ import annotations

import json
import math

import cv2
import numpy as np
import pytest

from _board_fixtures import free_board
from nurbscan.errors import NurbscanError
from nurbscan.io import read_image, write_image
from nurbscan.pattern import Pattern, load_pattern
from nurbscan.simulate.render import RenderSettings, render_view
from nurbscan.simulate.rig import axis_angle, default_rig, scale_camera
from nurbscan.simulate.scan import default_pattern
from nurbscan.simulate.scenes import make_scene
from nurbscan.simulate.target import Chessboard

ANGLE = 0.7  # table angle of the test views, rad


@pytest.fixture(scope="module")
def teapot():
    return make_scene("teapot")


@pytest.fixture(scope="module")
def rig_small():
    return scale_camera(default_rig(), 768, 576)


@pytest.fixture(scope="module")
def view(teapot, rig_small):
    """The teapot at 768 x 576 with the default (noisy, blurred) settings."""
    pat = default_pattern(rig_small.projector)
    return render_view(teapot, rig_small, pat, ANGLE, RenderSettings(), seed=1)


# ---------------------------------------------------------------------------- rig
def test_default_rig_geometry(teapot):
    rig = default_rig()
    cam, proj = rig.camera, rig.projector
    assert (cam.width, cam.height) == (3072, 2304)
    assert (proj.width, proj.height) == (1920, 1080)
    assert 15.0 <= math.degrees(axis_angle(rig)) <= 25.0
    np.testing.assert_allclose(cam.R, np.eye(3))
    # working distance: the table centre and the projector at 500-700 mm from the object
    centre = np.asarray(rig.turntable.to_rig(np.array([[0.0, 0.0, 58.5]]), 0.0))[0]
    assert 500 <= np.linalg.norm(centre) <= 700
    assert 500 <= np.linalg.norm(centre - np.asarray(proj.center)) <= 700
    # the teapot is inside both images at every table angle and fills most of the width
    pts = teapot.sample_surface(4000, seed=0)
    pts = pts[0] if isinstance(pts, tuple) else pts
    widths = []
    for a in np.linspace(0, 2 * np.pi, 8, endpoint=False):
        x = rig.turntable.to_rig(pts, a)
        pc, pp = cam.project(x), proj.project(x)
        for px, dev in ((pc, cam), (pp, proj)):
            assert np.all(np.isfinite(px))
            assert px.min() > 0 and px[:, 0].max() < dev.width and px[:, 1].max() < dev.height
        widths.append(np.ptp(pc[:, 0]) / cam.width)
    assert max(widths) > 0.6
    # radial distortion moves the image corner by a few px (Tsai: Xu = Xd (1 + k1 r^2))
    for dev in (cam, proj):
        xd = (0 - dev.cx) * dev.dx / dev.sx
        yd = (0 - dev.cy) * dev.dy
        shift = math.hypot(xd, yd) * dev.k1 * (xd**2 + yd**2) / dev.dx
        assert 1.0 < shift < 10.0


def test_rig_json_round_trip(tmp_path):
    from nurbscan.camera import load_rig

    rig = default_rig()
    rig.save(tmp_path / "rig.json")
    back = load_rig(tmp_path / "rig.json")
    x = np.array([[10.0, -20.0, 600.0], [-50.0, 30.0, 550.0]])
    np.testing.assert_allclose(back.projector.project(x), rig.projector.project(x), atol=1e-9)
    np.testing.assert_allclose(back.turntable.to_rig(x, 0.3), rig.turntable.to_rig(x, 0.3),
                               atol=1e-9)


# ---------------------------------------------------------------------------- truth
def test_truth_is_exact(view, teapot, rig_small):
    t = view.truth
    ys, xs = np.nonzero((t["surface_id"] >= 0) & t["lit"])
    assert ys.size > 20000
    rng = np.random.default_rng(0)
    pick = rng.choice(ys.size, 1000, replace=False)
    ys, xs = ys[pick], xs[pick]
    x_rig = t["point_rig"][ys, xs]
    x_obj = t["point_obj"][ys, xs]
    proj = np.stack([t["proj_x"][ys, xs], t["proj_y"][ys, xs]], axis=1)
    # projector coordinate = projector model of the stored point, within 1e-6 px
    assert np.abs(proj - rig_small.projector.project(x_rig)).max() < 1e-6
    # the point is where the pixel centre's ray meets the surface
    back = rig_small.camera.project(x_rig)
    assert np.abs(back - np.stack([xs, ys], axis=1)).max() < 1e-6
    # object and rig frames agree; depth is the camera z
    assert np.abs(rig_small.turntable.to_rig(x_obj, ANGLE) - x_rig).max() < 1e-9
    assert np.abs(t["depth"][ys, xs] - x_rig[:, 2]).max() < 1e-9
    # on the exact surface within 1 micrometre
    _, dist, _ = teapot.closest_point(x_obj)
    assert dist.max() < 1e-3


def test_shadows_exist_and_are_dark(view, teapot, rig_small):
    t = view.truth
    obj = t["surface_id"] >= 0
    shadow = obj & ~t["lit"]
    lit = obj & t["lit"]
    # interior of the shadow (all 8 neighbours in shadow too), away from blur
    k = np.ones((5, 5), np.uint8)
    core = cv2.erode(shadow.astype(np.uint8), k).astype(bool)
    assert core.sum() > 500
    g = view.grid.astype(float).max(axis=2)
    w = view.white.astype(float).max(axis=2)
    lit_level = np.percentile(w[cv2.erode(lit.astype(np.uint8), k).astype(bool)], 50)
    assert np.median(g[core]) < 0.3 * lit_level
    assert np.median(w[core]) < 0.3 * lit_level
    # independent oracle: rays from the projector to shadow points hit the surface first,
    # rays to lit points do not
    m_pts = t["point_obj"]
    po = rig_small.turntable.from_rig(np.asarray(rig_small.projector.center)[None], ANGLE)[0]
    for mask, blocked in ((core, True), (lit, False)):
        ys, xs = np.nonzero(mask)
        sel = np.random.default_rng(1).choice(ys.size, 200, replace=False)
        p = m_pts[ys[sel], xs[sel]]
        d = p - po
        dist = np.linalg.norm(d, axis=1)
        hit = teapot.intersect(np.broadcast_to(po, d.shape), d / dist[:, None])
        first = np.where(hit["hit"], hit["t"], np.inf)
        occluded = first < dist - 1e-3
        # shadow points are occluded or face away from the projector
        if blocked:
            n_obj = teapot.closest_point(p)[0]  # on the surface (sanity)
            assert np.abs(n_obj - p).max() < 1e-3
            assert occluded.mean() > 0.5
        else:
            assert not occluded.any()


def _edge_positions(img, white, truth, pattern, mix):
    """Sub-pixel rising edges of vertical bands along rows: (image estimate, truth), px.

    The band's light fraction per pixel is grid / white in the projector primaries (the
    camera RGB unmixed with the mixing matrix); the edge is located by the area (first
    moment) fit across it, x_e = x1 + 0.5 - sum f over the pixels x0..x1 spanning it.
    """
    inv = np.linalg.inv(mix)
    g = img @ inv.T
    w = white @ inv.T
    u, v = truth["proj_x"], truth["proj_y"]
    ok_rows = truth["lit"] & (truth["surface_id"] >= 0)
    edges = pattern.vertical_edges[:, 0]
    codes = pattern.band_codes("vertical")
    rgb = pattern.rgb[codes] > 0
    # no horizontal band within the pixel's footprint (plus 1 px for the defocus)
    foot = np.zeros_like(v)
    foot[:-1, :-1] = 0.5 * (np.abs(np.diff(v, axis=1))[:-1] + np.abs(np.diff(v, axis=0))[:, :-1])
    with np.errstate(invalid="ignore"):
        hband = pattern.stripe_field(v - foot - 1.0, "horizontal") < 0
        hband &= pattern.stripe_field(v + foot + 1.0, "horizontal") < 0
        hband &= pattern.stripe_field(v, "horizontal") < 0
    est, tru = [], []
    H, W = u.shape
    for y in range(2, H - 2, 3):
        row_u = u[y]
        for x in range(3, W - 4):
            a, b = row_u[x], row_u[x + 1]
            if not (np.isfinite(a) and np.isfinite(b)) or b <= a:
                continue
            i = np.searchsorted(edges, a)
            if i >= len(edges) or edges[i] > b:
                continue
            win = slice(x - 1, x + 3)
            if not (ok_rows[y - 1:y + 2, x - 2:x + 4].all() and hband[y, win].all()):
                continue
            # half the pixel footprint along u; the window must start dark and end in the band
            half = 0.5 * (abs(u[y, x + 1] - u[y, x]) + abs(u[y + 1, x] - u[y, x])) + 0.25
            if not (row_u[x - 1] + half < edges[i] < row_u[x + 2] - half
                    and row_u[x + 2] + half < pattern.vertical_edges[i, 1]):
                continue
            c = int(np.argmax(rgb[i]))  # a channel lit by this band
            f = g[y, win, c] / w[y, win, c]
            est.append(x + 2 + 0.5 - f.sum())
            tru.append(x + (edges[i] - a) / (b - a))
    return np.array(est), np.array(tru)


def test_band_edges_match_truth(teapot, rig_small, tmp_path):
    pat = Pattern.create(width=1920, height=1080, pitch=32, band=12)
    s = RenderSettings().ideal().replace(ambient=0.0, gamma=1.0, bit_depth=16, exposure=0.5)
    r = render_view(teapot, rig_small, pat, ANGLE, s, seed=0)
    # through a 16-bit file and back
    write_image(tmp_path / "g.png", r.grid)
    write_image(tmp_path / "w.png", r.white)
    g16 = read_image(tmp_path / "g.png", as_float=False)
    assert g16.dtype == np.uint16 and np.array_equal(g16, r.grid)
    g = read_image(tmp_path / "g.png").astype(float)
    w = read_image(tmp_path / "w.png").astype(float)
    est, tru = _edge_positions(g, w, r.truth, pat, np.asarray(s.mixing))
    assert est.size > 200
    err = np.abs(est - tru)
    assert np.median(err) < 0.005
    assert np.percentile(err, 99) < 0.05


def test_same_seed_same_images(teapot):
    rig = scale_camera(default_rig(), 192, 144)
    pat = default_pattern(rig.projector)
    a = render_view(teapot, rig, pat, 0.2, RenderSettings(), seed=5, stream=2)
    b = render_view(teapot, rig, pat, 0.2, RenderSettings(), seed=5, stream=2, workers=1)
    c = render_view(teapot, rig, pat, 0.2, RenderSettings(), seed=6, stream=2)
    assert np.array_equal(a.grid, b.grid) and np.array_equal(a.white, b.white)
    assert not np.array_equal(a.grid, c.grid)
    # noise is there, and its level follows the model (shot + read noise in electrons)
    n = RenderSettings().replace(noise=0.0)
    d = render_view(teapot, rig, pat, 0.2, n, seed=5, stream=2)
    diff = a.white.astype(float) - d.white.astype(float)
    assert 0.3 < diff.std() < 6.0


def test_encode_matches_the_plain_sensor_model():
    # oracle: the sensor model written as plain (allocating) expressions; the in-place encode
    # must give the same bits for the same generator
    from nurbscan.simulate.render import encode, noise_rng

    lin = np.random.default_rng(0).random((37, 53, 3), dtype=np.float32) * np.float32(1.3)
    for s in (RenderSettings(), RenderSettings(camera_blur=0.0, bit_depth=16, gamma=1.0)):
        rng = noise_rng(4, 2, 1)
        img = lin
        if s.camera_blur > 0:
            img = cv2.GaussianBlur(lin, (0, 0), sigmaX=s.camera_blur, sigmaY=s.camera_blur,
                                   borderType=cv2.BORDER_REFLECT)
        e = img * np.float32(s.exposure * s.full_well)
        sd = np.sqrt(np.clip(e, 0, None) + np.float32(s.read_noise ** 2))
        e = e + np.float32(s.noise) * sd * rng.standard_normal(e.shape, dtype=np.float32)
        v = np.clip(e / np.float32(s.full_well), 0.0, 1.0)
        if s.gamma != 1:
            v = v ** np.float32(1.0 / s.gamma)
        top = 255 if s.bit_depth == 8 else 65535
        want = np.rint(v * top).astype(np.uint8 if s.bit_depth == 8 else np.uint16)
        got = encode(lin, s, noise_rng(4, 2, 1))
        assert got.dtype == want.dtype and np.array_equal(got, want)
        assert np.array_equal(lin, np.random.default_rng(0).random((37, 53, 3),
                                                                   dtype=np.float32)
                              * np.float32(1.3))  # the input is not modified


# ---------------------------------------------------------------------------- target
def test_chessboard_corners_match_pose(rig_small):
    board, scene, r_b, t_b = free_board(rig_small, 3)
    pat = default_pattern(rig_small.projector)
    s = RenderSettings(table=False, noise=0.0)
    r = render_view(scene, rig_small, pat, 0.0, s, albedo=scene.albedo)
    grey = cv2.cvtColor(r.white, cv2.COLOR_RGB2GRAY)
    found, corners = cv2.findChessboardCorners(grey, (board.cols, board.rows))
    assert found
    corners = cv2.cornerSubPix(grey, corners, (5, 5), (-1, -1),
                               (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-4))
    truth = rig_small.camera.project(board.corners() @ r_b.T + t_b)
    found_xy = corners.reshape(-1, 2)
    if np.linalg.norm(found_xy[0] - truth[0]) > np.linalg.norm(found_xy[0] - truth[-1]):
        found_xy = found_xy[::-1]  # OpenCV may start from the opposite corner
    err = np.linalg.norm(found_xy - truth, axis=1)
    assert err.max() < 0.3


def test_board_albedo_layout():
    b = Chessboard()
    s = b.square
    pts = np.array([[0.5 * s, 0.5 * s], [1.5 * s, 0.5 * s], [-0.5 * s, -0.5 * s],
                    [-1.5 * s, 0.5 * s], [b.cols * s - 0.5 * s, b.rows * s - 0.5 * s]])
    np.testing.assert_allclose(b.albedo_at(pts), [b.black, b.white, b.black, b.white,
                                                   b.black if (b.cols + b.rows) % 2 == 0
                                                   else b.white])


def test_board_albedo_cell_matches_supersampling():
    """Cell means of the chessboard against 200 x 200 point samples of each cell (oracle):
    exact along edges for any cell shape, and at corners for cells along the board axes."""
    from nurbscan.simulate.render import step_coverage

    b = Chessboard()
    s, n = b.square, 300
    rng = np.random.default_rng(5)
    k, j = rng.integers(-1, b.cols + 1, n), rng.integers(-1, b.rows + 1, n)
    p = np.stack([k * s + rng.normal(0, 0.04, n), (j + rng.uniform(0.1, 0.9, n)) * s], 1)
    ang = rng.uniform(0, np.pi, n)
    ang2 = ang + rng.uniform(0.5, 2.6, n)
    dx = rng.uniform(0.02, 0.1, n)[:, None] * np.stack([np.cos(ang), np.sin(ang)], 1)
    dy = rng.uniform(0.02, 0.1, n)[:, None] * np.stack([np.cos(ang2), np.sin(ang2)], 1)
    g = (np.arange(200) + 0.5) / 200 - 0.5
    gs, gt = (a.ravel()[None, :, None] for a in np.meshgrid(g, g))

    def brute(p, dx, dy):
        pts = p[:, None] + dx[:, None] * gs + dy[:, None] * gt
        return b.albedo_at(pts.reshape(-1, 2)).reshape(len(p), -1).mean(axis=1)

    ref = brute(p, dx, dy)
    assert np.ptp(ref) > 0.5  # the cells do straddle edges
    np.testing.assert_allclose(b.albedo_cell(p, dx, dy), ref, atol=0.01)
    # one cell over a square wide takes every cell through the sum over all boundaries
    wide = b.albedo_cell(*(np.vstack([a, w]) for a, w in ((p, [0, 0]), (dx, [30, 0]),
                                                            (dy, [0, 30]))))
    np.testing.assert_allclose(wide[:-1], b.albedo_cell(p, dx, dy), atol=1e-12)
    # corner cells along the axes: the product of the one-axis means is exact
    pc = np.stack([k * s, j * s], 1) + rng.normal(0, 0.03, (n, 2))
    ax, ay = np.abs(dx[:, :1]) * [1, 0], np.abs(dy[:, 1:]) * [0, 1]
    np.testing.assert_allclose(b.albedo_cell(pc, ax, ay), brute(pc, ax, ay), atol=0.01)
    # limits of the trapezoid: a box and a point sample
    np.testing.assert_allclose(step_coverage([-0.1, 0.0, 0.2], 1.0, 0.0), [0.4, 0.5, 0.7])
    np.testing.assert_allclose(step_coverage([-0.1, 0.0, 0.2], 0.0, 0.0), [0.0, 0.5, 1.0])
    # trapezoid on [-0.75, 0.75], ramps 0.5 long: flat part and ramp
    np.testing.assert_allclose(step_coverage([0.25, 0.5], 1.0, 0.5), [0.75, 1 - 0.0625])


def test_printed_edges_move_with_the_board(rig_small):
    """Chessboard corners of a board square to the pixel grid, noise free: with the texture
    integrated over the sub-sample cells the corners are found within 0.075 px RMS (point
    sampled on the 4 x 4 sub-samples the edges snap to quarter pixels: about 0.12 px)."""
    from nurbscan.calibrate import detect_chessboard

    board, scene, r_b, t_b = free_board(rig_small, 0)
    args = (scene, rig_small, default_pattern(rig_small.projector), 0.0,
            RenderSettings(table=False, noise=0.0))
    r = render_view(*args, albedo=scene.albedo, albedo_cell=scene.albedo_cell, truth=False)
    # without the 3-D truth (as for calibration images) the images are the same
    full = render_view(*args, albedo=scene.albedo, albedo_cell=scene.albedo_cell)
    assert np.array_equal(r.white, full.white) and np.array_equal(r.grid, full.grid)
    assert "point_obj" in full.truth and "point_obj" not in r.truth and "proj_x" in r.truth
    truth = rig_small.camera.project(board.corners() @ r_b.T + t_b)
    c = detect_chessboard(r.white, (board.cols, board.rows))
    if np.linalg.norm(c[0] - truth[0]) > np.linalg.norm(c[0] - truth[-1]):
        c = c[::-1]
    assert np.sqrt(np.mean(np.sum((c - truth) ** 2, axis=1))) < 0.075


# ---------------------------------------------------------------------------- settings
def test_settings_round_trip_and_errors():
    s = RenderSettings(gloss=0.1, bit_depth=16)
    d = json.loads(json.dumps(s.to_dict()))
    assert RenderSettings.from_dict(d) == s
    with pytest.raises(NurbscanError, match="bit_depth"):
        RenderSettings(bit_depth=12)
    with pytest.raises(NurbscanError, match="camera_blur"):
        RenderSettings(camera_blur=-1.0)
    with pytest.raises(NurbscanError, match="unknown keys"):
        RenderSettings.from_dict({**d, "colour": 3})
    assert s.with_noise_scale(0.5).noise == pytest.approx(0.5)


# ---------------------------------------------------------------------------- command line
def test_cli_writes_scan_folder(tmp_path):
    from nurbscan.cli import main

    out = tmp_path / "scan"
    rig_path = tmp_path / "rig.json"
    scale_camera(default_rig(), 96, 72).save(rig_path)
    rc = main(["simulate", "sphere", "-o", str(out), "--views", "2", "--rig", str(rig_path),
               "--bit-depth", "16", "--seed", "3"])
    assert rc == 0
    doc = json.loads((out / "scan.json").read_text())
    assert doc["type"] == "nurbscan.scan" and doc["image_size"] == [96, 72]
    assert [v["table_angle"] for v in doc["views"]] == pytest.approx([0.0, math.pi])
    pat = load_pattern(out / doc["pattern"]["sidecar"])
    assert (pat.width, pat.height) == (1920, 1080)
    for v in doc["views"]:
        for key in ("grid", "white"):
            img = read_image(out / v[key], as_float=False)
            assert img.shape == (72, 96, 3) and img.dtype == np.uint16
    cal = doc["calibration"]
    assert cal["target"]["inner_corners"] == [9, 7] and cal["target"]["square_mm"] == 20.0
    kinds = [p["kind"] for p in cal["poses"]]
    assert kinds.count("free") >= 10
    assert len({p["table_angle"] for p in cal["poses"] if p["kind"] == "turntable"}) >= 3
    for p in cal["poses"]:
        assert (out / p["grid"]).is_file() and (out / p["white"]).is_file()
    truth = np.load(out / "truth" / "view_01.npz")
    for key in ("depth", "point_rig", "point_obj", "surface_id", "proj_x", "proj_y", "lit"):
        assert truth[key].shape[:2] == (72, 96)
    assert truth["point_rig"].dtype == np.float64
    assert (out / "truth" / "rig.json").is_file() and (out / "truth" / "scene.json").is_file()
    poses = json.loads((out / "truth" / "calibration.json").read_text())["poses"]
    assert len(poses) == len(cal["poses"])
    assert not list(out.rglob(".*"))  # no temporary files left
    # same seed, same images (through the files)
    out2 = tmp_path / "scan2"
    assert main(["simulate", "sphere", "-o", str(out2), "--views", "1", "--width", "96",
                 "--height", "72", "--bit-depth", "16", "--seed", "3",
                 "--no-calibration"]) == 0
    for key in ("grid", "white"):
        a = read_image(out / doc["views"][0][key], as_float=False)
        b = read_image(out2 / doc["views"][0][key], as_float=False)
        assert np.array_equal(a, b)
    assert main(["simulate", "sphere", "-o", str(out2), "--noise", "-1"]) == 2
    # absurd options were ignored or rendered (height 0 ignored, NaN noise, negative seed)
    for bad in (["--height", "0"], ["--width", "-5"], ["--noise", "nan"], ["--seed", "-1"]):
        out3 = tmp_path / "scan3"
        assert main(["simulate", "sphere", "-o", str(out3), "--views", "1", *bad]) == 2, bad
        assert not out3.exists()


def test_scan_in_two_processes_is_the_same_scan(tmp_path):
    """Rendering in worker processes changes nothing: same files, bit for bit."""
    from nurbscan.simulate.scan import simulate_scan

    rig = scale_camera(default_rig(), 96, 72)
    one = simulate_scan(make_scene("sphere"), tmp_path / "one", views=2, rig=rig, seed=4)
    two = simulate_scan(make_scene("sphere"), tmp_path / "two", views=2, rig=rig, seed=4,
                        workers=2)
    a, b = json.loads(one.read_text()), json.loads(two.read_text())
    assert a == b and len(a["calibration"]["poses"]) >= 10
    names = [v[k] for v in a["views"] + a["calibration"]["poses"] for k in ("grid", "white")]
    for name in names:
        assert np.array_equal(read_image(one.parent / name, as_float=False),
                              read_image(two.parent / name, as_float=False)), name
    for f in ("truth/view_00.npz", "truth/view_01.npz"):
        with np.load(one.parent / f) as za, np.load(two.parent / f) as zb:
            assert all(np.array_equal(za[k], zb[k], equal_nan=True) for k in za.files)
    assert ((one.parent / "truth/calibration.json").read_text()
            == (two.parent / "truth/calibration.json").read_text())
