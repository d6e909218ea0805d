"""The top-level Python API (issue #35): doctests, the lazy names, docs/python.md's example."""

from __future__ import annotations

import doctest
import importlib
import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import nurbscan
from nurbscan.errors import NurbscanError

ROOT = Path(__file__).resolve().parents[1]
DOCTEST_MODULES = ("nurbscan", "nurbscan.io.scan", "nurbscan.calibrate.opencv")


@pytest.mark.parametrize("name", DOCTEST_MODULES)
def test_docstring_examples_run(name):
    mod = importlib.import_module(name)
    res = doctest.testmod(mod, optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    assert res.attempted >= 5, f"{name}: only {res.attempted} examples"
    assert res.failed == 0


def test_every_public_name_resolves_to_its_stage():
    from nurbscan.camera import Rig
    from nurbscan.nurbs import fit_curve
    from nurbscan.pattern import LinePattern

    for name in nurbscan.__all__:
        assert getattr(nurbscan, name) is not None, name
    assert nurbscan.Rig is Rig and nurbscan.fit_curve is fit_curve
    assert nurbscan.LinePattern is LinePattern
    assert set(nurbscan.__all__) <= set(dir(nurbscan))
    with pytest.raises(AttributeError, match="no attribute 'nothing'"):
        nurbscan.nothing  # noqa: B018


def test_import_stays_lazy():
    """``import nurbscan`` imports no stage (and no numpy / OpenCV)."""
    code = ("import sys, nurbscan; print(sorted(m for m in sys.modules "
            "if m.startswith(('nurbscan.', 'numpy', 'cv2'))))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout
    assert eval(out) == ["nurbscan.errors"]


def test_every_name_is_listed_in_docs_python_md():
    text = (ROOT / "docs" / "python.md").read_text()
    for name in nurbscan.__all__:
        if name in ("__version__", "Scan", "Model"):
            continue
        assert f"`{name}" in text, name


def _scan_json(d: Path, **views) -> Path:
    doc = {"type": "nurbscan.scan", "version": 1, "image_size": [64, 48],
           "pattern": {"image": "pattern.png", "sidecar": "pattern.json"},
           "views": [{"index": 0, "table_angle": 0.5, "grid": "views/g.png",
                      "white": "views/w.png", **views}],
           "calibration": {"target": {"square_mm": 20.0},
                           "poses": [{"index": 3, "kind": "turntable", "table_angle": -1.0,
                                      "white": "calibration/p_white.png"}]}}
    (d / "scan.json").write_text(json.dumps(doc))
    return d


def test_load_scan_resolves_paths_inside_the_folder(tmp_path):
    scan = nurbscan.load_scan(_scan_json(tmp_path))
    root = tmp_path.resolve()
    assert scan.folder == root and scan.image_size == (64, 48)
    assert scan.views[0].grid == root / "views" / "g.png"
    assert scan.views[0].white == root / "views" / "w.png"
    assert scan.views[0].table_angle == 0.5
    assert scan.poses[0].index == 3 and scan.poses[0].table_angle == -1.0
    assert scan.poses[0].grid is None and scan.calibration_folder == root / "calibration"
    assert scan.pattern_sidecar == root / "pattern.json"
    assert nurbscan.load_scan(tmp_path / "scan.json") == scan


@pytest.mark.parametrize("bad", ["../x.png", "views/../../x.png", "/etc/passwd",
                                 "C:\\x.png", ""])
def test_load_scan_refuses_paths_leaving_the_folder(tmp_path, bad):
    _scan_json(tmp_path, grid=bad)
    with pytest.raises(NurbscanError) as exc:
        nurbscan.load_scan(tmp_path)
    msg = str(exc.value)
    assert "\n" not in msg and "scan.json" in msg and "views[0].grid" in msg


def test_load_scan_refuses_a_symlink_out_of_the_folder(tmp_path):
    outside = tmp_path / "outside"
    outside.mkdir()
    scan = tmp_path / "scan"
    scan.mkdir()
    (scan / "views").symlink_to(outside)
    _scan_json(scan)
    with pytest.raises(NurbscanError, match="leaves the scan folder"):
        nurbscan.load_scan(scan)


@pytest.mark.parametrize("text, what", [
    ("{", "scan.json"), ('{"type": "x"}', "not a nurbscan"),
    ('{"type": "nurbscan.scan"}', "image_size"),
    ('{"type": "nurbscan.scan", "image_size": [4, 4], "bit_depth": "x"}', "bit_depth"),
    ('{"type": "nurbscan.scan", "image_size": [4, 4], "views": {}}', "views: expected a list"),
    ('{"type": "nurbscan.scan", "image_size": [4, 4], "views": [{"grid": "g.png", '
     '"table_angle": "NaN"}]}', "views.0..table_angle"),
])
def test_load_scan_bad_json_is_one_line(tmp_path, text, what):
    (tmp_path / "scan.json").write_text(text)
    with pytest.raises(NurbscanError, match=what) as exc:
        nurbscan.load_scan(tmp_path)
    assert "\n" not in str(exc.value)


def test_load_scan_missing_folder(tmp_path):
    with pytest.raises(NurbscanError, match="scan.json: not found"):
        nurbscan.load_scan(tmp_path / "nothing")


def _python_block(md: Path) -> str:
    blocks = re.findall(r"```python\n(.*?)```", md.read_text(), re.S)
    assert len(blocks) == 1
    return blocks[0]


def test_docs_python_md_worked_example_runs(tmp_path, monkeypatch, capsys):
    """The example of docs/python.md, exec'd literally in an empty folder; the model it makes
    is measured against the simulated sphere (radius 60 mm about (0, 0, 60) mm)."""
    code = _python_block(ROOT / "docs" / "python.md")
    assert len([line for line in code.splitlines() if line.strip()]) <= 15
    monkeypatch.chdir(tmp_path)
    ns: dict = {}
    exec(compile(code, "docs/python.md", "exec"), ns)
    out = capsys.readouterr().out
    assert re.search(r"camera RMS \d\.\d+ px", out)
    model = nurbscan.load_model(tmp_path / "model")
    assert len(model.points) > 1000 and len(model.surfaces) >= 2
    r = np.linalg.norm(model.points - [0.0, 0.0, 60.0], axis=1)
    print(f"python.md: {len(model.points)} points, median |r - 60| = "
          f"{np.median(np.abs(r - 60.0)):.4f} mm")
    assert np.median(np.abs(r - 60.0)) < 0.5  # mm
    for name in ("sphere.3dm", "sphere.glb", "calib.json"):
        assert (tmp_path / name).stat().st_size > 1000, name
    truth = nurbscan.load_rig(tmp_path / "scan" / "truth" / "rig.json")
    assert abs(ns["calibration"].rig.camera.f / truth.camera.f - 1) < 0.01
