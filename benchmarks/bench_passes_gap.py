"""Where a merged model's whole-surface coverage falls short of what its passes can see
(issue 33, the gap between ``bench_passes``'s coverage and ``bench_passes_bound``'s bound).

The true samples are ``bench_passes``'s (40000 area-uniform samples of the WHOLE true
surface of the first pass, seed 1); a sample is *seen* when some view of either pass sees it
with the camera and lights it with the projector (:func:`bench_passes_bound.seen_by_views`,
each pass's own true rig and table angles, the sample moved into that pass's frame by the
true relative pose), and *covered* when it lies within 0.5 mm of the merged fused mesh (exact
point-to-mesh distances). Every seen sample that is not covered falls into the first class
that fits:

1. **table**: at most 2 mm above the table in every pass that sees it (cut as table);
2. **fused data cut**: a triangulated edge point and a Gordon-patch sample within 0.5 mm (the
   fusion had data there: its support, trim or part filters cut it);
3. **lines outside patches**: an edge point within 0.5 mm but no Gordon-patch sample (the
   decoded lines there belong to no complete patch, and the fusion fuses patches only);
4. **grazing**: no data within 0.5 mm and seen only beyond 75 degrees of incidence;
5. **not decoded**: no data within 0.5 mm, seen within 75 degrees.

Usage::

    python benchmarks/bench_passes_gap.py SCAN_A SCAN_B MERGED [--json OUT]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_passes import emit, pose_matrix  # noqa: E402
from bench_passes_bound import seen_by_views  # noqa: E402


def main(argv=None) -> int:
    from scipy.spatial import cKDTree

    from nurbscan.camera import load_rig
    from nurbscan.evaluate.table import gordon_cloud, mesh_distances
    from nurbscan.io.atomic import read_json
    from nurbscan.reconstruct import load_model
    from nurbscan.simulate.scenes import scene_from_dict

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scan_a", type=Path)
    ap.add_argument("scan_b", type=Path)
    ap.add_argument("merged", type=Path)
    ap.add_argument("--samples", type=int, default=40000)
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)

    spec_a = read_json(args.scan_a / "truth" / "scene.json")
    spec_b = read_json(args.scan_b / "truth" / "scene.json")
    scene_a, scene_b = scene_from_dict(spec_a), scene_from_dict(spec_b)
    P, N, _ = scene_a.sample_surface(args.samples, seed=1)
    Ti = np.linalg.inv(pose_matrix(spec_a) @ np.linalg.inv(pose_matrix(spec_b)))
    seen, seen75, low = [], [], np.ones(len(P), bool)
    for scan, scene, X, Y in ((args.scan_a, scene_a, P, N),
                              (args.scan_b, scene_b, P @ Ti[:3, :3].T + Ti[:3, 3],
                               N @ Ti[:3, :3].T)):
        rig = load_rig(scan / "truth" / "rig.json")
        angles = [v["table_angle"] for v in read_json(scan / "scan.json")["views"]]
        s = seen_by_views(scene, X, Y, rig, angles)
        seen.append(s.any(1))
        seen75.append((s & seen_by_views(scene, X, Y, rig, angles, 75.0)).any(1))
        low &= ~seen[-1] | (X[:, 2] <= 2.0)
    vis = seen[0] | seen[1]
    m = load_model(args.merged)
    covered = mesh_distances(m.fused.vertices, m.fused.faces, P) <= 0.5
    G, _ = gordon_cloud(m)
    edge = np.isfinite(cKDTree(np.asarray(m.edge_points)).query(
        P, distance_upper_bound=0.5)[0])
    patch = np.isfinite(cKDTree(G).query(P, distance_upper_bound=0.5)[0])
    miss = vis & ~covered
    graze = ~(seen75[0] | seen75[1])
    rest = miss & ~low
    classes = {"table": miss & low, "fused data cut": rest & edge & patch,
               "lines outside patches": rest & edge & ~patch,
               "patch samples without edge points": rest & ~edge & patch,
               "grazing": rest & ~edge & ~patch & graze,
               "not decoded": rest & ~edge & ~patch & ~graze}
    out = {"scene": spec_a.get("name"), "samples": args.samples,
           "whole_coverage": float(covered.mean()), "seen": float(vis.mean()),
           "seen_not_covered": float(miss.mean()),
           "covered_not_seen": float((covered & ~vis).mean()),
           "classes": {k: round(float(v.mean()), 5) for k, v in classes.items()}}
    return emit(out, args.json)


if __name__ == "__main__":
    sys.exit(main())
