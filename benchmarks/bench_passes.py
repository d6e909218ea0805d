"""Benchmark of the two-pass merge (issue 33): the object turned over, aligned without a prior.

Given two simulated scans of one object in two resting poses, their reconstructed models and
the merged model (``nurbscan merge``), measures against the truth (the truth is read here
only, never by the merge):

* **whole-surface coverage**: the share of the WHOLE true surface (area-uniform samples of
  the exact surface, not only what the turntable sees) within 0.5 mm of the fused mesh
  (exact point-to-mesh distances), for each pass alone and merged;
* **accuracy**: the mean (and 99th percentile, max) of the exact distances of area-uniform
  samples of the fused mesh to the true surface;
* **alignment**: the estimated transform of the second pass (global, and after the joint
  refinement) against the true relative pose ``T_A T_B^-1`` of the two poses recorded in
  ``truth/scene.json``: rotation error (degrees) and the largest displacement error of a
  point of the object (mm, translation error plus the rotation error at the object's
  radius); and the RMS distance over the overlap that the merge reports, beside the same RMS
  with the TRUE relative pose (``rms_true_pose_mm``: what a perfect alignment would report,
  the passes' own surfaces' disagreement).

Usage::

    python benchmarks/bench_passes.py SCAN_A SCAN_B MODEL_A MODEL_B MERGED [--json OUT]

prints one JSON document (and writes it to OUT).
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
from pathlib import Path

import numpy as np


def pose_matrix(spec: dict) -> np.ndarray:
    """``X_pass = T X_base`` of a truth scene dict (identity without a pose)."""
    T = np.eye(4)
    pose = spec.get("pose")
    if pose:
        T[:3, :3] = np.asarray(pose["R"], float)
        T[:3, 3] = np.asarray(pose["t"], float)
    return T


def motion_error(T_est: np.ndarray, T_true: np.ndarray, radius: float) -> dict:
    from scipy.spatial.transform import Rotation

    D = np.linalg.inv(T_true) @ T_est
    ang = float(np.linalg.norm(Rotation.from_matrix(D[:3, :3]).as_rotvec()))
    return {"rotation_error_deg": float(np.degrees(ang)),
            "translation_error_mm": float(np.linalg.norm(D[:3, 3])),
            "max_displacement_mm": float(np.linalg.norm(D[:3, 3]) + radius * ang)}


def surface_figures(fused, scene, P_true: np.ndarray, tol: float = 0.5,
                    n_mesh: int = 100_000) -> dict:
    import trimesh

    from nurbscan.evaluate.table import mesh_distances

    V, F = np.asarray(fused.vertices, float), np.asarray(fused.faces, np.int64)
    tm = trimesh.Trimesh(V, F, process=False)
    S, _ = trimesh.sample.sample_surface(tm, n_mesh, seed=0)
    d = scene.closest_point(S)[1]
    dt = mesh_distances(V, F, P_true)
    return {"whole_coverage": float((dt <= tol).mean()), "mean_mm": float(d.mean()),
            "p99_mm": float(np.percentile(d, 99)), "max_mm": float(d.max()),
            "faces": int(len(F)), "area_mm2": float(tm.area)}


def rms_true_pose(model_b, model_a, T_true: np.ndarray) -> float:
    """RMS over the overlap of pass B's surface samples (as the merge takes them) moved by
    the TRUE relative pose to pass A's fused mesh (mm; :func:`mesh_overlap_rms`)."""
    from nurbscan.merge.passes import PassOptions, mesh_overlap_rms, pass_surface

    P, _ = pass_surface(model_b, PassOptions())
    return mesh_overlap_rms(P, T_true, model_a.fused, PassOptions().alignment.overlap_distance)[1]


def emit(out: dict, path: Path | None) -> int:
    """Print ``out`` as JSON (and write it to ``path``); 0."""
    text = json.dumps(out, indent=1)
    print(text)
    if path:
        path.write_text(text)
    return 0


def main(argv=None) -> int:
    from nurbscan.io.atomic import read_json
    from nurbscan.reconstruct import load_model
    from nurbscan.simulate.scenes import scene_from_dict

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scan_a", type=Path)
    ap.add_argument("scan_b", type=Path)
    ap.add_argument("model_a", type=Path)
    ap.add_argument("model_b", type=Path)
    ap.add_argument("merged", type=Path)
    ap.add_argument("--samples", type=int, default=40000, help="true-surface samples")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)

    spec_a = read_json(args.scan_a / "truth" / "scene.json")
    spec_b = read_json(args.scan_b / "truth" / "scene.json")
    scene_a, scene_b = scene_from_dict(spec_a), scene_from_dict(spec_b)
    P_a = scene_a.sample_surface(args.samples, seed=1)[0]
    T_true = pose_matrix(spec_a) @ np.linalg.inv(pose_matrix(spec_b))  # pass B -> pass A
    out = {"machine": f"{platform.node()} {platform.machine()} {platform.processor()}",
           "scene": spec_a.get("name"), "pose_a": spec_a.get("pose"),
           "pose_b": spec_b.get("pose")}
    # each pass alone, in its own frame (the same true points moved into it)
    Ti = np.linalg.inv(T_true)
    models = {}
    for key, folder, scene, P in (("pass_a", args.model_a, scene_a, P_a),
                                  ("pass_b", args.model_b, scene_b,
                                   P_a @ Ti[:3, :3].T + Ti[:3, 3])):
        m = models[key] = load_model(folder)
        out[key] = surface_figures(m.fused, scene, P)
        print(f"{key}: {out[key]}", file=sys.stderr, flush=True)
    merged = load_model(args.merged)
    out["merged"] = surface_figures(merged.fused, scene_a, P_a)
    print(f"merged: {out['merged']}", file=sys.stderr, flush=True)
    rep = read_json(args.merged / "alignment.json")
    pb = rep["passes"][1]
    radius = float(np.max(np.linalg.norm(P_a - P_a.mean(0), axis=1)))
    out["alignment"] = {
        "global": motion_error(np.asarray(pb["global"]["matrix"]), T_true, radius),
        "refined": motion_error(np.asarray(pb["refined_matrix"]), T_true, radius),
        "overlap": pb["overlap"], "rms_mm": pb["rms_mm"],
        "global_rms_mm": pb["global"]["rms_mm"], "ambiguous": pb["global"]["ambiguous"],
        "rms_true_pose_mm": rms_true_pose(models["pass_b"], models["pass_a"], T_true),
        "object_radius_mm": radius, "warnings": rep["warnings"],
        "merge_s": rep.get("total_s")}
    return emit(out, args.json)


if __name__ == "__main__":
    sys.exit(main())
