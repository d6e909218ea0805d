"""Exports of a reconstructed model for CAD and VR (issue 8).

* NURBS: Rhino ``.3dm`` (:mod:`.rhino`, rhino3dm), IGES 5.3 (:mod:`.iges`, written by hand:
  entities 126 and 128) and STEP (:mod:`.step`, OpenCASCADE through OCP, the optional extra
  ``nurbscan[cad]``): by default the model's CAD surface set (:func:`nurbscan.merge.cad.cad_set`:
  every part of the covered surface on exactly one surface, cut back to the data; STEP sewn
  into shells), or with ``patches=True`` the per-view curves and surfaces of ``kinds``.
* Meshes (:mod:`.mesh`): ``.glb`` (metres, y up), ``.obj``, ``.ply``, ``.stl`` (millimetres),
  with vertex colours from the scan's white-light images: by default the model's fused mesh
  (``fused.ply``, :mod:`nurbscan.merge.fusion`; fused here when the folder has none), or the
  per-view Gordon patches tessellated (``patches=True``).

:func:`load_model` is the one place that reads a model folder (it uses
:func:`nurbscan.reconstruct.load_model`) and finds its scan, rig and white images.
"""

from __future__ import annotations

import os
from pathlib import Path

from ..errors import NurbscanError
from .iges import iges_text, write_iges
from .mesh import (
    MEMORY_BUDGET,
    MESH_FORMATS,
    MeshResult,
    build_mesh,
    mesh_bytes,
    tessellate,
    write_mesh,
)
from .rhino import to_rhino_curve, to_rhino_surface, write_3dm

__all__ = ["FORMATS", "NURBS_FORMATS", "MESH_FORMATS", "DEFAULT_KINDS", "ALL_KINDS",
           "MeshResult", "build_mesh", "export_model", "find_rig", "find_white_images",
           "find_white_paths", "fused_mesh",
           "iges_text", "load_model", "mesh_bytes", "select", "tessellate", "to_rhino_curve",
           "to_rhino_surface", "write_3dm", "write_iges", "write_mesh"]

NURBS_FORMATS = ("3dm", "igs", "step")
FORMATS = MESH_FORMATS + NURBS_FORMATS
ALL_KINDS = ("horizontal_line", "vertical_line", "horizontal_skin", "vertical_skin", "gordon")
DEFAULT_KINDS = ("horizontal_line", "vertical_line", "gordon")


def load_model(model_dir: str | os.PathLike):
    """Read a model folder (``model.json``, ``points.npz``); see docs/model-format.md."""
    from ..reconstruct import load_model as _load

    m = _load(model_dir)
    m.meta = dict(m.meta)
    m.meta.setdefault("_folder", str(Path(model_dir)))
    return m


def _resolve(name, model) -> Path | None:
    """A path recorded in the model's meta: as given, or relative to the model folder or its
    parent."""
    if not name:
        return None
    p = Path(str(name))
    folder = Path(model.meta.get("_folder", "."))
    folder = folder if folder.is_dir() else folder.parent
    for cand in (p, folder / p, folder.parent / p):
        if cand.exists():
            return cand
    return None


def find_rig(model):
    """The calibrated rig recorded in ``meta.calibration``, or None.

    Never the scan's ``truth/rig.json``: nothing downstream of the images reads the truth (a
    model without its calibration is exported without colour, with a warning by the caller).
    """
    from ..camera import load_rig

    for name in (model.meta.get("calibration"), ):
        p = _resolve(name, model)
        if p is not None and p.is_file():
            try:
                return load_rig(p)
            except NurbscanError:
                pass
    return None


def find_white_images(model) -> dict:
    """``{view index: white image (H, W, 3) float RGB}`` from the scan folder, or {}."""
    from ..io import read_image
    from ..io.atomic import read_json

    scan = _resolve(model.meta.get("source"), model)
    if scan is None or not (scan / "scan.json").is_file():
        return {}
    doc = read_json(scan / "scan.json")
    out = {}
    for v in doc.get("views", []):
        p = scan / str(v.get("white", ""))
        if p.is_file():
            out[int(v["index"])] = read_image(p)
    return out


def find_white_paths(model) -> dict:
    """``{view index: path of the white image}`` from the scan folder, or {}."""
    from ..io.atomic import read_json

    scan = _resolve(model.meta.get("source"), model)
    if scan is None or not (scan / "scan.json").is_file():
        return {}
    doc = read_json(scan / "scan.json")
    return {int(v["index"]): scan / str(v["white"]) for v in doc.get("views", [])
            if v.get("white") and (scan / str(v["white"])).is_file()}


def fused_mesh(model, colour: bool = True, max_triangles: int | None = None,
               progress=None) -> MeshResult:
    """The model's fused mesh as a :class:`MeshResult`: ``model.fused`` when the folder has
    one, else fused now (:func:`nurbscan.merge.fuse_model`, coloured when ``colour`` and the
    scan can be found); decimated to ``max_triangles`` (quadric error, Open3D) when it has
    more, the colours taken from the nearest vertex of the full mesh."""
    import numpy as np
    from scipy.spatial import cKDTree

    from ..merge.fusion import FusionOptions, decimate, fuse_model

    fm = getattr(model, "fused", None)
    if fm is None:
        if progress is not None:
            progress("the model has no fused mesh (fused.ply): fusing its views")
        rig = find_rig(model)
        white = find_white_paths(model) if colour and rig is not None else {}
        opt = FusionOptions() if max_triangles is None else FusionOptions(
            max_triangles=max_triangles)
        fm = fuse_model(model, rig, white, opt, progress=progress)
    V, F, C = fm.vertices, fm.faces, fm.colors
    info = {**fm.info}
    if max_triangles is not None and len(F) > max_triangles:
        V2, F = decimate(V, F, max_triangles)
        C = C[cKDTree(V).query(V2)[1]]
        V = V2
        info.update(vertices=int(len(V)), faces=int(len(F)))
    if not colour:
        C = np.tile(np.array([180, 180, 180, 255], np.uint8), (len(V), 1))
        info["colour"] = "neutral (--no-colour)"
    return MeshResult(V, F, C, np.zeros(len(V), int), info)


def select(model, kinds=DEFAULT_KINDS) -> tuple[list, list]:
    """``(curves, surfaces)`` as lists of ``(kind, geometry)`` of the requested kinds."""
    bad = set(kinds) - set(ALL_KINDS)
    if bad:
        raise NurbscanError(f"kinds: unknown {sorted(bad)}; expected some of {ALL_KINDS}")
    curves = [(c["kind"], c["curve"]) for c in model.curves if c["kind"] in kinds]
    surfaces = [(s["kind"], s["surface"]) for s in model.surfaces if s["kind"] in kinds]
    return curves, surfaces


def export_model(model, path: str | os.PathLike, fmt: str | None = None,
                 kinds=DEFAULT_KINDS, colour: bool = True, per_span: int = 4,
                 points: bool = False, patches: bool = False,
                 max_triangles: int | None = None, progress=None,
                 memory_budget: float | None = MEMORY_BUDGET) -> Path:
    """Export a model (a folder or a loaded Model) to ``path`` in ``fmt`` (default: suffix).

    NURBS formats (3dm, igs, step) hold the model's CAD surface set
    (:func:`nurbscan.merge.cad.cad_set`), or with ``patches`` the per-view curves and surfaces
    of ``kinds`` (step: the surfaces only); mesh formats (glb,
    obj, ply, stl) the fused mesh of the object (:func:`fused_mesh`, at most
    ``max_triangles``), or with ``patches`` the tessellated per-view patches of
    :func:`build_mesh`; coloured from the white-light images when ``colour`` and the scan can
    be found. The file is written atomically. ``memory_budget`` (bytes, None: no limit): a
    tessellation of the patches estimated to need more is refused before it is built
    (:func:`nurbscan.export.mesh.check_memory`).
    """
    path = Path(path)
    fmt = (fmt or path.suffix.lstrip(".")).lower()
    fmt = {"iges": "igs", "stp": "step"}.get(fmt, fmt)
    if fmt not in FORMATS:
        raise NurbscanError(f"format {fmt!r}: expected one of {', '.join(FORMATS)}")
    if points and fmt != "ply":
        raise NurbscanError(f"{path}: the point cloud is written as ply only, not {fmt!r}")
    if not hasattr(model, "surfaces"):
        model = load_model(model)
    if points:
        from .points import write_points

        rig = find_rig(model) if colour else None
        images = find_white_images(model) if colour and rig is not None else {}
        return write_points(model, path, rig, images)
    if fmt in NURBS_FORMATS:
        if patches:
            curves, surfaces = select(model, kinds)
        else:
            from ..merge.cad import cad_set

            if fmt == "step":
                from .step import _ocp

                _ocp()  # before the CAD set's work
            cad = cad_set(model, find_rig(model), progress=progress)
            if fmt == "step":
                from .step import write_step

                fused = getattr(model, "fused", None)
                if fused is not None and len(fused.faces):
                    # one face per region of the fused mesh, seams shared by both sides
                    from ..merge.cad import seams

                    part = seams(cad, fused) if cad.patches else None
                    if part is not None and part.loops:
                        if progress:
                            progress(f"CAD seams: {part.info['regions']} regions, "
                                     f"{part.info['chains']} seams")
                        return write_step(path, seamed=(part, cad.patches), progress=progress)
                # without a fused mesh: one trimmed face per region of a patch's kept cells
                return write_step(path, trimmed=cad.patches, progress=progress)
            curves, surfaces = [], [(f"cad view {d['view']}", d["surface"])
                                    for d in cad.surfaces]
        if fmt == "3dm":
            return write_3dm(path, curves, surfaces)
        if fmt == "step":
            from .step import write_step

            return write_step(path, [s for _, s in surfaces], progress=progress)
        return write_iges(path, [c for _, c in curves], [s for _, s in surfaces])
    if not patches:
        return write_mesh(path, fused_mesh(model, colour, max_triangles, progress), fmt)
    rig = find_rig(model) if colour else None
    images = find_white_images(model) if colour and rig is not None else {}
    mesh = build_mesh(model, rig, images, per_span=per_span, memory_budget=memory_budget)
    return write_mesh(path, mesh, fmt)
