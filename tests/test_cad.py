"""Tests of the CAD surface set (nurbscan.merge.cad) and its STEP/3dm/IGES export (issue 32).

Oracle: exact rational sphere patches (Piegl and Tiller's surface of revolution) standing in
for two views' Gordon patches that overlap, the second view's a layer 0.02 mm outside the
first's, with "measured" edge points only where each view saw the sphere."""

from __future__ import annotations

import numpy as np
import pytest

from _export_fixtures import CENTRE, R, quarter_sphere
from nurbscan.merge.cad import CadOptions, cad_set, overlap_area, sub_surface
from nurbscan.reconstruct import Model

OPT = CadOptions(cell_mm=0.5, cover_mm=0.4)


def _band(S, v=(0.3, 0.7)):
    (u0, u1), _ = S.domain
    return sub_surface(S, (u0, u1), v)


def _grid(S, n=60):
    (u0, u1), (v0, v1) = S.domain
    t = np.linspace(0, 1, n)
    return S.evaluate_grid(u0 + (u1 - u0) * t, v0 + (v1 - v0) * t).reshape(-1, 3)


def _scaled(S, r):
    """The patch as a layer of radius ``r`` about the sphere's centre."""
    from nurbscan.nurbs import NurbsSurface

    P = (np.asarray(S.control_points) - CENTRE) * (r / R) + CENTRE
    return NurbsSurface(S.degree_u, S.degree_v, S.knots_u, S.knots_v, P, S.weights)


def _two_views():
    """View 0: quarter 0 of the sphere's band (latitudes about +-35 degrees). View 1: the
    second half of quarter 0 (on view 0's patch) and the first half of quarter 1, radius
    R + 0.02, measured with noise; view 1's edge points stop at 60 % of quarter 1's band
    height (the rest of that patch runs past its data)."""
    A = _band(quarter_sphere(0))
    B1 = _scaled(sub_surface(A, (0.5, 1.0), A.domain[1]), R + 0.02)
    Q1 = _band(quarter_sphere(1))
    B2 = _scaled(sub_surface(Q1, (0.0, 0.5), Q1.domain[1]), R + 0.02)
    (v0, v1) = B2.domain[1]
    seen = sub_surface(B2, B2.domain[0], (v0, v0 + 0.6 * (v1 - v0)))
    surfaces = [{"kind": "gordon", "view": v, "patch": k, "n_curves": [41, 41],
                 "vertical": [0, 1], "horizontal": [0, 1], "surface": S}
                for v, k, S in ((0, 0, A), (1, 0, B1), (1, 1, B2))]
    # view 1 measured with noise (0.01 mm along the normal): its fit residual is larger
    rng = np.random.default_rng(5)
    noisy = [_grid(B1, 80), _grid(seen, 80)]
    noisy = [X + 0.01 * rng.standard_normal((len(X), 1)) * (X - CENTRE) / R for X in noisy]
    edges = [_grid(A, 120), *noisy]
    m = Model(surfaces=surfaces, views=[{"index": 0, "table_angle": 0.0},
                                        {"index": 1, "table_angle": 0.5 * np.pi}])
    m.edge_points = np.concatenate(edges)
    m.edge_view = np.concatenate([np.zeros(len(edges[0]), int),
                                  np.ones(len(edges[1]) + len(edges[2]), int)])
    return m, {"A": A, "B1": B1, "B2": B2, "seen": seen}


@pytest.fixture(scope="module")
def two_views():
    return _two_views()


def _area(S, n=80):
    (u0, u1), (v0, v1) = S.domain
    du, dv = (u1 - u0) / n, (v1 - v0) / n
    uu, vv = np.meshgrid(u0 + du * (np.arange(n) + 0.5), v0 + dv * (np.arange(n) + 0.5),
                         indexing="ij")
    D = S.derivatives(uu.ravel(), vv.ravel(), 1)
    return float(np.linalg.norm(np.cross(D[1, 0], D[0, 1]), axis=1).sum() * du * dv)


def test_sub_surface_is_exact():
    S = quarter_sphere(2)
    T = sub_surface(S, (0.13, 0.71), (0.2, 0.9))
    assert T.domain == ((0.13, 0.71), (0.2, 0.9))
    rng = np.random.default_rng(0)
    u, v = rng.uniform(0.13, 0.71, 200), rng.uniform(0.2, 0.9, 200)
    assert np.abs(T.evaluate(u, v) - S.evaluate(u, v)).max() < 1e-9


def test_cad_set_has_no_overlap_and_covers_the_data(two_views):
    """Every part of the covered sphere on exactly one surface: overlap under 1 % of the
    area (exact point inversion onto the other surfaces), the area of the union (A and the
    seen part of B2) within 2 %, nothing of B2 past its data beyond a pitch's fraction."""
    m, parts = two_views
    cad = cad_set(m, None, OPT)
    ov = overlap_area(cad.surfaces, tol=0.1)
    want = _area(parts["A"]) + _area(parts["seen"])
    assert ov["share"] < 0.01, ov
    assert abs(ov["area_mm2"] - want) / want < 0.02, (ov, want)
    X = np.concatenate([_grid(d["surface"], 15) for d in cad.surfaces])
    r = np.linalg.norm(X - CENTRE, axis=1)
    assert np.abs(r - R).max() < 0.021
    # B2 past its data: no CAD surface farther than half a pitch (here 0.3 of the cells'
    # pitch estimate) from the measured points
    from scipy.spatial import cKDTree

    d, _ = cKDTree(m.edge_points).query(X)
    assert d.max() < 0.5 * cad.info["pitch_mm"] + OPT.cell_mm, (d.max(), cad.info)
    # the better patch (view 0, least residual) keeps the overlap; view 1's copy goes
    assert {(s["view"], s["patch"]) for s in cad.surfaces} == {(0, 0), (1, 1)}


def test_step_read_back_as_sewn_shells(two_views, tmp_path):
    """STEP read back by OpenCASCADE (STEPControl_Reader): every face, at most 2 shells,
    no face outside a shell after sewing."""
    pytest.importorskip("OCP")
    from OCP.IFSelect import IFSelect_RetDone
    from OCP.STEPControl import STEPControl_Reader

    from nurbscan.export.step import sew_faces, shell_count, write_step

    m, _ = two_views
    cad = cad_set(m, None, OPT)
    path = write_step(tmp_path / "m.step", [d["surface"] for d in cad.surfaces])
    rd = STEPControl_Reader()
    assert rd.ReadFile(str(path)) == IFSelect_RetDone
    rd.TransferRoots()
    shape = rd.OneShape()
    shells, loose = shell_count(shape)
    from OCP.TopAbs import TopAbs_FACE
    from OCP.TopExp import TopExp_Explorer

    ex, faces = TopExp_Explorer(shape, TopAbs_FACE), 0
    while ex.More():
        faces += 1
        ex.Next()
    assert faces == len(cad.surfaces)
    assert 1 <= shells <= 2 and loose == 0, (shells, loose)
    # sewn again by OpenCASCADE from what was read: still one or two shells
    assert shell_count(sew_faces([shape], 0.05))[0] <= 2


def test_3dm_and_igs_of_the_cad_set(two_views, tmp_path):
    import rhino3dm

    from nurbscan.export import write_3dm, write_iges

    m, _ = two_views
    cad = cad_set(m, None, OPT)
    f = write_3dm(tmp_path / "m.3dm", [], [(f"cad view {d['view']}", d["surface"])
                                           for d in cad.surfaces])
    back = rhino3dm.File3dm.Read(str(f))
    assert len(back.Objects) == len(cad.surfaces)
    for obj, d in zip(back.Objects, cad.surfaces, strict=True):
        g = obj.Geometry
        (u0, u1), (v0, v1) = d["surface"].domain
        p = g.PointAt(0.5 * (u0 + u1), 0.5 * (v0 + v1))
        q = d["surface"].evaluate(np.array([0.5 * (u0 + u1)]), np.array([0.5 * (v0 + v1)]))[0]
        assert np.linalg.norm(np.array([p.X, p.Y, p.Z]) - q) < 1e-9
    text = write_iges(tmp_path / "m.igs", [], [d["surface"] for d in cad.surfaces]).read_text()
    assert text.count("     128") >= len(cad.surfaces)


def test_step_without_ocp_is_a_one_line_error(two_views, tmp_path, monkeypatch):
    import builtins

    from nurbscan.errors import NurbscanError
    from nurbscan.export.step import write_step

    real = builtins.__import__

    def no_ocp(name, *a, **k):
        if name == "OCP" or name.startswith("OCP."):
            raise ImportError("No module named 'OCP'")
        return real(name, *a, **k)

    monkeypatch.setattr(builtins, "__import__", no_ocp)
    m, _ = two_views
    with pytest.raises(NurbscanError, match=r"nurbscan\[cad\]"):
        write_step(tmp_path / "x.step", [quarter_sphere(0)])
    assert not (tmp_path / "x.step").exists()
