"""Tests of the resting poses (nurbscan.simulate.pose) and the blob scene (issue 33).

Oracle: the base scene's exact surface moved by the pose's rotation and translation; the
blob's derivatives against central finite differences."""

from __future__ import annotations

import json

import numpy as np
import pytest

from nurbscan.cli import main
from nurbscan.errors import NurbscanError
from nurbscan.simulate.pose import PosedScene, parse_pose, posed
from nurbscan.simulate.scenes import make_scene, scene_from_dict


@pytest.mark.parametrize("name,pose", [("teapot", "side"), ("teapot", "upside-down"),
                                       ("torus", "30,60,10"), ("blob", "side")])
def test_posed_scene_is_the_base_moved_and_set_down(name, pose):
    base = make_scene(name)
    sc = posed(base, pose)
    R, t = sc.R, sc.t
    assert np.allclose(R, parse_pose(pose)) and np.allclose(R @ R.T, np.eye(3))
    P, N, sid = sc.sample_surface(20000, seed=3)
    Pb, Nb, sidb = base.sample_surface(20000, seed=3)
    assert np.allclose(P, Pb @ R.T + t, atol=1e-9) and np.allclose(N, Nb @ R.T, atol=1e-9)
    # lowest point on the table, never below it; bounding box centred on the axis
    lo, hi = sc.bounds
    assert -1e-6 < P[:, 2].min() < 0.5
    assert abs(sc.mesh(0.05).vertices[:, 2].min()) < 0.05
    assert np.all(np.abs(0.5 * (lo[:2] + hi[:2])) < 0.1)
    # exact closest points of moved queries are the base's, moved
    q = P[:200] + 0.3 * N[:200]
    cp, d, _ = sc.closest_point(q)
    cpb, db, _ = base.closest_point((q - t) @ R)
    assert np.allclose(d, db, atol=1e-9) and np.allclose(cp, cpb @ R.T + t, atol=1e-9)
    # rays: a ray towards a surface point along its inward normal hits there (or nearer)
    o = P[:300] + 5.0 * N[:300]
    hit = sc.intersect(o, -N[:300])
    ok = hit["hit"]
    assert ok.mean() > 0.95
    assert np.all(hit["t"][ok] <= 5.0 + 1e-6)
    near = np.abs(hit["t"][ok] - 5.0) < 1e-6
    assert near.mean() > 0.8


def test_posed_scene_round_trips_through_its_dict():
    sc = posed(make_scene("teapot"), "upside-down")
    d = json.loads(json.dumps(sc.to_dict()))
    assert d["name"] == "teapot" and "pose" in d
    back = scene_from_dict(d)
    assert isinstance(back, PosedScene)
    P = sc.sample_surface(50, seed=1)[0]
    assert np.allclose(back.closest_point(P)[1], 0.0, atol=1e-7)
    # upside down: the lid's top is on the table, the bottom 116.55 mm up (0.1 mm of the
    # bottom's rim bulge aside)
    assert np.isclose(sc.bounds[1, 2], 37 * 3.15, atol=0.2)


def test_bad_poses_are_one_line_errors():
    for bad in ("sideways", "1,2", "a,b,c", "nan,0,0"):
        with pytest.raises(NurbscanError, match="--pose"):
            parse_pose(bad)
    with pytest.raises(NurbscanError):
        scene_from_dict({**make_scene("sphere").to_dict(), "pose": {"R": [[2, 0, 0]]}})


def test_blob_derivatives_and_mesh():
    b = make_scene("blob")
    rng = np.random.default_rng(0)
    u, v = rng.uniform(0.05, np.pi - 0.05, 200), rng.uniform(0, 2 * np.pi, 200)
    S = b._eval(0, u, v, 2)
    h = 1e-6
    fd_u = (b._eval(0, u + h, v, 1)[1] - b._eval(0, u - h, v, 1)[1]) / (2 * h)
    fd_v = (b._eval(0, u, v + h, 1)[2] - b._eval(0, u, v - h, 1)[2]) / (2 * h)
    fd_uv = (b._eval(0, u, v + h, 1)[1] - b._eval(0, u, v - h, 1)[1]) / (2 * h)
    assert np.allclose(fd_u, S[3], atol=1e-5) and np.allclose(fd_v, S[5], atol=1e-5)
    assert np.allclose(fd_uv, S[4], atol=1e-5)
    m = b.mesh(0.2)
    assert b.closest_point(m.triangles_center)[1].max() < 0.2
    # outward normals, lowest point on the table, not a surface of revolution
    P, N, _ = b.sample_surface(5000)
    assert np.all(np.einsum("ij,ij->i", N, P - np.array(b.center)) > 0)
    assert -1e-6 < P[:, 2].min() < 0.3
    # no symmetry: the blob turned by any half turn or mirrored is not itself
    Q = P[::10]
    for M in (np.diag([-1, -1, 1.0]), np.diag([1, -1, -1.0]), np.diag([-1, 1, 1.0]),
              np.diag([1, -1, 1.0])):
        c = np.array(b.center)
        assert np.median(b.closest_point((Q - c) @ M.T + c)[1]) > 1.0


def test_simulate_pose_writes_the_posed_truth(tmp_path):
    out = tmp_path / "scan"
    assert main(["simulate", "blob", "--pose", "upside-down", "-o", str(out), "--views", "1",
                 "--width", "160", "--height", "120", "--no-calibration", "--workers",
                 "1"]) == 0
    spec = json.loads((out / "truth" / "scene.json").read_text())
    sc = scene_from_dict(spec)
    assert isinstance(sc, PosedScene) and spec["pose"]["R"][2][2] == pytest.approx(-1.0)
    with np.load(out / "truth" / "view_00.npz") as z:
        q = z["point_obj"][z["surface_id"] >= 0]
    assert len(q) > 200
    assert sc.closest_point(q)[1].max() < 1e-6  # the truth pixels lie on the posed surface
    assert main(["simulate", "blob", "--pose", "nope", "-o", str(tmp_path / "x")]) == 2
