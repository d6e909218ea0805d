"""Tests of nurbscan.evaluate: Table I figures against an exact oracle (a plane scene and
models at known offsets), coverage, and the evaluation files."""

from __future__ import annotations

import json

import numpy as np
import pytest

from nurbscan.errors import NurbscanError
from nurbscan.evaluate import PAPER, evaluate_model, format_table
from nurbscan.io import write_json
from nurbscan.nurbs import NurbsCurve, NurbsSurface
from nurbscan.reconstruct import Model
from nurbscan.simulate.scenes import make_scene


@pytest.fixture()
def truth(tmp_path):
    """A truth folder: a 200 mm square plane z = 0 seen, in one view, on x in [-100, 0]."""
    scene = make_scene("plane", point=(0, 0, 0), normal=(0, 0, 1), size=200.0)
    d = tmp_path / "truth"
    write_json(d / "scene.json", scene.to_dict())
    xs, ys = np.meshgrid(np.linspace(-100, 0, 201), np.linspace(-100, 100, 401))
    pts = np.stack([xs, ys, np.zeros_like(xs)], -1)
    np.savez(d / "view_00.npz", point_obj=pts, surface_id=np.zeros(xs.shape, np.int32),
             depth=np.full(xs.shape, 600.0), table_angle=np.float64(0.0))
    return d


def _flat(x0, x1, y0, y1, z):
    P = np.array([[[x0, y0, z], [x0, y1, z]], [[x1, y0, z], [x1, y1, z]]], float)
    return NurbsSurface(1, 1, [0, 0, 1, 1], [0, 0, 1, 1], P)


def _model():
    surfaces = []
    # two Gordon patches at heights 0.01 and 0.03 over half of the seen part
    for k, (z, (y0, y1)) in enumerate([(0.01, (-100, 0)), (0.03, (0, 50))]):
        for kind in ("gordon", "horizontal_skin", "vertical_skin"):
            zz = z if kind == "gordon" else 2 * z
            surfaces.append({"kind": kind, "view": 0, "patch": k, "vertical": [0, 1],
                             "horizontal": [0, 1], "n_curves": [3, 3],
                             "surface": _flat(-100, 0, y0, y1, zz)})
    # a tilted line: distances grow linearly from 0 to 0.2 mm (mean 0.1)
    line = NurbsCurve(1, [0, 0, 1, 1], [[-50, -50, 0.0], [-50, 50, 0.2]])
    curves = [{"kind": "vertical_line", "view": 0, "direction": "vertical", "band": 0,
               "edge": 0, "coord": 1.0, "curve": line},
              {"kind": "horizontal_line", "view": 0, "direction": "horizontal", "band": 0,
               "edge": 0, "coord": 1.0, "curve": NurbsCurve(1, [0, 0, 1, 1],
                                                            [[-90, 0, 0.05], [-10, 0, 0.05]])}]
    return Model(curves=curves, surfaces=surfaces, views=[{"index": 0, "table_angle": 0.0}])


def test_table_against_exact_offsets(truth):
    ev = evaluate_model(_model(), truth, n_coverage=4000)
    r = ev["rows"]
    assert r["gordon"]["n"] == 2
    assert r["gordon"]["mean_mm"] == pytest.approx(0.02, abs=1e-9)
    assert r["gordon"]["std_mm"] == pytest.approx(0.01, abs=1e-9)
    assert r["gordon"]["min_mm"] == pytest.approx(0.01, abs=1e-9)
    assert r["gordon"]["max_mm"] == pytest.approx(0.03, abs=1e-9)
    assert r["horizontal_skin"]["mean_mm"] == pytest.approx(0.04, abs=1e-9)
    assert r["vertical_lines"]["mean_mm"] == pytest.approx(0.1, abs=1e-9)
    assert r["vertical_lines"]["max_sample_mm"] == pytest.approx(0.2, abs=1e-9)
    assert r["horizontal_lines"]["mean_mm"] == pytest.approx(0.05, abs=1e-9)
    assert r["gordon"]["paper"]["mean_mm"] == PAPER["gordon"][0]
    # seen: x in [-100, 0] (half the plane); covered: y in [-100, 50] of it -> 3/4
    assert ev["visible_share"] == pytest.approx(0.5, abs=0.03)
    assert ev["coverage"] == pytest.approx(0.75, abs=0.03)
    assert ev["views"][0]["coverage"] == pytest.approx(0.75, abs=0.03)
    assert ev["views"][0]["gordon"] == pytest.approx(0.02, abs=1e-9)
    md = format_table(ev)
    assert "| Gordon surface | 2 | 0.020000 |" in md
    assert f"{100 * ev['coverage']:.1f} %" in md


def test_entity_errors_shared_with_a_second_process(truth):
    """The samples measured in a spawned process give the same rows as in this one."""
    from nurbscan.evaluate.table import entity_errors
    from nurbscan.io.atomic import read_json
    from nurbscan.simulate.scenes import scene_from_dict

    spec = read_json(truth / "scene.json")
    scene = scene_from_dict(spec)
    one = entity_errors(_model(), scene)
    two = entity_errors(_model(), scene, spec=spec, share=0.45)
    for row in one:
        for k in ("mean", "max", "view"):
            assert np.array_equal(one[row][k], two[row][k]), (row, k)
    assert one["gordon"]["mean"] == pytest.approx([0.01, 0.03], abs=1e-9)


def test_evaluate_cli_files(truth, tmp_path, capsys):
    from nurbscan.cli import main

    _model().save(tmp_path / "model")
    assert main(["evaluate", str(tmp_path / "model"), "--truth", str(truth)]) == 0
    out = capsys.readouterr().out
    assert "Gordon surface" in out
    ev = json.loads((tmp_path / "model" / "evaluation.json").read_text())
    assert set(ev["rows"]) == {"horizontal_lines", "vertical_lines", "horizontal_skin",
                               "vertical_skin", "gordon"}
    for row in ev["rows"].values():
        assert {"mean_mm", "std_mm", "min_mm", "max_mm"} <= set(row)
    assert 0.0 <= ev["coverage"] <= 1.0
    assert (tmp_path / "model" / "evaluation.md").read_text().startswith("# Reconstruction")


def test_evaluate_missing_truth(tmp_path):
    with pytest.raises(NurbscanError, match="scene.json"):
        evaluate_model(_model(), tmp_path)


def test_empty_rows(truth):
    m = _model()
    m.curves = []
    ev = evaluate_model(m, truth, n_coverage=500)
    row = ev["rows"]["vertical_lines"]
    assert row["n"] == 0 and row["mean_mm"] is None
    assert "| vertical grid lines | 0 | - |" in format_table(ev)
