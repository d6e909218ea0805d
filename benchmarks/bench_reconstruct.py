"""Benchmark of the reconstruction (issue 7) at full size: image -> Gordon surfaces per view.

Renders one or two views of the teapot with the default rig (camera 3072 x 2304 = 7.1 MP,
projector 1920 x 1080) and the default noise (unless a scan folder is given), then per view
times reading the two images, the grid detection and the reconstruction (2-D curves, exact
light surfaces, 3-D curves, network, skins and Gordon patches), and measures the paper's
Table I figures and the coverage against the truth. The rig is the scan's calibrated
``calib.json`` beside the scan folder when present, else the true rig (``truth/rig.json``).

Usage: ``python benchmarks/bench_reconstruct.py [SCAN_DIR]`` (an existing scan is reused).
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def make_scan(out: Path, views: int = 2) -> Path:
    """Render a full-size teapot scan without calibration images into ``out``."""
    from nurbscan.simulate.scan import simulate_scan
    from nurbscan.simulate.scenes import make_scene

    return simulate_scan(make_scene("teapot"), out, views=views, calibration=False)


def evaluate(scan: Path) -> dict:
    """Reconstruct every view of ``scan`` (timed per view) and evaluate against its truth."""
    from nurbscan.camera import load_rig
    from nurbscan.evaluate import evaluate_model
    from nurbscan.reconstruct import reconstruct_scan

    scan = Path(scan)
    calib = scan.parent / "calib.json"
    rig_path = calib if calib.exists() else scan / "truth" / "rig.json"
    rig = load_rig(rig_path)
    t0 = time.perf_counter()
    model = reconstruct_scan(scan, rig)
    total = time.perf_counter() - t0
    ev = evaluate_model(model, scan / "truth")
    v = model.views
    out = {
        "camera size (px)": f"{rig.camera.width} x {rig.camera.height}",
        "rig": "calibrated (calib.json)" if calib.exists() else "true (truth/rig.json)",
        "views": len(v),
        "per view: image -> Gordon (s, mean)": float(np.mean([x["image_to_gordon_s"]
                                                              for x in v])),
        "per view: detection (s, mean)": float(np.mean([x["detect_s"] for x in v])),
        "per view: reconstruction after detection (s, mean)": float(np.mean(
            [x["triangulate_s"] + x["network_s"] for x in v])),
        "per view: reading the images (s, mean)": float(np.mean([x["read_s"] for x in v])),
        "total reconstruct_scan time (s)": total,
        "Gordon patches": len(model.surfaces_of("gordon")),
        "complete cells / cells": f"{sum(x['complete_cells'] for x in v)} / "
                                  f"{sum(x['cells'] for x in v)}",
        "coverage of the visible surface by Gordon patches": ev["coverage"],
    }
    ls = model.meta.get("light_surface", {})
    for d, r in ls.items():
        out[f"paper light surface vs exact, {d} edges: max (mm)"] = r["max_mm"]
        out[f"paper light surface vs exact, {d} edges: max (projector px)"] = r["max_px"]
    for row, r in ev["rows"].items():
        for k in ("mean_mm", "std_mm", "min_mm", "max_mm", "max_sample_mm"):
            out[f"{row} {k}"] = r[k]
        out[f"{row} n"] = r["n"]
    return out


def bench(scan: str | None = None) -> dict:
    """Render (unless ``scan`` is given), reconstruct and measure; a dict of figures."""
    if scan is not None:
        return evaluate(Path(scan))
    with tempfile.TemporaryDirectory(prefix="bench_reconstruct_") as tmp:
        t0 = time.perf_counter()
        make_scan(Path(tmp) / "scan")
        t_sim = time.perf_counter() - t0
        out = evaluate(Path(tmp) / "scan")
        out["simulation time (s)"] = t_sim
        return out


if __name__ == "__main__":
    res = bench(sys.argv[1] if len(sys.argv) > 1 else None)
    for k, v in res.items():
        print(f"{k}: {v:.6g}" if isinstance(v, float) else f"{k}: {v}")
