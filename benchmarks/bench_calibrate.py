"""Benchmark of the calibration (issue 6) on the full-size default rig.

Renders the calibration images of a synthetic scan with the default rig (camera 3072 x 2304,
projector 1920 x 1080) and the default noise, calibrates from them with one free pose held
out, and measures the figures of issue 6 against the simulator's true rig: reprojection RMS
(camera and projector px), focal lengths, principal points, k1, camera-projector pose,
turntable axis, and the triangulation error on the held-out pose.

Held-out pose: the decoded band-edge points on its white squares, at least 2 mm from a printed
square edge (the points the calibration itself uses), are triangulated with the calibrated rig
(camera ray meets the light surface of the decoded projector coordinate, corrected by the
calibration's band-edge bias) and compared with the true points (true camera ray meets the
true board). Reported: RMS in the camera frame (absolute), distance to the true plane, RMS
after the best rigid motion (the shape error: a principal point off by 0.2 px turns the
whole camera frame by 0.2 px / f, 40 microradians or 0.02 mm at 600 mm at full size, and the
issue allows 1 px), and the same with the TRUE rig (the detection's own floor).

The command itself (issue 30's memory target): ``nurbscan calibrate`` run as a user runs it
(its default 2 worker processes) on the same images, its resident memory sampled every 20 ms
with psutil: the peak of the sum over the command and its workers (resident set, and
proportional set size, which counts the pages the forked workers share once), and of its
largest process.

Usage: ``python benchmarks/bench_calibrate.py [SCAN_DIR]`` (an existing scan folder is reused;
a new one is rendered into SCAN_DIR and kept).
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HELD_OUT = 11  # a free pose (index in scan.json) kept out of the calibration


def make_scan(out: Path, width: int | None = None, height: int | None = None) -> Path:
    """Render a scan with calibration images (one object view of a plane) into ``out``."""
    from nurbscan.simulate import Plane
    from nurbscan.simulate.rig import default_rig, scale_camera
    from nurbscan.simulate.scan import simulate_scan

    rig = default_rig()
    if width:
        rig = scale_camera(rig, width, height)
    return simulate_scan(Plane(), out, views=1, rig=rig)


def evaluate(scan: Path, held_out: int = HELD_OUT, max_points: int = 4000) -> dict:
    """Calibrate ``scan`` (holding out pose ``held_out``) and measure against its truth."""
    from nurbscan.calibrate import Target, calibrate_scan, compare_rigs, held_out_error
    from nurbscan.calibrate.pipeline import DETECT_OPTIONS
    from nurbscan.camera import load_rig
    from nurbscan.detect import detect_grid
    from nurbscan.io import read_image
    from nurbscan.pattern import load_pattern

    scan = Path(scan)
    t0 = time.perf_counter()
    res = calibrate_scan(scan / "calibration", exclude=(held_out,),
                         max_points_per_view=max_points)
    t_cal = time.perf_counter() - t0
    true = load_rig(scan / "truth" / "rig.json")
    cmp = compare_rigs(res.rig, true)
    truth = json.loads((scan / "truth" / "calibration.json").read_text())
    pose = next(p for p in truth["poses"] if p["index"] == held_out)
    doc = json.loads((scan / "scan.json").read_text())
    entry = next(p for p in doc["calibration"]["poses"] if p["index"] == held_out)
    det = detect_grid(read_image(scan / entry["grid"]), load_pattern(scan / "pattern.json"),
                      read_image(scan / entry["white"]), DETECT_OPTIONS)
    f = res.figures
    bias = [f["edge_bias_projector_px"]["x"], f["edge_bias_projector_px"]["y"]]
    R, T = np.array(pose["board_to_rig"]["R"]), np.array(pose["board_to_rig"]["T"])
    target = Target.from_dict(doc["calibration"]["target"], "scan.json calibration.target")
    # the figure: the calibrated rig, the calibration's own edge-bias correction, the
    # points the calibration uses (white squares, away from printed edges)
    ho = held_out_error(res.rig, true, det, R, T, edge_bias=bias, target=target)
    ho_raw = held_out_error(res.rig, true, det, R, T, target=target)
    ho_all = held_out_error(res.rig, true, det, R, T)
    floor = held_out_error(true, true, det, R, T, edge_bias=bias, target=target)
    floor_raw = held_out_error(true, true, det, R, T, target=target)
    ce = floor_raw["coord_error_px"]
    return {
        "camera size (px)": f"{true.camera.width} x {true.camera.height}",
        "calibration time (s)": t_cal,
        "views used": f["views_used"],
        "projector observations": f["projector_observations"],
        "camera reprojection RMS (px)": f["camera_rms_px"],
        "projector reprojection RMS (projector px)": f["projector_rms_px"],
        "camera f rel. error": cmp["camera"]["f_rel_err"],
        "camera principal point error (px)": cmp["camera"]["principal_point_err_px"],
        "camera k1 rel. error": cmp["camera"]["k1_rel_err"],
        "projector f rel. error": cmp["projector"]["f_rel_err"],
        "projector principal point error (px)": cmp["projector"]["principal_point_err_px"],
        "projector k1 rel. error": cmp["projector"]["k1_rel_err"],
        "camera-projector translation error (mm)": cmp["relative_translation_err_mm"],
        "camera-projector rotation error (deg)": cmp["relative_rotation_err_deg"],
        "turntable direction error (deg)": cmp["turntable_direction_err_deg"],
        "turntable axis distance (mm)": cmp["turntable_axis_distance_mm"],
        "turntable table-top height error (mm)": cmp["turntable_height_err_mm"],
        "held-out pose triangulation RMS, camera frame (mm)": ho["rms_mm"],
        "held-out pose distance to plane RMS (mm)": ho["plane_rms_mm"],
        "held-out pose RMS after rigid alignment (shape, mm)": ho["aligned_rms_mm"],
        "held-out pose points (white squares, off printed edges)": ho["points"],
        "held-out pose gross errors (> 1 mm, left out)": ho["gross_errors"],
        "held-out pose triangulation RMS without edge-bias correction (mm)": ho_raw["rms_mm"],
        "held-out pose triangulation RMS, all decoded points, no correction (mm)":
            ho_all["rms_mm"],
        "held-out pose triangulation RMS with the TRUE rig (detection floor, mm)":
            floor["rms_mm"],
        "held-out pose triangulation RMS with the TRUE rig, no correction (mm)":
            floor_raw["rms_mm"],
        "detected - true projector coord, x rising / falling (mean, projector px)":
            f"{ce['x_rising']['mean']:+.3f} / {ce['x_falling']['mean']:+.3f}",
        "detected - true projector coord, y rising / falling (mean, projector px)":
            f"{ce['y_rising']['mean']:+.3f} / {ce['y_falling']['mean']:+.3f}",
        "detected - true projector coord std x / y (projector px)":
            f"{ce['x_rising']['std']:.3f} / {ce['y_rising']['std']:.3f}",
        "detector band-edge bias x / y (projector px)": f"{bias[0]:.3f} / {bias[1]:.3f}",
        "poses left out (target not found)": "; ".join(res.warnings) or "none",
    }


def command_memory(scan: Path, interval: float = 0.02) -> dict:
    """Run ``nurbscan calibrate SCAN/calibration`` (its defaults) in a child process and sample
    the resident memory of its process tree every ``interval`` s (psutil): the peak of the
    tree's sum (RSS, and PSS: shared pages counted once) and of its largest process (MB), the
    wall time (s) and the exit status."""
    import psutil

    with tempfile.TemporaryDirectory(prefix="bench_calibrate_cli_") as tmp:
        t0 = time.perf_counter()
        proc = subprocess.Popen([sys.executable, "-m", "nurbscan", "calibrate",
                                 str(scan / "calibration"), "-o", str(Path(tmp) / "calib.json"),
                                 "-q"], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        root = psutil.Process(proc.pid)
        total = largest = shared = 0.0
        while proc.poll() is None:
            try:
                tree = [root, *root.children(recursive=True)]
                rss, pss = [], []
                for p in tree:
                    try:
                        rss.append(p.memory_info().rss / 2**20)
                        pss.append(p.memory_full_info().pss / 2**20)
                    except psutil.NoSuchProcess:
                        pass
                total, largest = max(total, sum(rss)), max(largest, max(rss, default=0.0))
                shared = max(shared, sum(pss))
            except psutil.NoSuchProcess:
                pass
            time.sleep(interval)
        err = proc.stderr.read().decode(errors="replace").strip()
        return {"peak memory, the command and its workers (MB)": round(total, 1),
                "peak memory, the same, shared pages counted once (PSS, MB)": round(shared, 1),
                "peak memory, its largest process (MB)": round(largest, 1),
                "wall time (s)": round(time.perf_counter() - t0, 2),
                "exit status": proc.returncode,
                **({"error": err.splitlines()[-1][:200]} if proc.returncode else {})}


def bench(scan: str | None = None) -> dict:
    """Render (unless ``scan`` is given), calibrate and measure; a dict of figures."""
    if scan is not None:
        scan = Path(scan)
        if not (scan / "scan.json").is_file():
            t0 = time.perf_counter()
            make_scan(scan)
            t_sim = time.perf_counter() - t0
            out = evaluate(scan)
            out["simulation time (s)"] = t_sim
        else:
            out = evaluate(scan)
        out["nurbscan calibrate"] = command_memory(scan)
        return out
    with tempfile.TemporaryDirectory(prefix="bench_calibrate_") as tmp:
        t0 = time.perf_counter()
        make_scan(Path(tmp) / "scan")
        t_sim = time.perf_counter() - t0
        out = evaluate(Path(tmp) / "scan")
        out["simulation time (s)"] = t_sim
        out["nurbscan calibrate"] = command_memory(Path(tmp) / "scan")
        return out


if __name__ == "__main__":
    res = bench(sys.argv[1] if len(sys.argv) > 1 else None)
    for k, v in res.items():
        print(f"{k}: {v:.6g}" if isinstance(v, float) else f"{k}: {v}")
