"""Tests of the CAD surface set (nurbscan.merge.cad) and its STEP/3dm/IGES export (issue 32).

Oracle: exact rational sphere patches (Piegl and Tiller's surface of revolution) standing in
for two views' Gordon patches that overlap, the second view's a layer 0.02 mm outside the
first's, with "measured" edge points only where each view saw the sphere."""

from __future__ import annotations

import numpy as np
import pytest

from _export_fixtures import CENTRE, R, quarter_sphere
from nurbscan.merge.cad import CadOptions, cad_set, outline, overlap_area, sub_surface, unpinched
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


def _faces(shape):
    from OCP.TopAbs import TopAbs_FACE
    from OCP.TopExp import TopExp_Explorer

    ex, faces = TopExp_Explorer(shape, TopAbs_FACE), []
    while ex.More():
        faces.append(ex.Current())
        ex.Next()
    return faces


def _occ_area(face) -> float:
    from OCP.BRepGProp import BRepGProp
    from OCP.GProp import GProp_GProps

    g = GProp_GProps()
    BRepGProp.SurfaceProperties_s(face, g, 1e-9)
    return g.Mass()


def _cells_area(S, u, v, keep, n=8):
    """Area of the kept cells of S (midpoint rule, n x n points per cell)."""
    t = (np.arange(n) + 0.5) / n
    total = 0.0
    for i, j in zip(*np.nonzero(keep), strict=True):
        uu, vv = np.meshgrid(u[i] + (u[i + 1] - u[i]) * t, v[j] + (v[j + 1] - v[j]) * t,
                             indexing="ij")
        D = S.derivatives(uu.ravel(), vv.ravel(), 1)
        total += np.linalg.norm(np.cross(D[1, 0], D[0, 1]), axis=1).sum() * (
            (u[i + 1] - u[i]) * (v[j + 1] - v[j]) / n ** 2)
    return total


def _inside(loop, x, y):
    """Even-odd rule: whether points (x, y) lie inside the polygon ``loop`` (n, 2)."""
    a, b = loop, np.roll(loop, -1, axis=0)
    inside = np.zeros(len(x), bool)
    for (x0, y0), (x1, y1) in zip(a.astype(float), b.astype(float), strict=True):
        cross = (y0 > y) != (y1 > y)
        xs = x0 + (y - y0) * (x1 - x0) / np.where(y1 == y0, 1.0, y1 - y0)
        inside ^= cross & (x < xs)
    return inside


def test_outline_gives_back_the_mask():
    """The loops of random masks (holes, corner-touching cells) give back exactly the mask
    (even-odd rule at the cell centres), region by region; outer loops counter-clockwise,
    holes clockwise, areas adding up to the cell count; no collinear corners."""
    rng = np.random.default_rng(2)
    for trial in range(20):
        mask = rng.random((14, 11)) < (0.55 if trial % 2 else 0.8)
        regions = outline(mask)
        ii, jj = np.meshgrid(np.arange(14) + 0.5, np.arange(11) + 0.5, indexing="ij")
        got = np.zeros(mask.shape, int)
        for outer, holes in regions:
            inside = _inside(outer, ii.ravel(), jj.ravel())
            for h in holes:
                inside ^= _inside(h, ii.ravel(), jj.ravel())
            got += inside.reshape(mask.shape)
            area = [0.5 * np.sum(lp[:, 0] * np.roll(lp[:, 1], -1) - np.roll(lp[:, 0], -1)
                                 * lp[:, 1]) for lp in [outer, *holes]]
            assert area[0] > 0 and all(a < 0 for a in area[1:])
            assert sum(area) == inside.sum()
            for lp in [outer, *holes]:
                d0, d1 = lp - np.roll(lp, 1, axis=0), np.roll(lp, -1, axis=0) - lp
                assert np.all(d0[:, 0] * d1[:, 1] - d0[:, 1] * d1[:, 0] != 0)
        assert np.array_equal(got, mask.astype(int)), trial


def test_unpinched_drops_a_cell_per_checkerboard():
    rng = np.random.default_rng(4)
    for _ in range(20):
        mask = rng.random((12, 9)) < 0.6
        m = unpinched(mask)
        assert not (m & ~mask).any()
        blocks = np.stack([m[:-1, :-1], m[1:, :-1], m[:-1, 1:], m[1:, 1:]])
        cheq = ((blocks[0] & blocks[3] & ~blocks[1] & ~blocks[2])
                | (blocks[1] & blocks[2] & ~blocks[0] & ~blocks[3]))
        assert not cheq.any()
        assert (mask & ~m).sum() <= (mask.sum() + 1) // 2


def test_trimmed_face_is_the_kept_cells():
    """A trimmed face (OpenCASCADE) of a mask with a hole and a notch: valid
    (BRepCheck_Analyzer), its area (BRepGProp) that of the kept cells (midpoint rule on our
    own surface) to 1e-4, one face per region."""
    pytest.importorskip("OCP")
    from OCP.BRepCheck import BRepCheck_Analyzer

    from nurbscan.export.step import trimmed_faces

    S = _band(quarter_sphere(0))
    (u0, u1), (v0, v1) = S.domain
    u, v = np.linspace(u0, u1, 11), np.linspace(v0, v1, 9)
    keep = np.ones((10, 8), bool)
    keep[3:5, 2:5] = False   # a hole
    keep[8:, 6:] = False     # a notch
    keep[0, 0] = False
    keep[1, 1] = False       # a pinch corner: (0, 0) and (1, 1) out, (0, 1), (1, 0) kept
    assert not BRepCheck_Analyzer(trimmed_faces(S, u, v, keep)[0]).IsValid()
    keep = unpinched(keep)
    assert keep.sum() == 10 * 8 - 6 - 4 - 2 - 1
    faces = trimmed_faces(S, u, v, keep)
    assert len(faces) == 1
    assert BRepCheck_Analyzer(faces[0]).IsValid()
    want = _cells_area(S, u, v, keep)
    assert abs(_occ_area(faces[0]) - want) / want < 1e-4, (_occ_area(faces[0]), want)
    two = keep.copy()
    two[5, :] = False
    faces = trimmed_faces(S, u, v, two)
    assert len(faces) == 2
    got = sum(_occ_area(f) for f in faces)
    assert abs(got - _cells_area(S, u, v, two)) / got < 1e-4


def test_step_read_back_as_sewn_shells(two_views, tmp_path):
    """STEP of the CAD set (one trimmed face per region of a patch's kept cells) read back
    by OpenCASCADE (STEPControl_Reader): every face, at most two shells, no face outside a
    shell; the faces' area that of the kept cells."""
    pytest.importorskip("OCP")
    from OCP.IFSelect import IFSelect_RetDone
    from OCP.STEPControl import STEPControl_Reader

    from nurbscan.export.step import sew_faces, shell_count, write_step

    m, _ = two_views
    cad = cad_set(m, None, OPT)
    regions = sum(len(outline(p["keep"])) for p in cad.patches)
    path = write_step(tmp_path / "m.step", trimmed=cad.patches)
    rd = STEPControl_Reader()
    assert rd.ReadFile(str(path)) == IFSelect_RetDone
    rd.TransferRoots()
    shape = rd.OneShape()
    shells, loose = shell_count(shape)
    faces = _faces(shape)
    assert len(faces) == regions == 2, (len(faces), regions)
    assert 1 <= shells <= 2 and loose == 0, (shells, loose)
    want = sum(_cells_area(p["surface"], p["u"], p["v"], p["keep"], 3) for p in cad.patches)
    got = sum(_occ_area(f) for f in faces)
    assert abs(got - want) / want < 1e-3, (got, want)
    # sewn again by OpenCASCADE from what was read: still one or two shells
    assert shell_count(sew_faces([shape], 0.05))[0] <= 2
    # the untrimmed sub-surfaces (3dm, igs) as faces: one per rectangle
    path = write_step(tmp_path / "r.step", [d["surface"] for d in cad.surfaces])
    rd = STEPControl_Reader()
    rd.ReadFile(str(path))
    rd.TransferRoots()
    assert len(_faces(rd.OneShape())) == len(cad.surfaces) >= regions


def _three_views():
    """Three views on quarter 0's band: views 0 and 2 on the sphere, measured with noise;
    view 1 a layer 0.25 mm outside over the band's middle, its edge points exactly on it (the
    least residual: the best score), as a view whose edge points are all off together."""
    A = _band(quarter_sphere(0))
    B = _scaled(sub_surface(A, (0.3, 0.7), A.domain[1]), R + 0.25)
    rng = np.random.default_rng(7)
    surfaces, edges, views = [], [], []
    for v, S, noise in ((0, A, 0.01), (1, B, 0.0), (2, A, 0.01)):
        surfaces.append({"kind": "gordon", "view": v, "patch": 0, "n_curves": [41, 41],
                         "vertical": [0, 1], "horizontal": [0, 1], "surface": S})
        X = _grid(S, 100)
        X = X + noise * rng.standard_normal((len(X), 1)) * (X - CENTRE) / R
        edges.append(X)
        views.append(np.full(len(X), v))
    m = Model(surfaces=surfaces, views=[{"index": v, "table_angle": 0.0} for v in range(3)])
    m.edge_points, m.edge_view = np.concatenate(edges), np.concatenate(views)
    return m


def test_cross_view_consistency_cuts_the_odd_layer():
    """View 1's layer, 0.25 mm off the sphere and the two other views, wins ownership by
    score; the consistency cut (step 5) removes it and the other views' cells take its
    place: no CAD surface farther than 1e-6 mm from the sphere, the band covered as
    without the cut (area within 1 %), overlap under 1 %."""
    m = _three_views()
    off = cad_set(m, None, CadOptions(cell_mm=0.5, cover_mm=0.4, consistent_mm=None))
    on = cad_set(m, None, OPT)

    def radial(cad):
        X = np.concatenate([_grid(d["surface"], 15) for d in cad.surfaces])
        return np.abs(np.linalg.norm(X - CENTRE, axis=1) - R).max()

    assert radial(off) > 0.24                       # the odd layer kept without the cut
    assert radial(on) < 1e-6, on.info
    assert on.info["cells_inconsistent"] > 0
    assert 1 not in {d["view"] for d in on.surfaces}
    want = _area(_band(quarter_sphere(0)))
    ov = overlap_area(on.surfaces, tol=0.1)
    assert abs(ov["area_mm2"] - want) / want < 0.01, (ov, want)
    assert ov["share"] < 0.01, ov


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



def test_trimmed_faces_of_the_sphere_close_at_the_poles():
    """The four quarter spheres (their sides at v = 0 and 1 are the poles, degenerate) as
    trimmed faces of all their cells: valid, each a quarter of 4 pi R^2 to 1e-6, sewn into
    one shell with no face outside it."""
    pytest.importorskip("OCP")
    from OCP.BRepCheck import BRepCheck_Analyzer

    from nurbscan.export.step import sew_faces, shell_count, trimmed_faces

    faces = []
    for k in range(4):
        S = quarter_sphere(k)
        (u0, u1), (v0, v1) = S.domain
        f = trimmed_faces(S, np.linspace(u0, u1, 5), np.linspace(v0, v1, 5),
                          np.ones((4, 4), bool))
        assert len(f) == 1 and BRepCheck_Analyzer(f[0]).IsValid()
        assert abs(_occ_area(f[0]) / (np.pi * R ** 2) - 1) < 1e-6
        faces += f
    assert shell_count(sew_faces(faces, 0.05)) == (1, 0)


def _grid_mesh(S, n=100):
    """A triangulation (V, F) of surface ``S`` on an ``n x n`` parameter grid."""
    (u0, u1), (v0, v1) = S.domain
    V = S.evaluate_grid(np.linspace(u0, u1, n), np.linspace(v0, v1, n)).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(n - 1), np.arange(n - 1), indexing="ij")
    a = (i * n + j).ravel()
    F = np.concatenate([np.column_stack([a, a + n, a + n + 1]),
                        np.column_stack([a, a + n + 1, a + 1])])
    return V, F


def _latitude(X):
    w = X - CENTRE
    return np.arcsin(np.clip(w[:, 2] / np.linalg.norm(w, axis=1), -1, 1))


def test_fused_mesh_cuts_the_cells_past_the_data():
    """One view's patch (quarter 0's band) whose edge points (0.01 mm noise) cover only its
    middle latitudes; the fused mesh covers the same part (what screened Poisson trimmed to
    the data gives). Without the fused mesh the cells within half a pitch (2.1 mm) of the
    data and off it by under 4 robust sigmas stay: the set runs more than 1 mm past the
    data. With it, no sample of the CAD set (3 x 3 per cell) lies more than 0.15 mm past the
    seen latitudes (exact: the sphere's latitude of each sample), and the seen part stays
    covered (area within a 0.15 mm band of its border)."""
    from nurbscan.evaluate.table import cad_samples
    from nurbscan.merge import FusedMesh

    A = _band(quarter_sphere(0))
    (u0, u1), (v0, v1) = A.domain
    seen = sub_surface(A, (u0, u1), (v0 + 0.3 * (v1 - v0), v0 + 0.7 * (v1 - v0)))
    rng = np.random.default_rng(11)
    X = _grid(seen, 80)
    X = X + 0.01 * rng.standard_normal((len(X), 1)) * (X - CENTRE) / R
    m = Model(surfaces=[{"kind": "gordon", "view": 0, "patch": 0, "n_curves": [41, 41],
                         "vertical": [0, 1], "horizontal": [0, 1], "surface": A}],
              views=[{"index": 0, "table_angle": 0.0}])
    m.edge_points, m.edge_view = X, np.zeros(len(X), int)
    lat = _latitude(_grid(seen, 40))
    lo, hi = lat.min(), lat.max()

    def past(cad):
        P, _ = cad_samples(cad)
        phi = _latitude(P)
        return R * np.maximum(np.maximum(phi - hi, lo - phi), 0.0).max()

    old = cad_set(m, None, OPT)
    assert past(old) > 1.0, past(old)
    V, F = _grid_mesh(seen)
    m.fused = FusedMesh(V, F, np.full((len(V), 4), 200, np.uint8), {})
    new = cad_set(m, None, OPT)
    assert past(new) < 0.15, (past(new), new.info)
    assert new.info["cells_off_fused"] > 0
    want = _area(seen)
    border = 2 * (R * (hi - lo) + R * np.cos(hi) * 0.5 * np.pi)
    assert want - 0.15 * border < new.info["area_mm2"] <= want + 0.15 * border, new.info


def test_cad_row_against_the_true_sphere():
    """The evaluation row of a CAD set against the true sphere (exact closest points): the
    view-1 layer 0.25 mm off the sphere kept without the cross-view cut is measured as
    0.25 mm (its samples over 0.2 mm), the set with the cut as on the sphere; 9 samples per
    kept cell."""
    from nurbscan.evaluate.table import cad_row
    from nurbscan.simulate.scenes import Sphere

    m = _three_views()
    sphere = Sphere(radius=R, center=tuple(CENTRE))
    off = cad_set(m, None, CadOptions(cell_mm=0.5, cover_mm=0.4, consistent_mm=None))
    on = cad_set(m, None, OPT)
    r_off, r_on = cad_row(off, sphere), cad_row(on, sphere)
    assert r_off["n"] == 9 * off.info["cells_kept"] == 9 * r_off["cells"]
    assert abs(r_off["max_sample_mm"] - 0.25) < 1e-6
    assert r_off["over_limit"] > 0 and r_off["cells_over_limit"] > 0
    assert r_on["max_sample_mm"] < 1e-6 and r_on["over_limit"] == 0
    assert r_on["regions"] >= 1 and abs(r_on["area_mm2"] - on.info["area_mm2"]) < 1e-9


def _ripple(n=35, L=100.0, A=4.0, waves=6):
    """A bicubic sheet of ``n - 3`` uniform knot spans per direction over ``L`` mm whose
    control points follow ``A sin(2 pi waves x / L) cos(2 pi waves y / L)`` (mm): curvature
    radius at least 1.7 mm, many spans, as the teapot's Gordon patches have (32 x 21)."""
    from nurbscan.nurbs import NurbsSurface

    U = np.concatenate([[0.0] * 3, np.linspace(0, 1, n - 2), [1.0] * 3])
    x = np.linspace(0, L, n)
    X, Y = np.meshgrid(x, x, indexing="ij")
    Z = A * np.sin(2 * np.pi * waves * X / L) * np.cos(2 * np.pi * waves * Y / L)
    return NurbsSurface(3, 3, U, U, np.stack([X, Y, Z], -1))


def test_seams_eligibility_finds_the_near_sheet_of_a_rippled_patch():
    """``seams``' eligibility (its vertices within ``on_mm`` of the patch's surface, exact
    point inversion) of vertices 0.05 mm and 0.15 mm off a rippled patch along its normal:
    the exact distance is the offset (under the curvature radius), so exactly the first
    are within 0.1 mm and all within 0.2 mm (inversion exact to 4e-14 mm). The former
    Newton of cad.py (``_closest``: 16 x 16 start, undamped) stopped in a far minimum at a
    border for 16 of these 2000 vertices (up to 83.8 mm off; 11 of them 0.05 mm off) and
    called them not eligible."""
    from types import SimpleNamespace

    from scipy.spatial import cKDTree

    from nurbscan.merge.cad import SeamOptions, _eligible

    S = _ripple()
    rng = np.random.default_rng(1)
    u, v = rng.uniform(0.02, 0.98, (2, 2000))
    D = S.derivatives(u, v, 1)
    N = np.cross(D[1, 0], D[0, 1])
    N /= np.linalg.norm(N, axis=1)[:, None]
    h = np.where(np.arange(2000) < 1000, 0.05, 0.15)
    V = D[0, 0] + h[:, None] * N
    F = np.repeat(np.arange(2000)[:, None], 3, 1)  # one (degenerate) triangle per vertex
    cad = SimpleNamespace(patches=[{"surface": S}])
    eligible = _eligible(cad, V, F, cKDTree(D[0, 0]), np.zeros(2000, int), SeamOptions())
    t = np.arange(2000)
    got = eligible(t, np.zeros(2000, int))
    assert np.array_equal(got, h < 0.1), (np.flatnonzero(got != (h < 0.1)), h.size)
    assert eligible(t, np.zeros(2000, int), 0.2).all()
    assert not eligible(t, np.full(2000, -1)).any()


def test_cells_beside_own_data_the_patch_misses_are_cut():
    """One view's patch (quarter 0's band) measured densely (0.003 mm noise) over its middle
    latitudes, and along one latitude line 1 mm past them by accurate points that lie
    0.3 mm inside the patch (the object bends away there, the patch runs on): the residual
    test (median of the 6 nearest points) cuts the cells whose nearest points are on that
    line, but keeps those between whose nearest points are the dense ones: they lie within
    1 mm of data their patch misses by 0.3 mm. ``miss_sigma`` (15 robust sigmas of the view's
    residuals, here about 0.003 mm; 3 cells) cuts every cell
    within 3 cells of the missed line (no kept sample nearer than 1.2 mm to it) at the cost of
    a band along that line only (area lost under 1.5 mm times its length)."""
    from scipy.spatial import cKDTree

    from nurbscan.evaluate.table import cad_samples

    A = _band(quarter_sphere(0))
    (u0, u1), (v0, v1) = A.domain
    dv = v1 - v0
    seen = sub_surface(A, (u0, u1), (v0 + 0.3 * dv, v0 + 0.7 * dv))
    rng = np.random.default_rng(12)
    X = _grid(seen, 80)
    X = X + 0.003 * rng.standard_normal((len(X), 1)) * (X - CENTRE) / R
    lat_hi = _latitude(_grid(seen, 40)).max()
    # the missed line: 1 mm past the seen latitudes on the sphere, 0.3 mm inside the patch
    t = np.linspace(u0, u1, 400)
    Vl = np.full_like(t, v0 + 0.7 * dv)
    Lp = A.evaluate(t, Vl)
    w = Lp - CENTRE
    lat = np.arcsin(w[:, 2] / np.linalg.norm(w, axis=1)) + 1.0 / R
    ring = np.column_stack([np.cos(lat) * w[:, 0], np.cos(lat) * w[:, 1]]) / np.hypot(
        w[:, 0], w[:, 1])[:, None]
    L = CENTRE + (R - 0.3) * np.column_stack([ring, np.sin(lat)])
    assert abs(_latitude(L) - (lat_hi + 1.0 / R)).max() < 1e-3
    m = Model(surfaces=[{"kind": "gordon", "view": 0, "patch": 0, "n_curves": [41, 41],
                         "vertical": [0, 1], "horizontal": [0, 1], "surface": A}],
              views=[{"index": 0, "table_angle": 0.0}])
    m.edge_points = np.concatenate([X, L])
    m.edge_view = np.zeros(len(m.edge_points), int)

    def nearest(cad):
        P, _ = cad_samples(cad)
        return cKDTree(L).query(P)[0].min()

    old = cad_set(m, None, CadOptions(cell_mm=0.5, cover_mm=0.4, miss_sigma=None))
    new = cad_set(m, None, OPT)
    assert nearest(old) < 1.0, nearest(old)
    assert nearest(new) > 1.2, (nearest(new), new.info)
    assert new.info["cells_missed"] > 0 and old.info["cells_missed"] == 0
    length = R * np.cos(lat_hi) * 0.5 * np.pi
    lost = old.info["area_mm2"] - new.info["area_mm2"]
    assert 0 < lost < 1.5 * length, (lost, length)


def test_cells_past_the_patch_curves_are_cut():
    """One view's patch (quarter 0's band) measured densely over all of it, whose curves
    (5 vertical, 4 horizontal) begin one spacing after its first ``u`` and end one spacing
    before its last ``v`` (a patch that reaches past its curves, as at a contour). With
    ``beyond_spacing`` 0.4 the kept cells' centres lie at most 0.4 spacings past the curves
    and the cells beyond are cut, those of the corner past both included; without it every
    cell is kept."""
    from dataclasses import replace

    A = _band(quarter_sphere(0))
    (u0, u1), (v0, v1) = A.domain
    du, dv = u1 - u0, v1 - v0
    cu, cv = [u0 + 0.2 * du, u1], [v0, v1 - 0.25 * dv]  # spacings 0.2 du and 0.25 dv
    rng = np.random.default_rng(3)
    X = _grid(A, 80)
    X = X + 0.003 * rng.standard_normal((len(X), 1)) * (X - CENTRE) / R
    m = Model(surfaces=[{"kind": "gordon", "view": 0, "patch": 0, "n_curves": [5, 4],
                         "vertical": [u0, u1], "horizontal": [v0, v1],
                         "vertical_curves": cu, "horizontal_curves": cv, "surface": A}],
              views=[{"index": 0, "table_angle": 0.0}])
    m.edge_points = X
    m.edge_view = np.zeros(len(X), int)
    old = cad_set(m, None, replace(OPT, beyond_spacing=None))
    new = cad_set(m, None, OPT)
    assert old.patches[0]["keep"].all() and old.info["cells_beyond"] == 0, old.info
    p = new.patches[0]
    u, v = np.asarray(p["u"]), np.asarray(p["v"])
    uc, vc = 0.5 * (u[:-1] + u[1:]), 0.5 * (v[:-1] + v[1:])
    lo, hi = cu[0] - 0.4 * 0.2 * du, cv[1] + 0.4 * 0.25 * dv
    want = (uc >= lo)[:, None] & (vc <= hi)[None, :]
    assert np.array_equal(p["keep"], want), (np.argwhere(p["keep"] != want), lo, hi)
    assert new.info["cells_beyond"] == (~want).sum() > 0, new.info
    # the corner past both the first vertical and the last horizontal curve is gone
    assert not p["keep"][uc < lo][:, vc > hi].any()
