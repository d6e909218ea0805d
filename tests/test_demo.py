"""``nurbscan demo`` end to end at a small size (full size: benchmarks/bench_pipeline.py)."""

import json

from nurbscan.cli import main


def test_small_demo_writes_every_product(tmp_path):
    """Two views at 1024 x 768 px: the same path as ``make demo`` (simulate, calibrate from the
    images, reconstruct, export in the background, evaluate, report). Measured: Gordon mean
    0.023 mm over 34 patches, coverage 2.8 % (bands 3.4 px wide at this size), 36 s."""
    out = tmp_path / "demo"
    assert main(["demo", "-o", str(out), "--views", "2", "--width", "1024",
                 "--height", "768"]) == 0
    for name in ("pattern.png", "scan/scan.json", "calib.json", "model/model.json",
                 "model/model.png", "evaluation.json", "evaluation.md", "teapot.glb",
                 "report.html"):
        assert (out / name).is_file(), name
    ev = json.loads((out / "evaluation.json").read_text())
    assert set(ev["rows"]) == {"horizontal_lines", "vertical_lines", "horizontal_skin",
                               "vertical_skin", "gordon"}
    assert ev["rows"]["gordon"]["n"] >= 10
    assert ev["rows"]["gordon"]["mean_mm"] < 0.05
    assert 0 < ev["coverage"] <= 1
    assert (out / "teapot.glb").read_bytes()[:4] == b"glTF"
    # the report carries the evaluation (Table I beside the paper's)
    html = (out / "report.html").read_text()
    assert "Accuracy (Table I)" in html
    g = ev["rows"]["gordon"]
    assert f"<td>Gordon surface</td><td>{g['n']}</td><td>{g['mean_mm']:.4f}</td>" in html
    # the rig was calibrated from the images, not copied from the truth
    cal = json.loads((out / "calib.json").read_text())
    true = json.loads((out / "scan" / "truth" / "rig.json").read_text())
    f_cal, f_true = cal["camera"]["f"], true["camera"]["f"]
    assert f_cal != f_true and abs(f_cal / f_true - 1) < 0.01
