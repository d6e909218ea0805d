"""Peers side by side: Gray code, phase shifting and nurbscan's single shot (issue 37).

The same teapot views are scanned through the same simulator (same ray tracing, light model,
sensor and noise streams) by three methods, all triangulated with the same rig:

* **Gray code** (:mod:`nurbscan.peers.graycode`): OpenCV's pattern set, 46 images per view
  (22 bit planes and their inverses, white, black), decoded by OpenCV's rule (the vectorised
  :func:`~nurbscan.peers.graycode.decode_numpy`, identical output to ``getProjPixel``, see
  ``bench_graycode``), points on the light surface of the decoded column.
* **phase shift** (:mod:`nurbscan.peers.phaseshift`): N = 4 steps of period 16 projector px
  per direction with the complementary Gray code (8 planes per direction): 24 images per view,
  decoded per pixel to sub-pixel column and row, points on the light surface of the column.
* **nurbscan** single shot: grid + white image, :func:`nurbscan.detect.detect_grid` and
  :func:`nurbscan.reconstruct.reconstruct_view`; its edge points ("points") and dense samples of
  its Gordon patches ("Gordon").

Per view and condition (noise 0.5x, 1x, 2x at the default projector defocus 0.6 px; noise 1x at
twice the defocus): images per view, points, coverage (share of 20 000 random lit object
pixels whose true surface point has an output within 0.5 mm), point error against the exact
surface (mean, RMS, p95; 200 000 random points), and the method's time per view (decode +
triangulate; detect + reconstruct to Gordon; one run, on a shared machine). One ray-traced dark
render per defocus serves both multi-shot peers at every noise level, and nurbscan's grid and
white images are re-encoded from one render per defocus: bit for bit what fresh renders give.

Figure (issue 37): nurbscan's single-shot point RMS within 1.5 x the phase-shift peer's.

Environment: ``NURBSCAN_BENCH_PEER_VIEWS`` (2: table angles 45 and 180 degrees),
``NURBSCAN_BENCH_PEER_CAMERA`` (camera size, default ``1536x1152``: a quarter of the default
rig's 7.1 MP pixels, same field of view; projector 1920 x 1080), ``NURBSCAN_BENCH_CALIB``
(a calibrated ``calib.json`` to triangulate with; default the true rig),
``NURBSCAN_BENCH_PEER_CONDITIONS`` (the first n of the 4 conditions; for development).
"""

from __future__ import annotations

import math
import os
import platform
import statistics
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from bench_graycode import _coverage, with_calibration  # noqa: E402

N_VIEWS = int(os.environ.get("NURBSCAN_BENCH_PEER_VIEWS", "2"))
CAMERA = os.environ.get("NURBSCAN_BENCH_PEER_CAMERA", "1536x1152")
ANGLES = (math.radians(45.0), math.radians(180.0), math.radians(270.0), 0.0)
RMS_RATIO_TARGET = 1.5
ERROR_SAMPLE = 200_000
#: (name, noise scale, projector defocus scale)
CONDITIONS = (("noise 1x", 1.0, 1.0), ("noise 0.5x", 0.5, 1.0), ("noise 2x", 2.0, 1.0),
              ("noise 1x, defocus 2x", 1.0, 2.0))[
    :int(os.environ.get("NURBSCAN_BENCH_PEER_CONDITIONS", "4"))]
GC, PS, NP, NG = "Gray code (OpenCV)", "phase shift (N=4, T=16 px)", "nurbscan points", \
    "nurbscan Gordon"


def _sample(p: np.ndarray, n: int = ERROR_SAMPLE) -> np.ndarray:
    if len(p) <= n:
        return p
    return p[np.random.default_rng(0).choice(len(p), n, replace=False)]


def _rig():
    from nurbscan.simulate import default_rig, scale_camera

    w, h = (int(x) for x in CAMERA.lower().split("x"))
    return with_calibration(scale_camera(default_rig(), w, h))


def _row(r: dict) -> dict:
    return {"images": r["images"], "points": r["points"], "coverage": r["coverage"],
            **{k: r["error"][k] for k in ("mean_mm", "rms_mm", "p95_mm")}, "time": r["time"]}


def _nurbscan(view, pattern, scene, rig, crig, angle: float, k: int) -> tuple[dict, dict]:
    """nurbscan's single shot on one view's images: edge points and Gordon samples."""
    from nurbscan.detect import detect_grid
    from nurbscan.evaluate.table import gordon_cloud
    from nurbscan.peers.graycode import error_stats, world_error
    from nurbscan.reconstruct import Model, reconstruct_view
    from nurbscan.reconstruct.pipeline import add_view

    t = time.perf_counter()
    det = detect_grid(view["grid"], pattern, view["white"])
    t1 = time.perf_counter()
    res = reconstruct_view(det, crig, pattern)
    t2 = time.perf_counter()
    edge = np.asarray(res.edge_points).reshape(-1, 3)
    model = Model()
    add_view(model, res, crig, k, angle)
    cloud, _ = gordon_cloud(model)
    cloud = np.asarray(cloud).reshape(-1, 3)
    cloud_rig = rig.turntable.to_rig(cloud, angle) if len(cloud) else cloud
    tr = view["truth"]
    pts = {"images": 2, "points": int(len(edge)),
           "coverage": _coverage(tr, edge, "point_rig"),
           "error": error_stats(world_error(_sample(edge), scene, rig, angle)), "time": t2 - t}
    gor = {"images": 2, "points": int(len(cloud)), "coverage": _coverage(tr, cloud, "point_obj"),
           "error": error_stats(world_error(_sample(cloud_rig), scene, rig, angle)),
           "time": t2 - t}
    return {NP: pts, NG: gor}, {"detect (s)": round(t1 - t, 2),
                                "reconstruct to Gordon (s)": round(t2 - t1, 2),
                                "Gordon patches": len(res.patches),
                                "Gordon samples (0.35 mm apart)": int(len(cloud))}


def one_condition(scene, rig, crig, pattern, gcode, pcode, k: int, angle: float, settings,
                  base, nview) -> dict:
    """The three methods on one view under one RenderSettings."""
    from nurbscan.peers import graycode as gc
    from nurbscan.peers import phaseshift as ps
    from nurbscan.simulate.render import encode, noise_rng

    cols: dict = {}
    t = time.perf_counter()
    g = gc.scan_view(scene, rig, angle, calibrated_rig=crig, code=gcode, settings=settings,
                     seed=0, stream=k, decoder="numpy", base=base, error_sample=ERROR_SAMPLE)
    g["time"] = g["time_per_view_s"]
    g["coverage"] = _coverage(g["capture"].truth, g["points_rig"], "point_rig")
    cols[GC] = _row(g)
    g_sim = time.perf_counter() - t
    g = None
    t = time.perf_counter()
    p = ps.scan_view(scene, rig, angle, calibrated_rig=crig, code=pcode, settings=settings,
                     seed=0, stream=k, base=base, error_sample=ERROR_SAMPLE)
    p["time"] = p["time_per_view_s"]
    tr = p["capture"].truth
    p["coverage"] = _coverage(tr, p["points_rig"], "point_rig")
    cols[PS] = _row(p)
    p_sim = time.perf_counter() - t - p["time"]
    obj = tr["lit"] & (tr["surface_id"] >= 0)
    ok = obj & np.isfinite(p["column"]) & np.isfinite(p["row"])
    du = np.abs(p["column"] - tr["proj_x"])[ok]
    dv = np.abs(p["row"] - tr["proj_y"])[ok]
    ps_detail = {
        "decoded share of lit object pixels": float(ok.sum() / max(obj.sum(), 1)),
        "column error vs truth, median / RMS (projector px)":
            f"{np.median(du):.4f} / {np.sqrt(np.mean(du ** 2)):.4f}",
        "row error vs truth, median / RMS (projector px)":
            f"{np.median(dv):.4f} / {np.sqrt(np.mean(dv ** 2)):.4f}",
        "column error vs truth, RMS (projector px)": float(np.sqrt(np.mean(du ** 2))),
        "column error vs truth, median (projector px)": float(np.median(du)),
        "columns off by more than T/4 (share)": float(np.mean(du > pcode.period / 4)),
        "decode / triangulate (s)": f"{p['decode_s']:.2f} / {p['triangulate_s']:.2f}",
        "simulation of the images (s, not in the method's time)": round(p_sim, 1),
    }
    p = None
    # nurbscan: the view's grid and white images re-encoded at these sensor settings
    view = {"grid": encode(nview.linear_grid, settings, noise_rng(0, k, 0)),
            "white": encode(nview.linear_white, settings, noise_rng(0, k, 1)),
            "truth": nview.truth}
    ours, o_detail = _nurbscan(view, pattern, scene, rig, crig, angle, k)
    cols.update({m: _row(v) for m, v in ours.items()})
    side = {row: {m: cols[m][key] for m in cols} for row, key in (
        ("images per view", "images"), ("points", "points"),
        ("coverage (share of lit object pixels within 0.5 mm)", "coverage"),
        ("point error mean (mm)", "mean_mm"), ("point error RMS (mm)", "rms_mm"),
        ("point error p95 (mm)", "p95_mm"),
        ("time per view (s): decode + triangulate / detect + reconstruct", "time"))}
    for m in cols:
        side["time per view (s): decode + triangulate / detect + reconstruct"][m] = round(
            cols[m]["time"], 2)
    ps_rms = cols[PS]["rms_mm"]
    ratio = cols[NP]["rms_mm"] / ps_rms
    return {"RMS ratio nurbscan points / phase shift": round(ratio, 3),
            "RMS ratio nurbscan Gordon / phase shift": round(cols[NG]["rms_mm"] / ps_rms, 3),
            "RMS ratio Gray code / phase shift": round(cols[GC]["rms_mm"] / ps_rms, 3),
            "meets target (nurbscan points <= 1.5 x phase shift)":
                "yes" if ratio <= RMS_RATIO_TARGET else "NO",
            "side by side": side, "phase shift: details": ps_detail,
            "nurbscan: details": o_detail,
            "Gray code: simulation + decode (s)": round(g_sim, 1)}


def bench() -> dict:
    from nurbscan.peers import graycode as gc
    from nurbscan.peers import phaseshift as ps
    from nurbscan.simulate import RenderSettings, make_scene, render_view
    from nurbscan.simulate.scan import default_pattern

    t0 = time.perf_counter()
    load0 = os.getloadavg()
    rig, crig, how = _rig()
    scene = make_scene("teapot")
    scene.mesh()
    pattern = default_pattern(rig.projector)
    gcode = gc.GrayCode.for_projector(rig.projector)
    pcode = ps.PhaseShift.for_projector(rig.projector)
    default = RenderSettings()
    out: dict = {
        "camera": f"{rig.camera.width} x {rig.camera.height}",
        "projector": f"{rig.projector.width} x {rig.projector.height}",
        "scene": "teapot on the table",
        "rig used to triangulate (all methods)": how,
        "machine": f"{platform.machine()}, {os.cpu_count()} cores, shared",
        "load average at start (1, 5, 15 min)": ", ".join(f"{x:.1f}" for x in load0),
        "default noise, defocus (projector px)": f"{default.noise}, {default.projector_blur}",
    }
    views = {}
    for k, a in enumerate(ANGLES[:N_VIEWS]):
        res = {"table angle (deg)": round(math.degrees(a), 1)}
        cache: dict = {}
        for name, noise, blur in CONDITIONS:
            s = default.replace(noise=default.noise * noise,
                                projector_blur=default.projector_blur * blur)
            if blur not in cache:  # one ray-traced dark view and one grid view per defocus
                dark = gc.StripeSet(rig.projector.width, rig.projector.height, "vertical")
                cache[blur] = (render_view(scene, rig, dark, a, s, seed=0, stream=k),
                               render_view(scene, rig, pattern, a, s, seed=0, stream=k))
            base, nview = cache[blur]
            res[name] = one_condition(scene, rig, crig, pattern, gcode, pcode, k, a, s, base,
                                      nview)
            print(f"[bench_peers] view {k} {name} done {time.perf_counter() - t0:.0f} s",
                  file=sys.stderr, flush=True)
        cache.clear()
        views[f"view {k}"] = res
    out.update(views)
    med: dict = {}
    for name, _, _ in CONDITIONS:
        v = [views[x][name] for x in views]
        rms = {m: statistics.median(x["side by side"]["point error RMS (mm)"][m] for x in v)
               for m in (GC, PS, NP, NG)}
        med[name] = {**{f"{m} RMS (mm)": rms[m] for m in rms},
                     "phase shift column error RMS (projector px)": statistics.median(
                         x["phase shift: details"]["column error vs truth, RMS (projector px)"]
                         for x in v),
                     "phase shift column error median (projector px)": statistics.median(
                         x["phase shift: details"][
                             "column error vs truth, median (projector px)"] for x in v),
                     "RMS ratio nurbscan points / phase shift": rms[NP] / rms[PS],
                     "RMS ratio nurbscan Gordon / phase shift": rms[NG] / rms[PS]}
    out["median over views"] = med
    out["target ratio"] = RMS_RATIO_TARGET
    out["load average at end (1, 5, 15 min)"] = ", ".join(f"{x:.1f}" for x in os.getloadavg())
    out["benchmark wall time (s)"] = round(time.perf_counter() - t0, 1)
    return out


if __name__ == "__main__":
    import json

    print(json.dumps(bench(), indent=1, default=float))
