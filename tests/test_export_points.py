"""``nurbscan export model/ --format ply --points``: the point cloud with normals and colours,
read back by Open3D (the oracle; trimesh when Open3D is not installed)."""

from __future__ import annotations

import numpy as np
import pytest

from _export_fixtures import CENTRE, R, make_folders, quarter_sphere
from nurbscan.cli import main
from nurbscan.export import load_model

COLOURS = [(200, 30, 30), (30, 200, 30), (30, 30, 200), (200, 200, 30)]


def _read_ply(path):
    """(points, normals, colours in [0, 1]) as an independent reader sees them."""
    try:
        import open3d as o3d
    except ImportError:  # pragma: no cover - trimesh as the oracle
        import trimesh

        pc = trimesh.load(path, process=False)
        n = pc.metadata["_ply_raw"]["vertex"]["data"]
        return (np.asarray(pc.vertices), np.column_stack([n["nx"], n["ny"], n["nz"]]),
                np.asarray(pc.colors)[:, :3] / 255.0)
    pc = o3d.io.read_point_cloud(str(path))
    return np.asarray(pc.points), np.asarray(pc.normals), np.asarray(pc.colors)


@pytest.fixture
def model_with_points(tmp_path):
    """The four-patch sphere model of _export_fixtures with points sampled on its patches (view
    k's points on patch k) and the normals pointing out of the sphere."""
    folder = make_folders(tmp_path, COLOURS)
    m = load_model(folder)
    u = np.linspace(0.02, 0.98, 20)
    pts, views = [], []
    for k in range(4):
        s = quarter_sphere(k)
        uu, vv = np.meshgrid(u, u, indexing="ij")
        pts.append(s.evaluate(uu.ravel(), vv.ravel()).reshape(-1, 3))
        views.append(np.full(len(pts[-1]), k))
    m.points = np.concatenate(pts)
    m.normals = (m.points - CENTRE) / R
    m.point_view = np.concatenate(views)
    m.meta = {k: v for k, v in m.meta.items() if k != "_folder"}
    m.save(folder)
    return folder, m


def test_cli_writes_a_point_cloud_open3d_reads(model_with_points, tmp_path, capsys):
    folder, m = model_with_points
    out = tmp_path / "cloud.ply"
    assert main(["export", str(folder), "--format", "ply", "--points", "-o", str(out)]) == 0
    assert "wrote" in capsys.readouterr().out
    P, N, C = _read_ply(out)
    assert P.shape == (1600, 3) and N.shape == (1600, 3) and C.shape == (1600, 3)
    np.testing.assert_allclose(P, m.points, atol=1e-4)  # float32, mm
    np.testing.assert_allclose(N, m.normals, atol=1e-6)
    r = np.linalg.norm(P - CENTRE, axis=1)
    assert np.abs(r - R).max() < 1e-3
    # each point takes the colour of its own view's (uniform) white image where the camera
    # sees it, neutral grey (180) elsewhere
    rgb = np.round(C * 255).astype(int)
    own = np.array(COLOURS)[m.point_view]
    match = np.all(rgb == own, axis=1)
    grey = np.all(rgb == 180, axis=1)
    assert np.all(match | grey) and match.mean() > 0.5


def test_no_colour_gives_grey_and_other_formats_refuse(model_with_points, tmp_path, capsys):
    folder, _ = model_with_points
    out = tmp_path / "grey.ply"
    assert main(["export", str(folder), "--points", "--no-colour", "-o", str(out)]) == 0
    _, _, C = _read_ply(out)
    assert np.all(np.round(C * 255) == 180)
    bad = tmp_path / "cloud.glb"
    assert main(["export", str(folder), "--points", "-o", str(bad)]) == 2
    err = capsys.readouterr().err
    assert "ply only" in err and "\n" not in err.strip() and not bad.exists()


def test_a_model_without_points_is_refused(tmp_path, capsys):
    folder = make_folders(tmp_path)  # no points sampled
    out = tmp_path / "none.ply"
    assert main(["export", str(folder), "--points", "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert "no points" in err and "model" in err and not out.exists()
