"""Calibrate a whole rig from a scan's calibration folder; compare rigs; residual figures.

Steps (method.md section 4; issue 6):

1. Read ``scan.json`` beside the calibration folder: the target (chessboard: inner corners,
   square size), the pose list (white and grid images, ``kind`` free or turntable, the table
   angle of turntable poses) and the image size. The ``truth/`` folder is never read.
2. Camera: chessboard corners in each white image (a view where the target is not found is
   named in a warning and left out), Zhang's initialisation, Tsai fit
   (:mod:`nurbscan.calibrate.camera`).
3. Projector: the grid in each view is decoded by :func:`nurbscan.detect.detect_grid`; edge
   points on white squares of the target (away from the printed square edges, where the
   albedo step biases the band edges) become single-coordinate projector observations
   (:mod:`nurbscan.calibrate.projector`); initialisation, then the joint bundle of camera,
   projector and board poses, with a second pass after rejecting gross outliers (> 5 sigma).
   The detector's symmetric band-edge bias (bands read narrower or wider than drawn) is
   fitted as two nuisance parameters and reported (``edge_bias_projector_px``). On a printed
   target the white part where the grid is read is given a shape, a smooth height field over
   the board plane shared by all poses and fitted in the bundle
   (:mod:`nurbscan.calibrate.surface`; reported as ``board_surface``).
4. Turntable: axis from the turntable views (:mod:`nurbscan.calibrate.turntable`); its point
   is placed on the table top, the plane of the board's lower edge (the target stands on the
   table).
"""

from __future__ import annotations

import math
import os
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .._parallel import process_map
from ..detect.options import DetectOptions
from ..errors import NurbscanError
from ..io import chroma_subsampled, load_scan, read_image
from ..io.atomic import read_json
from ._bundle import (
    BundleState,
    ProjObs,
    camera_residuals,
    projector_residuals,
    run_bundle,
)
from ._tsai import back_project_local, project_local, rotmats
from .board import outside_field, white_area
from .camera import board_points, calibrate_camera, detect_chessboard
from .projector import board_frame_points, init_projector
from .surface import BoardSurface
from .turntable import fit_turntable

#: Sensor of the default camera (3072 px of 2.3 um) and micromirror array of the default
#: projector (1920 px of 7.56 um): pixel pitches are defaulted from these sensor widths when
#: neither scan.json nor the caller gives them (f and the pitch are not separately
#: identifiable; only f / pitch matters to the geometry).
DEFAULT_CAMERA_SENSOR_WIDTH_MM = 3072 * 0.0023
DEFAULT_PROJECTOR_SENSOR_WIDTH_MM = 1920 * 0.00756

MIN_VIEWS = 3

#: What a calibration without turntable poses says, in its warnings and in the rig file.
TURNTABLE_NOT_CALIBRATED = ("turntable not calibrated: the calibration set has no turntable "
                            "poses (fewer than 2 with a table angle), only the camera and the "
                            "projector are calibrated")


def turntable_calibrated(rig_json: dict) -> bool:
    """False when a rig file's turntable is marked ``"calibrated": false`` (a calibration of
    free poses only, :meth:`CalibrationResult.rig_dict`); True otherwise."""
    tt = rig_json.get("turntable") if isinstance(rig_json, dict) else None
    return not (isinstance(tt, dict) and tt.get("calibrated") is False)


@dataclass
class Target:
    """Chessboard description from scan.json (``calibration.target``).

    Only ``inner_corners`` and ``square_mm`` are needed: a checkerboard as people print it,
    glued on a larger white board. Then ``margin`` is None and the white part of the board
    where the projected grid is read is found in each white-light image
    (:func:`nurbscan.calibrate.board.white_area`). nurbscan's own simulated target
    (``"type": "nurbscan.chessboard"``) gives ``margin_mm``, the width of its white margin
    around the field of squares, and its white squares are read as well.
    """

    cols: int
    rows: int
    square: float
    margin: float | None = 20.0
    first_square_dark: bool = True

    @property
    def printed(self) -> bool:
        """True when the board's white part is to be found in the images (no margin given)."""
        return self.margin is None

    @classmethod
    def from_dict(cls, d: dict, source: str) -> Target:
        try:
            kind = str(d.get("type", "checkerboard"))
            if "chessboard" not in kind and "checkerboard" not in kind:
                raise ValueError(f"type {d.get('type')!r} is not a chessboard")
            cols, rows = (int(v) for v in d["inner_corners"])
            square = float(d["square_mm"])
            if cols < 2 or rows < 2 or not square > 0:
                raise ValueError(f"inner_corners {[cols, rows]}, square_mm {square}")
            # nurbscan's own target without a margin read as before (20 mm)
            margin = d.get("margin_mm", 20.0 if kind == "nurbscan.chessboard" else None)
            return cls(cols, rows, square, None if margin is None else float(margin),
                       bool(d.get("first_square_dark", True)))
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            raise NurbscanError(f"{source}: bad calibration target description ({exc})") from None

    def corners(self) -> np.ndarray:
        return board_points((self.cols, self.rows), self.square)


@dataclass
class CalibrationResult:
    """Everything :func:`calibrate_scan` found."""

    rig: Any  # nurbscan.camera.Rig
    views: list[str]  # names of the views used
    kinds: list[str]
    table_angles: list[float | None]
    kc: np.ndarray
    kp: np.ndarray
    rp: np.ndarray
    tp: np.ndarray
    rvecs: np.ndarray
    tvecs: np.ndarray
    figures: dict
    corner_residuals: list[np.ndarray]  # per view (N, 2) px
    corner_pixels: list[np.ndarray]
    proj_residuals: list[np.ndarray]  # per view (K,) projector px
    proj_pixels: list[np.ndarray]  # per view (K, 2) camera px
    warnings: list[str] = field(default_factory=list)
    turntable_calibrated: bool = True  # False: only free poses; rig.turntable a placeholder
    board_surface: BoardSurface | None = None  # the white part's shape (printed targets)

    def rig_dict(self) -> dict:
        """The rig's JSON (:meth:`nurbscan.camera.Rig.to_dict`); an uncalibrated turntable is
        marked ``"calibrated": false`` with a note (:func:`turntable_calibrated`)."""
        d = self.rig.to_dict()
        if not self.turntable_calibrated:
            d["turntable"] = {**d["turntable"], "calibrated": False,
                              "note": TURNTABLE_NOT_CALIBRATED}
        return d

    def residuals_dict(self) -> dict:
        """JSON-ready residual figures (``"type": "nurbscan.calibration_residuals"``)."""
        return {"type": "nurbscan.calibration_residuals", "version": 1, **self.figures,
                "warnings": list(self.warnings)}


def _say(progress, msg):
    if progress is not None:
        progress(msg)


def read_scan_json(calib_dir: Path) -> dict:
    """The scan.json beside (or inside) the calibration folder."""
    for cand in (calib_dir.parent / "scan.json", calib_dir / "scan.json"):
        if cand.is_file():
            doc = read_json(cand)
            if not isinstance(doc, dict):
                raise NurbscanError(f"{cand}: not a nurbscan scan (a JSON object with "
                                    "\"type\": \"nurbscan.scan\"; docs/scan-format.md)")
            return doc | {"_path": str(cand), "_root": str(cand.parent)}
    raise NurbscanError(f"{calib_dir}: no scan.json beside the calibration folder (looked in "
                        f"{calib_dir.parent} and {calib_dir})")


def _pitch(doc: dict, key: str, width: int, default_sensor: float) -> tuple[float, float]:
    dev = doc.get(key)
    if isinstance(dev, dict) and "pixel_pitch_mm" in dev:
        p = dev["pixel_pitch_mm"]
        p = (float(p), float(p)) if np.isscalar(p) else (float(p[0]), float(p[1]))
        if min(p) <= 0:
            raise NurbscanError(f"scan.json {key}.pixel_pitch_mm={p}: must be positive")
        return p
    d = default_sensor / float(width)
    return d, d


def _clean_board_points(xy: np.ndarray, target: Target, keep_off_edges_mm: float) -> np.ndarray:
    """(K,) bool: board points (K, 2), mm, on a white square or the white margin, at least
    ``keep_off_edges_mm`` from any printed square edge and from the board's outline."""
    xy = np.asarray(xy, float)
    s = target.square
    ix, iy = np.floor(xy[:, 0] / s), np.floor(xy[:, 1] / s)
    in_sq = (ix >= -1) & (ix <= target.cols - 1) & (iy >= -1) & (iy <= target.rows - 1)
    white = ~in_sq | ((ix + iy) % 2 == 1)
    fx, fy = xy[:, 0] / s - ix, xy[:, 1] / s - iy
    m = keep_off_edges_mm / s
    away = ~in_sq | ((fx > m) & (fx < 1 - m) & (fy > m) & (fy < 1 - m))
    x0, x1 = -s - target.margin, target.cols * s + target.margin
    y0, y1 = -s - target.margin, target.rows * s + target.margin
    inside = (xy[:, 0] > x0 + 2 * keep_off_edges_mm) & (xy[:, 0] < x1 - 2 * keep_off_edges_mm) \
        & (xy[:, 1] > y0 + 2 * keep_off_edges_mm) & (xy[:, 1] < y1 - 2 * keep_off_edges_mm)
    # points just outside the square field are on the white margin: away from the outer squares
    near_field = (xy[:, 0] > -s - keep_off_edges_mm) & (xy[:, 0] < target.cols * s
                                                        + keep_off_edges_mm) \
        & (xy[:, 1] > -s - keep_off_edges_mm) & (xy[:, 1] < target.rows * s + keep_off_edges_mm)
    return white & away & inside & ~(~in_sq & near_field) & np.all(np.isfinite(xy), axis=1)


def _edge_sign(det) -> np.ndarray:
    """(L,) per line: -1 rising edge, +1 falling edge, 0 centre-line (``edge`` 2)."""
    e = np.asarray(det.edge)
    return np.where(e == 2, 0.0, 2.0 * e - 1.0)


def oriented_corners(corners: np.ndarray, target: Target) -> np.ndarray:
    """Detected inner corners (N, 2) in the board's physical order: board y down the image.

    OpenCV's chessboard finder may return an (even + even) board's corners from either end;
    such a board looks the same turned by 180 degrees, so the order with the board's y axis
    pointing down the image is taken (the physical orientation of a board standing upright).
    """
    col = corners[(target.rows - 1) * target.cols] - corners[0]
    if col[1] < 0 and (target.cols + target.rows) % 2 == 0:
        return corners[::-1].copy()
    return corners


def edge_observations(det, kc, rvec, tvec, target: Target, view: int, dc,
                      max_points: int, keep_off_edges_mm: float = 2.0,
                      rng: np.random.Generator | None = None,
                      white_area: np.ndarray | None = None, field_pad: float = 0.25) -> ProjObs:
    """Single-coordinate projector observations from a detection result on the target.

    Keeps edge points (or centre-line points) whose board point (camera ray meets the view's
    board plane) lies on a white square or the white margin, at least ``keep_off_edges_mm``
    from any printed square edge and from the board's outline; with ``white_area`` (a printed
    target: the mask of the board's white part found in the white-light image, (H, W) bool)
    the points on that mask outside the checkerboard field widened by ``field_pad`` squares.
    Then at most ``max_points`` of them (evenly at random).
    """
    x = np.asarray(det.x, float)
    if len(x) == 0:
        return ProjObs(np.zeros((0, 2)), np.zeros(0), np.zeros(0, np.int64),
                       np.zeros(0, np.int64), np.zeros(0))
    px = np.stack([x, np.asarray(det.y, float)], axis=1)
    line = np.asarray(det.line)
    axis = np.asarray(det.direction)[line].astype(np.int64)
    value = np.asarray(det.coord, float)[line]
    v = np.full(len(px), view, np.int64)
    sign = _edge_sign(det)[line]
    o = ProjObs(px, value, axis, v, sign)
    xy = board_frame_points(kc, rvec[None], tvec[None], ProjObs(px, value, axis, v * 0), *dc)
    if white_area is None:
        keep = _clean_board_points(xy, target, keep_off_edges_mm)
    else:
        h, w = white_area.shape
        ij = np.round(px).astype(np.int64)
        inimg = (ij[:, 0] >= 0) & (ij[:, 0] < w) & (ij[:, 1] >= 0) & (ij[:, 1] < h)
        ij = np.clip(ij, 0, [w - 1, h - 1])
        keep = inimg & white_area[ij[:, 1], ij[:, 0]] & outside_field(
            xy, (target.cols, target.rows), target.square, field_pad)
    idx = np.flatnonzero(keep)
    if len(idx) > max_points:
        rng = rng or np.random.default_rng(0)
        idx = np.sort(rng.choice(idx, max_points, replace=False))
    return ProjObs(o.pixels[idx], o.value[idx], o.axis[idx], o.view[idx], o.sign[idx])


def consistent_labels(obs: ProjObs, det, kc, rvecs, tvecs, dc, tol_px: float = 4.0,
                      ransac_px: float = 3.0) -> np.ndarray:
    """(K,) bool: observations whose decoded label agrees with the view's board homography.

    A line decoded with a wrong label (a block of lines read one window off) puts its points
    a whole line spacing or more off in the projector. Per view, the board -> projector
    homography of the decoded grid intersections (``det.cam`` mapped onto the board plane by
    the view's pose, ``det.proj``) is found by RANSAC (:func:`cv2.findHomography`, threshold
    ``ransac_px`` projector px; Fischler and Bolles 1981), and an observation is kept when its
    projector coordinate is within ``tol_px`` of the homography's prediction at its board
    point (lens distortion over a board moves the prediction by well under the lines'
    spacing). Views with fewer than 8 intersections keep all their observations.

    Parameters
    ----------
    obs : ProjObs
        Observations of ONE view (its ``view`` index into ``rvecs``, ``tvecs``).
    det : nurbscan.detect.DetectionResult
        That view's detection (its ``cam`` and ``proj`` intersections).
    kc, rvecs, tvecs, dc
        Camera intrinsics, board poses (P, 3) and camera pixel pitch.
    """
    import cv2

    cam, prj = np.asarray(det.cam, float), np.asarray(det.proj, float)
    if len(obs.view) == 0 or len(cam) < 8:
        return np.ones(len(obs.view), bool)
    v = int(obs.view[0])
    z = np.zeros(len(cam))
    xy = board_frame_points(kc, rvecs, tvecs, ProjObs(cam, z, z.astype(np.int64),
                                                      np.full(len(cam), v)), *dc)
    ok = np.all(np.isfinite(xy), axis=1)
    H, _ = cv2.findHomography(xy[ok], prj[ok], cv2.RANSAC, ransac_px)
    if H is None:
        return np.ones(len(obs.view), bool)
    xo = board_frame_points(kc, rvecs, tvecs, obs, *dc)
    q = np.column_stack([xo, np.ones(len(xo))]) @ H.T
    q = q[:, :2] / q[:, 2:]
    r = np.take_along_axis(q, obs.axis[:, None], axis=1)[:, 0] - obs.value
    return np.abs(r) < tol_px


def corner_weights(per_view_rms: np.ndarray) -> np.ndarray:
    """Weights (P,) of each view's chessboard corners in the joint bundle.

    Corner errors are not alike from view to view: a board out of focus, under a glint or
    seen at a grazing angle gives corners several times worse than the others (on the
    simulated default rig the views' corner errors now range over 0.013-0.027 px RMS; when
    the renderer still point-sampled the printed edges, its square-on pose was at 0.12 px
    against 0.03-0.06 px for the others). Each view's corner residuals are scaled by
    ``min(1, median / rms_i)`` (``rms_i`` its RMS in the camera-only fit): inverse-variance
    weighting of the views worse than the median (variance components by view; Foerstner
    1979), the others kept at 1 so that a single good view does not dominate.

    Parameters
    ----------
    per_view_rms : ndarray, shape (P,)
        Corner reprojection RMS of each view, camera px.

    Returns
    -------
    ndarray, shape (P,)
        Weights in (0, 1].
    """
    rms = np.asarray(per_view_rms, float)
    med = float(np.median(rms))
    with np.errstate(divide="ignore", invalid="ignore"):
        w = np.where(rms > 0, med / rms, 1.0)
    return np.clip(np.nan_to_num(w, nan=1.0), 1e-3, 1.0)


def _corner_index(board_pts: np.ndarray, target: Target) -> np.ndarray:
    """Index (row-major, x fastest) of board corners given by their board coordinates."""
    ij = np.round(board_pts[:, :2] / target.square).astype(int)
    return ij[:, 1] * target.cols + ij[:, 0]


def _concat(obs: list[ProjObs]) -> ProjObs:
    return ProjObs(*(np.concatenate([getattr(o, k) for o in obs])
                     for k in ("pixels", "value", "axis", "view", "sign")))


#: :func:`~nurbscan.detect.detect_grid` options for the calibration poses: the detection
#: options that buy coverage with less exact points are off. The corner points
#: (``corner_dominance``) keep their raw positions, not re-measured in the band's colour
#: channels; the lines labelled from the family's coordinate map (``fit_rounds``) and the
#: extra end test (``new_end_residual``) change which points of the board are kept; the
#: calibration fits every point. bench_calibrate, three-pose set: held-out pose RMS
#: 0.0217 mm with all three, 0.0167 without the corner points, 0.0163 without the fit
#: labels as well, 0.0161 without any (the figure before they existed). The check of short
#: lines without a consistent intersection (``min_checked_length``) is off too: a board
#: has no occluding contours, and with it the held-out RMS was 0.0173 mm instead of 0.0149.
#: The edge filter stays at band / 8 (``sigma_per_band``): the noise-adapted band / 10 gave
#: 0.0186 mm (detection floor 0.0122 -> 0.0152 mm); the boards' bands are not squeezed.
#: The support of row-less points by the plane of their neighbouring lines
#: (``plane_radius``) is off: on a flat board the rows hold their neighbours, and the points
#: it keeps are less exact (held-out pose, detection floor with the true rig 0.0119 ->
#: 0.0169 mm, held-out RMS 0.0143 -> 0.0199 mm). A point goes with its band partner whatever
#: dropped the partner (``partner_drops`` "all"): with "unmeasured" the points beside the
#: partners dropped as kinks stay, and the held-out pose's detection floor was 0.0118 ->
#: 0.0137 mm. The bands are paired and read along pixel rows and columns
#: (``read_along`` "pixels"), not along the other family's edges: on the held-out pose the
#: grid runs keep 1.6 % more points (211,487 against 208,132) but the detection floor with
#: the true rig rises from 0.0118 to 0.0137 mm.
DETECT_OPTIONS = DetectOptions().replace(
    corner_dominance=1.0, fit_rounds=0, new_end_residual=0.0, min_checked_length=0.0,
    sigma_per_band=8.0, plane_radius=0.0, partner_drops="all", read_along="pixels")


def _is_line_pattern(pattern) -> bool:
    """True for a :class:`nurbscan.pattern.LinePattern` (any grid of straight lines)."""
    try:
        from ..pattern import LinePattern
    except ImportError:  # pragma: no cover - before the LinePattern class exists
        return False
    return isinstance(pattern, LinePattern)


def _relative(path: Path, root: Path) -> str:
    """``path`` as scan.json names it: relative to the scan folder when inside it."""
    try:
        return path.relative_to(root.resolve()).as_posix()
    except ValueError:
        return str(path)


def _read_pose(job) -> tuple[tuple[int, int], np.ndarray | None, Any, np.ndarray | None]:
    """One pose's image size ``(W, H)``, chessboard corners (None: not found), decoded grid
    (None when the board is not found) and, for a printed target, the mask of the board's
    white part (:func:`nurbscan.calibrate.board.white_area`; None otherwise)."""
    from ..detect import detect_grid

    wpath, gpath, pattern, target, require_all = job
    inner = (target.cols, target.rows)
    # the files' own integer type: detect linearises it by table look-up (several times
    # faster than from float32)
    white = read_image(wpath, as_float=False)
    c = detect_chessboard(white, inner, first_square_dark=target.first_square_dark)
    if c is None and require_all:
        raise NurbscanError(f"{wpath}: calibration target not found ({target.cols} x "
                            f"{target.rows} inner corners)")
    if c is None:
        return (white.shape[1], white.shape[0]), None, None, None
    area = white_area(white, c, inner, target.square) if target.printed else None
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        grid = read_image(gpath, as_float=False)
        if grid.shape[:2] != white.shape[:2]:
            raise NurbscanError(f"{wpath}: size {white.shape[1]} x {white.shape[0]} does not "
                                f"match the grid image {Path(gpath).name} ({grid.shape[1]} x "
                                f"{grid.shape[0]})")
        if _is_line_pattern(pattern):
            from ..detect import detect_lines

            det = detect_lines(grid, pattern, white=white)
        else:
            # a chroma-subsampled JPEG's colour channels have displaced edges (detect_grid)
            det = detect_grid(grid, pattern, white,
                              DETECT_OPTIONS.replace(chroma_subsampled=chroma_subsampled(gpath)))
    return (white.shape[1], white.shape[0]), c, det, area


def calibrate_scan(calib_dir: str | os.PathLike, pattern=None, *,
                   exclude: tuple[int, ...] = (), camera_pitch: float | None = None,
                   projector_pitch: float | None = None, max_points_per_view: int = 1500,
                   progress: Callable[[str], None] | None = None,
                   workers: int = 1, require_all: bool = False,
                   pose_cache: dict | None = None,
                   projector_weight: float = 1.0,
                   allow_outside: bool = False,
                   board_surface: bool | None = None,
                   surface_spacing: float | None = None,
                   surface_weight: float = 0.3) -> CalibrationResult:
    """Calibrate camera, projector and turntable from a scan's calibration images.

    Parameters
    ----------
    calib_dir : path-like
        The calibration folder (``scan/calibration``); ``scan.json`` is read beside it.
    pattern : nurbscan.pattern.Pattern or path-like, optional
        The projected pattern (default ``pattern.json`` of the scan folder).
    exclude : tuple of int
        Pose indices (scan.json ``index``) to leave out (e.g. a held-out pose).
    camera_pitch, projector_pitch : float, optional
        Pixel pitch, mm (default: scan.json ``camera.pixel_pitch_mm`` /
        ``projector.pixel_pitch_mm``, else the default rig's sensor width over the image
        width).
    max_points_per_view : int
        Projector observations kept per view (edge points, at random).
    progress : callable, optional
        Called with one line per step.
    workers : int
        Processes reading the poses side by side (chessboard and grid detection; 0: one per
        CPU); the result does not depend on it.
    require_all : bool
        Refuse (:class:`NurbscanError` naming the file) a pose whose white-light image shows
        no target, instead of leaving it out with a warning.
    allow_outside : bool
        Accept pose paths in ``scan.json`` that are absolute or leave the scan folder
        (:func:`nurbscan.io.load_scan`; refused by default).
    pose_cache : dict, optional
        The caller's store of what was read from each pose's images (corners, decoded grid,
        white area), keyed by the image paths: filled on the first call and reused by later
        calls with the same dict (e.g. leave-one-pose-out calibrations of one set).
    board_surface : bool, optional
        Fit the shape of the board's white part (:mod:`nurbscan.calibrate.surface`) instead
        of taking it for the plane of the corners; default: for a printed target (its white
        part found in the images), not for nurbscan's own exact target.
    surface_spacing : float, optional
        Knot spacing of that surface, mm (default: one square of the target).
    surface_weight : float
        Weight of its roughness penalty (:func:`nurbscan.calibrate._bundle.run_bundle`).

    Returns
    -------
    CalibrationResult
    """
    from ..camera import Camera, Projector, Rig, Turntable
    from ..pattern import Pattern, load_pattern

    t0 = time.perf_counter()
    calib_dir = Path(calib_dir)
    if not calib_dir.is_dir():
        raise NurbscanError(f"{calib_dir}: calibration folder not found")
    doc = read_scan_json(calib_dir)
    root = Path(doc["_root"])
    # the poses' paths resolved inside the scan folder, the fields checked
    scan = load_scan(root, allow_outside=allow_outside)
    cal = doc.get("calibration")
    if not isinstance(cal, dict) or "target" not in cal or "poses" not in cal:
        raise NurbscanError(f"{doc['_path']}: no 'calibration' section with target and poses")
    target = Target.from_dict(cal["target"], f"{doc['_path']} calibration.target")
    if pattern is None:
        pattern = root / "pattern.json"
    if not isinstance(pattern, Pattern):
        pattern = load_pattern(pattern)
    for q in scan.poses:
        if q.grid is None:
            raise NurbscanError(f"{doc['_path']}: calibration.poses[{q.index}]: missing 'grid'")
    poses = [q for q in scan.poses if q.index not in set(exclude)]
    if len(poses) < MIN_VIEWS:
        left = (f" ({len(scan.poses) - len(poses)} of {len(scan.poses)} left out by exclude)"
                if len(poses) < len(scan.poses) else "")
        raise NurbscanError(f"{doc['_path']}: {len(poses)} calibration poses{left}; at least "
                            f"{MIN_VIEWS} are needed")
    board = target.corners()
    warn_list: list[str] = []
    names, kinds, angles, corners, dets, areas = [], [], [], [], [], []
    size = None
    jobs = [(p.white, p.grid, pattern, target, require_all) for p in poses]

    def seen(i: int, res) -> None:
        _say(progress, f"[{time.perf_counter() - t0:6.1f} s] {todo[i][1].name}: "
             + ("target not found" if res[1] is None else f"{res[2].nlines} lines"))

    missing = []
    cache = {} if pose_cache is None else pose_cache
    todo = [j for j in jobs if (str(j[0]), str(j[1])) not in cache]
    for j, r in zip(todo, process_map(_read_pose, todo, workers, done=seen), strict=True):
        cache[(str(j[0]), str(j[1]))] = r
    for p, j in zip(poses, jobs, strict=True):
        shape = cache[(str(j[0]), str(j[1]))][0]
        if tuple(shape) != scan.image_size:  # one camera, one image size
            raise NurbscanError(f"{p.white}: {shape[0]} x {shape[1]} px, but the scan's images "
                                f"are {scan.image_size[0]} x {scan.image_size[1]} "
                                f"({doc['_path']} image_size)")
    for p, j in zip(poses, jobs, strict=True):
        shape, c, det, area = cache[(str(j[0]), str(j[1]))]
        size = size or shape
        if c is None:
            missing.append(str(p.white))
            msg = f"{p.white}: calibration target not found; pose left out"
            warnings.warn(msg, UserWarning, stacklevel=2)
            warn_list.append(msg)
            continue
        c = oriented_corners(c, target)
        names.append(_relative(p.white, root))
        kinds.append(p.kind)
        angles.append(p.table_angle)
        corners.append(c)
        dets.append((p.grid, det))
        areas.append(area)
    if len(corners) < MIN_VIEWS:
        nf = f" (not found in {', '.join(missing)})" if missing else ""
        raise NurbscanError(f"{calib_dir}: the target was found in {len(corners)} image(s); "
                            f"at least {MIN_VIEWS} are needed{nf}")
    dc = (camera_pitch, camera_pitch) if camera_pitch else _pitch(
        doc, "camera", size[0], DEFAULT_CAMERA_SENSOR_WIDTH_MM)
    dp = (projector_pitch, projector_pitch) if projector_pitch else _pitch(
        doc, "projector", pattern.width, DEFAULT_PROJECTOR_SENSOR_WIDTH_MM)
    _say(progress, f"[{time.perf_counter() - t0:6.1f} s] target found in {len(corners)} of "
         f"{len(poses)} white images")
    cam = calibrate_camera(corners, board, size, *dc, names=names)
    med = float(np.median(cam.per_view_rms))
    bad = np.flatnonzero(cam.per_view_rms > max(5.0 * med, 0.5))
    if len(bad) and len(corners) - len(bad) >= MIN_VIEWS:
        for i in bad:
            msg = (f"{names[i]}: chessboard corners inconsistent (RMS {cam.per_view_rms[i]:.2f} "
                   f"px against a median {med:.2f} px); pose left out")
            warnings.warn(msg, UserWarning, stacklevel=2)
            warn_list.append(msg)
        keep = [i for i in range(len(corners)) if i not in set(bad.tolist())]
        names, kinds, angles, corners, dets, areas = (
            [lst[i] for i in keep] for lst in (names, kinds, angles, corners, dets, areas))
        cam = calibrate_camera(corners, board, size, *dc, names=names)
    _say(progress, f"[{time.perf_counter() - t0:6.1f} s] camera: RMS {cam.rms:.4f} px")

    obs = []
    rng = np.random.default_rng(0)
    lines, n_label = _is_line_pattern(pattern), 0
    for i, (gpath, det) in enumerate(dets):
        o = edge_observations(det, cam.kc, cam.rvecs[i], cam.tvecs[i], target, i, dc,
                              max_points_per_view, rng=rng, white_area=areas[i])
        if lines:
            # thin-line grids: labels checked against the view's board homography
            good = consistent_labels(o, det, cam.kc, cam.rvecs, cam.tvecs, dc)
            n_label += int(np.sum(~good))
            o = ProjObs(o.pixels[good], o.value[good], o.axis[good], o.view[good],
                        o.sign[good])
        if len(o.view) < 50:
            msg = f"{gpath}: projected grid not decoded on the target; pose not used for the " \
                  "projector"
            warnings.warn(msg, UserWarning, stacklevel=2)
            warn_list.append(msg)
        obs.append(o)
        _say(progress, f"[{time.perf_counter() - t0:6.1f} s] {gpath.name}: "
             f"{len(det.band)} lines, {len(o.view)} observations")
    proj = _concat(obs)
    kp0, rp0, tp0 = init_projector(cam.kc, cam.rvecs, cam.tvecs, proj, dc, dp,
                                   (pattern.width, pattern.height))
    st = BundleState(kc=cam.kc, rvecs=cam.rvecs, tvecs=cam.tvecs, kp=kp0, rp=rp0, tp=tp0)
    cw = corner_weights(cam.per_view_rms)
    surface = None
    if (target.printed if board_surface is None else board_surface) and len(proj.view):
        xy = board_frame_points(cam.kc, cam.rvecs, cam.tvecs, proj, *dc)
        surface = BoardSurface.spanning(xy[np.all(np.isfinite(xy), axis=1)],
                                        surface_spacing or target.square)
    st = run_bundle(st, cam.corners, proj, dc, dp, corner_weight=cw,
                    proj_weight=projector_weight, surface=surface,
                    surface_weight=surface_weight)
    r = projector_residuals(st.kc, st.rvecs, st.tvecs, st.kp, st.rp, st.tp, proj, dc, dp,
                            st.shrink, st.surface)
    sigma = 1.4826 * np.median(np.abs(r))
    good = np.abs(r) < max(5 * sigma, 0.05)
    n_out = int(np.sum(~good))
    if n_out:
        proj = ProjObs(proj.pixels[good], proj.value[good], proj.axis[good], proj.view[good],
                       proj.sign[good])
        st = run_bundle(st, cam.corners, proj, dc, dp, corner_weight=cw,
                        proj_weight=projector_weight, surface=st.surface,
                        surface_weight=surface_weight)
    _say(progress, f"[{time.perf_counter() - t0:6.1f} s] bundle: camera RMS "
         f"{st.cost['camera_rms_px']:.4f} px, projector RMS {st.cost['projector_rms_px']:.4f} "
         f"px ({len(proj.view)} observations, {n_out} outliers left out)")

    # turntable
    tt_idx = [i for i, k in enumerate(kinds) if k == "turntable" and angles[i] is not None]
    turntable = None
    tt_fig: dict[str, Any] = {}
    if len(tt_idx) >= 2:
        th = np.array([float(angles[i]) for i in tt_idx])
        used = []  # corners of each turntable view, those left out of the camera fit NaN
        for i in tt_idx:
            c = np.full_like(corners[i], np.nan)
            m = cam.corners.view == i
            c[_corner_index(cam.corners.board[m], target)] = cam.corners.pixels[m]
            used.append(c)
        tt = fit_turntable(st.rvecs[tt_idx], st.tvecs[tt_idx], th, board, used, st.kc, *dc)
        # table top: the board's lower edge rests on the table
        # a printed target's white border is not known: the field's own lower edge
        margin = target.margin or 0.0
        x0, x1 = -target.square - margin, target.cols * target.square + margin
        y1 = target.rows * target.square + margin
        bottom = rotmats(tt.rvec0) @ np.array([(x0 + x1) / 2, y1, 0.0]) + tt.tvec0
        point = tt.point + tt.direction * float(tt.direction @ (bottom - tt.point))
        turntable = Turntable(point=point, direction=tt.direction)
        tt_fig = {"calibrated": True, "views": len(tt_idx), "rms_px": tt.rms_px,
                  "table_angle_rms_deg": tt.angle_rms_deg}
    else:
        msg = TURNTABLE_NOT_CALIBRATED
        warnings.warn(msg, UserWarning, stacklevel=2)
        warn_list.append(msg)
        # a placeholder (a Rig holds a turntable), marked uncalibrated in the rig file
        turntable = Turntable(point=np.array([0.0, 0.0, 600.0]), direction=np.array([0, -1.0, 0]))
        tt_fig = {"calibrated": False, "note": msg}

    camera = Camera(width=size[0], height=size[1], f=float(st.kc[0]), cx=float(st.kc[1]),
                    cy=float(st.kc[2]), dx=dc[0], dy=dc[1], sx=float(st.kc[3]),
                    k1=float(st.kc[4]), R=np.eye(3), T=np.zeros(3), name="camera")
    projector = Projector(width=pattern.width, height=pattern.height, f=float(st.kp[0]),
                          cx=float(st.kp[1]), cy=float(st.kp[2]), dx=dp[0], dy=dp[1],
                          sx=float(st.kp[3]), k1=float(st.kp[4]), R=rotmats(st.rp),
                          T=np.asarray(st.tp, float), name="projector")
    rig = Rig(camera=camera, projector=projector, turntable=turntable)
    turntable_ok = bool(tt_fig.get("calibrated", False))

    rc = camera_residuals(st.kc, st.rvecs, st.tvecs, cam.corners, *dc)
    rpj = projector_residuals(st.kc, st.rvecs, st.tvecs, st.kp, st.rp, st.tp, proj, dc, dp,
                              st.shrink, st.surface)
    P = len(names)
    cres = [rc[cam.corners.view == i] for i in range(P)]
    pres = [rpj[proj.view == i] for i in range(P)]
    per_view = []
    for i in range(P):
        per_view.append({
            "image": names[i], "kind": kinds[i], "table_angle": angles[i],
            "camera_rms_px": float(np.sqrt(np.mean(np.sum(cres[i]**2, axis=1)))),
            "projector_rms_px": float(np.sqrt(np.mean(pres[i]**2))) if len(pres[i]) else None,
            "projector_observations": int(len(pres[i])),
        })
    figures = {
        "camera_rms_px": float(np.sqrt(np.mean(np.sum(rc**2, axis=1)))),
        "camera_max_px": float(np.max(np.linalg.norm(rc, axis=1))),
        "projector_rms_px": float(np.sqrt(np.mean(rpj**2))),
        "projector_max_px": float(np.max(np.abs(rpj))),
        "projector_observations": int(len(rpj)),
        "projector_outliers": n_out,
        "projector_label_rejects": n_label,
        # centre-lines of thin lines (sign 0) have no band-edge bias
        "edge_bias_projector_px": {"x": float(st.shrink[0]), "y": float(st.shrink[1]),
                                   "note": "falling band edges read +bias, rising -bias"}
        if np.any(proj.sign != 0) else None,
        "camera_init_rms_px": float(cam.rms),
        "board_surface": None if st.surface is None else _surface_figures(
            st, proj, dc, surface_spacing or target.square, surface_weight),
        "views_used": P, "views_given": len(poses),
        "pixel_pitch_mm": {"camera": list(dc), "projector": list(dp)},
        "turntable": tt_fig,
        "per_view": per_view,
        "time_s": time.perf_counter() - t0,
    }
    return CalibrationResult(
        rig=rig, views=names, kinds=kinds, table_angles=angles, kc=st.kc, kp=st.kp, rp=st.rp,
        tp=st.tp, rvecs=st.rvecs, tvecs=st.tvecs, figures=figures, corner_residuals=cres,
        corner_pixels=[cam.corners.pixels[cam.corners.view == i] for i in range(P)],
        proj_residuals=pres,
        proj_pixels=[proj.pixels[proj.view == i] for i in range(P)], warnings=warn_list,
        turntable_calibrated=turntable_ok, board_surface=st.surface)


def _surface_figures(st: BundleState, proj: ProjObs, dc, spacing: float, weight: float) -> dict:
    """The fitted white-part shape at the projector observations: height RMS and extremes
    (mm), knot spacing, coefficient count, roughness weight."""
    from .surface import surface_points

    xy = surface_points(st.kc, st.rvecs, st.tvecs, proj.pixels, proj.view, *dc, st.surface)[1]
    h = st.surface.height(np.nan_to_num(xy))
    return {"height_rms_mm": float(np.sqrt(np.mean(h**2))), "height_min_mm": float(h.min()),
            "height_max_mm": float(h.max()), "knot_spacing_mm": float(spacing),
            "coefficients": int(len(st.surface.coef)), "roughness_weight": float(weight),
            "note": "height of the board's white part over the plane of the chessboard "
                    "corners, fitted with the rig (all poses share it)"}


# ---------------------------------------------------------------------------------- figures


def _cam_params(cam) -> tuple[np.ndarray, tuple[float, float]]:
    return (np.array([cam.f, cam.cx, cam.cy, cam.sx, cam.k1], float),
            (float(cam.dx), float(cam.dy)))


def _line_distance(p1, a1, p2) -> float:
    d = np.asarray(p2, float) - np.asarray(p1, float)
    return float(np.linalg.norm(d - (d @ a1) * a1))


def compare_rigs(estimated, true) -> dict:
    """Errors of an estimated rig against the true one (the figures of issue 6).

    Focal lengths are compared in pixels (``f sx / dx`` and ``f / dy``: f and the pitch are not
    separately identifiable) and k1 as ``k1 dy^2`` (px^-2), so that rigs with different pitch
    conventions compare fairly.

    Returns
    -------
    dict
        ``camera`` / ``projector``: ``f_rel_err`` (largest relative error of the two pixel focal
        lengths), ``principal_point_err_px``, ``k1_rel_err``; ``relative_translation_err_mm``
        and ``relative_rotation_err_deg`` (camera -> projector transform; the rig frames are
        the cameras' so the camera's own pose is also compared);
        ``turntable_direction_err_deg``, ``turntable_axis_distance_mm`` (largest distance of
        the estimated axis from the true one over the table-top disc: the true point and the
        points 100 mm along the axis), ``turntable_point_err_mm`` (along the axis).
    """
    out: dict[str, Any] = {}
    for name in ("camera", "projector"):
        e, t = getattr(estimated, name), getattr(true, name)
        fe = np.array([e.f * e.sx / e.dx, e.f / e.dy])
        ft = np.array([t.f * t.sx / t.dx, t.f / t.dy])
        k1e, k1t = e.k1 * e.dy**2, t.k1 * t.dy**2
        out[name] = {
            "f_px": fe.tolist(), "f_px_true": ft.tolist(),
            "f_rel_err": float(np.max(np.abs(fe / ft - 1))),
            "principal_point_err_px": float(np.hypot(e.cx - t.cx, e.cy - t.cy)),
            "sx_err": float(e.sx - t.sx),
            "k1_rel_err": float(abs(k1e / k1t - 1)) if k1t != 0 else float(abs(k1e)),
        }

    def pose(c):
        return np.asarray(c.R, float), np.asarray(c.T, float)

    Rce, Tce = pose(estimated.camera)
    Rct, Tct = pose(true.camera)
    Rpe, Tpe = pose(estimated.projector)
    Rpt, Tpt = pose(true.projector)
    # camera -> projector: x_p = Rp Rc^T (x_c - Tc) + Tp
    Rre, Rrt = Rpe @ Rce.T, Rpt @ Rct.T
    Tre, Trt = Tpe - Rre @ Tce, Tpt - Rrt @ Tct
    dR = Rre @ Rrt.T
    out["relative_rotation_err_deg"] = float(np.degrees(np.arccos(np.clip(
        (np.trace(dR) - 1) / 2, -1, 1))))
    out["relative_translation_err_mm"] = float(np.linalg.norm(Tre - Trt))
    out["baseline_mm"] = float(np.linalg.norm(Rrt.T @ Trt))
    te, tt = estimated.turntable, true.turntable
    ae, at = np.asarray(te.direction, float), np.asarray(tt.direction, float)
    out["turntable_direction_err_deg"] = float(np.degrees(np.arccos(np.clip(ae @ at, -1, 1))))
    pe, pt = np.asarray(te.point, float), np.asarray(tt.point, float)
    out["turntable_axis_distance_mm"] = max(_line_distance(pe, ae, pt + s * at)
                                            for s in (0.0, 100.0))
    out["turntable_point_err_mm"] = float(np.linalg.norm(pe - pt))
    out["turntable_height_err_mm"] = float(at @ (pe - pt))
    return out


def triangulate_edges(rig, pixels: np.ndarray, value: np.ndarray, axis: np.ndarray,
                      iterations: int = 8) -> np.ndarray:
    """Triangulate band-edge points: camera ray meets the projector's light surface.

    A point ``X = s d`` of the camera ray (rig frame = camera frame) lies on the light surface
    of the projector coordinate ``v`` (axis ``a``) where the projector's projection of X has
    ``a``-coordinate ``v`` (method.md section 5, step 2, the exact form): a 1-D root in the
    depth ``s``, solved by the secant method for all points at once.

    Parameters
    ----------
    rig : nurbscan.camera.Rig
    pixels : ndarray (K, 2) camera px; value : ndarray (K,) projector px; axis : ndarray (K,)

    Returns
    -------
    ndarray, shape (K, 3)
        Points in the rig frame, mm (NaN where the iteration fails).
    """
    kc, dc = _cam_params(rig.camera)
    kp, dp = _cam_params(rig.projector)
    d = back_project_local(np.asarray(pixels, float), kc, *dc)
    Rp, Tp = np.asarray(rig.projector.R, float), np.asarray(rig.projector.T, float)
    ax = np.asarray(axis)[:, None]

    def g(s):
        X = d * s[:, None]
        uv = project_local(X @ Rp.T + Tp, kp, *dp)
        return np.take_along_axis(uv, ax, axis=1)[:, 0] - value

    s0 = np.full(len(d), 500.0)
    s1 = np.full(len(d), 700.0)
    g0, g1 = g(s0), g(s1)
    for _ in range(iterations):
        with np.errstate(divide="ignore", invalid="ignore"):
            s2 = s1 - g1 * (s1 - s0) / (g1 - g0)
        s2 = np.where(np.isfinite(s2), s2, s1)
        s0, g0, s1 = s1, g1, s2
        g1 = g(s1)
    return d * s1[:, None]


def held_out_error(rig_est, rig_true, det, board_R, board_T, max_points: int = 20000,
                   edge_bias=None, target: Target | None = None,
                   keep_off_edges_mm: float = 2.0, gross_mm: float = 1.0) -> dict:
    """Triangulation error on a target pose left out of the calibration (issue 6).

    Edge points of the pose's decoded grid are triangulated with the estimated rig
    (:func:`triangulate_edges`: camera ray meets the projector's light surface of the decoded
    coordinate); the truth for a camera pixel is where the TRUE camera ray through it meets
    the TRUE board plane (board -> rig pose ``board_R``, ``board_T``), so the error is the
    depth error along the ray caused by the rig and by the decoded projector coordinate.

    With ``target`` given, only the points the calibration itself uses are measured: on a
    white square or the white margin, at least ``keep_off_edges_mm`` from a printed square
    edge and from the board's outline (classified with the TRUE board pose; the same rule as
    :func:`edge_observations`); black squares reflect too little light to decode, and the
    albedo step at a printed edge moves the band edges. Without it, every decoded point on
    the board plane is measured.

    Parameters
    ----------
    rig_est, rig_true : nurbscan.camera.Rig
        Rig to triangulate with and the simulator's true rig.
    det : nurbscan.detect.DetectionResult
        Detection of the held-out pose's grid image.
    board_R, board_T : ndarray, shapes (3, 3), (3,)
        True board -> rig pose of the held-out view (mm).
    max_points : int
        Points measured at most (evenly at random, fixed seed).
    edge_bias : array_like (2,), optional
        Band-edge bias per axis found by the calibration (``figures["edge_bias_projector_px"]``,
        projector px): rising edges read ``-bias``, falling ``+bias``
        (:func:`nurbscan.calibrate._bundle.projector_residuals`); the decoded coordinates are
        corrected by it before triangulating.
    target : Target, optional
        The chessboard (point selection above).
    gross_mm : float
        Errors above this (decoding errors: wrong band) are counted, not averaged.

    Returns
    -------
    dict
        ``rms_mm`` (3-D distance to the true point), ``plane_rms_mm`` (distance to the true
        plane), ``aligned_rms_mm`` (3-D distance after the best rigid motion of the points
        onto the truth: the shape error), ``median_mm``, ``points``, ``gross_errors``,
        ``board_extent_mm``, and
        ``coord_error_px``: mean and standard deviation of the (corrected) decoded projector
        coordinate minus the TRUE rig's coordinate at the point, per axis (x, y) and edge kind
        (rising, falling), projector px: the detection's own bias and noise.
    """
    px = np.stack([np.asarray(det.x, float), np.asarray(det.y, float)], axis=1)
    line = np.asarray(det.line)
    axis = np.asarray(det.direction)[line].astype(np.int64)
    value = np.asarray(det.coord, float)[line]
    sign = _edge_sign(det)[line]  # rising -1, falling +1, centre-line 0
    if edge_bias is not None:
        value = value + sign * np.asarray(edge_bias, float)[axis]
    kt, dt = _cam_params(rig_true.camera)
    Rc, Tc = np.asarray(rig_true.camera.R, float), np.asarray(rig_true.camera.T, float)
    board_R, board_T = np.asarray(board_R, float), np.asarray(board_T, float)
    n = board_R[:, 2]

    def truth(p):
        # true camera ray in the rig frame (the true camera pose may differ from identity)
        o = -Rc.T @ Tc
        dw = back_project_local(p, kt, *dt) @ Rc
        with np.errstate(divide="ignore", invalid="ignore"):
            s = (n @ (board_T - o)) / (dw @ n)
        return o + dw * s[:, None]

    if target is not None and len(px):
        Xb = (truth(px) - board_T) @ board_R
        keep = _clean_board_points(Xb[:, :2], target, keep_off_edges_mm)
        px, axis, value, sign = px[keep], axis[keep], value[keep], sign[keep]
    if len(px) > max_points:
        idx = np.sort(np.random.default_rng(0).choice(len(px), max_points, replace=False))
        px, axis, value, sign = px[idx], axis[idx], value[idx], sign[idx]
    if len(px) == 0:
        raise NurbscanError("held-out pose: no decoded edge points on the target")
    X = triangulate_edges(rig_est, px, value, axis)
    Xt = truth(px)
    Xb = (Xt - board_T) @ board_R
    # decoded coordinate against the true rig's projector coordinate of the true point
    kp, dp = _cam_params(rig_true.projector)
    uv = project_local(Xt @ np.asarray(rig_true.projector.R, float).T
                       + np.asarray(rig_true.projector.T, float), kp, *dp)
    dv = value - np.take_along_axis(uv, axis[:, None], axis=1)[:, 0]
    ok = np.all(np.isfinite(X), axis=1) & np.all(np.isfinite(Xt), axis=1)
    err = np.linalg.norm(X - Xt, axis=1)
    gross = ok & (err > gross_mm)
    good = ok & ~gross
    e = err[good]
    pl = (X[good] - board_T) @ n
    # shape error: the same distances after the best rigid motion of the triangulated points
    # onto the truth (Kabsch; Arun, Huang and Blostein 1987): what is left when the rig's
    # frame (e.g. its principal point) is slightly off but the geometry is right
    A, B = X[good], Xt[good]
    if len(A) >= 3:
        ca, cb = A.mean(axis=0), B.mean(axis=0)
        U, _, Vt = np.linalg.svd((A - ca).T @ (B - cb))
        Rk = Vt.T @ np.diag([1, 1, np.sign(np.linalg.det(Vt.T @ U.T))]) @ U.T
        aligned = float(np.sqrt(np.mean(np.sum(((A - ca) @ Rk.T - (B - cb))**2, axis=1))))
    else:
        aligned = float("nan")
    coord: dict[str, dict[str, float]] = {}
    for a, an in ((0, "x"), (1, "y")):
        for sg, sn in ((-1.0, "rising"), (1.0, "falling")):
            m = good & (axis == a) & (sign == sg)
            coord[f"{an}_{sn}"] = {"mean": float(np.mean(dv[m])) if m.any() else float("nan"),
                                   "std": float(np.std(dv[m])) if m.any() else float("nan"),
                                   "n": int(np.sum(m))}
    return {"rms_mm": float(np.sqrt(np.mean(e**2))), "plane_rms_mm": float(np.sqrt(np.mean(
        pl**2))), "median_mm": float(np.median(e)), "points": int(len(e)),
            "gross_errors": int(np.sum(gross)), "aligned_rms_mm": aligned,
            "board_extent_mm": float(np.ptp(Xb[good, 0])) if len(e) else 0.0,
            "coord_error_px": coord}


def residual_image(result: CalibrationResult, size: tuple[int, int], tile: int = 384,
                   cols: int = 4) -> np.ndarray:
    """A picture of the residuals, one panel per pose (uint8 RGB).

    Camera: each chessboard corner as a dot with its reprojection error vector scaled so that
    the largest is 10 % of the panel (green). Projector: each observation's residual as a dot
    coloured from blue (0) to red (3 x the projector RMS or more). The scale is written on
    each panel.
    """
    import cv2

    P = len(result.views)
    rows = math.ceil(P / cols)
    w, h = size
    sc = tile / w
    th = int(round(h * sc))
    canvas = np.full((rows * th, cols * tile, 3), 255, np.uint8)
    cmax = max(float(np.max(np.linalg.norm(np.concatenate(result.corner_residuals), axis=1))),
               1e-9)
    arrow = 0.1 * tile / cmax
    prms = max(result.figures["projector_rms_px"], 1e-9)
    for i in range(P):
        r0, c0 = divmod(i, cols)
        panel = np.full((th, tile, 3), 245, np.uint8)
        pp = result.proj_pixels[i] * sc
        pr = np.clip(np.abs(result.proj_residuals[i]) / (3 * prms), 0, 1)
        col = np.stack([255 * pr, np.zeros_like(pr), 255 * (1 - pr)], axis=1).astype(np.uint8)
        ij = np.round(pp).astype(int)
        ok = (ij[:, 0] >= 0) & (ij[:, 0] < tile) & (ij[:, 1] >= 0) & (ij[:, 1] < th)
        panel[ij[ok, 1], ij[ok, 0]] = col[ok]
        for (x, y), (ex, ey) in zip(result.corner_pixels[i] * sc, result.corner_residuals[i],
                                    strict=True):
            p0 = (int(round(x)), int(round(y)))
            p1 = (int(round(x + ex * arrow)), int(round(y + ey * arrow)))
            cv2.arrowedLine(panel, p0, p1, (0, 150, 0), 1, tipLength=0.3)
            cv2.circle(panel, p0, 1, (0, 0, 0), -1)
        rms = result.figures["per_view"][i]["camera_rms_px"]
        label = f"{i}: {Path(result.views[i]).stem} cam {rms:.3f} px"
        cv2.putText(panel, label, (4, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.38, (0, 0, 0), 1)
        cv2.putText(panel, f"arrows x{arrow / sc:.0f}", (4, th - 6), cv2.FONT_HERSHEY_SIMPLEX,
                    0.38, (0, 0, 0), 1)
        cv2.rectangle(panel, (0, 0), (tile - 1, th - 1), (180, 180, 180), 1)
        canvas[r0 * th:(r0 + 1) * th, c0 * tile:(c0 + 1) * tile] = panel
    return canvas
