"""Independent oracle for decoded grid labels on the shared real set (procam-colour-grid).

Nothing here is used by the detector. Two checks of each decoded label:

* absolute: the source project's own calibration (``reference/calibration.yml``: camera and
  projector intrinsics with 4-term distortion, stereo R, T) and the board pose from OpenCV's
  ``findChessboardCorners`` + ``solvePnP`` on the white-light image predict, for every decoded
  centre on the board plane, its projector coordinate; a label is wrong when its line's median
  distance from that prediction exceeds half the line pitch;
* relative: the decoded intersections mapped to the board plane (undistorted camera -> board
  homography of the corners) and a RANSAC homography board -> projector fitted to them; a
  line whose intersections are off it by half a pitch or more is wrong (an off-by-one label
  within a correct neighbourhood).

The board's white area, where lines count as visible, is the board (the largest bright region
of the white-light image, holes filled) minus the checkerboard itself (its corner hull grown by
1.6 squares), 6 px inside the board's edge and the image border. A line is visible when its
centre (within 2 projector px of its coordinate, by the board's homography) crosses the white
area over at least 20 camera px, decoded when 5 of its decoded centres lie within 3 px of the
white area.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

INNER = (9, 6)  # inner corners per row, per column (calib-info.yml boardSize 7 x 10 squares)
SQUARE_MM = 24.0


def real_dir() -> Path:
    """The shared real set (env NURBSCAN_REAL_DIR overrides)."""
    env = os.environ.get("NURBSCAN_REAL_DIR")
    if env:
        return Path(env)
    return Path(__file__).resolve().parents[2] / "shared" / "real" / "procam-colour-grid"


def read_rgb(path: Path) -> np.ndarray:
    a = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if a is None:
        raise FileNotFoundError(path)
    return np.ascontiguousarray(a[:, :, ::-1])


#: The De Bruijn sequence of order 3 over symbols 1..4 as their createDeBruijnSeq.m builds it,
#: cropped to the lines inside the 800 x 600 projector image (README of the set).
SYMBOLS = (4, 4, 1, 4, 3, 1, 4, 2, 1, 4, 1, 1, 3, 4, 1, 3, 3, 1, 3, 2, 1, 3, 1, 1, 2, 4, 1, 2, 3)
COLOURS = (("r", (255, 0, 0)), ("y", (255, 191, 0)), ("l", (128, 255, 0)),
           ("g", (0, 255, 128)), ("c", (0, 255, 255)), ("b", (0, 64, 255)),
           ("p", (191, 0, 255)), ("m", (255, 0, 191)))


def real_pattern():
    """The set's projected pattern as a LinePattern, built from the README's rules: lines 3 px
    wide, centres at 11 + 29 k (vertical, 28 lines) and 11 + 21 k (horizontal, 29 lines, the
    last cut by the image border), symbol s -> colour 2s (vertical: y g b m) and 2s - 1
    (horizontal: r l c p), 1-based in the colour list r y l g c b p m."""
    from nurbscan.pattern import LineFamily, LinePattern

    def family(name, n, pitch, size, offset):
        c = 11 + pitch * np.arange(n)
        lower = tuple(float(v) for v in c - 1.5)
        upper = tuple(float(min(v, size - 0.5)) for v in c + 1.5)
        codes = tuple(2 * s - 2 + offset for s in SYMBOLS[:n])
        return LineFamily(name, codes, lower, upper)

    return LinePattern(800, 600, COLOURS, 3, family("vertical", 28, 29, 800, 1),
                       family("horizontal", 29, 21, 600, 0), crossing="horizontal-over")


def reference_calibration(root: Path) -> dict:
    fs = cv2.FileStorage(str(root / "reference" / "calibration.yml"), cv2.FILE_STORAGE_READ)
    out = {k: fs.getNode(k).mat() for k in ("camK", "camKc", "prjK", "prjKc", "R", "T")}
    fs.release()
    return out


def board_corners(white_rgb: np.ndarray) -> np.ndarray | None:
    grey = cv2.cvtColor(white_rgb, cv2.COLOR_RGB2GRAY)
    ok, c = cv2.findChessboardCorners(grey, INNER, cv2.CALIB_CB_ADAPTIVE_THRESH
                                      | cv2.CALIB_CB_NORMALIZE_IMAGE)
    if not ok:
        return None
    c = cv2.cornerSubPix(grey, c, (5, 5), (-1, -1),
                         (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-3))
    return c.reshape(-1, 2).astype(np.float64)


def board_object_points() -> np.ndarray:
    j, i = np.mgrid[0:INNER[1], 0:INNER[0]]
    return np.c_[i.ravel() * SQUARE_MM, j.ravel() * SQUARE_MM, np.zeros(i.size)]


def white_area(white_rgb: np.ndarray, corners: np.ndarray, margin: int = 6
               ) -> tuple[np.ndarray, np.ndarray]:
    """The board (H, W) bool, and its white area outside the checkerboard (H, W) bool."""
    grey = cv2.cvtColor(white_rgb, cv2.COLOR_RGB2GRAY)
    _, bright = cv2.threshold(cv2.GaussianBlur(grey, (5, 5), 0), 0, 255,
                              cv2.THRESH_BINARY + cv2.THRESH_OTSU)
    # the component that holds the checkerboard's centre
    n, lab = cv2.connectedComponents(bright)
    cx, cy = corners.mean(0)
    hull = cv2.convexHull(corners.astype(np.float32)).reshape(-1, 2)
    # checker region: the corner hull grown by about one square about its centre
    centre = hull.mean(0)
    sq = np.median(np.linalg.norm(np.diff(corners.reshape(INNER[1], INNER[0], 2), axis=1),
                                  axis=2))
    grow = hull + (hull - centre) / np.linalg.norm(hull - centre, axis=1)[:, None] * 1.6 * sq
    board = np.zeros(grey.shape, np.uint8)
    counts = np.bincount(lab.ravel())
    counts[0] = 0
    # the largest bright component (the board; the checkerboard's white squares join it)
    big = int(np.argmax(counts))
    board[lab == big] = 255
    contours, _ = cv2.findContours(board, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    filled = np.zeros_like(board)
    cv2.drawContours(filled, contours, -1, 255, -1)
    plane = cv2.erode(filled, np.ones((3, 3), np.uint8))
    # the margin also from the image border (a line cut by the border is not visible)
    filled = cv2.erode(filled, np.ones((2 * margin + 1, 2 * margin + 1), np.uint8),
                       borderType=cv2.BORDER_CONSTANT, borderValue=0)
    checker = np.zeros_like(board)
    cv2.fillConvexPoly(checker, np.round(grow).astype(np.int32), 255)
    return plane > 0, (filled > 0) & (checker == 0)


@dataclass
class PoseOracle:
    corners: np.ndarray
    rvec: np.ndarray
    tvec: np.ndarray
    cal: dict
    board: np.ndarray
    area: np.ndarray

    def board_point(self, xy: np.ndarray) -> np.ndarray:
        """Camera px (N, 2) -> 3-D point on the board plane in the camera frame (N, 3)."""
        und = cv2.undistortPoints(xy.reshape(-1, 1, 2).astype(np.float64), self.cal["camK"],
                                  self.cal["camKc"]).reshape(-1, 2)
        rays = np.c_[und, np.ones(len(und))]
        rot, _ = cv2.Rodrigues(self.rvec)
        nrm = rot[:, 2]
        p0 = self.tvec.ravel()
        t = (p0 @ nrm) / (rays @ nrm)
        return rays * t[:, None]

    def projector(self, xy: np.ndarray) -> np.ndarray:
        """Predicted projector px (N, 2) of camera px on the board plane."""
        X = self.board_point(xy)
        rv, _ = cv2.Rodrigues(self.cal["R"])
        p, _ = cv2.projectPoints(X.reshape(-1, 1, 3), rv, self.cal["T"].ravel(),
                                 self.cal["prjK"], self.cal["prjKc"])
        return p.reshape(-1, 2)

    def board_mm(self, xy: np.ndarray) -> np.ndarray:
        """Camera px -> board coordinates (mm) (N, 2)."""
        X = self.board_point(xy)
        rot, _ = cv2.Rodrigues(self.rvec)
        return ((X - self.tvec.ravel()) @ rot)[:, :2]


def pose_oracle(root: Path, n: int) -> PoseOracle | None:
    white = read_rgb(root / "images" / f"lightGrid{n:02d}.png")
    corners = board_corners(white)
    if corners is None:
        return None
    cal = reference_calibration(root)
    ok, rvec, tvec = cv2.solvePnP(board_object_points(), corners, cal["camK"], cal["camKc"])
    return PoseOracle(corners, rvec, tvec, cal, *white_area(white, corners))


@dataclass
class LineCheck:
    visible: list          # (direction, index) of the lines visible on the white area
    coverage: float        # share of the visible lines' runs (rows / columns) on the white
    #                        area that hold a decoded centre of the right line
    decoded: list          # of those, the ones decoded with the right label on the white area
    wrong: list            # (direction, index, line id, reason) of decoded lines found wrong
    offset: tuple          # median (reference prediction - label coordinate), per direction
    inliers: int           # RANSAC inliers of the board -> projector homography
    crossings: int         # decoded intersections


def _visible(pattern, oracle: PoseOracle, pj_of, min_length: float, half: float = 2.0
             ) -> list:
    """Lines whose centre (the white area's pixels within ``half`` projector px of their
    coordinate, by ``pj_of``) crosses the white area over at least ``min_length`` camera px."""
    yy, xx = np.nonzero(oracle.area)
    grid = np.c_[xx, yy].astype(np.float64)
    pj = pj_of(grid)
    out = {}
    for d, name in enumerate(("vertical", "horizontal")):
        cen = np.asarray(pattern.family(name).centres, np.float64)
        for i, c in enumerate(cen):
            near = np.abs(pj[:, d] - c) < half
            if near.sum() >= 2 and np.ptp(grid[near][:, 1 - d]) >= min_length:
                out[(d, i)] = set(np.round(grid[near][:, 1 - d]).astype(int).tolist())
    return out


def check_labels(result, pattern, oracle: PoseOracle, min_length: float = 20.0,
                 ransac_px: float = 3.0) -> LineCheck:
    """Visible / decoded / wrong lines of one pose (module notes).

    The board -> projector homography is fitted (RANSAC, ``ransac_px``) to the decoded
    intersections; every decoded line's centres are mapped through it and the line is wrong
    when their median projector coordinate is half a pitch or more from its label's. Visible
    lines are predicted by the same homography over the white area (so the count does not
    depend on which lines were decoded, only on the homography that most of them agree on).
    """
    pitch = [float(np.median(np.diff(pattern.family(n).centres)))
             for n in ("vertical", "horizontal")]
    h, w = oracle.area.shape
    empty = LineCheck([], 0.0, [], [], (np.nan, np.nan), 0, len(result.cam))
    if len(result.cam) < 8:
        return empty
    b = oracle.board_mm(result.cam)
    hmat, mask = cv2.findHomography(b, result.proj, cv2.RANSAC, ransac_px)
    if hmat is None:
        return empty

    def to_proj(xy):
        bb = oracle.board_mm(xy)
        return cv2.perspectiveTransform(bb.reshape(-1, 1, 2), hmat).reshape(-1, 2)

    visible = _visible(pattern, oracle, to_proj, min_length)
    # a decoded line counts when 5 of its centres are within 3 px of the white area (the
    # area's border is an estimate: a line along the board's edge can run just outside it)
    near_area = cv2.dilate(oracle.area.astype(np.uint8), np.ones((7, 7), np.uint8)) > 0
    decoded, wrong = set(), []
    offs = [[], []]
    covered: dict = {}
    for li in range(result.nlines):
        pts = result.polyline(li)
        d = int(result.direction[li])
        ix = np.clip(np.round(pts[:, 0]).astype(int), 0, w - 1)
        iy = np.clip(np.round(pts[:, 1]).astype(int), 0, h - 1)
        on_board = oracle.board[iy, ix]
        if on_board.sum() < 5:  # off the board plane: the board's homography does not apply
            continue
        pts, ix, iy = pts[on_board], ix[on_board], iy[on_board]
        err = float(np.median(to_proj(pts)[:, d] - result.coord[li]))
        if abs(err) >= 0.5 * pitch[d]:
            wrong.append((d, int(result.band[li]), li, f"homography: {err:+.1f} px"))
            continue
        offs[d].append(float(np.median(oracle.projector(pts)[:, d] - result.coord[li])))
        if near_area[iy, ix].sum() >= 5:
            decoded.add((d, int(result.band[li])))
            runs = np.round(pts[:, 1 - d]).astype(int)[near_area[iy, ix]]
            covered.setdefault((d, int(result.band[li])), set()).update(runs.tolist())
    offset = tuple(float(np.median(o)) if o else np.nan for o in offs)
    vis = sorted(visible)
    total = sum(len(r) for r in visible.values())
    hit = sum(len(r & covered.get(k, set())) for k, r in visible.items())
    return LineCheck(vis, hit / total if total else 0.0, sorted(set(vis) & decoded), wrong,
                     offset, int(mask.sum()), len(result.cam))


#: The reference calibration's projector frame is offset from the pattern's by about this
#: (median over the 8 poses of the decoded lines' (prediction - label), projector px), a
#: constant of the set: measured, not fitted per pose. A pose whose decode were shifted by a
#: whole line would differ from it by a pitch (29 / 21 px).
REFERENCE_OFFSET = (-49.0, 27.0)


def shift_ok(check: LineCheck, pattern, tol_share: float = 0.5) -> bool:
    """Whether the pose's median offset from the reference calibration is within half a pitch
    of :data:`REFERENCE_OFFSET` in both directions (no global shift of the labels)."""
    for d, name in enumerate(("vertical", "horizontal")):
        pitch = float(np.median(np.diff(pattern.family(name).centres)))
        if np.isfinite(check.offset[d]) and abs(check.offset[d] - REFERENCE_OFFSET[d]) \
                >= tol_share * pitch:
            return False
    return True


def object_mask(root: Path, n: int) -> np.ndarray:
    """The source's object mask of scene ``n`` (objectROI09 / 10), (H, W) bool."""
    a = cv2.imread(str(root / "images" / f"objectROI{n:02d}.png"), cv2.IMREAD_GRAYSCALE)
    if a is None:
        raise FileNotFoundError(root / "images" / f"objectROI{n:02d}.png")
    return a > 127


def epipolar_distance(cam: np.ndarray, proj: np.ndarray, cal: dict,
                      offset=REFERENCE_OFFSET) -> np.ndarray:
    """Distance (projector px) of each projector point from the epipolar line of its camera
    point under the reference calibration (undistorted points, F = K_p^-T [T]x R K_c^-1), the
    projector points moved into the reference's projector frame by :data:`REFERENCE_OFFSET`."""
    kc, kp = cal["camK"], cal["prjK"]
    uc = cv2.undistortPoints(cam.reshape(-1, 1, 2), kc, cal["camKc"], P=kc).reshape(-1, 2)
    pj = proj + np.asarray(offset)[None, :]
    up = cv2.undistortPoints(pj.reshape(-1, 1, 2), kp, cal["prjKc"], P=kp).reshape(-1, 2)
    t = cal["T"].ravel()
    tx = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
    f = np.linalg.inv(kp).T @ tx @ cal["R"] @ np.linalg.inv(kc)
    lines = (f @ np.c_[uc, np.ones(len(uc))].T).T
    num = np.abs((lines * np.c_[up, np.ones(len(up))]).sum(1))
    return num / np.hypot(lines[:, 0], lines[:, 1])


@dataclass
class SceneCheck:
    lines: int        # decoded lines with centres on the object
    crossings: int    # decoded intersections on the object
    wrong: list       # (direction, index, line id, reason)
    epipolar_p50: float
    epipolar_p95: float
    shifted_p5: float  # 5th percentile of the epipolar distance had a label been off by one


def check_scene(result, pattern, root: Path, n: int, flat: bool) -> SceneCheck:
    """Labels of a scene on its object mask.

    Every decoded intersection on the object is checked against the epipolar geometry of the
    reference calibration (:func:`epipolar_distance`): a line is wrong when the median distance
    of its intersections exceeds half the smallest distance that a label off by one line
    would give (``shifted_p5 / 2``). A flat scene (09) is also checked against a RANSAC
    camera -> projector homography of its intersections, like the poses.
    """
    mask = object_mask(root, n)
    h, w = mask.shape
    cal = reference_calibration(root)
    ix = np.clip(np.round(result.cam[:, 0]).astype(int), 0, w - 1)
    iy = np.clip(np.round(result.cam[:, 1]).astype(int), 0, h - 1)
    on = mask[iy, ix]
    cam, proj, cl = result.cam[on], result.proj[on], result.cross_line[on]
    pitch = np.array([float(np.median(np.diff(pattern.family(d).centres)))
                      for d in ("vertical", "horizontal")])
    dist = epipolar_distance(cam, proj, cal)
    shifted = np.min([epipolar_distance(cam, proj + s * np.eye(2)[d] * pitch[d], cal)
                      for d in (0, 1) for s in (-1, 1)], axis=0)
    tol = 0.5 * float(np.percentile(shifted, 5)) if len(shifted) else 0.0
    wrong = []
    for li in np.unique(cl):
        sel = (cl == li).any(1)
        med = float(np.median(dist[sel]))
        if med > tol:
            wrong.append((int(result.direction[li]), int(result.band[li]), int(li),
                          f"epipolar: {med:.1f} px > {tol:.1f}"))
    if flat and len(cam) >= 8:
        und = cv2.undistortPoints(cam.reshape(-1, 1, 2), cal["camK"], cal["camKc"],
                                  P=cal["camK"]).reshape(-1, 2)
        hmat, _ = cv2.findHomography(und, proj, cv2.RANSAC, 3.0)
        err = cv2.perspectiveTransform(und.reshape(-1, 1, 2), hmat).reshape(-1, 2) - proj
        for li in np.unique(cl):
            for d in (0, 1):
                sel = cl[:, d] == li
                if sel.any() and abs(float(np.median(err[sel, d]))) >= 0.5 * pitch[d]:
                    wrong.append((d, int(result.band[li]), int(li), "homography"))
    nl = 0
    for li in range(result.nlines):
        p = np.round(result.polyline(li)).astype(int)
        if mask[np.clip(p[:, 1], 0, h - 1), np.clip(p[:, 0], 0, w - 1)].sum() >= 5:
            nl += 1
    p50 = float(np.median(dist)) if len(dist) else np.nan
    p95 = float(np.percentile(dist, 95)) if len(dist) else np.nan
    return SceneCheck(nl, int(on.sum()), wrong, p50, p95, 2 * tol)
