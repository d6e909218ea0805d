"""Benchmark of ``nurbscan.export`` and the report (issue 8).

``bench()`` builds a synthetic model folder of 200 Gordon patches (a 10 x 20 tiling of a wavy
height field, each patch bicubic with 8 x 8 control points, 5 x 5 knot spans) and 400 cubic
curves (10 control points), then times the export to each format (median of
``$NURBSCAN_BENCH_REPEAT`` runs, default 3; meshes neutral-coloured: the model has no scan) and
the HTML report, with output sizes and the mesh's counts.
"""

from __future__ import annotations

import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from nurbscan.export import FORMATS, build_mesh, export_model, load_model
from nurbscan.nurbs import NurbsCurve, NurbsSurface
from nurbscan.reconstruct import Model

N_U, N_V = 10, 20


def synthetic_model() -> Model:
    """200 bicubic Gordon patches and 400 cubic curves on ``z = 10 sin(x/40) cos(y/30)`` (mm)."""
    U = np.array([0, 0, 0, 0, 0.2, 0.4, 0.6, 0.8, 1, 1, 1, 1])
    g = np.linspace(0, 1, 8)
    surfaces, curves = [], []
    for i in range(N_U):
        for j in range(N_V):
            x = (i + g) * 25.0
            y = (j + g) * 25.0
            X, Y = np.meshgrid(x, y, indexing="ij")
            Z = 10 * np.sin(X / 40) * np.cos(Y / 30)
            s = NurbsSurface(3, 3, U, U, np.stack([X, Y, Z], -1))
            surfaces.append({"kind": "gordon", "view": 0, "patch": len(surfaces),
                             "vertical": [0, 1], "horizontal": [0, 1], "n_curves": [8, 8],
                             "surface": s})
            for k, line in enumerate((np.stack([X[:, 0], Y[:, 0], Z[:, 0]], 1),
                                      np.stack([X[0], Y[0], Z[0]], 1))):
                P = np.array([np.interp(np.linspace(0, 1, 10), g, line[:, d])
                              for d in range(3)]).T
                c = NurbsCurve(3, [0, 0, 0, 0, 1 / 7, 2 / 7, 3 / 7, 4 / 7, 5 / 7, 6 / 7,
                                   1, 1, 1, 1], P)
                curves.append({"kind": ("horizontal_line", "vertical_line")[k], "view": 0,
                               "direction": ("horizontal", "vertical")[k], "band": len(curves),
                               "edge": 0, "coord": float(len(curves)), "curve": c})
    return Model(curves=curves, surfaces=surfaces, views=[{"index": 0, "table_angle": 0.0}])


def bench() -> dict:
    """Export times (s, median), file sizes (bytes) and mesh counts."""
    from nurbscan.report import write_report

    repeat = int(os.environ.get("NURBSCAN_BENCH_REPEAT", "3"))
    out: dict = {"model": f"{N_U * N_V} Gordon patches (8 x 8 bicubic), {2 * N_U * N_V} "
                          "cubic curves", "repeat": repeat}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        synthetic_model().save(tmp / "model")
        t0 = time.perf_counter()
        model = load_model(tmp / "model")
        out["load model s"] = round(time.perf_counter() - t0, 4)
        t0 = time.perf_counter()
        mesh = build_mesh(model, per_span=4)
        out["mesh (per_span 4) s"] = round(time.perf_counter() - t0, 4)
        out["mesh vertices"] = mesh.info["vertices"]
        out["mesh faces"] = mesh.info["faces"]
        for fmt in FORMATS:
            times = []
            for _ in range(repeat):
                t0 = time.perf_counter()
                path = export_model(model, tmp / f"m.{fmt}", fmt)
                times.append(time.perf_counter() - t0)
            out[f"export {fmt}"] = {"median s": round(statistics.median(times), 4),
                                    "bytes": path.stat().st_size}
        t0 = time.perf_counter()
        page = write_report(tmp / "model", tmp / "report.html")
        out["report"] = {"s": round(time.perf_counter() - t0, 4), "bytes": page.stat().st_size}
    return out


if __name__ == "__main__":
    import json

    json.dump(bench(), sys.stdout, indent=1)
    print()
