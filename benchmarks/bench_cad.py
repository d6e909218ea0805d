"""Benchmark of the CAD surface set and its STEP file (issue 32, ``nurbscan.merge.cad``).

``bench()`` takes a model folder (``$NURBSCAN_BENCH_CAD_MODEL``; default: a fresh
``nurbscan demo --width 1024 --height 768`` in a temporary folder, about 2 minutes) and
writes its STEP file into a temporary folder by the path of ``nurbscan export MODEL --format
step`` (:func:`nurbscan.export.export_model`: the CAD set, :func:`nurbscan.merge.cad.cad_set`,
then with a fused mesh the seamed faces of :func:`nurbscan.merge.cad.seams`); the model
folder is only read. Then measures:

* the CAD set: surfaces (rectangles, 3dm/igs), kept patches and cells, area; ``cad_set``'s
  CPU time and the whole export's (wall and CPU of this process, s), the file's size;
* the STEP read back by OpenCASCADE (``STEPControl_Reader``): faces, shells
  (:func:`nurbscan.export.step.shell_count`, and faces in none), faces invalid
  (``BRepCheck_Analyzer`` per face), edges of one face (free), of two, of three or more, the
  faces' area (``BRepGProp``) over the CAD set's;
* the overlap between the CAD surfaces (:func:`nurbscan.merge.cad.overlap_area`, 12 x 12
  samples per surface inverted onto the others, 0.1 mm) as a share of their area (target
  under 1 %);
* when the scan has its truth (``$NURBSCAN_BENCH_CAD_TRUTH``, default ``MODEL/../scan/truth``)
  the CAD row of ``nurbscan evaluate --cad`` (:func:`nurbscan.evaluate.table.cad_row` of the
  same CAD set: 3 x 3 samples per kept cell, exact distances to the true surface): worst
  sample (target <= 0.2 mm), samples and cells over 0.2 mm, mean, p99.
"""

from __future__ import annotations

import json
import os
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _model(tmp: Path) -> Path:
    env = os.environ.get("NURBSCAN_BENCH_CAD_MODEL")
    if env:
        return Path(env)
    from nurbscan.cli import main

    demo = tmp / "demo"
    if main(["demo", "--width", "1024", "--height", "768", "-o", str(demo)]) != 0:
        raise RuntimeError(f"nurbscan demo -o {demo} failed")
    return demo / "model"


def _read_back(path: Path) -> dict:
    """Faces, shells, invalid faces, edges by their number of faces, area of a STEP file."""
    from OCP.BRepCheck import BRepCheck_Analyzer
    from OCP.BRepGProp import BRepGProp
    from OCP.collections import (
        IndexedDataMap_TopoDS_Shape_List_TopoDS_Shape_TopTools_ShapeMapHasher as EdgeFaces,
    )
    from OCP.GProp import GProp_GProps
    from OCP.IFSelect import IFSelect_RetDone
    from OCP.STEPControl import STEPControl_Reader
    from OCP.TopAbs import TopAbs_EDGE, TopAbs_FACE
    from OCP.TopExp import TopExp, TopExp_Explorer
    from OCP.TopoDS import TopoDS

    from nurbscan.export.step import shell_count

    rd = STEPControl_Reader()
    if rd.ReadFile(str(path)) != IFSelect_RetDone:
        return {"error": f"STEPControl_Reader could not read {path.name}"}
    rd.TransferRoots()
    shape = rd.OneShape()
    faces, ex = [], TopExp_Explorer(shape, TopAbs_FACE)
    while ex.More():
        faces.append(TopoDS.Face(ex.Current()))
        ex.Next()
    shells, loose = shell_count(shape)
    emap = EdgeFaces()
    TopExp.MapShapesAndAncestors_s(shape, TopAbs_EDGE, TopAbs_FACE, emap)
    n = [emap.FindFromIndex(i).Size() for i in range(1, emap.Extent() + 1)]
    g = GProp_GProps()
    BRepGProp.SurfaceProperties_s(shape, g)
    return {"faces": len(faces), "shells": shells, "faces in no shell": loose,
            "faces invalid": sum(not BRepCheck_Analyzer(f).IsValid() for f in faces),
            "edges": len(n), "edges of one face (free)": sum(k == 1 for k in n),
            "edges of two faces": sum(k == 2 for k in n),
            "edges of three or more": sum(k >= 3 for k in n), "area mm2": round(g.Mass(), 1)}


def bench() -> dict:
    """The CAD set's and its STEP file's figures (see the module docstring)."""
    import nurbscan.merge.cad as cad_mod
    from nurbscan.evaluate.table import cad_row
    from nurbscan.export import export_model, load_model
    from nurbscan.io.atomic import read_json
    from nurbscan.merge.cad import overlap_area
    from nurbscan.simulate.scenes import scene_from_dict

    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        folder = _model(tmp)
        out: dict = {"model": str(folder)}
        model = load_model(folder)
        # the export's own CAD set, kept for the other figures (built once)
        made, cad_set = {}, cad_mod.cad_set

        def keep(*a, **k):
            c0 = time.process_time()
            made["cad"] = cad_set(*a, **k)
            made["cpu"] = time.process_time() - c0
            return made["cad"]

        cad_mod.cad_set = keep
        try:
            t0, c0 = time.perf_counter(), time.process_time()
            path = export_model(model, tmp / "model.step", "step",
                                progress=lambda m: print(m, file=sys.stderr, flush=True))
            wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        finally:
            cad_mod.cad_set = cad_set
        cad = made["cad"]
        out["cad set"] = {"surfaces (3dm/igs rectangles)": len(cad.surfaces),
                          "patches kept": len(cad.patches),
                          "cells kept": cad.info.get("cells_kept"),
                          "area mm2": round(cad.info["area_mm2"], 1),
                          "cad_set cpu s": round(made["cpu"], 1)}
        out["export step"] = {"wall s": round(wall, 1), "cpu s": round(cpu, 1),
                              "MB": round(path.stat().st_size / 1e6, 2),
                              "fused mesh": getattr(model, "fused", None) is not None}
        back = _read_back(path)
        if "area mm2" in back:
            back["area / CAD set"] = round(back["area mm2"] / cad.info["area_mm2"], 4)
        out["step read back"] = back
        c0 = time.process_time()
        ov = overlap_area(cad.surfaces, tol=0.1)
        out["overlap"] = {"overlap mm2": round(ov["overlap_mm2"], 2),
                          "area mm2": round(ov["area_mm2"], 1), "share": round(ov["share"], 6),
                          "cpu s": round(time.process_time() - c0, 1)}
        truth = Path(os.environ.get("NURBSCAN_BENCH_CAD_TRUTH",
                                    folder.parent / "scan" / "truth"))
        if (truth / "scene.json").is_file():
            c0 = time.process_time()
            row = cad_row(cad, scene_from_dict(read_json(truth / "scene.json")))
            out["evaluate --cad"] = {
                "truth": str(truth), "samples": row["n"],
                "worst sample mm": round(row["max_sample_mm"], 4),
                "samples over 0.2 mm": row["over_limit"],
                "cells over 0.2 mm": row["cells_over_limit"],
                "mean mm": round(row["mean_mm"], 5), "p99 mm": round(row["p99_mm"], 4),
                "cpu s": round(time.process_time() - c0, 1)}
        else:
            out["evaluate --cad"] = f"no truth at {truth}"
    return out


if __name__ == "__main__":
    json.dump(bench(), sys.stdout, indent=1)
    print()
