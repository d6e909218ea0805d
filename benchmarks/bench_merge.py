"""Benchmark of the merge stage (issue 32): registration of perturbed table angles.

A scan's ``scan.json`` is copied with every view's table angle but the first (which fixes the
object frame) perturbed by up to 2 degrees (uniform, seed 0); the images are the same
(symbolic links). Both scans are reconstructed (views in the object frame as their table
angles put them, not merged) and then merged (:func:`nurbscan.merge.merge_views`: table left
out, views registered). Measured: each view's recovered table angle against the true one, the
other rotation and translation of its correction, the registration's time, and the paper's
Table I Gordon figures against the truth for the exact angles (unregistered), the perturbed
angles unregistered and the perturbed angles registered. The rig is the scan's calibrated
``calib.json`` beside the scan folder when present, else the true rig.

Usage: ``python benchmarks/bench_merge.py [SCAN_DIR]``, or ``python benchmarks/bench_merge.py
--model MODEL_DIR SCAN_DIR`` with an unmerged model of the scan (``reconstruct --no-register
--keep-table``, or one written before the merge stage): its views are then turned as the
perturbed angles would have put them (``X_obj' = Rz(-delta) X_obj``, exactly what the angle
does to a view reconstructed in the rig frame) instead of reconstructing twice. Without it a
the demo's teapot scan is rendered: 8 views at the default camera's 3072 x 2304
(``NURBSCAN_BENCH_MERGE_SIZE=WxH`` for another size, e.g. 1024x768, where the views' own
errors allow only about 0.05 degrees; ``NURBSCAN_BENCH_QUICK=1``: 640 x 480 with a coarse
grid, where the surface does not fix the turns and the registration is refused with a
warning). ``NURBSCAN_BENCH_MERGE_SCAN=SCAN_DIR`` measures an existing scan instead (e.g. the
full-resolution demo's, with the ``calib.json`` it calibrated from images beside it).
"""

from __future__ import annotations

import copy
import json
import math
import os
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np


def make_scan(out: Path) -> Path:
    """Render an 8-view teapot scan without calibration images into ``out``."""
    from nurbscan.simulate.render import RenderSettings
    from nurbscan.simulate.rig import default_rig, scale_camera
    from nurbscan.simulate.scan import simulate_scan
    from nurbscan.simulate.scenes import make_scene

    kw = {}
    if os.environ.get("NURBSCAN_BENCH_QUICK"):
        from nurbscan.pattern import Pattern

        rig = scale_camera(default_rig(), 640, 480)
        kw = {"pattern": Pattern.create(1920, 1080, pitch=32, band=12)}
    else:
        size = os.environ.get("NURBSCAN_BENCH_MERGE_SIZE")
        rig = default_rig()
        if size:
            rig = scale_camera(rig, *(int(x) for x in size.lower().split("x")))
    simulate_scan(make_scene("teapot"), out, views=8, rig=rig, calibration=False,
                  settings=RenderSettings(), workers=2, **kw)
    return out


def perturbed_copy(scan: Path, out: Path, max_deg: float = 2.0, seed: int = 0) -> dict:
    """``out``: the scan with perturbed table angles (links to its files); the perturbations
    (degrees) by view index."""
    out.mkdir(parents=True)
    for p in scan.iterdir():
        if p.name not in ("scan.json", "truth"):
            (out / p.name).symlink_to(p.resolve())
    doc = json.loads((scan / "scan.json").read_text())
    rng = np.random.default_rng(seed)
    deg = str(doc.get("angle_unit", "radians")).startswith("deg")
    delta = {}
    for n, v in enumerate(doc["views"]):
        d = 0.0 if n == 0 else float(rng.uniform(-max_deg, max_deg))
        delta[int(v.get("index", n))] = d
        v["table_angle"] = float(v["table_angle"]) + (d if deg else math.radians(d))
    (out / "scan.json").write_text(json.dumps(doc, indent=1))
    return delta


def _gordon(ev: dict) -> dict:
    r = ev["rows"]["gordon"]
    return {"mean_mm": r["mean_mm"], "max_mm": r["max_mm"], "coverage": ev["coverage"]}


def evaluate(scan: Path) -> dict:
    from nurbscan.camera import load_rig
    from nurbscan.evaluate import evaluate_model
    from nurbscan.merge import merge_views
    from nurbscan.reconstruct import reconstruct_scan

    scan = Path(scan)
    calib = scan.parent / "calib.json"
    rig = load_rig(calib if calib.exists() else scan / "truth" / "rig.json")
    truth = scan / "truth"
    out: dict = {"scan": str(scan) if os.environ.get("NURBSCAN_BENCH_MERGE_SCAN") else
                 "rendered (the demo's teapot, 8 views)",
                 "rig": "calibrated (calib.json)" if calib.exists() else "true (truth/rig.json)",
                 "camera size (px)": f"{rig.camera.width} x {rig.camera.height}"}
    exact = reconstruct_scan(scan, rig, merge=None, workers=2)
    out["exact angles, unregistered: Gordon"] = _gordon(evaluate_model(exact, truth))
    with tempfile.TemporaryDirectory(prefix="bench_merge_") as tmp:
        pscan = Path(tmp) / "scan"
        delta = perturbed_copy(scan, pscan)
        # the copy's folders are links to the scan's: paths that resolve outside it
        pert = reconstruct_scan(pscan, rig, merge=None, workers=2, allow_outside=True)
    out["perturbed angles, unregistered: Gordon"] = _gordon(evaluate_model(pert, truth))
    for name, model in (("exact", exact), ("perturbed", pert)):
        m = copy.deepcopy(model)
        t0 = time.perf_counter()
        with warnings.catch_warnings(record=True) as w:
            warnings.simplefilter("always")
            merge_views(m, rig.turntable)
        out[f"{name} angles: merge time (s)"] = time.perf_counter() - t0
        out[f"{name} angles: warnings"] = "; ".join(str(x.message) for x in w) or "none"
        reg = m.meta["merge"].get("registration", {})
        out[f"{name} angles: registration applied"] = bool(reg.get("applied"))
        d = delta if name == "perturbed" else dict.fromkeys(delta, 0.0)
        errs, others, trans = [], [], []
        for v in m.views:
            true = float(v["table_angle"]) - math.radians(d[int(v["index"])])
            errs.append(math.degrees(v["registered_table_angle"] - true))
            others.append(v["registration"]["other_rotation_deg"])
            trans.append(float(np.linalg.norm(v["registration"]["translation_mm"])))
        out[f"{name} angles: registered - true table angle, max |.| (deg)"] = float(
            np.max(np.abs(errs)))
        out[f"{name} angles: registered - true table angle per view (deg)"] = " ".join(
            f"{e:+.4f}" for e in errs)
        out[f"{name} angles: other rotation, max (deg)"] = float(np.max(others))
        out[f"{name} angles: translation, max (mm)"] = float(np.max(trans))
        if name == "perturbed":
            out["perturbations (deg)"] = " ".join(f"{x:+.3f}" for x in delta.values())
            out["perturbed angles, registered: Gordon"] = _gordon(evaluate_model(m, truth))
            out["table left out (patches)"] = m.meta["merge"]["table"]["patches_removed"]
    return out


def perturbed_model(model, delta: dict):
    """A copy of an unmerged model with each view placed at its table angle + ``delta``
    (degrees): its curves, surfaces and points turned by ``-delta`` about the axis."""
    from nurbscan.merge import moved_curve, moved_points, moved_surface

    m = copy.deepcopy(model)
    for entry in m.views:
        v = int(entry["index"])
        a = math.radians(delta[v])
        R = np.array([[math.cos(a), math.sin(a), 0.0], [-math.sin(a), math.cos(a), 0.0],
                      [0.0, 0.0, 1.0]])
        t = np.zeros(3)
        entry["table_angle"] = float(entry["table_angle"]) + a
        for s in m.surfaces:
            if s["view"] == v:
                s["surface"] = moved_surface(s["surface"], R, t)
        for c in m.curves:
            if c["view"] == v:
                c["curve"] = moved_curve(c["curve"], R, t)
        sel = m.point_view == v
        m.points[sel], m.normals[sel] = moved_points(m.points[sel], R, t), m.normals[sel] @ R.T
        sel = m.edge_view == v
        m.edge_points[sel] = moved_points(m.edge_points[sel], R, t)
    return m


def evaluate_model_dir(model_dir: Path, scan: Path) -> dict:
    """The figures of :func:`evaluate` from an unmerged model of ``scan``, perturbed in place
    (:func:`perturbed_model`)."""
    from nurbscan.camera import load_rig
    from nurbscan.evaluate import evaluate_model
    from nurbscan.merge import merge_views
    from nurbscan.reconstruct import load_model

    scan = Path(scan)
    calib = scan.parent / "calib.json"
    rig = load_rig(calib if calib.exists() else scan / "truth" / "rig.json")
    exact = load_model(model_dir)
    rng = np.random.default_rng(0)
    delta = {int(v["index"]): (0.0 if n == 0 else float(rng.uniform(-2, 2)))
             for n, v in enumerate(exact.views)}
    m = perturbed_model(exact, delta)
    t0 = time.perf_counter()
    merge_views(m, rig.turntable)
    out = {"rig": "calibrated (calib.json)" if calib.exists() else "true (truth/rig.json)",
           "camera size (px)": f"{rig.camera.width} x {rig.camera.height}",
           "perturbed angles: merge time (s)": time.perf_counter() - t0,
           "perturbed angles: warnings": "; ".join(m.meta["merge"]["warnings"]) or "none",
           "perturbations (deg)": " ".join(f"{x:+.3f}" for x in delta.values())}
    errs = [math.degrees(v["registered_table_angle"] - float(v["table_angle"]))
            + delta[int(v["index"])] for v in m.views]
    out["perturbed angles: registered - true table angle, max |.| (deg)"] = float(
        np.max(np.abs(errs)))
    out["perturbed angles: registered - true table angle per view (deg)"] = " ".join(
        f"{e:+.4f}" for e in errs)
    out["perturbed angles: other rotation, max (deg)"] = float(np.max(
        [v["registration"]["other_rotation_deg"] for v in m.views]))
    out["perturbed angles: translation, max (mm)"] = float(np.max(
        [np.linalg.norm(v["registration"]["translation_mm"]) for v in m.views]))
    out["perturbed angles, registered: Gordon"] = _gordon(evaluate_model(m, scan / "truth"))
    out["exact angles, unregistered: Gordon"] = _gordon(evaluate_model(exact, scan / "truth"))
    return out


def bench(scan: str | None = None) -> dict:
    """Render (unless ``scan`` is given), reconstruct, perturb, merge and measure."""
    scan = scan or os.environ.get("NURBSCAN_BENCH_MERGE_SCAN")
    if scan is not None:
        return evaluate(Path(scan))
    with tempfile.TemporaryDirectory(prefix="bench_merge_scan_") as tmp:
        t0 = time.perf_counter()
        make_scan(Path(tmp) / "scan")
        t_sim = time.perf_counter() - t0
        out = evaluate(Path(tmp) / "scan")
        out["simulation time (s)"] = t_sim
        return out


if __name__ == "__main__":
    if len(sys.argv) == 4 and sys.argv[1] == "--model":
        res = evaluate_model_dir(Path(sys.argv[2]), Path(sys.argv[3]))
    else:
        res = bench(sys.argv[1] if len(sys.argv) > 1 else None)
    for k, v in res.items():
        print(f"{k}: {v:.6g}" if isinstance(v, float) else f"{k}: {v}")
