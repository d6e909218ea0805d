"""A rig calibrated by OpenCV alone, imported into nurbscan and used to reconstruct (issue #35).

What a user who calibrated the projector-camera pair elsewhere does, done with OpenCV's own
functions on a nurbscan scan's calibration images, then handed to nurbscan as OpenCV's
``FileStorage`` YAML:

1. Per pose, the chessboard corners and the decoded projected grid, as nurbscan reads them
   (:func:`nurbscan.calibrate.calibrate_scan`'s pose reading; nurbscan's own rig is the
   reference it is compared with).
2. Camera: :func:`cv2.calibrateCamera` on the corners with OpenCV's default model (``k1, k2,
   p1, p2, k3``; Zhang 2000).
3. Projector as an inverse camera (Zhang 2000; Moreno and Taubin 2012 with the board pose
   known): the grid intersections' camera pixels undistorted by OpenCV's camera model
   (:func:`cv2.undistortPoints`) and intersected with the board plane of OpenCV's pose, kept on
   the white squares away from printed edges; their projector pixels known from the code.
   :func:`cv2.calibrateCamera` for the projector, then :func:`cv2.stereoCalibrate` with both
   intrinsics fixed (``CALIB_FIX_INTRINSIC``) for ``R, T`` (``x_prj = R x_cam + T``).
4. Turntable (OpenCV has none): the closed-form axis of
   :func:`nurbscan.calibrate.turntable.initial_axis` from OpenCV's board poses of the turntable
   poses (relative rotations and a linear least-squares point; no nurbscan camera model), the
   axis point moved to the table top (the board's lower edge) as nurbscan's calibration does.
5. Written with :class:`cv2.FileStorage` (keys ``K1 D1 K2 D2 R T`` as ``stereoCalibrate``
   names them, plus ``camSize prjSize turntablePoint turntableDirection``), read back by
   :func:`nurbscan.calibrate.opencv.read_opencv` (``nurbscan rig convert``).

Usage::

    python benchmarks/opencv_calibrate.py SCAN_DIR -o OUT_DIR [--workers 2]

writes ``OUT_DIR/{own_calib.json, opencv.yml, opencv_calib.json, model_own/, model_opencv/}``
(``--model``: OpenCV's distortion model, default ``fix-k3``; the two reconstructions
through the ``nurbscan`` command line, each evaluated against ``SCAN_DIR/truth``) and prints
the two Table I rows side by side.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import warnings
from pathlib import Path

import cv2
import numpy as np


def _poses(calib_dir: Path, exclude=()):
    from nurbscan.calibrate.pipeline import Target, read_scan_json

    doc = read_scan_json(calib_dir)
    root = Path(doc["_root"])
    cal = doc["calibration"]
    target = Target.from_dict(cal["target"], "calibration.target")
    unit = str(doc.get("angle_unit", "radians")).lower()
    poses = []
    for p in cal["poses"]:
        if int(p.get("index", -1)) in set(exclude):
            continue
        ang = p.get("table_angle")
        if ang is not None and unit.startswith("deg"):
            ang = np.radians(float(ang))
        poses.append((root / p["white"], root / p["grid"], str(p.get("kind", "free")), ang))
    return doc, target, poses


def _board_xy(px: np.ndarray, K, D, rvec, tvec) -> np.ndarray:
    """Board-frame (X, Y) (K, 2), mm, of camera pixels (K, 2): OpenCV's camera ray of each
    pixel meets the board plane of the pose ``rvec, tvec`` (board -> camera)."""
    n = cv2.undistortPoints(px.reshape(-1, 1, 2).astype(np.float64), K, D).reshape(-1, 2)
    d = np.column_stack([n, np.ones(len(n))])
    R = cv2.Rodrigues(np.asarray(rvec, float))[0]
    t = np.asarray(tvec, float).ravel()
    s = (R[:, 2] @ t) / (d @ R[:, 2])
    X = d * s[:, None]
    return ((X - t) @ R)[:, :2]


def opencv_calibration(calib_dir, out_yml, workers: int = 2, progress=print,
                       camera_flags: int = 0, projector_flags: int = 0,
                       pose_cache: dict | None = None, exclude=()) -> dict:
    """Calibrate camera, projector and turntable with OpenCV (steps 1-5 of the module notes)
    and write ``out_yml``; returns the figures (RMS of each OpenCV fit, point counts) and
    nurbscan's own calibration result (``"own"``) for comparison. ``camera_flags`` and
    ``projector_flags`` are :func:`cv2.calibrateCamera` flags (default 0: OpenCV's default
    model, ``k1, k2, p1, p2, k3``); ``pose_cache`` and ``exclude`` (pose indices left out)
    as :func:`calibrate_scan`'s."""
    from nurbscan.calibrate import calibrate_scan
    from nurbscan.calibrate.board import outside_field
    from nurbscan.calibrate.pipeline import _clean_board_points, oriented_corners
    from nurbscan.calibrate.turntable import initial_axis
    from nurbscan.pattern import load_pattern

    calib_dir = Path(calib_dir)
    doc, target, poses = _poses(calib_dir, exclude)
    pattern = load_pattern(Path(doc["_root"]) / "pattern.json")
    cache: dict = {} if pose_cache is None else pose_cache
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        own = calibrate_scan(calib_dir, pattern, pose_cache=cache, workers=workers,
                             exclude=tuple(exclude))
    progress(f"nurbscan: camera {own.figures['camera_rms_px']:.4f} px, projector "
             f"{own.figures['projector_rms_px']:.4f} px")
    board = target.corners().astype(np.float32)
    read = []
    for white, grid, kind, ang in poses:
        size, c, det, area = cache[(str(white), str(grid))]
        if c is not None:
            read.append((oriented_corners(c, target), det, area, kind, ang))
    size = tuple(int(s) for s in size)

    # 2. camera
    rms_c, K1, D1, rv, tv = cv2.calibrateCamera(
        [board] * len(read), [r[0].astype(np.float32).reshape(-1, 1, 2) for r in read],
        size, None, None, flags=camera_flags)
    progress(f"OpenCV camera: RMS {rms_c:.4f} px ({len(read)} poses, D = "
             f"{np.round(D1.ravel(), 5).tolist()})")

    # 3. projector as an inverse camera, from the grid intersections on the board
    objs, cam_pts, prj_pts = [], [], []
    for (_, det, area, _, _), r, t in zip(read, rv, tv, strict=True):
        cam, prj = np.asarray(det.cam, float), np.asarray(det.proj, float)
        if len(cam) == 0:
            continue
        xy = _board_xy(cam, K1, D1, r, t)
        if area is None:
            keep = _clean_board_points(xy, target, 2.0)
        else:
            h, w = area.shape
            ij = np.clip(np.round(cam).astype(np.int64), 0, [w - 1, h - 1])
            keep = area[ij[:, 1], ij[:, 0]] & outside_field(
                xy, (target.cols, target.rows), target.square, 0.25)
        if np.sum(keep) < 20:
            continue
        objs.append(np.column_stack([xy[keep], np.zeros(np.sum(keep))]).astype(np.float32))
        cam_pts.append(cam[keep].astype(np.float32).reshape(-1, 1, 2))
        prj_pts.append(prj[keep].astype(np.float32).reshape(-1, 1, 2))
    psize = (int(pattern.width), int(pattern.height))
    rms_p, K2, D2, _, _ = cv2.calibrateCamera(objs, prj_pts, psize, None, None,
                                              flags=projector_flags)
    crit = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 200, 1e-12)
    rms_s, *_, R, T, _, _ = cv2.stereoCalibrate(
        objs, cam_pts, prj_pts, K1, D1, K2, D2, size, flags=cv2.CALIB_FIX_INTRINSIC,
        criteria=crit)
    n_pts = int(sum(len(o) for o in objs))
    progress(f"OpenCV projector: RMS {rms_p:.4f} px; stereo RMS {rms_s:.4f} px "
             f"({len(objs)} poses, {n_pts} grid intersections)")

    # 4. turntable from OpenCV's board poses
    tt = [i for i, r in enumerate(read) if r[3] == "turntable" and r[4] is not None]
    rvt = np.array([np.ravel(rv[i]) for i in tt])
    tvt = np.array([np.ravel(tv[i]) for i in tt])
    a, p, r0, t0 = initial_axis(rvt, tvt, np.array([float(read[i][4]) for i in tt]))
    margin = target.margin or 0.0
    x0, x1 = -target.square - margin, target.cols * target.square + margin
    y1 = target.rows * target.square + margin
    bottom = cv2.Rodrigues(r0)[0] @ np.array([(x0 + x1) / 2, y1, 0.0]) + t0
    point = p + a * float(a @ (bottom - p))

    # 5. OpenCV's own writer
    pitch = own.figures["pixel_pitch_mm"]
    fs = cv2.FileStorage(str(out_yml), cv2.FILE_STORAGE_WRITE)
    for key, m in (("K1", K1), ("D1", D1), ("K2", K2), ("D2", D2), ("R", R), ("T", T),
                   ("camSize", np.array([size], float)), ("prjSize", np.array([psize], float)),
                   ("camPixelPitch", np.array([pitch["camera"]], float)),
                   ("prjPixelPitch", np.array([pitch["projector"]], float)),
                   ("turntablePoint", point.reshape(3, 1)),
                   ("turntableDirection", a.reshape(3, 1))):
        fs.write(key, np.asarray(m, np.float64))
    fs.release()
    return {"own": own, "camera_rms_px": float(rms_c), "projector_rms_px": float(rms_p),
            "stereo_rms_px": float(rms_s), "poses": len(read), "projector_points": n_pts,
            "turntable_poses": len(tt)}


def _nurbscan(*args) -> None:
    subprocess.run([sys.executable, "-m", "nurbscan", *map(str, args)], check=True)


#: OpenCV distortion models (:func:`cv2.calibrateCamera` flags) the comparison can use
MODELS = {
    "default": 0,  # k1, k2, p1, p2, k3
    "fix-k3": cv2.CALIB_FIX_K3,  # k1, k2, p1, p2: OpenCV's advice for lenses that are not wide
    "k1": cv2.CALIB_FIX_K2 | cv2.CALIB_FIX_K3 | cv2.CALIB_ZERO_TANGENT_DIST,
}


def compare(scan: Path, out: Path, workers: int = 2, model: str = "fix-k3") -> dict:
    """Both rigs, both reconstructions, both evaluations; the Gordon rows side by side."""
    out.mkdir(parents=True, exist_ok=True)
    fig = opencv_calibration(scan / "calibration", out / "opencv.yml", workers,
                             camera_flags=MODELS[model], projector_flags=MODELS[model])
    own = fig.pop("own")
    from nurbscan.io.atomic import write_json

    write_json(out / "own_calib.json", own.rig_dict())
    _nurbscan("rig", "convert", out / "opencv.yml", "-o", out / "opencv_calib.json")
    rows = {}
    for name in ("own", "opencv"):
        model = out / f"model_{name}"
        _nurbscan("reconstruct", scan, "--calib", out / f"{name}_calib.json", "-o", model,
                  "--workers", workers, "--no-fuse", "-q")
        _nurbscan("evaluate", model, "--truth", scan / "truth", "-q")
        ev = json.loads((model / "evaluation.json").read_text())
        rows[name] = ev
    return {"calibration": fig, "evaluations": rows}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scan", type=Path)
    ap.add_argument("-o", "--output", type=Path, required=True)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--model", choices=sorted(MODELS), default="fix-k3",
                    help="OpenCV's distortion model (default fix-k3: k1, k2, p1, p2)")
    a = ap.parse_args(argv)
    res = compare(a.scan, a.output, a.workers, a.model)
    print(json.dumps(res["calibration"], indent=1))
    print("| rig | Gordon n | Gordon mean mm | Gordon max mm | h lines mean | v lines mean "
          "| coverage |")
    print("|---|---|---|---|---|---|---|")
    for name, ev in res["evaluations"].items():
        g, h, v = (ev["rows"][k] for k in ("gordon", "horizontal_lines", "vertical_lines"))
        print(f"| {name} | {g['n']} | {g['mean_mm']:.6f} | {g['max_mm']:.6f} "
              f"| {h['mean_mm']:.6f} | {v['mean_mm']:.6f} | {100 * ev['coverage']:.1f} % |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
