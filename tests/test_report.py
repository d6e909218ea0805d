"""The HTML scan report (issue 8): contents, no network, and a headless-Chromium screenshot
showing the 3-D model drawn."""

from __future__ import annotations

import base64
import json
import re
import subprocess
from pathlib import Path

import cv2
import numpy as np
import pytest

from _export_fixtures import CENTRE, R, make_folders
from nurbscan.cli import main
from nurbscan.report import build_report, detect_overlays, error_colours, write_report

CHROMIUM = Path("/usr/bin/chromium")


@pytest.fixture(scope="module")
def model_dir(tmp_path_factory):
    folder = make_folders(tmp_path_factory.mktemp("report"))
    ev = {"type": "nurbscan.evaluation", "version": 1, "coverage": 0.4321,
          "coverage_tolerance_mm": 0.5,
          "rows": {"gordon": {"n": 4, "mean_mm": 0.0123, "std_mm": 0.002, "min_mm": 0.01,
                              "max_mm": 0.02, "max_sample_mm": 0.05, "label": "Gordon surface",
                              "paper": {"mean_mm": 0.030582, "std_mm": 0.0391224,
                                        "min_mm": 2.17415e-05, "max_mm": 1.05252}}},
          "views": [{"index": 0, "gordon": 0.011, "coverage": 0.2}]}
    (folder / "evaluation.json").write_text(json.dumps(ev))
    ov = np.zeros((300, 1200, 3), np.uint8)
    ov[:, ::7] = (0, 0, 255)
    cv2.imwrite(str(folder / "view_00_overlay.png"), ov)
    return folder


def _glb(page: str, name: str) -> bytes:
    m = re.search(rf'<script type="application/octet-stream" id="glb-{name}">([^<]*)<', page)
    assert m, name
    return base64.b64decode(m.group(1))


def _colours(glb: bytes) -> tuple[np.ndarray, np.ndarray]:
    """Vertex positions (m) and RGBA colours of the first primitive of a GLB."""
    n = int.from_bytes(glb[12:16], "little")
    doc = json.loads(glb[20:20 + n])
    binary = glb[28 + n:]
    prim = doc["meshes"][0]["primitives"][0]["attributes"]

    def acc(i, dtype, comps):
        a = doc["accessors"][i]
        bv = doc["bufferViews"][a["bufferView"]]
        off = bv.get("byteOffset", 0) + a.get("byteOffset", 0)
        return np.frombuffer(binary, dtype, a["count"] * comps, off).reshape(-1, comps)

    return acc(prim["POSITION"], np.float32, 3), acc(prim["COLOR_0"], np.uint8, 4)


def test_report_contents(model_dir):
    page = build_report(model_dir)
    assert page.startswith("<!doctype html>")
    # self-contained: no external resources
    assert not re.search(r'(src|href)\s*=\s*["\']?(https?:)?//', page)
    assert "import(" not in page.split("<script type=module>")[1].split("</script>")[0]
    # the accuracy table beside the paper's figures, and the coverage
    assert "Gordon surface" in page and "0.0123" in page and "0.0306" in page
    assert "43.2%" in page
    # the overlay, downscaled to 640 px wide
    uris = re.findall(r"src='data:image/png;base64,([^']+)'", page)
    assert len(uris) == 2  # overlay + model picture
    ov = cv2.imdecode(np.frombuffer(base64.b64decode(uris[0]), np.uint8), cv2.IMREAD_COLOR)
    assert ov.shape == (160, 640, 3)
    # heat map: the truth is a sphere of radius R + 0.1, the mesh's vertices lie on radius R
    pos, col = _colours(_glb(page, "error"))
    assert np.allclose(np.linalg.norm(pos / 0.001 - CENTRE, axis=1), R, atol=1e-3)
    assert "mean 0.1000 mm" in page
    assert np.array_equal(col, np.repeat(error_colours(np.array([0.1]), 0.1), len(col), 0))
    pos2, col2 = _colours(_glb(page, "colour"))
    assert np.array_equal(pos, pos2) and len(np.unique(col2[:, :3], axis=0)) > 4
    assert "data:text/javascript;base64," in page


def test_error_colours_ramp():
    c = error_colours(np.array([0.0, 0.5, 1.0, 3.0]), 1.0)
    assert c[0, :3].tolist() == [49, 54, 149] and c[-1, :3].tolist() == [215, 48, 39]
    assert c[2].tolist() == c[3].tolist()  # clipped at vmax
    assert c[1, :3].tolist() == [116, 196, 118]


def test_cli_report_without_evaluation_or_truth(model_dir, tmp_path, capsys):
    import shutil as sh

    m = tmp_path / "model"
    sh.copytree(model_dir, m)
    (m / "evaluation.json").unlink()
    out = tmp_path / "r.html"
    assert main(["report", str(m), "-o", str(out), "--no-heat-map"]) == 0
    page = out.read_text()
    assert "Accuracy" not in page and 'id="glb-error"' not in page
    assert "no ground truth found" in page
    assert main(["report", str(tmp_path / "missing"), "-o", str(tmp_path / "x.html")]) == 2
    assert not (tmp_path / "x.html").exists()


def _screenshot(html: Path, png: Path, tmp: Path) -> None:
    cmd = [str(CHROMIUM), "--headless", "--no-sandbox", "--disable-gpu", "--use-gl=swiftshader",
           "--enable-unsafe-swiftshader", "--disable-quic", "--no-first-run",
           "--disable-background-networking", "--disable-component-update", "--disable-sync",
           f"--user-data-dir={tmp}", f"--screenshot={png}", "--window-size=800,600",
           "--virtual-time-budget=5000", html.resolve().as_uri()]
    subprocess.run(cmd, capture_output=True, timeout=120, check=False)
    assert png.is_file(), "chromium wrote no screenshot"


@pytest.mark.skipif(not CHROMIUM.exists(),
                    reason="/usr/bin/chromium missing (apt-get install -y chromium)")
def test_report_draws_the_model_in_headless_chromium(model_dir, tmp_path):
    html = write_report(model_dir, tmp_path / "report.html")
    png = tmp_path / "shot.png"
    _screenshot(html, png, tmp_path / "profile")
    img = cv2.imread(str(png), cv2.IMREAD_COLOR)
    assert img.shape[:2] == (600, 800)
    # the viewer is the first section: 440 px high below the header, background #1d2229
    view = img[70:470, 40:740].reshape(-1, 3).astype(int)
    bg = np.array([0x29, 0x22, 0x1D])  # BGR
    drawn = np.abs(view - bg).max(1) > 12
    assert drawn.mean() > 0.03, f"model covers {drawn.mean():.3%} of the canvas"
    assert len(np.unique(view[drawn], axis=0)) > 50  # shaded, coloured surface
    # a page whose viewer cannot start stays blank there (the check can fail)
    broken = tmp_path / "broken.html"
    broken.write_text(html.read_text().replace('"three":', '"three-x":'))
    _screenshot(broken, tmp_path / "blank.png", tmp_path / "profile2")
    blank = cv2.imread(str(tmp_path / "blank.png"), cv2.IMREAD_COLOR)[70:470, 40:740]
    assert (np.abs(blank.reshape(-1, 3).astype(int) - bg).max(1) > 12).mean() < 0.001



def test_overlays_detected_from_a_simulated_scan(tmp_path):
    scan = tmp_path / "scan"
    assert main(["simulate", "teapot", "-o", str(scan), "--views", "1", "--width", "768",
                 "--height", "576", "--no-calibration"]) == 0
    ov = detect_overlays(scan)
    assert len(ov) == 1
    name, uri = ov[0]
    n_lines = int(re.match(r"view 0: (\d+) lines", name).group(1))
    assert n_lines > 200  # the teapot at 768 x 576 shows some 400 edge lines
    img = cv2.imdecode(np.frombuffer(base64.b64decode(uri.split(",", 1)[1]), np.uint8),
                       cv2.IMREAD_COLOR)
    assert img.shape == (480, 640, 3)
    hsv = cv2.cvtColor(img, cv2.COLOR_BGR2HSV)
    vivid = (hsv[..., 1] > 150) & (hsv[..., 2] > 150)  # lines drawn in the band colours
    assert vivid.mean() > 0.01
    # without a scan.json sidecar pattern, nothing is detected
    (scan / "pattern.json").unlink()
    assert detect_overlays(scan) == []
