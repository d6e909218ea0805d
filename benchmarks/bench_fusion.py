"""Benchmark of the fused mesh (issue 32, ``nurbscan.merge.fusion``) on the demo teapot.

``bench()`` takes a demo folder (``$NURBSCAN_FUSION_DEMO``, default ``demo/``: the output of
``nurbscan demo``, with ``model/``, ``calib.json`` and ``scan/``; built with ``nurbscan demo``
when absent, about 4 minutes), copies its model, fuses the views (:func:`fuse_model`, the
calibrated rig, the white images, the default options) and measures against the truth as
``nurbscan evaluate`` does:

* fusion time (wall and CPU of this process, s), triangles, connected parts;
* mean / max distance of the fused mesh to the true surface (100 000 area-uniform samples)
  beside the Gordon patches' Table I mean, and their ratio (target <= 1.2; absolute <= 0.015
  mm);
* coverage of the turntable-visible true surface within 0.5 mm, beside the Gordon patches';
* area of the mesh over the true area it covers (no doubled layer: target within 3 %), and
  over the true area the Gordon patches cover; the tessellated patches' area for comparison;
* the glb: size (target <= 15 MB) and the Khronos glTF-Validator's errors and warnings
  (when node and ``.venv/node/node_modules/gltf-validator`` are there).

Also fuses the triangulated edge points (``samples="edges"``) and reports their accuracy, to
say which samples give the better mesh.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _demo() -> Path:
    demo = Path(os.environ.get("NURBSCAN_FUSION_DEMO", ROOT / "demo"))
    if not (demo / "model" / "model.json").is_file():
        from nurbscan.cli import main

        if main(["demo", "-o", str(demo)]) != 0:
            raise RuntimeError(f"nurbscan demo -o {demo} failed")
    return demo


def _validate(path: Path) -> dict | None:
    node = shutil.which("node")
    modules = ROOT / ".venv" / "node" / "node_modules"
    if node is None or not (modules / "gltf-validator").is_dir():
        return None
    res = subprocess.run([node, str(ROOT / "tests" / "gltf_validate.cjs"), str(path),
                          str(modules)], capture_output=True, text=True, timeout=300)
    if res.returncode != 0:
        return None
    issues = json.loads(res.stdout)["issues"]
    return {"errors": issues["numErrors"], "warnings": issues["numWarnings"]}


def _fuse(model, rig, white, options):
    from nurbscan.merge import fuse_model

    t0, c0 = time.perf_counter(), time.process_time()
    fm = fuse_model(model, rig, white, options,
                    progress=lambda m: print(m, file=sys.stderr, flush=True))
    return fm, round(time.perf_counter() - t0, 2), round(time.process_time() - c0, 2)


def bench() -> dict:
    """The fused mesh's figures on the demo teapot (see the module docstring)."""
    from nurbscan.camera import load_rig
    from nurbscan.evaluate import evaluate_model
    from nurbscan.export import build_mesh, export_model, find_white_paths, load_model
    from nurbscan.merge import FusionOptions

    demo = _demo()
    out: dict = {"demo": str(demo)}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        shutil.copytree(demo / "model", tmp / "model",
                        ignore=shutil.ignore_patterns("overlays", "fused.ply"))
        model = load_model(tmp / "model")
        model.fused = None
        rig = load_rig(demo / "calib.json")
        white = find_white_paths(model)
        fm, wall, cpu = _fuse(model, rig, white, FusionOptions())
        model.fused = fm
        out["fusion"] = {"wall s": wall, "cpu s": cpu, "triangles": fm.info["faces"],
                         "poisson depth": fm.info["poisson_depth"],
                         "trim mm": fm.info["trim_mm"], "pitch mm": fm.info["pitch_mm"],
                         "colour": fm.info["colour"]}
        ev = evaluate_model(model, demo / "scan" / "truth", workers=2)
        f, g = ev["fused"], ev["rows"]["gordon"]
        out["accuracy"] = {"fused mean mm": round(f["mean_mm"], 5),
                           "fused p99 mm": round(f["p99_mm"], 4),
                           "fused max mm": round(f["max_mm"], 4),
                           "gordon mean mm": round(g["mean_mm"], 5),
                           "gordon max sample mm": round(g["max_sample_mm"], 4),
                           "fused / gordon mean": round(f["mean_mm"] / g["mean_mm"], 3)}
        out["coverage"] = {"fused": round(f["coverage"], 4), "gordon": round(ev["coverage"], 4),
                           "fused - gordon": round(f["coverage"] - ev["coverage"], 4)}
        patches = build_mesh(model, per_span=4).trimesh()
        out["area"] = {"fused mm2": round(f["area_mm2"], 1),
                       "true covered by fused mm2": round(f["true_covered_area_mm2"], 1),
                       "fused / true covered": round(f["area_ratio"], 4),
                       "true covered by gordon mm2": round(f["gordon_covered_area_mm2"], 1),
                       "fused / true covered by gordon": round(f["area_ratio_gordon"], 4),
                       "patches mesh / true covered by gordon": round(
                           patches.area / f["gordon_covered_area_mm2"], 3)}
        out["parts"] = f["parts"]
        glb = export_model(model, tmp / "teapot.glb")
        out["glb"] = {"MB": round(glb.stat().st_size / 1e6, 3), "validator": _validate(glb)}
        # the raw triangulated edge points as the samples instead of the Gordon patches
        fe, wall_e, cpu_e = _fuse(model, rig, None, FusionOptions(samples="edges"))
        model.fused = fe
        ev_e = evaluate_model(model, demo / "scan" / "truth", workers=2)
        out["edge samples"] = {"fused mean mm": round(ev_e["fused"]["mean_mm"], 5),
                               "coverage": round(ev_e["fused"]["coverage"], 4),
                               "fused / true covered": round(ev_e["fused"]["area_ratio"], 4),
                               "parts": ev_e["fused"]["parts"], "cpu s": cpu_e}
    return out


if __name__ == "__main__":
    json.dump(bench(), sys.stdout, indent=1)
    print()
