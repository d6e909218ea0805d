"""Tests of the phase-shift peer (nurbscan.peers.phaseshift) against the simulator's truth."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from nurbscan.camera import Rig
from nurbscan.errors import NurbscanError
from nurbscan.peers import graycode as gc
from nurbscan.peers import phaseshift as ps
from nurbscan.reconstruct import intersect_exact
from nurbscan.simulate import RenderSettings, default_rig, make_scene, scale_camera
from nurbscan.simulate.render import pattern_light
from nurbscan.simulate.rig import _scaled

ANGLE = 0.3
MATTE = RenderSettings(gloss=0.0)


def _rig(w: int = 640, h: int = 480) -> Rig:
    """A w x h camera and a 480 x 270 projector (the default rig's fields of view)."""
    r0 = scale_camera(default_rig(), w, h)
    return Rig(camera=r0.camera, projector=_scaled(r0.projector, 480, 270),
               turntable=r0.turntable)


@pytest.fixture(scope="module")
def setup():
    """A matte sphere on the table under N = 4, T = 16 px, default noise; and noise-free."""
    rig = _rig()
    scene = make_scene("sphere")
    code = ps.PhaseShift.for_projector(rig.projector)
    cap = ps.render_phase_shift(scene, rig, code, ANGLE, MATTE, seed=3, workers=2)
    clean = ps.render_phase_shift(scene, rig, code, ANGLE, MATTE.replace(noise=0.0), seed=3,
                                  workers=2)
    return rig, scene, code, cap, clean


def _interior(truth: dict) -> np.ndarray:
    """Lit object pixels at least 2 px away from any other kind of pixel (no mixed pixels)."""
    lit = (truth["lit"] & (truth["surface_id"] >= 0)).astype(np.uint8)
    return cv2.erode(lit, np.ones((5, 5), np.uint8)).astype(bool)


def test_patterns_decode_to_the_projector_pixels():
    """The projector's own images, decoded as if seen by a linear camera, give every pixel's
    coordinate (the 8-bit fringes leave < 0.01 px); the bands reproduce the images."""
    code = ps.PhaseShift(width=200, height=90, period=16, steps=5, camera_gamma=1.0)
    assert code.gray_bits("vertical") == 4 + 1 and code.gray_bits("horizontal") == 3 + 1
    imgs = code.projector_images()
    assert len(imgs) == code.n_images == 2 * 5 + 5 + 4
    x = np.arange(200)
    phi = 2 * np.pi * (x + 0.5) / 16
    assert np.array_equal(imgs[2][0], np.rint(127.5 + 127.5 * np.cos(phi - 4 * np.pi / 5)))
    cap = gc.StripeCapture(images=imgs, white=None, black=None, truth={})
    col, row, _ = ps.decode(cap, code)
    xx, yy = np.meshgrid(np.arange(200), np.arange(90))
    assert np.abs(col - xx).max() < 0.01 and np.abs(row - yy).max() < 0.01
    centres = {"vertical": np.arange(200), "horizontal": np.arange(90)}
    for (direction, edges, levels), img in zip(code.images(), imgs, strict=True):
        c = centres[direction]
        prof = np.zeros(c.size)
        lv = np.full(len(edges), 255) if levels is None else levels
        for (r, f), v in zip(edges, lv, strict=True):
            prof[(c > r) & (c < f)] = v
        assert np.array_equal(prof, img[0, :] if direction == "vertical" else img[:, 0])


def test_graded_stripes_light_equals_the_binary_one():
    """A StripeSet with levels 255 is the same light as without levels; level 51 is 0.2 of it."""
    edges = ((9.5, 17.5), (30.5, 31.5))
    a = gc.StripeSet(64, 32, "vertical", edges, (0, 2))
    b = gc.StripeSet(64, 32, "vertical", edges, (0, 2), (255, 255))
    c = gc.StripeSet(64, 32, "vertical", edges, (0, 2), (51, 51))
    u = np.linspace(-1, 64, 997)
    v = np.full_like(u, 3.0)
    la, lb, lc = (pattern_light(s, 0.6).light(u, v) for s in (a, b, c))
    assert np.array_equal(la, lb) and la.max() > 0.99
    assert np.allclose(lc, 0.2 * la, atol=1e-12)


def test_decoded_coordinates_against_truth(setup):
    """Measured (640 x 480, projector 480 x 270, matte sphere, 1x noise): 0.972 decoded, median
    |error| 0.0275 px, none off by T / 4; RMS 0.038 px (column and row) on the interior pixels
    with modulation >= 0.1."""
    rig, scene, code, cap, _ = setup
    col, row, ex = ps.decode(cap, code)
    tr = cap.truth
    lit = tr["lit"] & (tr["surface_id"] >= 0)
    ok = lit & np.isfinite(col) & np.isfinite(row)
    assert ok.sum() / lit.sum() > 0.95
    du, dv = col - tr["proj_x"], row - tr["proj_y"]
    assert 0.01 < np.median(np.abs(du[ok])) < 0.05
    assert np.mean(np.abs(du[ok]) > code.period / 4) < 0.002  # period-order errors
    good = ok & _interior(tr) & (ex["modulation"][..., 0] >= 0.1)
    for d in (du, dv):
        rms = np.sqrt(np.mean(d[good] ** 2))
        assert 0.015 < rms < 0.05
    # the dark table (albedo 0.03, modulation 0.003): decoded only at a few mixed pixels next
    # to the sphere (measured 31 of 83 029)
    table = (tr["surface_id"] == -2) & tr["lit"]
    assert np.mean(np.isfinite(col[table])) < 0.001


def test_complementary_gray_code_removes_period_border_errors(setup):
    """Unwrapping with the plain m-bit Gray code (k1 alone) jumps a period at the borders
    where the code and the phase disagree by noise or blur; the complementary code does not."""
    _, _, code, cap, _ = setup
    col, _, ex = ps.decode(cap, code)
    tr = cap.truth
    nb = code.gray_bits("vertical")
    lin = [ps._linearise(im, code.camera_gamma) for im in cap.images[:code.steps + nb]]
    phi, avg, _ = ps.wrapped_phase(lin[:code.steps])
    g = np.zeros(phi.shape, int)
    k1 = np.zeros(phi.shape, int)
    for im in lin[code.steps:code.steps + nb - 1]:  # the m-bit Gray code of the period index
        g ^= im > avg
        k1 = 2 * k1 + g
    plain = (phi + 2 * np.pi * k1) * code.period / (2 * np.pi) - 0.5
    ok = np.isfinite(col) & tr["lit"] & (tr["surface_id"] >= 0)
    gross_plain = np.mean(np.abs(plain - tr["proj_x"])[ok] > code.period / 2)
    gross = np.mean(np.abs(col - tr["proj_x"])[ok] > code.period / 2)
    assert gross_plain > 0.001 and gross < 0.0002  # measured 0.0026 and 0


def test_phase_noise_follows_the_n_step_formula(setup):
    """sigma_x = T / (2 pi) sqrt(2 / N) sigma_I / B (Zhang 2018, sec. 2.2): the variance of the
    decoded column's noise (noisy - noise-free decode) against the formula with each pixel's
    image noise sigma_I measured from the same images (measured ratio 0.97 at a predicted
    0.040 px on 30 773 pixels)."""
    _, _, code, cap, clean = setup
    col, _, ex = ps.decode(cap, code)
    col0, _, ex0 = ps.decode(clean, code)
    good = _interior(cap.truth) & np.isfinite(col) & np.isfinite(col0)
    n = code.steps
    eps2 = sum((ps._linearise(a, 2.2) - ps._linearise(b, 2.2)) ** 2
               for a, b in zip(cap.images[:n], clean.images[:n], strict=True)) / n
    b = ex0["modulation"][..., 0]
    good &= b >= 0.1
    predicted = (code.period / (2 * np.pi)) ** 2 * (2 / n) * eps2[good] / b[good] ** 2
    measured = (col - col0)[good] ** 2
    assert good.sum() > 20000
    assert 0.75 < measured.mean() / predicted.mean() < 1.33


def test_points_against_truth(setup):
    """The points lie on the pixels' rays at the decoded column: their distance to the true
    point is |column error| times the ray's mm per projector px; in projector px their RMS is
    the literature's few hundredths of a pixel (measured: median 0.0275 px, RMS 0.066 px with
    the silhouettes' mixed pixels; 0.057 mm RMS, 1.9 mm per projector px along the rays)."""
    rig, scene, code, cap, _ = setup
    col, row, _ = ps.decode(cap, code)
    tr = cap.truth
    H, W = col.shape
    # oracle: the exact projector coordinate of each pixel gives the true surface point
    pts, pix = ps.triangulate(col, row, rig)
    obj = (tr["surface_id"] >= 0).ravel()[pix]
    pts, pix = pts[obj], pix[obj]
    xy = np.stack([pix % W, pix // W], axis=1).astype(float)
    o, d = rig.camera.back_project(xy)
    true_u = tr["proj_x"].ravel()[pix]
    exact, _, _ = intersect_exact(rig.projector, o, d, "vertical", true_u)
    truth_pts = tr["point_rig"].reshape(-1, 3)[pix]
    assert np.nanmax(np.linalg.norm(exact - truth_pts, axis=1)) < 1e-4
    lo, _, _ = intersect_exact(rig.projector, o, d, "vertical", true_u - 0.5)
    hi, _, _ = intersect_exact(rig.projector, o, d, "vertical", true_u + 0.5)
    mm_per_px = np.linalg.norm(hi - lo, axis=1)
    err = np.linalg.norm(pts - truth_pts, axis=1)
    du = np.abs(col.ravel()[pix] - true_u)
    small = du < 0.5
    assert np.allclose(err[small], du[small] * mm_per_px[small], rtol=0.02, atol=1e-5)
    px = err / mm_per_px
    rms_px = np.sqrt(np.mean(px ** 2))
    assert 0.015 < np.median(px) < 0.05 and rms_px < 0.1
    e = gc.error_stats(gc.world_error(pts, scene, rig, ANGLE))
    # 1 projector px of the 480 px projector is ~0.8 mm at 600 mm
    assert 0.01 < e["rms_mm"] < 0.08 and e["p95_mm"] < 0.15


def test_exact_mode_agrees_with_fast():
    rig = _rig(320, 240)
    scene = make_scene("sphere")
    code = ps.PhaseShift.for_projector(rig.projector, steps=4)
    s = MATTE.replace(noise=0.0)
    fast = ps.render_phase_shift(scene, rig, code, ANGLE, s, mode="fast", workers=2)
    exact = ps.render_phase_shift(scene, rig, code, ANGLE, s, mode="exact", workers=2)
    assert exact.stats["render_view_calls"] == 1 + 2 * 4  # 10 images per direction, 3 a call
    cf, rf, _ = ps.decode(fast, code)
    ce, re_, _ = ps.decode(exact, code)
    both = np.isfinite(cf) & np.isfinite(ce) & _interior(fast.truth)
    assert both.sum() > 5000
    assert np.median(np.abs(cf - ce)[both]) < 0.01 and np.median(np.abs(rf - re_)[both]) < 0.01


def test_scan_view_round_trip_and_errors(setup):
    rig, scene, _, _, _ = setup
    small = scale_camera(rig, 320, 240)
    code = ps.PhaseShift.for_projector(small.projector, steps=6, period=32)
    assert code.n_images == 2 * 6 + (4 + 1) + (4 + 1)
    r = ps.scan_view(scene, small, ANGLE, code=code, settings=MATTE, seed=1, workers=2,
                     error_sample=2000)
    assert r["images"] == code.n_images == len(r["capture"].images)
    assert r["error_points"] == 2000 < r["points"] == len(r["points_rig"])
    assert 0.9 < r["coverage"] <= 1.0
    obj = small.turntable.from_rig(r["points_rig"], ANGLE)
    dist = np.abs(np.linalg.norm(obj - np.asarray(scene.center), axis=1) - scene.radius)
    assert r["error"]["rms_mm"] == pytest.approx(np.sqrt(np.mean(dist ** 2)), rel=0.15)
    assert ps.PhaseShift.from_dict(code.to_dict()) == code
    with pytest.raises(NurbscanError, match="steps"):
        ps.PhaseShift(steps=3)
    with pytest.raises(NurbscanError, match="even"):
        ps.PhaseShift(period=15)
    with pytest.raises(NurbscanError, match="unknown keys"):
        ps.PhaseShift.from_dict({**code.to_dict(), "bogus": 1})
    with pytest.raises(NurbscanError, match="projector's size"):
        ps.render_phase_shift(scene, small, ps.PhaseShift(width=64, height=48))
    with pytest.raises(NurbscanError, match="images"):
        ps.decode(gc.StripeCapture(images=r["capture"].images[:-1], white=None, black=None,
                                   truth={}), code)


def test_shared_dark_render_gives_the_same_images():
    """One dark render serves several noise levels: bit for bit a fresh render's images."""
    from nurbscan.simulate import render_view

    rig = _rig(200, 150)
    scene = make_scene("sphere")
    code = ps.PhaseShift.for_projector(rig.projector)
    base = render_view(scene, rig, gc.StripeSet(480, 270, "vertical"), ANGLE,
                       MATTE.replace(noise=0.5), seed=2, stream=1, workers=2)
    s = MATTE.replace(noise=2.0)
    fresh = ps.render_phase_shift(scene, rig, code, ANGLE, s, seed=2, stream=1, workers=2)
    shared = ps.render_phase_shift(scene, rig, code, ANGLE, s, seed=2, stream=1, workers=2,
                                   base=base)
    assert shared.stats["render_view_calls"] == 0 and fresh.stats["render_view_calls"] == 1
    for a, b in zip(fresh.images + [fresh.white, fresh.black],
                    shared.images + [shared.white, shared.black], strict=True):
        assert np.array_equal(a, b)
    assert not np.array_equal(fresh.white, gc._grey(base.white))  # other noise
