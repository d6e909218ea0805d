"""docs/scanning.md followed literally on a scan laid out by hand (issue #35).

The simulator only provides the photographs: they are copied into a new folder with the layout
of the page, without truth/, under the minimal scan.json of the page (filled in as the page
says: image size, one entry per view and per calibration pose, angles in radians), and the
page's commands are run as they are written. The model is measured against the simulated
sphere (radius 60 mm about (0, 0, 60) mm).
"""

from __future__ import annotations

import copy
import json
import math
import re
import shlex
import shutil
from pathlib import Path

import numpy as np

from nurbscan.cli import main
from nurbscan.export import load_model
from nurbscan.pattern import load_pattern
from nurbscan.simulate import make_scene, simulate_scan
from nurbscan.simulate.rig import default_rig, scale_camera
from nurbscan.simulate.target import FREE_POSES, TABLE_POSE_ANGLES

DOC = Path(__file__).resolve().parents[1] / "docs" / "scanning.md"
VIEWS = 2


def _blocks(lang: str) -> list[str]:
    return re.findall(rf"```{lang}\n(.*?)```", DOC.read_text(), re.S)


def _commands(block: str) -> list[list[str]]:
    return [shlex.split(line)[1:] for line in block.splitlines() if line.startswith("nurbscan ")]


def _lay_out_by_hand(photos: Path, scan: Path) -> None:
    """Copy the photographs into the page's layout and write the page's minimal scan.json."""
    (scan / "views").mkdir(parents=True)
    (scan / "calibration").mkdir()
    for sub in ("views", "calibration"):
        for f in sorted((photos / sub).glob("*.png")):
            shutil.copy(f, scan / sub / f.name)
    (doc,) = [json.loads(b) for b in _blocks("json")]
    view0, (free0, table0) = doc["views"][0], doc["calibration"]["poses"]
    doc["image_size"] = [640, 480]
    doc["views"] = []
    for k in range(VIEWS):  # the turntable's angles: VIEWS steps over a full turn
        v = copy.deepcopy(view0)
        v.update(index=k, table_angle=2 * math.pi * k / VIEWS,
                 grid=f"views/view_{k:02d}_grid.png", white=f"views/view_{k:02d}_white.png")
        doc["views"].append(v)
    poses = []
    angles = [None] * len(FREE_POSES) + [math.radians(a) for a in TABLE_POSE_ANGLES]
    for i, a in enumerate(angles):
        p = copy.deepcopy(free0 if a is None else table0)
        p.update(index=i, white=f"calibration/pose_{i:02d}_white.png",
                 grid=f"calibration/pose_{i:02d}_grid.png")
        if a is not None:
            p["table_angle"] = a
        poses.append(p)
    doc["calibration"]["poses"] = poses
    (scan / "scan.json").write_text(json.dumps(doc, indent=1))


def test_scanning_doc_followed_literally(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    sh = _blocks("sh")
    small = [c for b in sh for c in _commands(b) if c[0] == "pattern" and "--pitch" in c]
    steps = [c for b in sh for c in _commands(b) if c[0] != "pattern"]
    assert len(small) == 1 and [c[0] for c in steps][:2] == ["calibrate", "reconstruct"]
    # the projector's pattern, from the page (a 640 x 480 camera: the coarse grid)
    assert main(small[0]) == 0
    pattern = load_pattern(tmp_path / "scan" / "pattern.json")
    # the "photographs": the simulator renders them, then only the images are kept
    photos = tmp_path / "photos"
    simulate_scan(make_scene("sphere"), photos, views=VIEWS,
                  rig=scale_camera(default_rig(), 640, 480), pattern=pattern)
    _lay_out_by_hand(photos, tmp_path / "scan")
    shutil.rmtree(photos)
    assert not (tmp_path / "scan" / "truth").exists()
    for cmd in steps:
        assert main(cmd) == 0, cmd
    out = capsys.readouterr().out
    assert "camera RMS" in out
    model = load_model(tmp_path / "scan" / "model")
    assert len(model.points) > 1000 and len(model.surfaces_of("gordon")) > 10
    r = np.linalg.norm(model.points - [0.0, 0.0, 60.0], axis=1)
    print(f"scanning.md: {len(model.points)} points, {len(model.surfaces_of('gordon'))} Gordon "
          f"patches, median |r - 60| = {np.median(np.abs(r - 60.0)):.4f} mm")
    assert np.median(np.abs(r - 60.0)) < 0.5  # mm
    assert (tmp_path / "scan" / "model" / "overlays" / "view_00_overlay.png").is_file()
    assert (tmp_path / "scan" / "calib_residuals.png").is_file()
    ply = tmp_path / "scan" / "points.ply"
    try:
        import open3d as o3d
    except ImportError:  # pragma: no cover - trimesh as the reader
        import trimesh

        assert len(trimesh.load(ply, process=False).vertices) == len(model.points)
    else:
        cloud = o3d.io.read_point_cloud(str(ply))
        assert len(cloud.points) == len(model.points) and cloud.has_normals()
        np.testing.assert_allclose(np.asarray(cloud.points), model.points, atol=1e-3)
    assert (tmp_path / "scan" / "model.glb").stat().st_size > 10000
