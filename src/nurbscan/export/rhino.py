"""Rhino ``.3dm`` writer through rhino3dm (OpenNURBS).

OpenNURBS stores ``n + p - 1`` knots for ``n`` control points of degree ``p``: the textbook
vector of ``n + p + 1`` knots (Piegl and Tiller eq. 2.1) without its first and last entry.
Rational control points are set homogeneous, ``(w x, w y, w z, w)`` (``ON_4dPoint``).
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from ..errors import NurbscanError
from ..io.atomic import atomic_path_fixed
from ..nurbs import NurbsCurve, NurbsSurface

__all__ = ["to_rhino_curve", "to_rhino_surface", "write_3dm"]


def _rhino():
    try:
        import rhino3dm
    except ImportError as exc:  # pragma: no cover - a declared dependency
        raise NurbscanError(f"3dm export: rhino3dm is not installed ({exc})") from None
    return rhino3dm


def to_rhino_curve(c: NurbsCurve):
    """A ``rhino3dm.NurbsCurve`` equal to ``c`` (3-D; 2-D curves get z = 0)."""
    r = _rhino()
    P = np.asarray(c.control_points, float)
    if P.shape[1] == 2:
        P = np.column_stack([P, np.zeros(len(P))])
    if P.shape[1] != 3:
        raise NurbscanError(f"3dm export: curve of dimension {P.shape[1]}; expected 2 or 3")
    w = np.ones(len(P)) if c.weights is None else np.asarray(c.weights, float)
    rational = bool(np.any(w != 1.0))
    rc = r.NurbsCurve(3, rational, c.degree + 1, len(P))
    U = np.asarray(c.knots, float)[1:-1]
    for k, x in enumerate(U):
        rc.Knots[k] = float(x)
    for k, (p, wk) in enumerate(zip(P * w[:, None], w, strict=True)):
        rc.Points[k] = r.Point4d(float(p[0]), float(p[1]), float(p[2]), float(wk))
    return rc


def to_rhino_surface(s: NurbsSurface):
    """A ``rhino3dm.NurbsSurface`` equal to ``s`` (3-D control points)."""
    r = _rhino()
    P = np.asarray(s.control_points, float)
    if P.shape[2] != 3:
        raise NurbscanError(f"3dm export: surface of dimension {P.shape[2]}; expected 3")
    nu, nv = P.shape[:2]
    w = np.ones((nu, nv)) if s.weights is None else np.asarray(s.weights, float)
    rational = bool(np.any(w != 1.0))
    rs = r.NurbsSurface.Create(3, rational, s.degree_u + 1, s.degree_v + 1, nu, nv)
    for k, x in enumerate(np.asarray(s.knots_u, float)[1:-1]):
        rs.KnotsU[k] = float(x)
    for k, x in enumerate(np.asarray(s.knots_v, float)[1:-1]):
        rs.KnotsV[k] = float(x)
    H = P * w[..., None]
    for i in range(nu):
        for j in range(nv):
            h = H[i, j]
            rs.Points[i, j] = r.Point4d(float(h[0]), float(h[1]), float(h[2]), float(w[i, j]))
    return rs


def _uuid(name: str):
    """A fixed identifier for ``name`` (UUID 5 in nurbscan's namespace): OpenNURBS would draw
    random ones, and two exports of one model would differ."""
    import uuid

    return uuid.uuid5(uuid.NAMESPACE_URL, f"nurbscan:{name}")


def write_3dm(path: str | os.PathLike, curves: Iterable[tuple[str, NurbsCurve]] = (),
              surfaces: Iterable[tuple[str, NurbsSurface]] = (), version: int = 7) -> Path:
    """Write curves and surfaces to a Rhino ``.3dm`` file atomically, one layer per kind.

    Parameters
    ----------
    path : path-like
        Output file.
    curves, surfaces : iterables of (layer name, geometry)
        Geometry in mm (the file's unit system is set to millimetres).
    version : int
        OpenNURBS archive version (7 by default, read by Rhino 7 and later).
    """
    r = _rhino()
    f = r.File3dm()
    f.Settings.ModelUnitSystem = r.UnitSystem.Millimeters
    layers: dict[str, int] = {}

    def layer(name: str) -> int:
        if name not in layers:
            lay = r.Layer()
            lay.Name = name
            lay.Id = _uuid(f"layer/{name}")
            layers[name] = f.Layers.Add(lay)
        return layers[name]

    def attributes(name: str, k: int):
        attr = r.ObjectAttributes()
        attr.LayerIndex = layer(name)
        attr.Id = _uuid(f"object/{k}")  # the same file for the same model (not random ids)
        return attr

    n = 0
    for name, c in curves:
        f.Objects.AddCurve(to_rhino_curve(c), attributes(name, n))
        n += 1
    for name, s in surfaces:
        f.Objects.AddSurface(to_rhino_surface(s), attributes(name, n))
        n += 1
    if n == 0:
        raise NurbscanError("3dm export: nothing to write (no curves or surfaces)")
    path = Path(path)
    with atomic_path_fixed(path) as tmp:  # the name OpenNURBS records: the same every run
        if not f.Write(str(tmp), version):
            raise NurbscanError(f"{path}: rhino3dm failed to write the file")
    return path
