"""Calibration and reconstruction on real photographs: the shared projector-camera set (issue 31).

The first figures nurbscan measures on photographs it did not render itself. The set
(``../shared/real/procam-colour-grid/`` or ``$NURBSCAN_REAL_PROCAM``; read its README, academic
licence) is laid out as scan folders by ``benchmarks/real_procam.py`` in a scratch folder; the
benchmark skips with the reason when the set is absent. Figures:

* board found in the 8 calibration poses (OpenCV's chessboard detector);
* camera reprojection RMS: the camera-only fit of Tsai's model (one radial term) and, beside
  it, OpenCV's ``calibrateCamera`` with its 5 distortion terms on the same corners; and the
  camera RMS left in the joint bundle with the projector;
* projector reprojection RMS (projector px, per decoded coordinate: each centre-line point
  fixes one projector coordinate), per pose; the board's white part fitted as a smooth height
  field shared by the poses (:mod:`nurbscan.calibrate.surface`: the white board is not the
  plane of the printed corners), and beside it the same calibration with the white part
  taken for that plane;
* leave-one-pose-out: for each pose, the rig (and the white part's shape) calibrated from the
  7 others; the held-out pose's projector RMS over all its decoded points on the white part,
  its board pose fitted to its corners and those points with the rig and shape fixed (the
  figure that tells a shape that predicts a new pose from one that only absorbs residuals),
  with and without the shape; the pose's decoded
  centre-line points on the board's white part are triangulated (camera ray meets the light
  plane of the line's projector coordinate, :func:`nurbscan.calibrate.triangulate_edges`);
  reported: the RMS distance of those points to their best plane (mm: the flatness of a real
  plane as the scanner measures it), and the checkerboard's 24 mm squares measured from the
  triangulation: each inner corner's camera ray meets that triangulated plane, and the
  distances between neighbouring corners are compared with 24 mm (mean error and RMS, mm and
  %; the corners themselves are not lit by decoded lines, so the plane carries the
  triangulation's scale to them);
* the two scenes, each from its one photograph with the calibration of poses 1-8: the decoded
  centre-line points inside the source's object mask triangulated in the rig frame; RMS
  distance to their best-fit plane (09) and cylinder (10, with its radius), and pictures in
  ``/work/scratch/real-recon/`` (``$NURBSCAN_REAL_RECON``): the points drawn over the
  photograph coloured by their distance to the fitted surface, and a view from the side.
  Nothing else is known of the scenes' true shape: these are reported, not targets.

Pictures of the calibration residuals per pose go to ``/work/scratch/real-calib/``
(``$NURBSCAN_REAL_CALIB``).

Usage: ``python benchmarks/bench_real_calibrate.py``.
"""

from __future__ import annotations

import importlib.util
import os
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
CALIB_OUT = Path(os.environ.get("NURBSCAN_REAL_CALIB", "/work/scratch/real-calib"))
RECON_OUT = Path(os.environ.get("NURBSCAN_REAL_RECON", "/work/scratch/real-recon"))
#: Projector observations kept per pose (centre-line points on the board's white part, at
#: random). With the default 1500 the 12,000 projector residuals outweigh the 432 corners
#: in the joint bundle: camera RMS 0.461 px (intrinsics pulled: cy 237 -> 161 px), projector
#: 0.691 px, and 5 min a calibration on the shared machine; with 300: 0.243 / 0.691 px, 30 s.
POINTS = 300


def _converter():
    spec = importlib.util.spec_from_file_location("real_procam", HERE / "real_procam.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


# ------------------------------------------------------------------------------ geometry
def fit_plane(X: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Least-squares plane of points (N, 3): centroid, unit normal, signed distances (N,)."""
    c = X.mean(axis=0)
    n = np.linalg.svd(X - c, full_matrices=False)[2][2]
    return c, n, (X - c) @ n


def fit_cylinder(X: np.ndarray) -> tuple[np.ndarray, np.ndarray, float, np.ndarray]:
    """Least-squares cylinder of points (N, 3): a point of the axis, its direction, the radius
    and the signed radial distances (N,).

    Gauss-Newton (Levenberg-Marquardt) on the radial distances over the axis direction (two
    angles about a start direction), the axis point (two offsets across it) and the radius
    (Eberly, Least squares fitting of data by cylinders, 2003), started from each principal
    direction of the points as the axis, with the axis at several distances behind and in
    front of them along their least principal direction; the best fit is kept.
    """
    from scipy.optimize import least_squares

    c = X.mean(axis=0)
    _, _, Vt = np.linalg.svd(X - c, full_matrices=False)
    best = None
    for ia in range(3):
        a0 = Vt[ia]
        e1 = np.cross(a0, [1.0, 0, 0] if abs(a0[0]) < 0.9 else [0, 1.0, 0])
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(a0, e1)
        nrm = Vt[2] if ia != 2 else Vt[1]

        def model(p, a0=a0, e1=e1, e2=e2):
            a = a0 + p[0] * e1 + p[1] * e2
            a = a / np.linalg.norm(a)
            d = X - (c + p[2] * e1 + p[3] * e2)
            return a, np.linalg.norm(d - np.outer(d @ a, a), axis=1)

        for r0 in (30.0, 100.0, 300.0, 1000.0):
            for s in (-1.0, 1.0):
                off = s * r0 * nrm
                p0 = np.array([0.0, 0.0, off @ e1, off @ e2, r0])
                res = least_squares(lambda p, m=model: m(p)[1] - p[4], p0, method="lm")
                a, r = model(res.x)
                rms = float(np.sqrt(np.mean((r - res.x[4])**2)))
                if best is None or rms < best[0]:
                    q = c + res.x[2] * e1 + res.x[3] * e2
                    best = (rms, q, a, abs(float(res.x[4])), r - abs(res.x[4]))
    return best[1], best[2], best[3], best[4]


def family_offset(X: np.ndarray, axis: np.ndarray) -> float:
    """Mean distance (mm) of the horizontal lines' points (axis 1) from the best plane of the
    vertical lines' points (axis 0), along its normal oriented away from the camera: how far
    the two families' light surfaces disagree on a plane."""
    c, n, _ = fit_plane(X[axis == 0])
    n = n if n @ c > 0 else -n
    return float(np.mean((X[axis == 1] - c) @ n))


def _white_points(det, mask):
    """Centre-line points of a detection inside a mask (H, W): pixels (K, 2), value, axis,
    line id."""
    px = np.stack([det.x, det.y], axis=1)
    line = np.asarray(det.line)
    axis = np.asarray(det.direction)[line].astype(np.int64)
    value = np.asarray(det.coord, float)[line]
    ij = np.clip(np.round(px).astype(int), 0, [mask.shape[1] - 1, mask.shape[0] - 1])
    keep = mask[ij[:, 1], ij[:, 0]]
    return px[keep], value[keep], axis[keep], line[keep]


def _ray_plane(rig, px, c, n):
    from nurbscan.calibrate._tsai import back_project_local
    from nurbscan.calibrate.pipeline import _cam_params

    kc, dc = _cam_params(rig.camera)
    d = back_project_local(np.asarray(px, float), kc, *dc)
    return d * ((c @ n) / (d @ n))[:, None]


def square_sizes(corners_3d: np.ndarray, inner: tuple[int, int]) -> np.ndarray:
    """Distances (mm) between neighbouring inner corners (row and column neighbours)."""
    nx, ny = inner
    g = corners_3d.reshape(ny, nx, 3)
    return np.concatenate([np.linalg.norm(np.diff(g, axis=1), axis=2).ravel(),
                           np.linalg.norm(np.diff(g, axis=0), axis=2).ravel()])


# ------------------------------------------------------------------------------ pictures
def _colour(v: np.ndarray, vmax: float) -> np.ndarray:
    """Blue (-vmax) - white (0) - red (+vmax), uint8 (N, 3) RGB."""
    t = np.clip(v / max(vmax, 1e-9), -1, 1)
    r = np.where(t > 0, 255, 255 * (1 + t))
    b = np.where(t < 0, 255, 255 * (1 - t))
    g = 255 * (1 - np.abs(t))
    return np.stack([r, g, b], axis=1).astype(np.uint8)


def scene_picture(photo: np.ndarray, px: np.ndarray, X: np.ndarray, dist: np.ndarray,
                  title: str) -> np.ndarray:
    """The points over the (darkened) photograph coloured by distance to the fitted surface,
    beside a side view (rig x-z, depth to the right), uint8 RGB."""
    import cv2

    h, w = photo.shape[:2]
    vmax = 3 * float(np.sqrt(np.mean(dist**2)))
    col = _colour(dist, vmax)
    left = (photo.astype(np.float32) * 0.45).astype(np.uint8).copy()
    for (x, y), c in zip(np.round(px).astype(int), col, strict=True):
        cv2.circle(left, (int(x), int(y)), 1, tuple(int(v) for v in c), -1)
    right = np.full((h, w, 3), 20, np.uint8)
    # side view: z (depth) horizontally, -y (up) vertically, equal scales
    z, y = X[:, 2], X[:, 1]
    span = max(np.ptp(z), np.ptp(y), 1e-6) * 1.15
    s = 0.9 * min(w, h) / span
    u = (z - z.mean()) * s + w / 2
    v = (y - y.mean()) * s + h / 2
    for a, b, c in zip(np.round(u).astype(int), np.round(v).astype(int), col, strict=True):
        if 0 <= a < w and 0 <= b < h:
            right[b, a] = c
    out = np.hstack([left, right])
    cv2.putText(out, title, (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1)
    cv2.putText(out, f"colour: distance to the fit, +-{vmax:.2f} mm", (6, h - 8),
                cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 255), 1)
    cv2.putText(out, f"side view (depth ->, {span:.0f} mm across)", (w + 6, 18),
                cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1)
    return out


def residual_pictures(res, cache: dict, out: Path) -> list[Path]:
    """One picture per pose at the camera's resolution, over the darkened white-light image:
    each chessboard corner's reprojection error as an arrow (x 40, green), each projector
    observation as a dot coloured by its residual (blue 0 -> red 2 projector px or more)."""
    import cv2

    from nurbscan.io import read_image, write_image

    whites = {Path(k[0]).name: k[0] for k in cache}
    paths = []
    for i, name in enumerate(res.views):
        img = read_image(whites[Path(name).name], as_float=False)
        pic = (img.astype(np.float32) * 0.4).astype(np.uint8).copy()
        r = np.clip(np.abs(res.proj_residuals[i]) / 2.0, 0, 1)
        for (x, y), t in zip(np.round(res.proj_pixels[i]).astype(int), r, strict=True):
            cv2.circle(pic, (int(x), int(y)), 2, (int(255 * t), 40, int(255 * (1 - t))), -1)
        for (x, y), (ex, ey) in zip(res.corner_pixels[i], res.corner_residuals[i],
                                    strict=True):
            p0 = (int(round(x)), int(round(y)))
            p1 = (int(round(x + 40 * ex)), int(round(y + 40 * ey)))
            cv2.arrowedLine(pic, p0, p1, (0, 255, 0), 1, tipLength=0.3)
        pv = res.figures["per_view"][i]
        cv2.putText(pic, f"{Path(name).stem}: camera {pv['camera_rms_px']:.3f} px (arrows x40), "
                    f"projector {pv['projector_rms_px']:.3f} px", (6, 16),
                    cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 255), 1)
        cv2.putText(pic, "dots: projector residual, blue 0 -> red >= 2 projector px", (6, 470),
                    cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 255), 1)
        path = out / f"{Path(name).stem.replace('_white', '')}_residuals.png"
        write_image(path, pic)
        paths.append(path)
    return paths


# ------------------------------------------------------------------------------ the figures
def held_out_projector(res, corners: np.ndarray, det, area: np.ndarray) -> tuple[float, int]:
    """Projector RMS (projector px) of a pose left out of the calibration ``res``, and the
    number of its observations: all its decoded centre-line points on the board's white part
    (labels checked against its board homography); its board pose (6 unknowns) fitted, with
    the rig and the white part's shape fixed, first to its corners alone, then to its corners
    and those points (soft-L1 loss, scale 2 projector px)."""
    from scipy.optimize import least_squares

    from nurbscan.calibrate import Target
    from nurbscan.calibrate._bundle import CornerObs, ProjObs, camera_residuals, projector_residuals
    from nurbscan.calibrate.camera import board_points
    from nurbscan.calibrate.pipeline import consistent_labels, edge_observations, oriented_corners

    target = Target(6, 9, 24.0, margin=None)
    dc = tuple(res.figures["pixel_pitch_mm"]["camera"])
    dp = tuple(res.figures["pixel_pitch_mm"]["projector"])
    c = oriented_corners(corners, target)
    cobs = CornerObs(board_points((6, 9), 24.0), c, np.zeros(len(c), np.int64))

    def cam(p):
        return camera_residuals(res.kc, p[None, :3], p[None, 3:], cobs, *dc).ravel()

    starts = [least_squares(cam, np.r_[r, t], method="lm") for r, t in
              zip(res.rvecs, res.tvecs, strict=True)]
    p0 = min(starts, key=lambda s: s.cost).x
    o = edge_observations(det, res.kc, p0[:3], p0[3:], target, 0, dc, 10**9, white_area=area)
    good = consistent_labels(o, det, res.kc, p0[None, :3], p0[None, 3:], dc)
    o = ProjObs(o.pixels[good], o.value[good], o.axis[good], o.view[good], o.sign[good])

    def prj(p):
        return projector_residuals(res.kc, p[None, :3], p[None, 3:], res.kp, res.rp, res.tp, o,
                                   dc, dp, None, res.board_surface)

    fit = least_squares(lambda p: np.nan_to_num(np.r_[cam(p), prj(p)], nan=10.0), p0,
                        loss="soft_l1", f_scale=2.0)
    r = prj(fit.x)
    r = r[np.isfinite(r)]
    return float(np.sqrt(np.mean(r**2))), int(len(r))


def calibration_figures(scans: dict, cache: dict) -> tuple[dict, object]:
    import cv2

    from nurbscan.calibrate import board_points, calibrate_scan, write_outputs

    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = calibrate_scan(scans["calib"] / "calibration", pose_cache=cache,
                             max_points_per_view=POINTS)
    t_cal = time.perf_counter() - t0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        flat = calibrate_scan(scans["calib"] / "calibration", pose_cache=cache,
                              max_points_per_view=POINTS, board_surface=False)
    CALIB_OUT.mkdir(parents=True, exist_ok=True)
    write_outputs(res, CALIB_OUT / "calib.json")
    residual_pictures(res, cache, CALIB_OUT)
    f = res.figures
    # OpenCV on the same corners (the corners the camera fit used)
    corners = [v[1] for v in cache.values() if v[1] is not None]
    board = board_points((6, 9), 24.0).astype(np.float32)
    rms5, K, dist, _, _ = cv2.calibrateCamera([board] * len(corners),
                                              [c.astype(np.float32) for c in corners],
                                              (640, 480), None, None)
    per = {Path(v["image"]).stem.replace("_white", ""): {
        "camera RMS (px)": v["camera_rms_px"], "projector RMS (px)": v["projector_rms_px"],
        "projector observations": v["projector_observations"]} for v in f["per_view"]}
    cam, prj = res.rig.camera, res.rig.projector
    out = {
        "board found (poses)": f"{f['views_used']} / {f['views_given']}",
        "camera RMS, camera-only Tsai fit (px)": f["camera_init_rms_px"],
        "camera RMS, OpenCV calibrateCamera 5 terms, same corners (px)": float(rms5),
        "camera RMS in the joint bundle (px)": f["camera_rms_px"],
        "projector RMS per decoded coordinate (projector px)": f["projector_rms_px"],
        "projector RMS, white part taken for the corners' plane (projector px)":
            flat.figures["projector_rms_px"],
        "camera RMS in the joint bundle, white part taken for the corners' plane (px)":
            flat.figures["camera_rms_px"],
        "white part's height over the corners' plane, RMS (mm)":
            f["board_surface"]["height_rms_mm"],
        "white part's height, range (mm)":
            f"{f['board_surface']['height_min_mm']:.2f} .. "
            f"{f['board_surface']['height_max_mm']:.2f}",
        "white part's shape: knot spacing (mm) / coefficients":
            f"{f['board_surface']['knot_spacing_mm']:g} / "
            f"{f['board_surface']['coefficients']}",
        "projector max residual (projector px)": f["projector_max_px"],
        "projector observations": f["projector_observations"],
        "projector outliers left out": f["projector_outliers"],
        "projector observations with labels off the board homography": f[
            "projector_label_rejects"],
        "projector observations kept per pose": POINTS,
        "turntable": "calibrated" if res.turntable_calibrated else "not calibrated",
        "camera f (px) fx / fy": f"{cam.f * cam.sx / cam.dx:.1f} / {cam.f / cam.dy:.1f}",
        "camera principal point (px)": f"{cam.cx:.1f}, {cam.cy:.1f}",
        "projector f (px) fx / fy": f"{prj.f * prj.sx / prj.dx:.1f} / {prj.f / prj.dy:.1f}",
        "projector principal point (px)": f"{prj.cx:.1f}, {prj.cy:.1f}",
        "baseline (mm)": float(np.linalg.norm(-np.asarray(res.rig.projector.R).T
                                              @ np.asarray(res.rig.projector.T))),
        "per pose": per,
        "calibration time (s)": t_cal,
    }
    return out, res


def leave_one_out(scans: dict, cache: dict, poses=tuple(range(1, 9))) -> dict:
    from nurbscan.calibrate import calibrate_scan, triangulate_edges

    rows = {}
    keys = {int(Path(k[0]).stem.split("_")[1]): k for k in cache}
    all_sq, all_plane, held = [], [], {"shape": [], "flat": []}
    for k in poses:
        shape, corners, det, area = cache[keys[k]]
        if corners is None:
            rows[f"pose {k:02d}"] = "board not found"
            continue
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            res = calibrate_scan(scans["calib"] / "calibration", exclude=(k,), pose_cache=cache,
                                 max_points_per_view=POINTS)
            flat = calibrate_scan(scans["calib"] / "calibration", exclude=(k,),
                                  pose_cache=cache, max_points_per_view=POINTS,
                                  board_surface=False)
        hp = held_out_projector(res, corners, det, area)
        hf = held_out_projector(flat, corners, det, area)
        held["shape"].append(hp)
        held["flat"].append(hf)
        px, value, axis, _ = _white_points(det, area)
        X = triangulate_edges(res.rig, px, value, axis)
        ok = np.all(np.isfinite(X), axis=1)
        X, axis = X[ok], axis[ok]
        c, n, d = fit_plane(X)
        # gross points (wrong labels) are counted, not averaged
        med = 1.4826 * np.median(np.abs(d))
        good = np.abs(d) < max(6 * med, 1.0)
        c, n, d = fit_plane(X[good])
        C = _ray_plane(res.rig, corners, c, n)
        sq = square_sizes(C, (6, 9))
        all_sq.append(sq)
        all_plane.append(d)
        rows[f"pose {k:02d}"] = {
            "held-out projector RMS (projector px), white part's shape / plane":
                f"{hp[0]:.3f} / {hf[0]:.3f} ({hp[1]} points)",
            "points": int(good.sum()), "gross points (> 6 sigma)": int((~good).sum()),
            "plane RMS (mm)": float(np.sqrt(np.mean(d**2))),
            "plane RMS, vertical / horizontal lines alone (mm)": " / ".join(
                f"{np.sqrt(np.mean(fit_plane(X[good & (axis == a)])[2]**2)):.3f}"
                for a in (0, 1)),
            "horizontal lines behind the vertical lines' plane (mm)": family_offset(
                X[good], axis[good]),
            "square mean (mm)": float(sq.mean()),
            "square error mean (mm)": float(sq.mean() - 24.0),
            "square error RMS (mm)": float(np.sqrt(np.mean((sq - 24.0)**2))),
            "square error mean (%)": float(100 * (sq.mean() / 24.0 - 1)),
            "distance (mm)": float(np.linalg.norm(c)),
        }
    sq = np.concatenate(all_sq)
    d = np.concatenate(all_plane)
    def pooled(v):
        return float(np.sqrt(sum(r * r * n for r, n in v) / sum(n for _, n in v)))

    rows["all poses"] = {
        "held-out projector RMS, white part's shape fitted (projector px)": pooled(
            held["shape"]),
        "held-out projector RMS, white part taken for the corners' plane (projector px)":
            pooled(held["flat"]),
        "plane RMS (mm)": float(np.sqrt(np.mean(d**2))),
        "square error mean (mm)": float(sq.mean() - 24.0),
        "square error RMS (mm)": float(np.sqrt(np.mean((sq - 24.0)**2))),
        "square error mean (%)": float(100 * (sq.mean() / 24.0 - 1)),
        "square error RMS (%)": float(100 * np.sqrt(np.mean((sq / 24.0 - 1)**2))),
    }
    return rows


def scene_figures(scans: dict, rig) -> dict:
    from nurbscan.calibrate import triangulate_edges
    from nurbscan.detect import detect_lines
    from nurbscan.io import read_image, write_image
    from nurbscan.pattern import load_pattern

    RECON_OUT.mkdir(parents=True, exist_ok=True)
    out = {}
    for k, kind in ((9, "plane"), (10, "cylinder")):
        scan = scans[f"scene{k:02d}"]
        pattern = load_pattern(scan / "pattern.json")
        grid = read_image(scan / "views/view_00_grid.png", as_float=False)
        white = read_image(scan / "views/view_00_white.png", as_float=False)
        mask = read_image(scan / "views/view_00_mask.png", as_float=False)
        mask = (mask if mask.ndim == 2 else mask[..., 0]) > 127
        t0 = time.perf_counter()
        det = detect_lines(grid, pattern, white=white)
        t_det = time.perf_counter() - t0
        px, value, axis, line = _white_points(det, mask)
        X = triangulate_edges(rig, px, value, axis)
        ok = np.all(np.isfinite(X), axis=1)
        px, X, axis = px[ok], X[ok], axis[ok]
        lines_in = np.unique(line[ok])
        row = {"decoded lines in the image": int(det.nlines), "points in the mask": len(X),
               "lines in the mask": int(len(lines_in)), "detect time (s)": t_det}
        if len(X) < 20:
            out[f"scene {k:02d}"] = row | {"note": "too few decoded points in the mask"}
            continue
        if kind == "plane":
            c, n, d = fit_plane(X)
            row |= {"plane RMS (mm)": float(np.sqrt(np.mean(d**2))),
                    "plane RMS, vertical / horizontal lines alone (mm)": " / ".join(
                        f"{np.sqrt(np.mean(fit_plane(X[axis == a])[2]**2)):.3f}"
                        for a in (0, 1)),
                    "horizontal lines behind the vertical lines' plane (mm)": family_offset(
                        X, axis),
                    "max |distance| (mm)": float(np.max(np.abs(d))),
                    "distance from the camera (mm)": float(np.linalg.norm(c))}
        else:
            q, a, r, d = fit_cylinder(X)
            c0, n0, d0 = fit_plane(X)
            row |= {"cylinder RMS (mm)": float(np.sqrt(np.mean(d**2))),
                    "cylinder radius (mm)": r,
                    "cylinder axis (rig frame)": [round(float(v), 3) for v in a],
                    "max |distance| (mm)": float(np.max(np.abs(d))),
                    "best plane RMS, for comparison (mm)": float(np.sqrt(np.mean(d0**2)))}
        pic = scene_picture(grid, px, X, d, f"shot {k:02d}: {len(X)} points, {kind} RMS "
                            f"{np.sqrt(np.mean(d**2)):.2f} mm")
        write_image(RECON_OUT / f"scene{k:02d}_points.png", pic)
        np.savez_compressed(RECON_OUT / f"scene{k:02d}_points.npz", points_rig=X, pixels=px)
        row["picture"] = str(RECON_OUT / f"scene{k:02d}_points.png")
        out[f"scene {k:02d}"] = row
    return out


def bench() -> dict:
    conv = _converter()
    data = conv.data_dir()
    if data is None:
        return {"skipped": f"real procam set not found ({conv.REL_PATH} beside the repository "
                           f"or ${conv.ENV})"}
    with tempfile.TemporaryDirectory(prefix="real_procam_") as tmp:
        scans = conv.lay_out(Path(tmp), data)
        cache: dict = {}
        cal, res = calibration_figures(scans, cache)
        out = {"calibration (poses 1-8)": cal}
        out["leave one pose out"] = leave_one_out(scans, cache)
        out["scenes (calibration of poses 1-8)"] = scene_figures(scans, res.rig)
    return out


def _print(d: dict, indent: int = 0) -> None:
    for k, v in d.items():
        if isinstance(v, dict):
            print(" " * indent + f"{k}:")
            _print(v, indent + 2)
        else:
            print(" " * indent + (f"{k}: {v:.6g}" if isinstance(v, float) else f"{k}: {v}"))


if __name__ == "__main__":
    _print(bench())
    sys.exit(0)
