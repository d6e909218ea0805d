"""Upper bound of the whole-surface coverage of turntable passes (issue 33), from the truth.

A pass can reconstruct only what some view's camera sees AND the projector lights: a point
of the object counts as *seen by a view* when

* it projects inside the camera image and the ray from the camera's centre meets the object
  first at it (not occluded; the surface is two-sided, as the renderer treats it), and
* it projects inside the projector image, the projector lies on the side of the surface the
  camera sees, and the ray from the projector's centre meets the object first at it (not in
  shadow);

the same tests as the renderer's truth (``surface_id`` and ``lit``,
:func:`nurbscan.simulate.render._trace`, shadow rays :func:`~nurbscan.simulate.render._shadowed`,
``shadow_epsilon``), applied to area-uniform samples of the WHOLE true surface (the samples
:mod:`bench_passes` measures coverage on) instead of to pixels. So the shares below bound what
any reconstruction of those views can cover; no pixel footprint, no grazing-angle limit (a
second figure keeps only points seen by camera and projector within ``--max-incidence``
degrees of the normal, closer to what the grid detector can measure).

Each resting pose is :func:`nurbscan.simulate.pose.posed` (rotated, set down on the table);
the same base-frame samples are moved into every pose, so passes combine by their union.
Reported: per pose the share seen by its views; the union with the upright pass; the best
pair and the best triple of passes over all poses tried.

Usage::

    python benchmarks/bench_passes_bound.py [--scene teapot] [--views 8] [--samples 20000]
        [--json OUT]
"""

from __future__ import annotations

import argparse
import itertools
import json
import platform
import sys
import time
from pathlib import Path

import numpy as np

#: Poses tried besides the named ones: the object's "down" direction over the sphere
#: (rotations about x then y, degrees); an azimuth about z hardly matters on a turntable.
GRID = [(rx, ry, 0.0) for rx in (30.0, 60.0, 120.0, 150.0) for ry in (0.0, 90.0, 180.0, 270.0)] \
    + [(0.0, 90.0, 0.0), (0.0, -90.0, 0.0), (-90.0, 0.0, 0.0), (90.0, 0.0, 90.0),
       (45.0, 45.0, 0.0), (135.0, 45.0, 0.0), (-45.0, 45.0, 0.0), (-135.0, 45.0, 0.0)]


def seen_by_views(scene, points: np.ndarray, normals: np.ndarray, rig, angles,
                  max_incidence_deg: float = 90.0, eps: float = 1e-3) -> np.ndarray:
    """Which points (N, 3) of ``scene`` (object frame, mm; normals (N, 3)) each view sees
    with the camera and lights with the projector: bool (N, V) (module notes)."""
    from nurbscan.simulate.render import _object_transform, _shadowed

    cam, proj = rig.camera, rig.projector
    cmin = np.cos(np.radians(max_incidence_deg))
    out = np.zeros((len(points), len(angles)), bool)
    for k, a in enumerate(angles):
        m, t = _object_transform(rig.turntable, float(a))
        x_rig = points @ m.T + t
        n_rig = normals @ m.T
        ok = np.ones(len(points), bool)
        for dev in (cam, proj):
            px = np.asarray(dev.project(x_rig), float).reshape(-1, 2)
            ok &= ((px[:, 0] >= -0.5) & (px[:, 0] <= dev.width - 0.5)
                   & (px[:, 1] >= -0.5) & (px[:, 1] <= dev.height - 0.5))
        c_cam = np.asarray(cam.center, float)
        c_proj = np.asarray(proj.center, float)
        to_cam = c_cam - x_rig
        to_cam /= np.linalg.norm(to_cam, axis=1)[:, None]
        to_proj = c_proj - x_rig
        to_proj /= np.linalg.norm(to_proj, axis=1)[:, None]
        n_cam = n_rig * np.sign(np.einsum("ij,ij->i", n_rig, to_cam))[:, None]
        cos_c = np.abs(np.einsum("ij,ij->i", n_rig, to_cam))
        cos_p = np.einsum("ij,ij->i", n_cam, to_proj)
        ok &= (cos_p > 0) & (cos_c > 0)
        if max_incidence_deg < 90.0:
            ok &= (cos_p >= cmin) & (cos_c >= cmin)
        for centre, cos in ((c_cam, cos_c), (c_proj, cos_p)):
            idx = np.flatnonzero(ok)
            if idx.size:
                o_obj = (centre - t) @ m  # m^T (c - t), row vector
                hidden = _shadowed(scene, o_obj, points[idx], cos[idx], eps)
                ok[idx[hidden]] = False
        out[:, k] = ok
    return out


def never_seen(mask: np.ndarray, P: np.ndarray, sid: np.ndarray, top: int = 8) -> list:
    """Where the samples no pass sees lie: per surface id (most first), their share of all
    samples and their mean position and height range in the upright (base) frame, mm."""
    out = []
    for s in np.unique(sid[mask]):
        m = mask & (sid == s)
        out.append({"surface": int(s), "share": round(float(m.mean()), 4),
                    "mean_mm": np.round(P[m].mean(0), 1).tolist(),
                    "z_range_mm": np.round([P[m, 2].min(), P[m, 2].max()], 1).tolist(),
                    "of_surface": round(float(m.sum() / max((sid == s).sum(), 1)), 3)})
    out.sort(key=lambda d: -d["share"])
    return out[:top]


def pose_name(p) -> str:
    return p if isinstance(p, str) else ",".join(f"{a:g}" for a in p)


def main(argv=None) -> int:
    from scipy.spatial.transform import Rotation

    from nurbscan.simulate.pose import parse_pose, posed
    from nurbscan.simulate.rig import default_rig
    from nurbscan.simulate.scenes import make_scene

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", default="teapot")
    ap.add_argument("--views", type=int, default=8)
    ap.add_argument("--samples", type=int, default=20000)
    ap.add_argument("--max-incidence", type=float, default=75.0,
                    help="degrees; the second figure's limit on both incidence angles")
    ap.add_argument("--no-grid", action="store_true", help="only the named poses")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)

    t0 = time.perf_counter()
    base = make_scene(args.scene)
    rig = default_rig()
    angles = 2 * np.pi * np.arange(args.views) / args.views
    Pb, Nb, sid = base.sample_surface(args.samples, seed=1)
    poses = ["upright", "side", "upside-down"] + ([] if args.no_grid else GRID)
    seen, seen_lim = {}, {}
    for p in poses:
        R = parse_pose(p) if isinstance(p, str) else Rotation.from_euler(
            "xyz", p, degrees=True).as_matrix()
        sc = posed(base, R)
        P, N = Pb @ sc.R.T + sc.t, Nb @ sc.R.T
        s = seen_by_views(sc, P, N, rig, angles)
        seen[pose_name(p)] = s.any(1)
        seen_lim[pose_name(p)] = (s & seen_by_views(sc, P, N, rig, angles,
                                                    args.max_incidence)).any(1)
        print(f"[{time.perf_counter() - t0:6.1f} s] {pose_name(p)}: seen "
              f"{seen[pose_name(p)].mean():.4f}, within {args.max_incidence:g} deg "
              f"{seen_lim[pose_name(p)].mean():.4f}; per view "
              f"{np.round(s.mean(0), 3).tolist()}", file=sys.stderr, flush=True)

    names = list(seen)

    def best(k, table):
        combos = [(float(np.logical_or.reduce([table[n] for n in c]).mean()), c)
                  for c in itertools.combinations(names, k)]
        combos.sort(reverse=True)
        return [{"poses": list(c), "share": round(v, 4)} for v, c in combos[:5]]

    out = {"machine": f"{platform.node()} {platform.machine()}", "scene": args.scene,
           "views": args.views, "samples": args.samples, "target": 0.97,
           "max_incidence_deg": args.max_incidence,
           "single": {n: round(float(seen[n].mean()), 4) for n in names},
           "single_within_incidence": {n: round(float(seen_lim[n].mean()), 4) for n in names},
           "with_upright": {n: round(float((seen["upright"] | seen[n]).mean()), 4)
                            for n in names if n != "upright"},
           "with_upright_within_incidence": {
               n: round(float((seen_lim["upright"] | seen_lim[n]).mean()), 4)
               for n in names if n != "upright"},
           "best_pairs": best(2, seen), "best_triples": best(3, seen),
           "best_pairs_within_incidence": best(2, seen_lim),
           "best_triples_within_incidence": best(3, seen_lim),
           "all_poses": round(float(np.logical_or.reduce(list(seen.values())).mean()), 4),
           "never_seen_upright_side": never_seen(~(seen["upright"] | seen["side"]), Pb, sid),
           "never_seen_all_poses": never_seen(~np.logical_or.reduce(list(seen.values())),
                                              Pb, sid),
           "seconds": round(time.perf_counter() - t0, 1)}
    text = json.dumps(out, indent=1)
    print(text)
    if args.json:
        args.json.write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
