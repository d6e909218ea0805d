"""Thin-line grid detection (nurbscan.detect.line_grid, ridges, colour_model)."""

from __future__ import annotations

import numpy as np
import pytest

from _line_synth import de_bruijn
from _real_oracle import read_rgb, real_dir, real_pattern
from nurbscan.detect import DetectionResult, detect_lines

REAL = real_dir()
HAVE_REAL = (REAL / "images" / "colorGrid01.png").is_file()
NEED_REAL = pytest.mark.skipif(not HAVE_REAL, reason=f"shared real set not found at {REAL}")


@NEED_REAL
def test_real_pattern_helper_renders_the_projected_image():
    """The test helper's LinePattern (README rules) renders pattern.png exactly."""
    pat = real_pattern()
    ref = read_rgb(REAL / "pattern.png")
    assert pat.render().shape == ref.shape
    assert int((pat.render() != ref).any(axis=2).sum()) == 0


def test_blank_and_noise_images_give_an_empty_result_with_warnings():
    pat = real_pattern()
    for img in (np.zeros((120, 160, 3), np.uint8),
                np.random.default_rng(1).integers(0, 255, (120, 160, 3)).astype(np.uint8)):
        with pytest.warns(UserWarning, match="no grid found"):
            r = detect_lines(img, pat)
        assert isinstance(r, DetectionResult)
        assert r.nlines == 0 and len(r.cam) == 0
        assert r.warnings and r.warnings[0].startswith("no grid found")


# ---------------------------------------------------------------- synthetic photographs

def _three_colour_pattern():
    """A pattern unlike the real one: 3 colours per direction (order 3, window 3), other
    pitches and widths, vertical and horizontal palettes interleaved differently."""
    from nurbscan.pattern import LineFamily, LinePattern

    colours = (("red", (255, 0, 0)), ("green", (0, 255, 0)), ("blue", (0, 0, 255)),
               ("yellow", (255, 255, 0)), ("cyan", (0, 255, 255)), ("magenta", (255, 0, 255)))
    seq = de_bruijn(3, 3)  # 27 symbols
    v = seq[:26]
    h = seq[1:27]

    def fam(name, syms, pitch, width, first, size, codes):
        c = first + pitch * np.arange(len(syms))
        keep = c + width / 2 <= size - 0.5
        c = c[keep]
        return LineFamily(name, tuple(codes[s] for s in np.asarray(syms)[keep]),
                          tuple(float(x - width / 2) for x in c),
                          tuple(float(x + width / 2) for x in c))

    return LinePattern(800, 600, colours, 3, fam("vertical", v, 30, 4, 14.5, 800, (0, 1, 2)),
                       fam("horizontal", h, 22, 3, 12, 600, (3, 4, 5)))


def _truth_check(result, pattern, hmat):
    """Per decoded line: the median projector coordinate of its centres (through the true
    homography) minus its label's coordinate; the visible lines (their centre inside the
    camera image over at least 40 px); and the RMS of all centres' coordinate errors."""
    hinv = np.linalg.inv(hmat)
    pts = np.c_[result.x, result.y]
    pj = (hinv @ np.c_[pts, np.ones(len(pts))].T).T
    pj = pj[:, :2] / pj[:, 2:]
    err_pt = pj[np.arange(len(pts)), result.point_direction] - result.coord[result.line]
    med = np.array([np.median(err_pt[result.start[i]:result.stop[i]])
                    for i in range(result.nlines)])
    w, h = result.image_size
    visible = []
    for d, name in enumerate(("vertical", "horizontal")):
        if getattr(pattern, name) is None:
            continue
        for i, c in enumerate(pattern.family(name).centres):
            t = np.linspace(0, pattern.height if d == 0 else pattern.width, 400)
            pp = np.c_[np.full_like(t, c), t] if d == 0 else np.c_[t, np.full_like(t, c)]
            cam = (hmat @ np.c_[pp, np.ones(len(t))].T).T
            cam = cam[:, :2] / cam[:, 2:]
            inside = ((cam[:, 0] > 8) & (cam[:, 0] < w - 9) & (cam[:, 1] > 8)
                      & (cam[:, 1] < h - 9))
            if inside.sum() >= 2 and np.ptp(cam[inside, 1 - d]) >= 40:
                visible.append((d, i))
    return med, visible, float(np.sqrt(np.mean(err_pt[np.abs(err_pt) < 2] ** 2)))


SYNTH_CASES = {
    # name: render_photo keyword arguments
    "plain": {},
    "gamma1.8_matrix_noise": {"gamma": 1 / 1.8, "colour_matrix": "random", "noise": 0.02},
    "linear_grey_bg_squares": {"gamma": 1.0, "colour_matrix": "random", "ambient": 0.5,
                               "background": 0.4, "squares": True},
    "dark_gamma3": {"gamma": 1 / 3.0, "gain": 0.6, "ambient": 0.2, "colour_matrix": "random",
                    "blur": 1.0},
}


@pytest.mark.parametrize("which", ["real", "three"])
@pytest.mark.parametrize("case", list(SYNTH_CASES))
@pytest.mark.parametrize("use_white", [True, False])
def test_synthetic_photograph_labels_are_all_right(which, case, use_white):
    """A LinePattern on a plane, under blur, noise, a grey non-black background, an unknown
    gamma and a random colour matrix: every decoded line has its true label (the homography's
    projector coordinate of its centres within a quarter pitch of its label's), at least 95 %
    of the lines in view are decoded, and the centres are sub-pixel accurate."""
    from _line_synth import default_homography, random_colour_matrix, render_photo

    pat = real_pattern() if which == "real" else _three_colour_pattern()
    kw = dict(SYNTH_CASES[case])
    seed = sorted(SYNTH_CASES).index(case)
    if kw.get("colour_matrix") == "random":
        kw["colour_matrix"] = random_colour_matrix(seed)
    hmat = default_homography(angle=0.03 + 0.02 * seed)
    img = render_photo(pat, hmat, seed=seed, **kw)
    white = render_photo(pat, hmat, seed=seed + 100, white=True, **kw) if use_white else None
    r = detect_lines(img, pat, white)
    assert not r.warnings
    med, visible, rms = _truth_check(r, pat, hmat)
    pitch = [float(np.median(np.diff(pat.family(n).centres))) for n in ("vertical", "horizontal")]
    tol = np.where(r.direction == 0, pitch[0], pitch[1]) / 4
    wrong = np.nonzero(np.abs(med) > tol)[0]
    assert len(wrong) == 0, [(int(r.direction[i]), int(r.band[i]), float(med[i])) for i in wrong]
    decoded = {(int(d), int(b)) for d, b in zip(r.direction, r.band, strict=True)}
    share = len(decoded & set(visible)) / len(visible)
    assert share >= 0.95, (share, sorted(set(visible) - decoded))
    assert rms < 0.35, rms  # projector px (0.27 camera px at this scale), noise included
    # intersections: their projector points are the true ones within a fraction of a pixel
    cam = (np.linalg.inv(hmat) @ np.c_[r.cam, np.ones(len(r.cam))].T).T
    cam = cam[:, :2] / cam[:, 2:]
    assert len(r.cam) > 100
    assert np.percentile(np.linalg.norm(cam - r.proj, axis=1), 95) < 0.3


# ---------------------------------------------------------------- the shared real set

@pytest.fixture(scope="module")
def real_detections():
    """detect_lines on every shot of the shared set (with its white-light image)."""
    pat = real_pattern()
    out = {}
    for n in range(1, 11):
        img = read_rgb(REAL / "images" / f"colorGrid{n:02d}.png")
        white = read_rgb(REAL / "images" / f"lightGrid{n:02d}.png")
        out[n] = detect_lines(img, pat, white)
    return pat, out


@NEED_REAL
@pytest.mark.parametrize("pose", range(1, 9))
def test_real_poses_decode_95_percent_with_no_wrong_label(real_detections, pose):
    """Of the grid lines visible on the board's white area (outside the checkerboard), at
    least 95 % decoded, none with a wrong label: every decoded line's centres on the board
    mapped through the board's RANSAC homography (board -> projector, fitted to the decoded
    intersections) lie within half a pitch of its label's coordinate, and the pose's labels as
    a whole agree with the source's own calibration (no global shift; _real_oracle)."""
    from _real_oracle import check_labels, pose_oracle, shift_ok

    pat, dets = real_detections
    r = dets[pose]
    oracle = pose_oracle(REAL, pose)
    assert oracle is not None, "findChessboardCorners failed on the white-light image"
    chk = check_labels(r, pat, oracle)
    assert chk.inliers >= 0.9 * chk.crossings > 150
    assert chk.wrong == []
    assert shift_ok(chk, pat), chk.offset
    assert len(chk.visible) >= 35
    share = len(chk.decoded) / len(chk.visible)
    assert share >= 0.95, (share, sorted(set(chk.visible) - set(chk.decoded)))


@NEED_REAL
@pytest.mark.parametrize("scene", [9, 10])
def test_real_scenes_decode_with_no_wrong_label(real_detections, scene):
    """Scenes 09 (flat sheet) and 10 (curved band): every decoded intersection on the object
    lies on its epipolar line of the source's calibration within half the distance a label
    off by one line would put it (and, for the flat sheet, on one RANSAC homography)."""
    from _real_oracle import check_scene

    pat, dets = real_detections
    chk = check_scene(dets[scene], pat, REAL, scene, flat=scene == 9)
    assert chk.wrong == []
    assert chk.shifted_p5 > 4 * chk.epipolar_p95  # the check can see an off-by-one label
    assert chk.lines >= 40 and chk.crossings >= 150


def test_bad_arrays_raise_one_line_errors():
    from nurbscan.errors import NurbscanError

    pat = real_pattern()
    img = np.zeros((120, 160, 3), np.uint8)
    for bad, what in ((np.zeros((10, 10, 3), np.uint8), "image"),
                      (np.zeros((120, 160, 2), np.uint8), "image"),
                      (np.full((120, 160, 3), np.nan, np.float32), "image")):
        with pytest.raises(NurbscanError, match=what) as exc:
            detect_lines(bad, pat)
        assert "\n" not in str(exc.value)
    with pytest.raises(NurbscanError, match="white image"):
        detect_lines(img, pat, np.zeros((100, 160, 3), np.uint8))


@NEED_REAL
def test_real_photograph_without_the_grid_gives_an_empty_result_with_warnings():
    """The white-light photographs (no grid projected; scene 10's shows a plaid curtain)."""
    pat = real_pattern()
    for n in (1, 10):
        img = read_rgb(REAL / "images" / f"lightGrid{n:02d}.png")
        with pytest.warns(UserWarning, match="no grid found"):
            r = detect_lines(img, pat)
        assert r.nlines == 0 and len(r.cam) == 0
        assert r.warnings[0].startswith("no grid found")


@NEED_REAL
def test_real_mirrored_photograph_refuses_the_backward_direction():
    """Pose 01 flipped upside down: the horizontal lines' code reads backwards. Read forwards
    (the default) they are refused with a warning, not mislabelled; the vertical lines are
    still decoded, with their true labels (the pose's oracle on the flipped image)."""
    from _real_oracle import check_labels, pose_oracle

    pat = real_pattern()
    img = read_rgb(REAL / "images" / "colorGrid01.png")[::-1].copy()
    with pytest.warns(UserWarning, match="horizontal lines read backwards"):
        r = detect_lines(img, pat)
    assert (r.direction == 1).sum() == 0
    assert (r.direction == 0).sum() >= 50
    # the vertical labels against the unflipped pose's oracle
    flipped = DetectionResult(**{**r.__dict__, "y": 479.0 - r.y,
                                 "cam": np.zeros((0, 2)), "proj": np.zeros((0, 2))})
    ref = detect_lines(read_rgb(REAL / "images" / "colorGrid01.png"), pat)
    oracle = pose_oracle(REAL, 1)
    good = check_labels(ref, pat, oracle)
    # homography of the unflipped decode checks the flipped decode's vertical lines
    chk = check_labels(DetectionResult(**{**flipped.__dict__, "cam": ref.cam,
                                          "proj": ref.proj}), pat, oracle)
    assert good.wrong == [] and chk.wrong == []


def test_synthetic_vertical_lines_only():
    """A pattern of one direction: its lines decoded with their true labels, no crossings."""
    from _line_synth import default_homography, render_photo
    from nurbscan.pattern import LinePattern

    full = real_pattern()
    pat = LinePattern(800, 600, full.colours, 3, full.vertical, None)
    hmat = default_homography()
    r = detect_lines(render_photo(pat, hmat, seed=3), pat)
    med, visible, _ = _truth_check(r, pat, hmat)
    assert (r.direction == 0).all() and len(r.cam) == 0
    assert np.all(np.abs(med) < 29 / 4)
    assert len({int(b) for b in r.band} & {i for _, i in visible}) >= 0.95 * len(visible)
    assert (r.votes > 0).mean() > 0.5 and np.all((r.agreement >= 0) & (r.agreement <= 1))


def test_centre_lines_round_trip_and_overlay(tmp_path):
    """A detect_lines result (edge = 2 centre-lines) survives lines.json, and its overlay draws
    each line in its band's colour where the line is."""
    from _line_synth import default_homography, render_photo
    from nurbscan.detect import draw_line_overlay, load_detection

    pat = real_pattern()
    img = render_photo(pat, default_homography(), seed=5)
    r = detect_lines(img, pat)
    assert r.nlines > 40 and np.all(r.edge == 2) and np.all(r.cross_edge == 2)
    back = load_detection(r.save(tmp_path / "lines.json"))
    assert back.nlines == r.nlines and np.array_equal(back.edge, r.edge)
    assert np.allclose(back.x, r.x, atol=1e-4) and np.allclose(back.cam, r.cam, atol=1e-4)
    ov = draw_line_overlay(img, r, pat, scale=2)
    assert ov.shape == (2 * img.shape[0], 2 * img.shape[1], 3) and ov.dtype == np.uint8
    i = int(np.argmax(r.stop - r.start))  # the longest line: its middle centre's pixel
    mid = r.polyline(i)[(r.stop[i] - r.start[i]) // 2]
    px = np.round((mid + 0.5) * 2 - 0.5).astype(int)
    codes = pat.family(("vertical", "horizontal")[r.direction[i]]).codes
    want = pat.rgb[codes[r.band[i]]].astype(int)
    got = ov[px[1] - 1:px[1] + 2, px[0] - 1:px[0] + 2].reshape(-1, 3).astype(float)
    base = draw_line_overlay(img, DetectionResult.empty(r.image_size), pat, scale=2)
    base = base[px[1] - 1:px[1] + 2, px[0] - 1:px[0] + 2].reshape(-1, 3).astype(float)
    k = int(np.argmax(np.abs(got - base).sum(1)))  # the pixel the line changed most
    d, t = got[k] - base[k], want - base[k]
    assert np.abs(d).sum() > 60  # drawn (anti-aliased, so blended with the photograph)
    assert d @ t / (np.linalg.norm(d) * np.linalg.norm(t)) > 0.9  # toward the band's colour


def test_cli_detect_reads_a_thin_line_pattern(tmp_path, capsys):
    """`nurbscan pattern --from-image` then `nurbscan detect` on a photograph of thin lines:
    centre-lines written with an overlay; a photograph without the grid is a one-line error,
    exit 2, nothing written."""
    from _line_synth import default_homography, render_photo
    from nurbscan.cli import main
    from nurbscan.detect import load_detection
    from nurbscan.io import write_image

    pat = real_pattern()
    write_image(tmp_path / "projected.png", pat.render())
    hmat = default_homography()
    write_image(tmp_path / "grid.png", render_photo(pat, hmat, seed=7))
    write_image(tmp_path / "white.png", render_photo(pat, hmat, white=True, seed=8))
    assert main(["pattern", "--from-image", str(tmp_path / "projected.png"),
                 "-o", str(tmp_path / "pattern.json")]) == 0
    assert main(["detect", str(tmp_path / "grid.png"), "--white", str(tmp_path / "white.png"),
                 "--pattern", str(tmp_path / "pattern.json"), "-o", str(tmp_path / "lines.json"),
                 "--overlay", str(tmp_path / "overlay.png")]) == 0
    r = load_detection(tmp_path / "lines.json")
    assert r.nlines > 40 and np.all(r.edge == 2) and (tmp_path / "overlay.png").is_file()
    capsys.readouterr()
    assert main(["detect", str(tmp_path / "white.png"), "--pattern",
                 str(tmp_path / "pattern.json"), "-o", str(tmp_path / "none.json")]) == 2
    err = capsys.readouterr().err.strip()
    assert "white.png: no grid found" in err and "\n" not in err
    assert not (tmp_path / "none.json").exists()
