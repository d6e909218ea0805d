"""STEP (ISO 10303-21, AP214) writer of the CAD surface set, through OpenCASCADE (OCP).

Each surface becomes a ``Geom_BSplineSurface`` (distinct knots and multiplicities, poles and
weights; OCP's arrays are 1-based) and a face bounded by its natural boundary
(``BRepBuilderAPI_MakeFace``); the faces are sewn into shells (``BRepBuilderAPI_Sewing``:
edges within ``tolerance`` mm are joined) and written with ``STEPControl_Writer`` in mm.
The CAD set of a model with a fused mesh is written as :func:`seamed_faces`: one face per
region of the fused mesh (:func:`nurbscan.merge.cad.seams`), each seam one 3-D B-spline edge
used by both faces, so that the faces form shells by construction.
OCP is the optional extra ``nurbscan[cad]`` (``cadquery-ocp-novtk``).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..errors import NurbscanError
from ..io.atomic import atomic_path
from ..nurbs import NurbsSurface

__all__ = ["occ_face", "occ_surface", "seamed_faces", "sew_faces", "shell_count", "trimmed_faces",
           "write_step"]

#: Sewing tolerance of seamed faces, mm: the seams' vertices lie up to
#: ``SeamOptions.on_mm`` (0.1) from each side's surface (up to ``fill_mm``, 0.2, where a gap was
#: closed: those edges carry their own tolerance).
SEAM_TOLERANCE = 0.1

OCP_MISSING = ("STEP export needs OpenCASCADE (OCP): pip install 'nurbscan[cad]' "
               "(cadquery-ocp-novtk)")


def _ocp():
    """Import check: a one-line error when OCP is missing."""
    try:
        import OCP  # noqa: F401
    except ImportError:
        raise NurbscanError(OCP_MISSING) from None


def _knots(U: np.ndarray):
    from OCP.collections import Array1_double, Array1_int

    vals, mults = np.unique(np.asarray(U, float), return_counts=True)
    k = Array1_double(1, len(vals))
    m = Array1_int(1, len(vals))
    for i, (x, c) in enumerate(zip(vals, mults, strict=True)):
        k.SetValue(i + 1, float(x))
        m.SetValue(i + 1, int(c))
    return k, m


def occ_surface(s: NurbsSurface):
    """The ``Geom_BSplineSurface`` equal to ``s``."""
    _ocp()
    from OCP.collections import Array2_double, Array2_gp_Pnt
    from OCP.Geom import Geom_BSplineSurface
    from OCP.gp import gp_Pnt

    P = np.asarray(s.control_points, float)
    nu, nv = P.shape[:2]
    poles = Array2_gp_Pnt(1, nu, 1, nv)
    for i in range(nu):
        for j in range(nv):
            poles.SetValue(i + 1, j + 1, gp_Pnt(*map(float, P[i, j])))
    ku, mu = _knots(s.knots_u)
    kv, mv = _knots(s.knots_v)
    if s.is_rational:
        W = np.asarray(s.weights, float)
        w = Array2_double(1, nu, 1, nv)
        for i in range(nu):
            for j in range(nv):
                w.SetValue(i + 1, j + 1, float(W[i, j]))
        g = Geom_BSplineSurface(poles, w, ku, kv, mu, mv, s.degree_u, s.degree_v)
    else:
        g = Geom_BSplineSurface(poles, ku, kv, mu, mv, s.degree_u, s.degree_v)
    return g


def occ_face(s: NurbsSurface):
    """A ``TopoDS_Face`` on the B-spline surface equal to ``s`` (natural boundary)."""
    from OCP.BRepBuilderAPI import BRepBuilderAPI_MakeFace

    mk = BRepBuilderAPI_MakeFace(occ_surface(s), 1e-6)
    if not mk.IsDone():
        raise NurbscanError("STEP export: OpenCASCADE could not make a face of a surface")
    return mk.Face()


def trimmed_faces(s: NurbsSurface, u: np.ndarray, v: np.ndarray, keep: np.ndarray) -> list:
    """``TopoDS_Face`` s of the kept cells of ``s``: one face per 4-connected region of
    ``keep`` (nu, nv), on the whole surface, bounded by the region's outline in the parameter
    plane (cell boundaries ``u`` (nu + 1,), ``v`` (nv + 1,); holes as inner wires).

    Each outline segment is an edge given by its pcurve (a ``Geom2d_Line`` on the surface)
    between shared vertices; the 3-D curves are computed from the pcurves
    (``BRepLib::BuildCurves3d``), and ``ShapeFix_Face`` settles the wires' orientation.
    """
    from OCP.BRep import BRep_Builder
    from OCP.BRepBuilderAPI import (
        BRepBuilderAPI_MakeEdge,
        BRepBuilderAPI_MakeFace,
        BRepBuilderAPI_MakeVertex,
        BRepBuilderAPI_MakeWire,
    )
    from OCP.BRepLib import BRepLib
    from OCP.Geom2d import Geom2d_Line
    from OCP.gp import gp_Dir2d, gp_Pnt, gp_Pnt2d
    from OCP.ShapeFix import ShapeFix_Face

    from ..merge.cad import outline

    g = occ_surface(s)
    u, v = np.asarray(u, float), np.asarray(v, float)

    def wire(loop):
        uv = np.column_stack([u[loop[:, 0]], v[loop[:, 1]]])
        X = s.evaluate(uv[:, 0], uv[:, 1])
        verts = [BRepBuilderAPI_MakeVertex(gp_Pnt(*map(float, x))).Vertex() for x in X]
        same = np.linalg.norm(X - np.roll(X, -1, axis=0), axis=1) < 1e-9
        for k in np.flatnonzero(same[:-1]):  # a pole: one vertex for a degenerate side
            verts[k + 1] = verts[k]
        if same[-1]:
            verts[0] = verts[-1]
        mw = BRepBuilderAPI_MakeWire()
        for k in range(len(uv)):
            a, b = uv[k], uv[(k + 1) % len(uv)]
            d = b - a
            length = float(np.hypot(*d))
            line = Geom2d_Line(gp_Pnt2d(float(a[0]), float(a[1])),
                               gp_Dir2d(float(d[0]), float(d[1])))
            e = BRepBuilderAPI_MakeEdge(line, g, verts[k], verts[(k + 1) % len(uv)], 0.0,
                                        length)
            if not e.IsDone():
                raise NurbscanError("STEP export: OpenCASCADE could not make a trimming edge")
            edge = e.Edge()
            if same[k]:
                BRep_Builder().Degenerated(edge, True)
            mw.Add(edge)
        if not mw.IsDone():
            raise NurbscanError("STEP export: OpenCASCADE could not make a trimming wire")
        return mw.Wire()

    faces = []
    for outer, holes in outline(np.asarray(keep, bool)):
        mk = BRepBuilderAPI_MakeFace(g, wire(outer), True)
        for h in holes:
            mk.Add(wire(h))
        if not mk.IsDone():
            raise NurbscanError("STEP export: OpenCASCADE could not make a trimmed face")
        f = mk.Face()
        BRepLib.BuildCurves3d_s(f)
        fix = ShapeFix_Face(f)
        fix.Perform()
        faces.append(fix.Face())
    return faces


def _seam_curve(X: np.ndarray, smooth: int, tol: float):
    """A ``Geom_BSplineCurve`` through the polyline ``X`` (n, 3): its inner points smoothed
    (``smooth`` rounds of the mean of each point and its two neighbours, ends fixed), then
    approximated (``GeomAPI_PointsToBSpline``, cubic, C2, within ``tol`` mm)."""
    from OCP.collections import Array1_gp_Pnt
    from OCP.GeomAbs import GeomAbs_C2
    from OCP.GeomAPI import GeomAPI_PointsToBSpline
    from OCP.gp import gp_Pnt

    X = np.array(X, float)
    for _ in range(smooth if len(X) > 2 else 0):
        X[1:-1] = (X[:-2] + X[1:-1] + X[2:]) / 3.0
    if len(X) == 2:
        X = np.array([X[0], 0.5 * (X[0] + X[1]), X[1]])
    arr = Array1_gp_Pnt(1, len(X))
    for i, x in enumerate(X):
        arr.SetValue(i + 1, gp_Pnt(*map(float, x)))
    fit = GeomAPI_PointsToBSpline(arr, 3 if len(X) > 3 else 2, 8, GeomAbs_C2, tol)
    if not fit.IsDone():
        raise NurbscanError("STEP export: OpenCASCADE could not fit a seam curve")
    return fit.Curve()


def seamed_faces(seams, patches, smooth: int = 3, tol: float = 0.02) -> list:
    """``TopoDS_Face`` s of the fused mesh's regions (:func:`nurbscan.merge.cad.seams`), each
    on its Gordon surface, bounded by seams that are ONE edge shared by the faces either side.

    Every chain (a polyline along the fused mesh between junctions) becomes one 3-D
    B-spline edge (:func:`_seam_curve`: smoothed, ``GeomAPI_PointsToBSpline`` within ``tol``
    mm) between vertices shared at the junctions. Each region's loops are wires of those
    edges (reversed where the region lies on the chain's right); the face is
    ``BRepBuilderAPI_MakeFace(surface, outer wire)`` plus its holes' wires reversed (OCC's
    convention for ``MakeFace.Add``), and ``ShapeFix_Face`` adds the pcurves (projection of
    each 3-D edge onto the face's surface) and sets the edges' tolerances to the distance
    between the curve and the surface (at most about ``SeamOptions.on_mm`` plus ``tol``).
    The faces share their edges; sewing (:func:`sew_faces`) only joins them into shells.

    Parameters
    ----------
    seams : nurbscan.merge.cad.Seams
    patches : list of dict
        ``CadSet.patches`` (``surface`` per region label).
    smooth, tol : int, float
        See :func:`_seam_curve`.

    Returns
    -------
    list of TopoDS_Face
        One per region, in the order of ``sorted(seams.loops)``.
    """
    from OCP.BRepBuilderAPI import (
        BRepBuilderAPI_MakeEdge,
        BRepBuilderAPI_MakeFace,
        BRepBuilderAPI_MakeVertex,
        BRepBuilderAPI_MakeWire,
    )
    from OCP.gp import gp_Pnt
    from OCP.ShapeFix import ShapeFix_Face
    from OCP.TopoDS import TopoDS

    V = seams.points
    ends = np.unique(np.concatenate([[c[0], c[-1]] for c in seams.chains]))
    verts = {int(i): BRepBuilderAPI_MakeVertex(gp_Pnt(*map(float, V[i]))).Vertex()
             for i in ends}
    edges = []
    for c in seams.chains:
        e = BRepBuilderAPI_MakeEdge(_seam_curve(V[c], smooth, tol), verts[int(c[0])],
                                    verts[int(c[-1])])
        if not e.IsDone():
            raise NurbscanError("STEP export: OpenCASCADE could not make a seam edge")
        edges.append(e.Edge())
    faces = []
    for region, loops in sorted(seams.loops.items()):
        g = occ_surface(patches[region]["surface"])
        wires = []
        for k, loop in enumerate(loops):
            mw = BRepBuilderAPI_MakeWire()
            for c, fwd in loop:
                mw.Add(edges[c] if fwd else TopoDS.Edge(edges[c].Reversed()))
            if not mw.IsDone():
                raise NurbscanError("STEP export: OpenCASCADE could not make a seam wire")
            wires.append(mw.Wire() if k == 0 else TopoDS.Wire(mw.Wire().Reversed()))
        mk = BRepBuilderAPI_MakeFace(g, wires[0], True)
        for w in wires[1:]:
            mk.Add(w)
        if not mk.IsDone():
            raise NurbscanError("STEP export: OpenCASCADE could not make a seamed face")
        sf = ShapeFix_Face(mk.Face())
        sf.Perform()
        faces.append(sf.Face())
    return faces


def sew_faces(faces, tolerance: float = 0.05):
    """The faces sewn (``BRepBuilderAPI_Sewing``, edges closer than ``tolerance`` mm
    joined); returns the sewn shape (a shell, or a compound of shells and faces)."""
    from OCP.BRepBuilderAPI import BRepBuilderAPI_Sewing

    sew = BRepBuilderAPI_Sewing(tolerance)
    for f in faces:
        sew.Add(f)
    sew.Perform()
    return sew.SewedShape()


def shell_count(shape) -> tuple[int, int]:
    """``(shells, faces not in a shell)`` of a shape."""
    from OCP.TopAbs import TopAbs_FACE, TopAbs_SHELL
    from OCP.TopExp import TopExp_Explorer

    shells, in_shells = 0, 0
    ex = TopExp_Explorer(shape, TopAbs_SHELL)
    while ex.More():
        shells += 1
        fx = TopExp_Explorer(ex.Current(), TopAbs_FACE)
        while fx.More():
            in_shells += 1
            fx.Next()
        ex.Next()
    faces = 0
    fx = TopExp_Explorer(shape, TopAbs_FACE)
    while fx.More():
        faces += 1
        fx.Next()
    return shells, faces - in_shells


def write_step(path: str | os.PathLike, surfaces=(), tolerance: float = 0.05,
               progress=None, trimmed=(), seamed=None) -> Path:
    """Write surfaces and trimmed surfaces, sewn into shells, as a STEP file (mm) atomically.

    Parameters
    ----------
    path : path-like
    surfaces : iterable of NurbsSurface
        Faces with their natural boundary.
    tolerance : float
        Sewing tolerance, mm.
    progress : callable, optional
    trimmed : iterable of dict
        Trimmed faces: ``surface``, ``u``, ``v``, ``keep`` as in
        :attr:`nurbscan.merge.cad.CadSet.patches` (:func:`trimmed_faces`).
    seamed : tuple, optional
        ``(seams, patches)``: the fused mesh's regions (:func:`nurbscan.merge.cad.seams`)
        and ``CadSet.patches``, as faces with shared seams (:func:`seamed_faces`), sewn at
        ``max(tolerance, SEAM_TOLERANCE)``.
    """
    _ocp()
    from OCP.IFSelect import IFSelect_RetDone
    from OCP.Interface import Interface_Static
    from OCP.STEPControl import STEPControl_AsIs, STEPControl_Writer

    say = progress or (lambda _m: None)
    faces = [occ_face(s) for s in surfaces]
    for p in trimmed:
        faces += trimmed_faces(p["surface"], p["u"], p["v"], p["keep"])
    if seamed is not None:
        faces += seamed_faces(*seamed)
        tolerance = max(tolerance, SEAM_TOLERANCE)
    if not faces:
        raise NurbscanError("STEP export: nothing to write (no surfaces)")
    say(f"STEP: sewing {len(faces)} faces (tolerance {tolerance:g} mm)")
    shape = sew_faces(faces, tolerance)
    shells, loose = shell_count(shape)
    say(f"STEP: {shells} shells, {loose} faces in none")
    Interface_Static.SetCVal_s("write.step.unit", "MM")
    w = STEPControl_Writer()
    w.Transfer(shape, STEPControl_AsIs)
    path = Path(path)
    with atomic_path(path) as tmp:
        if w.Write(str(tmp)) != IFSelect_RetDone:
            raise NurbscanError(f"{path}: OpenCASCADE failed to write the STEP file")
    return path
