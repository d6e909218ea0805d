"""Global registration on passes sampled from the exact surfaces (issue 33): for each scene,
two resting poses, each seen as a turntable pass sees it (area-uniform samples of the exact
surface above the table whose normals point at most 60 degrees below the horizon, 5 um noise
along the normal), aligned by :func:`nurbscan.merge.global_registration.align_surfaces` and
compared with the true relative pose. Shows which shapes allow an alignment (the teapot, the
blob) and which are ambiguous (surfaces of revolution, the sphere).

Usage: ``python benchmarks/bench_align_truth.py [SCENE:POSE_B ...]`` (default teapot:side,
blob:upside-down, torus:side, cylinder:side, sphere:30,60,0); prints one JSON line per scene.
"""

from __future__ import annotations

import json
import sys
import time

import numpy as np


def seen(sc, n=60000, seed=0, noise=0.005):
    P, N, _ = sc.sample_surface(n, seed=seed)
    keep = (P[:, 2] > 2.0) & (N[:, 2] > -0.5)
    rng = np.random.default_rng(seed + 50)
    return P[keep] + noise * rng.standard_normal((keep.sum(), 1)) * N[keep], N[keep]


def main(argv=None) -> int:
    from nurbscan.errors import NurbscanError
    from nurbscan.merge.global_registration import align_surfaces, motion_difference
    from nurbscan.simulate.pose import posed
    from nurbscan.simulate.scenes import make_scene

    cases = (argv if argv else sys.argv[1:]) or ["teapot:side", "blob:upside-down",
                                                 "torus:side", "cylinder:side",
                                                 "sphere:30,60,0"]
    for case in cases:
        name, pose = case.split(":", 1)
        base = make_scene(name)
        A, B = posed(base, "upright"), posed(base, pose)
        TA, TB = np.eye(4), np.eye(4)
        TA[:3, :3], TA[:3, 3] = A.R, A.t
        TB[:3, :3], TB[:3, 3] = B.R, B.t
        true = TA @ np.linalg.inv(TB)
        t0 = time.perf_counter()
        row = {"scene": name, "pose_b": pose}
        try:
            al = align_surfaces(seen(B, seed=2), seen(A, seed=1))
            ang, tr = motion_difference(true, al.matrix)
            row.update({"rotation_error_deg": round(ang, 5), "translation_error_mm": round(tr, 5),
                        "overlap": al.overlap, "rms_mm": al.rms_mm, "ambiguous": al.ambiguous,
                        "candidates": len(al.candidates), "warnings": al.warnings})
        except NurbscanError as exc:
            row["error"] = str(exc)
        row["seconds"] = round(time.perf_counter() - t0, 1)
        print(json.dumps(row), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
