"""IGES 5.3 writer: rational B-spline curves (entity 126) and surfaces (entity 128), by hand.

The file has the five fixed-format sections of the IGES 5.3 specification (US PRO, 1996):
Start (S), Global (G), Directory Entry (D, two 80-column lines per entity), Parameter Data (P)
and Terminate (T). Every line is 80 columns: data in 1-72, the section letter in 73, the
sequence number in 74-80; in the P section columns 66-72 hold the entity's DE pointer. Units
are millimetres (global parameter 14 = 2, ``2HMM``). Reals are written as the shortest decimal
that round-trips (Python's ``repr``), so that a reader recovers the float64 values exactly.
"""

from __future__ import annotations

import datetime as _dt
import os
from collections.abc import Iterable, Sequence
from pathlib import Path

import numpy as np

from ..errors import NurbscanError
from ..io.atomic import write_bytes
from ..nurbs import NurbsCurve, NurbsSurface

__all__ = ["iges_text", "write_iges"]


def _real(x: float) -> str:
    """The shortest round-trip decimal of ``x`` with a decimal point (IGES real literal)."""
    s = repr(float(x)).upper()
    if not np.isfinite(x):
        raise NurbscanError(f"IGES: non-finite real {x!r}")
    mant, _, exp = s.partition("E")
    if "." not in mant:
        mant += "."
    return mant + ("E" + exp if exp else "")


def _holl(s: str) -> str:
    """A Hollerith string ``nHtext``."""
    return f"{len(s)}H{s}"


def _lines(section: str, text_lines: Sequence[str]) -> list[str]:
    return [f"{t:<72.72}{section}{k + 1:7d}" for k, t in enumerate(text_lines)]


def _pack(tokens: Sequence[str], width: int, delim: str = ",", end: str = ";") -> list[str]:
    """Pack parameter tokens into lines of at most ``width`` characters, never splitting one."""
    out, cur = [], ""
    n = len(tokens)
    for k, tok in enumerate(tokens):
        piece = tok + (end if k == n - 1 else delim)
        if len(piece) > width:
            raise NurbscanError(f"IGES: parameter {tok!r} longer than {width} columns")
        if len(cur) + len(piece) > width:
            out.append(cur)
            cur = ""
        cur += piece
    if cur:
        out.append(cur)
    return out


def _curve_params(c: NurbsCurve) -> list[str]:
    """Entity 126 parameters: K, M, PROP1-4, knots, weights, points, V0, V1, normal."""
    P = np.asarray(c.control_points, float)
    if P.shape[1] == 2:
        P = np.column_stack([P, np.zeros(len(P))])
    if P.shape[1] != 3:
        raise NurbscanError(f"IGES: curve of dimension {P.shape[1]}; expected 2 or 3")
    w = np.ones(len(P)) if c.weights is None else np.asarray(c.weights, float)
    U = np.asarray(c.knots, float)
    polynomial = int(np.allclose(w, w[0], rtol=0, atol=0))
    u0, u1 = c.domain
    toks = ["126", str(len(P) - 1), str(c.degree), "0", "0", str(polynomial), "0"]
    toks += [_real(x) for x in U] + [_real(x) for x in w] + [_real(x) for x in P.ravel()]
    toks += [_real(u0), _real(u1), _real(0), _real(0), _real(0)]
    return toks


def _surface_params(s: NurbsSurface) -> list[str]:
    """Entity 128 parameters; weights and points with the u index varying fastest."""
    P = np.asarray(s.control_points, float)
    if P.shape[2] != 3:
        raise NurbscanError(f"IGES: surface of dimension {P.shape[2]}; expected 3")
    nu, nv = P.shape[:2]
    w = np.ones((nu, nv)) if s.weights is None else np.asarray(s.weights, float)
    polynomial = int(np.all(w == w.flat[0]))
    (u0, u1), (v0, v1) = s.domain
    toks = ["128", str(nu - 1), str(nv - 1), str(s.degree_u), str(s.degree_v),
            "0", "0", str(polynomial), "0", "0"]
    toks += [_real(x) for x in s.knots_u] + [_real(x) for x in s.knots_v]
    toks += [_real(x) for x in w.T.ravel()]
    toks += [_real(x) for x in P.transpose(1, 0, 2).reshape(-1)]
    toks += [_real(u0), _real(u1), _real(v0), _real(v1)]
    return toks


def iges_text(curves: Iterable[NurbsCurve] = (), surfaces: Iterable[NurbsSurface] = (),
              name: str = "model.igs", description: str = "nurbscan NURBS model",
              timestamp: _dt.datetime | None = None) -> str:
    """The text of an IGES 5.3 file holding the given curves (126) and surfaces (128).

    Parameters
    ----------
    curves, surfaces : iterables of NurbsCurve / NurbsSurface
        Geometry in mm (3-D control points; 2-D curves get z = 0).
    name : str
        File name written into the Global section.
    description : str
        Start-section text.
    timestamp : datetime, optional
        Generation date (UTC now when omitted).

    Returns
    -------
    str
        The file, lines of 80 columns joined by ``\\n``.
    """
    ts = (timestamp or _dt.datetime.now(_dt.UTC)).strftime("%Y%m%d.%H%M%S")
    entities = [(126, _curve_params(c)) for c in curves]
    entities += [(128, _surface_params(s)) for s in surfaces]
    if not entities:
        raise NurbscanError("IGES: nothing to write (no curves or surfaces)")
    start = _lines("S", [description[k:k + 72] for k in range(0, max(len(description), 1), 72)])
    glob = [_holl(","), _holl(";"), _holl("nurbscan"), _holl(name), _holl("nurbscan"),
            _holl("nurbscan 0.1"), "32", "38", "6", "308", "15", _holl("nurbscan"),
            _real(1), "2", _holl("MM"), "1", _real(1), _holl(ts), _real(1e-6), _real(0),
            _holl("nurbscan"), _holl("nurbscan"), "11", "0", _holl(ts)]
    g = _lines("G", _pack(glob, 72))
    d_text, p_text = [], []
    for k, (etype, toks) in enumerate(entities):
        de = 2 * k + 1
        plines = _pack(toks, 64)
        first = len(p_text) + 1
        p_text += [f"{t:<64}{de:>8d}" for t in plines]
        d_text.append(f"{etype:8d}{first:8d}{0:8d}{0:8d}{0:8d}{0:8d}{0:8d}{0:8d}{'00000000':>8}")
        d_text.append(f"{etype:8d}{0:8d}{0:8d}{len(plines):8d}{0:8d}{'':8}{'':8}{'':8}{0:8d}")
    d = _lines("D", d_text)
    p = _lines("P", p_text)
    term = f"S{len(start):7d}G{len(g):7d}D{len(d):7d}P{len(p):7d}"
    t = _lines("T", [term])
    return "\n".join(start + g + d + p + t) + "\n"


def write_iges(path: str | os.PathLike, curves: Iterable[NurbsCurve] = (),
               surfaces: Iterable[NurbsSurface] = (), **kw) -> Path:
    """Write :func:`iges_text` to ``path`` atomically (ASCII) and return the path."""
    path = Path(path)
    text = iges_text(curves, surfaces, name=path.name, **kw)
    return write_bytes(path, text.encode("ascii"))
