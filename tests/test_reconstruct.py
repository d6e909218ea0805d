"""Tests of nurbscan.reconstruct: light surfaces, batched fits, network and Gordon patches, and
a small end-to-end scan (simulate -> reconstruct without truth/ -> evaluate against truth)."""

from __future__ import annotations

import dataclasses
import json
import shutil

import cv2
import numpy as np
import pytest

from nurbscan.camera import Turntable
from nurbscan.nurbs import NurbsCurve, NurbsSurface
from nurbscan.nurbs.basis import averaging_knots
from nurbscan.reconstruct import Model, load_model
from nurbscan.reconstruct._batch import evaluate_chains, fit_chains, uniform_knots01
from nurbscan.reconstruct.light import (
    compare_light_surfaces,
    intersect_exact,
    intersect_surface,
    other_coordinate,
    paper_light_surface,
)
from nurbscan.reconstruct.merge import curve_to_object, rig_to_object
from nurbscan.reconstruct.network import (
    NetLine,
    complete_cells,
    gordon_patch,
    patch_extents,
    rectangles,
)
from nurbscan.reconstruct.triangulate import lstsq_spline, lstsq_splines
from nurbscan.simulate.rig import default_rig


@pytest.fixture(scope="module")
def rig():
    return default_rig()


def _object_points(rig, n=4000, seed=1):
    rng = np.random.default_rng(seed)
    aim = np.array([0.0, 0.0, 600.0])
    return aim + rng.uniform(-60, 60, (n, 3))


# ---------------------------------------------------------------------- light surfaces
@pytest.mark.parametrize("direction,axis", [("vertical", 0), ("horizontal", 1)])
def test_exact_light_surface_recovers_points(rig, direction, axis):
    """Camera ray x exact light surface of the point's own projector coordinate = the point.

    Oracle: the camera module's Tsai projection (independent of the cubic solved here)."""
    X = _object_points(rig)
    pp = rig.projector.project(X)
    px = rig.camera.project(X)
    o, d = rig.camera.back_project(px)
    P, other, t = intersect_exact(rig.projector, o, d, direction, pp[:, axis])
    assert np.all(np.isfinite(P))
    assert np.max(np.linalg.norm(P - X, axis=1)) < 1e-6
    assert np.max(np.abs(other - pp[:, 1 - axis])) < 1e-6
    assert np.allclose(t, np.linalg.norm(X - o, axis=1), atol=1e-6)


def test_other_coordinate_is_the_projection_of_the_point(rig):
    """A camera pixel on the projector edge x = c (y = c) is given the projector y (x) of the
    object point seen there. Oracle: the projector's Tsai projection of that point."""
    X = _object_points(rig, 2000, seed=2)
    pp = rig.projector.project(X)
    px = rig.camera.project(X)
    assert np.abs(other_coordinate(rig, px, "vertical", pp[:, 0]) - pp[:, 1]).max() < 1e-6
    assert np.abs(other_coordinate(rig, px, "horizontal", pp[:, 1]) - pp[:, 0]).max() < 1e-6


def test_exact_light_surface_near_principal_point(rig):
    """Edges through the projector's principal point (Xd = 0) are solved as accurately."""
    X = _object_points(rig, 4000)
    pp = rig.projector.project(X)
    X = X[np.abs(pp[:, 0] - rig.projector.cx) < 20]  # rays that meet the plane x = cx nearby
    assert len(X) > 50
    c = np.full(len(X), rig.projector.cx)
    o, d = rig.camera.back_project(rig.camera.project(X))
    P, other, _ = intersect_exact(rig.projector, o, d, "vertical", c)
    assert np.isfinite(P).all()
    q = rig.projector.project(P)
    assert np.max(np.abs(q[:, 0] - rig.projector.cx)) < 1e-7
    assert np.max(np.abs(q[:, 1] - other)) < 1e-7


def test_paper_light_surface_vs_exact(rig):
    """The conic ruled surface lies within 1e-3 px of the exact one for the default projector,
    and its deviation grows with the distortion (k1 x 100 gives a measurable error)."""
    X = _object_points(rig, 3000)
    pp = rig.projector.project(X)
    px = rig.camera.project(X)
    res = {}
    for k1 in (rig.projector.k1, 100 * rig.projector.k1):
        proj = dataclasses.replace(rig.projector, k1=k1)
        pq = proj.project(X)
        coords, pixels = [], []
        for c in (300.5, 900.5, 1500.5):
            sel = np.abs(pq[:, 0] - c) < 30
            coords.append(c)
            pixels.append(rig.camera.project(proj_points(proj, X[sel], c)))
        res[k1] = compare_light_surfaces(proj, rig.camera, "vertical", coords, pixels)
    small, big = res[rig.projector.k1], res[100 * rig.projector.k1]
    assert small["n"] > 50 and small["max_px"] < 1e-3 and small["max_mm"] < 1e-3
    assert big["max_px"] > 10 * small["max_px"]
    assert np.isfinite(pp).all() and np.isfinite(px).all()


def proj_points(proj, X, c):
    """Points on the light surface x = c: move each point along its projector ray's row."""
    pq = proj.project(X)
    pq[:, 0] = c
    o, d = proj.back_project(pq)
    depth = np.linalg.norm(X - o, axis=1)
    return o + depth[:, None] * d


def test_intersect_surface_plane():
    """Newton ray/surface intersection on a bilinear plane patch (closed-form oracle)."""
    S = NurbsSurface(1, 1, [0, 0, 1, 1], [0, 0, 1, 1],
                     np.array([[[0, 0, 10.0], [0, 5, 10.0]], [[5, 0, 10.0], [5, 5, 10.0]]]))
    d = np.array([[0.1, 0.2, 1.0], [0.3, 0.05, 1.0]])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    P, uv = intersect_surface(S, np.zeros(3), d)
    expect = d * (10.0 / d[:, 2:3])
    assert np.allclose(P, expect, atol=1e-9)
    assert np.allclose(uv, expect[:, :2] / 5.0, atol=1e-9)


def test_paper_light_surface_is_degree_2_by_1(rig):
    S = paper_light_surface(rig.projector, "horizontal", 540.5)
    assert (S.degree_u, S.degree_v) == (2, 1) and S.control_points.shape == (3, 2, 3)
    # the near curve projects onto the projector line y = 540.5 at its ends and middle
    Pn = S.evaluate(np.array([0.0, 0.5, 1.0]), np.zeros(3))
    Pf = S.evaluate(np.array([0.0, 0.5, 1.0]), np.ones(3))
    for P in (Pn, Pf):
        assert np.allclose(rig.projector.project(P)[:, 1], 540.5, atol=1e-6)


# ---------------------------------------------------------------------- fits
def test_batched_fit_matches_single_lstsq():
    """fit_chains (sparse batched normal equations) = dense per-chain least squares."""
    rng = np.random.default_rng(3)
    ts, ys, ids, spans = [], [], [], []
    for c in range(25):
        m = rng.integers(8, 60)
        t = np.sort(rng.uniform(0, 1, m))
        t[0], t[-1] = 0.0, 1.0
        ts.append(t)
        ys.append(np.stack([np.sin(3 * t + c), t**2], 1) + 0.01 * rng.standard_normal((m, 2)))
        ids.append(np.full(m, c))
        spans.append(int(rng.integers(1, 4)))
    t, Y, cid, nsp = np.concatenate(ts), np.concatenate(ys), np.concatenate(ids), np.array(spans)
    ctrl, inl, rms = fit_chains(t, Y, cid, nsp, smooth=1e-6)
    assert inl.all()
    for c in range(25):
        ref = lstsq_spline(ts[c], ys[c], uniform_knots01(spans[c]), smooth=1e-6)
        assert np.allclose(ctrl[c], ref.control_points, atol=1e-8)
    fitted = evaluate_chains(t, cid, nsp, ctrl)
    assert np.allclose(np.sqrt(np.mean(np.sum((fitted - Y) ** 2, 1))), np.sqrt(np.mean(rms**2)),
                       rtol=0.2)
    # the fit's own values at t are evaluate_chains', bit for bit (with the outlier pass too)
    for robust in (None, 0.01):
        ctrl, _, _, fit = fit_chains(t, Y, cid, nsp, smooth=1e-6, robust=robust,
                                     return_fitted=True)
        np.testing.assert_array_equal(fit, evaluate_chains(t, cid, nsp, ctrl))


def test_batched_fit_rejects_outliers():
    t = np.linspace(0, 1, 40)
    Y = (2 * t + 1)[:, None].copy()
    Y[7] += 5.0
    ctrl, inl, rms = fit_chains(t, Y, np.zeros(40, int), np.array([2]), robust=0.05)
    assert not inl[7] and inl.sum() >= 37  # a neighbour of the outlier may go too
    assert rms[0] < 1e-4  # the tiny smoothing penalty only


# ---------------------------------------------------------------------- network
def _surface(u, v):
    """A smooth analytic surface X(u, v) (mm) over projector coordinates (px)."""
    return np.stack([0.2 * u, 0.2 * v, 600 + 30 * np.sin(u / 150.0) * np.cos(v / 170.0)], -1)


def _netline(direction, c, w, knot=16.0):
    cc = np.full_like(w, c)
    P = _surface(cc, w) if direction == "vertical" else _surface(w, cc)
    n = int(np.ceil((w[-1] - w[0]) / knot))
    curve = lstsq_spline(w, P, w[0] + (w[-1] - w[0]) * uniform_knots01(n))
    return NetLine(direction, float(c), 0, 0, w, P, np.array([w[0]]), np.array([w[-1]]), [curve])


def test_lstsq_splines_is_bit_for_bit_one_fit_at_a_time():
    """Stacked fits on shared params and knots (cubic, and the quadratic of a 3-curve patch)
    give the control points of lstsq_spline one at a time, bit for bit, and fit the data."""
    rng = np.random.default_rng(5)
    for c_knots in (np.arange(100.0, 400, 16), np.array([100.0, 116.0, 132.0])):
        p = min(3, len(c_knots) - 1)
        K = averaging_knots(c_knots, p)
        w = np.linspace(c_knots[0], c_knots[-1], 6 * len(c_knots))
        pts = np.stack([_surface(w, np.full_like(w, v)) for v in (80.0, 96.0, 150.0, 290.0)])
        pts = pts + rng.normal(scale=0.01, size=pts.shape)
        Q = lstsq_splines(w, pts, K, degree=p, smooth=1e-9)
        assert Q.shape == (4, len(K) - p - 1, 3)
        for j in range(4):
            one = lstsq_spline(w, pts[j], K, degree=p, smooth=1e-9)
            assert np.array_equal(Q[j], one.control_points)
            if p == 3:  # the cubic follows the smooth surface within the noise
                assert np.abs(one.evaluate(w) - pts[j]).max() < 0.05


def test_data_ranges_equal_one_line_at_a_time():
    """The batched data ranges of a rectangle side (patch_extents) equal the single-line
    ones and the lines' true data ends, with and without the residual filter."""
    from nurbscan.reconstruct.network import _data_range, _data_ranges

    lines = [_netline("vertical", c, np.linspace(70 + 5 * k, 310 - 3 * k, 400))
             for k, c in enumerate(np.arange(100.0, 200, 16))]
    for max_res in (np.inf, 1e-3):
        got = _data_ranges(lines, 120.0, 250.0, 2.0, 10.0, max_res)
        ref = np.array([_data_range(ln, 120.0, 250.0, 2.0, 10.0, max_res) for ln in lines])
        assert np.array_equal(got, ref)
        # every line's data runs on without a gap to its own ends (the truth)
        assert np.allclose(got[:, 0], [70 + 5 * k for k in range(len(lines))], atol=1e-9)
        assert np.allclose(got[:, 1], [310 - 3 * k for k in range(len(lines))], atol=1e-9)
    # a line whose data stop 30 px short of b (a gap of 40 px > max_gap): its range ends there
    short = _netline("vertical", 300.0, np.r_[np.linspace(70, 220, 200), np.linspace(260, 310, 50)])
    assert np.allclose(_data_ranges([short], 120.0, 200.0, 2.0, 10.0)[0], (70.0, 220.0))


def test_gordon_patch_reproduces_analytic_surface():
    cu = np.sort(np.r_[np.arange(100.0, 400, 16), np.arange(106.0, 400, 16)])
    cv = np.sort(np.r_[np.arange(80.0, 300, 16), np.arange(86.0, 300, 16)])
    V = [_netline("vertical", c, np.linspace(70, 310, 400)) for c in cu]
    H = [_netline("horizontal", c, np.linspace(90, 410, 500)) for c in cv]
    mask, X = complete_cells(V, H)
    assert mask.all()
    rects = rectangles(mask, 2)
    assert rects == [(0, len(cu) - 1, 0, len(cv) - 1)]
    p = gordon_patch(V, H, rects[0])
    uu, vv = np.meshgrid(np.linspace(cu[0], cu[-1], 23), np.linspace(cv[0], cv[-1], 19),
                         indexing="ij")
    G = p.gordon.evaluate(uu.ravel(), vv.ravel())
    assert np.max(np.linalg.norm(G - _surface(uu.ravel(), vv.ravel()), axis=1)) < 2e-3
    # the Gordon surface interpolates the network curves (Gordon 1969)
    on_v = p.gordon.evaluate(np.full(50, cu[3]), np.linspace(cv[0], cv[-1], 50))
    assert np.max(np.linalg.norm(on_v - V[3].curves[0].evaluate(np.linspace(cv[0], cv[-1], 50)),
                                 axis=1)) < 1e-3
    # the skins are worse than or as good as the Gordon surface between the curves
    L1 = p.horizontal_skin.evaluate(uu.ravel(), vv.ravel())
    assert np.max(np.linalg.norm(L1 - _surface(uu.ravel(), vv.ravel()), axis=1)) < 0.05


def test_crossing_tolerance_grows_with_obliquity():
    """Curves 0.1 mm apart at their crossings: beyond a 0.07 mm tolerance seen face on, within
    it seen at a grazing angle (0.07 / max(cos, 0.3)); the line curves keep the nominal test."""
    cu = np.arange(100.0, 200, 16)
    cv = np.arange(80.0, 180, 16)
    V = [_netline("vertical", c, np.linspace(70, 190, 200)) for c in cu]
    H = [_netline("horizontal", c, np.linspace(90, 210, 200)) for c in cv]
    for ln in H:  # the horizontal family 0.1 mm off the surface, along z
        c = ln.curves[0]
        ln.curves[0] = NurbsCurve(c.degree, c.knots, c.control_points + [0.0, 0.0, 0.1])
    # the surface faces the front viewpoint (cos about 0.84) and turns from the side one (0.25)
    front = np.array([30.0, 26.0, 0.0])
    side = np.array([30.0 + 6000.0, 26.0, 600.0 + 600.0])
    mask, _ = complete_cells(V, H, 0.07)
    assert not mask.any()
    mask, _ = complete_cells(V, H, 0.07, viewpoint=front)
    assert not mask.any()
    mask, _ = complete_cells(V, H, 0.07, viewpoint=side)
    assert mask.all() and all(not ln.validated for ln in V + H)
    mask, _ = complete_cells(V, H, 0.07, viewpoint=side, min_cos=0.8)
    assert not mask.any()
    mask, _ = complete_cells(V, H, 0.11)
    assert mask.all() and all(ln.validated for ln in V + H)


def test_network_splits_at_holes():
    """A missing stretch of one vertical line (a shadow) splits the network into patches."""
    cu = np.arange(100.0, 420, 16)
    cv = np.arange(80.0, 300, 16)
    V = [_netline("vertical", c, np.linspace(70, 310, 400)) for c in cu]
    w = np.linspace(70, 310, 400)
    keep = (w < 150) | (w > 200)
    a, b = w[keep & (w < 150)], w[keep & (w > 200)]
    la, lb = _netline("vertical", cu[8], a), _netline("vertical", cu[8], b)
    V[8] = NetLine("vertical", float(cu[8]), 0, 0, w[keep], np.r_[la.points, lb.points],
                   np.array([a[0], b[0]]), np.array([a[-1], b[-1]]), la.curves + lb.curves)
    H = [_netline("horizontal", c, np.linspace(90, 430, 500)) for c in cv]
    mask, _ = complete_cells(V, H)
    bad = ~mask
    assert bad.any() and bad[7:9].any() and not bad[:7].any()
    rects = rectangles(mask, 2, overlap=False)
    covered = np.zeros_like(mask)
    for i0, i1, j0, j1 in rects:
        assert i1 - i0 >= 2 and j1 - j0 >= 2
        assert mask[i0:i1, j0:j1].all() and not covered[i0:i1, j0:j1].any()
        covered[i0:i1, j0:j1] = True
    assert len(rects) >= 2


def _chain(c, w, z):
    from nurbscan.reconstruct.triangulate import Line3D

    P = _surface(np.full_like(w, c), w)
    P[:, 2] += z  # a surface in front of (z < 0) or behind the analytic one
    return Line3D("vertical", 0, 0, float(c), np.zeros(8), np.zeros((4, 2)), 0.0, w, P)


def test_build_lines_keeps_both_sides_of_an_occluding_contour():
    """Front and back surface of one edge meet at a contour with a sub-pixel overlap in w
    (both kept, two intervals); a mislabelled chain overlapping by 10 px is dropped."""
    from nurbscan.reconstruct.network import build_lines

    back = _chain(100.0, np.linspace(60, 120.3, 120), 0.0)
    front = _chain(100.0, np.linspace(120.0, 200, 160), -25.0)
    V, H = build_lines([back, front])
    assert not H and len(V) == 1
    assert np.allclose(V[0].starts, [60, 120]) and np.allclose(V[0].ends, [120.3, 200])
    V, _ = build_lines([back, front], overlap=0.0)  # the older rule drops the smaller
    assert np.allclose(V[0].starts, [120]) and np.allclose(V[0].ends, [200])
    wrong = _chain(100.0, np.linspace(110, 150, 60), 40.0)
    V, _ = build_lines([_chain(100.0, np.linspace(60, 200, 280), 0.0), wrong])
    assert np.allclose(V[0].starts, [60]) and np.allclose(V[0].ends, [200])


def test_rectangles_greedy_largest_first():
    m = np.zeros((6, 8), bool)
    m[0:4, 0:5] = True
    m[4:6, 5:8] = True
    m[5, 0] = True
    r = rectangles(m, 2)
    assert r[0] == (0, 4, 0, 5) and r[1] == (4, 6, 5, 8) and len(r) == 2


def test_rectangles_split_as_repeated_largest():
    """The greedy split recomputes only the rows a taken rectangle changed; it gives the same
    rectangles in the same order as taking :func:`_largest` of the whole mask each time, and
    each is as large as a brute-force search finds (random masks, blobs and noise)."""
    from nurbscan.reconstruct.network import _largest

    rng = np.random.default_rng(7)
    for k in range(60):
        R, C = rng.integers(3, 40, 2)
        m = rng.random((R, C)) < (0.6 + 0.35 * (k % 3 == 0))
        if k % 2:  # blobs: rectangles of many sizes
            m = np.zeros((R, C), bool)
            for _ in range(4):
                r0, c0 = rng.integers(0, R), rng.integers(0, C)
                m[r0:r0 + rng.integers(1, 20), c0:c0 + rng.integers(1, 20)] = True
        free, ref = m.copy(), []
        while (r := _largest(free, 2, 2)) is not None:
            if not ref:  # the largest area by brute force (summed-area table)
                S = np.pad(free.astype(int).cumsum(0).cumsum(1), ((1, 0), (1, 0)))
                r0, r1, c0, c1 = np.ix_(*(np.arange(n + 1) for n in (R, R, C, C)))
                full = (S[r1, c1] - S[r0, c1] - S[r1, c0] + S[r0, c0]) == (r1 - r0) * (c1 - c0)
                area = np.where(full & (r1 - r0 >= 2) & (c1 - c0 >= 2), (r1 - r0) * (c1 - c0), 0)
                assert (r[1] - r[0]) * (r[3] - r[2]) == area.max()
            ref.append(r)
            free[r[0]:r[1], r[2]:r[3]] = False
        assert rectangles(m, 2, overlap=False) == ref


def test_rectangles_cover_narrow_strips_by_overlapping():
    """A one-cell strip beside a larger rectangle is covered by a rectangle reusing cells."""
    m = np.zeros((7, 9), bool)
    m[0:4, 0:6] = True  # 4 x 6: taken first
    m[4, 1:4] = True  # a strip one cell high below it
    m[0:2, 6] = True  # a strip one cell wide beside it
    m[6, 8] = True  # a lone cell: no 2 x 2 window of complete cells holds it
    plain = rectangles(m, 2, overlap=False)
    assert plain == [(0, 4, 0, 6)]
    r = rectangles(m, 2)
    assert r[0] == (0, 4, 0, 6) and len(r) == 3
    covered = np.zeros_like(m)
    for i0, i1, j0, j1 in r:
        assert i1 - i0 >= 2 and j1 - j0 >= 2 and m[i0:i1, j0:j1].all()
        covered[i0:i1, j0:j1] = True
    lone = np.zeros_like(m)
    lone[6, 8] = True
    assert np.array_equal(covered, m & ~lone)
    # the strip below: the rows 3-4 window grown along the strip, (3, 5, 1, 4)
    assert (3, 5, 1, 4) in r and (0, 2, 5, 7) in r


# ---------------------------------------------------------------------- frames and model I/O
def test_object_frame_matches_turntable(rig):
    tt = rig.turntable
    X = np.random.default_rng(0).normal(0, 50, (20, 3))
    for ang in (0.0, 1.1):
        rig_pts = tt.to_rig(X, ang)
        assert np.allclose(rig_to_object(rig_pts, tt, ang), X, atol=1e-9)
        plain = Turntable(point=tt.point, direction=tt.direction)
        assert np.allclose(rig_to_object(rig_pts, plain, ang), X, atol=1e-9)
    c = NurbsCurve(3, uniform_knots01(2), tt.to_rig(X[:5], 0.7))
    assert np.allclose(curve_to_object(c, tt, 0.7).control_points, X[:5], atol=1e-9)


def test_model_round_trip(tmp_path):
    c = NurbsCurve(3, uniform_knots01(1), np.arange(12.0).reshape(4, 3))
    s = NurbsSurface(1, 1, [0, 0, 1, 1], [0, 0, 1, 1], np.arange(12.0).reshape(2, 2, 3))
    m = Model(curves=[{"kind": "vertical_line", "view": 0, "direction": "vertical", "band": 3,
                       "edge": 1, "coord": 12.5, "curve": c}],
              surfaces=[{"kind": "gordon", "view": 1, "patch": 0, "vertical": [1, 2],
                         "horizontal": [3, 4], "n_curves": [2, 2], "surface": s}],
              views=[{"index": 0}], points=np.ones((5, 3)), normals=np.ones((5, 3)),
              point_view=np.zeros(5, int), meta={"x": 1})
    m.save(tmp_path / "model")
    assert {p.name for p in (tmp_path / "model").iterdir()} == {"model.json", "points.npz",
                                                                 "model.png"}
    m2 = load_model(tmp_path / "model")
    assert np.allclose(m2.curves[0]["curve"].control_points, c.control_points)
    assert np.allclose(m2.surfaces[0]["surface"].control_points, s.control_points)
    assert m2.surfaces[0]["kind"] == "gordon" and m2.points.shape == (5, 3)
    doc = json.loads((tmp_path / "model" / "model.json").read_text())
    assert doc["type"] == "nurbscan.model" and doc["counts"]["gordon"] == 1


# ---------------------------------------------------------------------- end to end
@pytest.fixture(scope="module")
def small_scan(tmp_path_factory):
    """A 768 x 576, 2-view teapot scan with a coarse grid (pitch 32, band 12 projector px)."""
    from nurbscan.pattern import Pattern
    from nurbscan.simulate.render import RenderSettings
    from nurbscan.simulate.rig import scale_camera
    from nurbscan.simulate.scan import simulate_scan
    from nurbscan.simulate.scenes import make_scene

    out = tmp_path_factory.mktemp("scan") / "scan"
    rig = scale_camera(default_rig(), 768, 576)
    simulate_scan(make_scene("teapot"), out, views=2, rig=rig, calibration=False,
                  settings=RenderSettings(samples=2),
                  pattern=Pattern.create(1920, 1080, pitch=32, band=12))
    return out


def test_detect_cli_with_the_rig(small_scan, tmp_path, capsys):
    """`nurbscan detect --calib` decodes with the rig's epipolar constraint too: at least the
    lines of a plain run, labels still right against the truth; an image of another size than
    the rig's camera is a one-line error (exit 2) and writes nothing."""
    from nurbscan.cli import main
    from nurbscan.detect import evaluate_detection
    from nurbscan.detect.result import load_detection
    from nurbscan.pattern import load_pattern

    views, pj = small_scan / "views", str(small_scan / "pattern.json")
    rig = str(small_scan / "truth" / "rig.json")
    args = ["detect", str(views / "view_00_grid.png"), "--pattern", pj, "--white",
            str(views / "view_00_white.png")]
    assert main(args + ["-o", str(tmp_path / "plain.json")]) == 0
    assert main(args + ["--calib", rig, "-o", str(tmp_path / "rig.json")]) == 0
    plain = load_detection(tmp_path / "plain.json")
    withrig = load_detection(tmp_path / "rig.json")
    assert withrig.nlines >= plain.nlines
    ev = evaluate_detection(withrig, small_scan / "truth" / "view_00.npz", load_pattern(pj))
    assert ev["label_rate"] >= 0.995, ev
    small = tmp_path / "small.png"
    cv2.imwrite(str(small), cv2.imread(str(views / "view_00_grid.png"))[:100, :100])
    capsys.readouterr()
    assert main(["detect", str(small), "--pattern", pj, "--calib", rig, "-o",
                 str(tmp_path / "x.json")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "does not match the camera" in err[0], err
    assert not (tmp_path / "x.json").exists()


def test_reconstruct_cli_without_truth_and_evaluate(small_scan, tmp_path, capsys):
    """`nurbscan reconstruct` on a copy of the scan without truth/ (the rig file given as
    --calib), then `nurbscan evaluate` against the truth: Table I figures and keys."""
    from nurbscan.cli import main

    blind = tmp_path / "blind"
    shutil.copytree(small_scan, blind, ignore=shutil.ignore_patterns("truth"))
    assert not (blind / "truth").exists()
    calib = tmp_path / "calib.json"
    shutil.copy(small_scan / "truth" / "rig.json", calib)
    assert main(["reconstruct", str(blind), "--calib", str(calib), "-o",
                 str(tmp_path / "model"), "-q"]) == 0
    model = load_model(tmp_path / "model")
    assert len(model.views) == 2
    # the merge stage ran: views 0 and 180 degrees apart do not overlap, which is said on
    # stderr (also with -q); both keep their turntable poses, recorded in model.json
    err = capsys.readouterr().err
    assert "warning: views [1] overlap no view connected to view 0" in err, err
    merge = model.meta["merge"]
    assert merge["registration"]["unregistered"] == [1] and "table" in merge
    for v in model.views:
        assert v["registration"]["axis_angle_deg"] == 0.0
        assert abs(v["registered_table_angle"] - v["table_angle"]) == 0.0
        assert np.array(v["object_from_rig"]["R"]).shape == (3, 3)
    # the detected lines of each view as a picture: the decoded lines are drawn in full
    # colour over the photograph dimmed to 35 % (at most 89 of 255 alone)
    import cv2

    for k in (0, 1):
        pic = cv2.imread(str(tmp_path / "model" / "overlays" / f"view_{k:02d}_overlay.png"))
        assert pic is not None and pic.shape == (576, 768, 3)
        assert np.mean(pic.max(axis=2) > 150) > 0.01
    assert len(model.surfaces_of("gordon")) >= 2
    assert len(model.points) > 100 and np.allclose(np.linalg.norm(model.normals, axis=1), 1)
    ls = model.meta["light_surface"]
    assert ls["vertical"]["max_px"] < 1e-3 and ls["horizontal"]["max_mm"] < 1e-3
    capsys.readouterr()
    ev_path = tmp_path / "evaluation.json"
    assert main(["evaluate", str(tmp_path / "model"), "--truth", str(small_scan / "truth"),
                 "-o", str(ev_path)]) == 0
    printed = capsys.readouterr().out
    assert "Gordon surface" in printed and "horizontal grid lines" in printed
    ev = json.loads(ev_path.read_text())
    assert set(ev["rows"]) == {"horizontal_lines", "vertical_lines", "horizontal_skin",
                               "vertical_skin", "gordon"}
    for r in ev["rows"].values():
        assert {"mean_mm", "std_mm", "min_mm", "max_mm"} <= set(r)
    assert 0 < ev["coverage"] <= 1
    assert ev_path.with_suffix(".md").exists()
    # the command line computes what the views see in a second process: same figures
    from nurbscan.evaluate import evaluate_model

    here = evaluate_model(model, small_scan / "truth", workers=1)
    assert here["coverage"] == ev["coverage"] and here["rows"]["gordon"] == ev["rows"]["gordon"]
    rows = ev["rows"]
    # a quarter-resolution camera (pixels 4x larger than the paper's) still beats the paper
    assert rows["gordon"]["mean_mm"] < 0.05 and rows["gordon"]["max_mm"] < 0.2
    assert rows["vertical_skin"]["mean_mm"] < 0.06 and rows["horizontal_skin"]["mean_mm"] < 0.08
    assert rows["vertical_lines"]["mean_mm"] < 0.06
    assert rows["horizontal_lines"]["mean_mm"] < 0.11
    assert len(ev["views"]) == 2


def test_samples_beside_an_occluding_contour_are_left_out_of_the_patches(small_scan):
    """View 0 of the small teapot scan (the true rig): with the samples within 3 px of a
    nearer surface dropped (``drop_occluded``, ``occlusion_px=3``) the worst of the Gordon patches'
    10 x 10 samples is 0.70 mm from the true surface; with them kept (``occlusion_px=None``,
    the default) 1.20 mm (measured 2026-12-02: 0.695 and 1.198 mm)."""
    from nurbscan.camera import load_rig
    from nurbscan.io import read_image
    from nurbscan.reconstruct.pipeline import plan_scan, reconstruct_detection
    from nurbscan.reconstruct.view import reconstruct_view
    from nurbscan.simulate.scenes import scene_from_dict

    rig = load_rig(small_scan / "truth" / "rig.json")
    scene = scene_from_dict(json.loads((small_scan / "truth" / "scene.json").read_text()))
    task = plan_scan(small_scan, rig, views=[0]).tasks[0]
    det = reconstruct_detection(read_image(task.grid, as_float=False), task.pattern,
                                read_image(task.white, as_float=False), rig)

    def worst(**kw):
        res = reconstruct_view(det, rig, task.pattern, **kw)
        X = np.concatenate([_grid_samples(p.gordon) for p in res.patches])
        return scene.closest_point(rig_to_object(X, rig.turntable, task.angle))[1].max()

    assert worst(occlusion_px=3.0) < 0.8
    assert worst() > 1.0


def _grid_samples(surface, n=10):
    (u0, u1), (v0, v1) = surface.domain
    uu, vv = np.meshgrid(np.linspace(u0, u1, n), np.linspace(v0, v1, n))
    return surface.evaluate(uu.ravel(), vv.ravel())


def test_views_in_two_processes_give_the_same_model(small_scan):
    from nurbscan.camera import load_rig
    from nurbscan.reconstruct import reconstruct_scan

    rig = load_rig(small_scan / "truth" / "rig.json")
    one = reconstruct_scan(small_scan, rig, workers=1)
    two = reconstruct_scan(small_scan, rig, workers=2)
    assert len(one.surfaces) == len(two.surfaces) > 0
    for a, b in zip(one.surfaces, two.surfaces, strict=True):
        assert (a["view"], a["kind"]) == (b["view"], b["kind"])
        assert np.array_equal(a["surface"].control_points, b["surface"].control_points)
    assert np.array_equal(one.points, two.points)


def test_reconstruct_cli_errors(small_scan, tmp_path, capsys):
    from nurbscan.cli import main

    assert main(["reconstruct", str(tmp_path / "nope"), "--calib",
                 str(small_scan / "truth" / "rig.json"), "-o", str(tmp_path / "m")]) == 2
    assert "scan.json" in capsys.readouterr().err
    assert main(["evaluate", str(tmp_path / "nope"), "--truth", str(small_scan / "truth")]) == 2


def test_validated_runs_need_five_agreeing_crossings():
    """A run must span two cells (five crossings) to validate a line curve."""
    from nurbscan.reconstruct.network import _validated_runs

    params = np.array([10.0, 16.0, 26.0, 32.0, 42.0, 48.0, 58.0])
    seg = np.array([0, 0, 0, 0, 0, 1, 1])
    good = np.array([True, True, False, True, True, True, True])
    # 10-16: two crossings; 32-42: two (48 is another interval); 48-58: two
    assert _validated_runs(params, seg, good) == []
    good[2] = True
    assert _validated_runs(params, seg, good) == [(10.0, 42.0, 0)]
    assert _validated_runs(params, seg, good, min_crossings=2) == [(10.0, 42.0, 0),
                                                                   (48.0, 58.0, 1)]
    good[0] = False  # 16-42: four crossings, one cell and a half
    assert _validated_runs(params, seg, good) == []
    assert _validated_runs(params, seg, good, min_crossings=3) == [(16.0, 42.0, 0)]


def test_line_curves_need_a_curve_that_fits_its_data():
    """A validated run needs its interval's curve to fit the samples (RMS within half the
    crossing tolerance); the cells do not depend on it."""
    cu = np.arange(100.0, 200, 16)
    cv = np.arange(80.0, 180, 16)
    V = [_netline("vertical", c, np.linspace(70, 190, 200)) for c in cu]
    H = [_netline("horizontal", c, np.linspace(90, 210, 200)) for c in cv]
    for ln in V + H:
        ln.fit_rms = np.array([0.002])
    V[2].fit_rms = np.array([0.05])
    mask, _ = complete_cells(V, H, 0.07)
    assert mask.all()
    assert not V[2].validated and all(ln.validated for ln in V[:2] + V[3:] + H)
    mask, _ = complete_cells(V, H, 0.07, max_fit_rms=1.0)
    assert mask.all() and V[2].validated == [(cv[0], cv[-1], 0)]


def test_cells_reach_past_the_data_ends():
    """Lines whose data stop 2 px short of their last crossing (the blurred corner of a band
    crossing) complete the last cells by their end tangents, and the patch stays exact."""
    from nurbscan.reconstruct.network import _evaluate

    cu = np.sort(np.r_[np.arange(100.0, 260, 16), np.arange(106.0, 260, 16)])
    cv = np.sort(np.r_[np.arange(80.0, 200, 16), np.arange(86.0, 200, 16)])
    # vertical data end 2 px before the last horizontal curve, horizontal ones 2 px before
    # the last vertical curve
    V = [_netline("vertical", c, np.linspace(70, cv[-1] - 2.0, 300)) for c in cu]
    H = [_netline("horizontal", c, np.linspace(90, cu[-1] - 2.0, 300)) for c in cv]
    mask0, _ = complete_cells(V, H, reach=0.0)
    assert not mask0[-1, :].any() and not mask0[:, -1].any() and mask0[:-1, :-1].all()
    mask, X = complete_cells(V, H, reach=4.0)
    assert mask.all()
    # the crossings the tangents reach are exact to the curvature term (well under 0.07 mm)
    uu, vv = np.meshgrid(cu, cv, indexing="ij")
    assert np.max(np.linalg.norm(X - _surface(uu, vv), axis=2)) < 2e-3
    p = gordon_patch(V, H, (0, len(cu) - 1, 0, len(cv) - 1), reach=4.0)
    G = p.gordon.evaluate(uu.ravel(), vv.ravel())
    assert np.max(np.linalg.norm(G - _surface(uu.ravel(), vv.ravel()), axis=1)) < 2e-3
    # beyond the domain: the end tangent line; inside: the curve
    c = V[0].curves[0]
    lo, hi = c.domain
    d1 = c.derivatives(np.array([hi]), 1)[1][0]
    ext = _evaluate(c, np.array([hi - 1.0, hi + 3.0]))
    assert np.allclose(ext[0], c.evaluate(np.array([hi - 1.0]))[0])
    assert np.allclose(ext[1], c.evaluate(np.array([hi]))[0] + 3.0 * d1)
    # a line that does not reach within 4 px stays short
    assert not complete_cells(V, H, reach=1.5)[0][-1, :].any()


def _true_error(p, n=25):
    (a0, a1), (b0, b1) = p.gordon.domain
    uu, vv = np.meshgrid(np.linspace(a0, a1, n), np.linspace(b0, b1, n), indexing="ij")
    G = p.gordon.evaluate(uu.ravel(), vv.ravel())
    return float(np.max(np.linalg.norm(G - _surface(uu.ravel(), vv.ravel()), axis=1)))


def test_patch_reaches_as_far_as_its_side_curves_go():
    """Horizontal lines lost beyond the rectangle (an occluding contour, a shadow) while the
    vertical ones go on: the patch reaches to their data ends (less the margin), at most to
    the next horizontal line; the added strip follows the true surface."""
    cu = np.sort(np.r_[np.arange(100.0, 230, 16), np.arange(106.0, 230, 16)])
    cv = np.sort(np.r_[np.arange(80.0, 200, 16), np.arange(86.0, 200, 16)])
    top = 139.0  # vertical data stop 5 px past the horizontal line at 134 (next at 144)
    V = [_netline("vertical", c, np.linspace(70, top, 300)) for c in cu]
    H = [_netline("horizontal", c, np.linspace(90, 240, 300)) for c in cv]
    mask, _ = complete_cells(V, H, reach=0.0)
    j1 = int(np.searchsorted(cv, 134.0))
    assert mask[:, :j1].all() and not mask[:, j1:].any()
    rect = rectangles(mask, 2)[0]
    assert rect == (0, len(cu) - 1, 0, j1)
    du0, du1, dv0, dv1 = patch_extents(V, H, rect, mask, margin=1.0)
    # horizontal data run 10 / 12 px past the first / last vertical curve, the vertical ones
    # 10 px below the first horizontal curve: all reach to their data less 1 px
    assert (du0, du1, dv0) == pytest.approx((9.0, 11.0, 9.0))
    assert dv1 == pytest.approx(top - 1.0 - 134.0)
    p = gordon_patch(V, H, rect, extend=(du0, du1, dv0, dv1))
    assert p.horizontal == pytest.approx((cv[0] - 9.0, top - 1.0))
    assert p.vertical == pytest.approx((cu[0] - 9.0, cu[-1] + 11.0))
    assert p.n_curves == (len(cu), j1 + 1)
    # 0.0039 mm, at the corners of two extended sides (0.033 mm without the twist term)
    assert _true_error(p) < 5e-3
    # the real curves are still interpolated
    w = np.linspace(cv[0] - 9.0, top - 1.0, 40)
    on_v = p.gordon.evaluate(np.full(40, cu[2]), w)
    assert np.max(np.linalg.norm(on_v - V[2].curves[0].evaluate(w), axis=1)) < 1e-4
    # no reach beyond the next line: data that go on to 160 stop at 144 - 1
    V2 = [_netline("vertical", c, np.linspace(70, 160, 300)) for c in cu]
    assert patch_extents(V2, H, rect, mask, margin=1.0)[3] == pytest.approx(143.0 - 134.0)
    # nor across a data gap wider than max_gap
    V3 = [_netline("vertical", c, np.r_[np.linspace(70, 135, 250), np.linspace(141, 160, 50)])
          for c in cu]
    assert patch_extents(V3, H, rect, mask, margin=1.0, max_gap=4.0)[3] == pytest.approx(0.0)
    assert patch_extents(V3, H, rect, mask, margin=1.0, max_gap=8.0)[3] == pytest.approx(9.0)
    # nor with samples its curve does not follow: a step at 136 stops the walk before it
    V4 = [_netline("vertical", c, np.linspace(70, 160, 300)) for c in cu]
    k = np.searchsorted(V4[3].w, 136.0)
    V4[3].points[k:] += [0.0, 0.0, 0.5]
    assert patch_extents(V4, H, rect, mask, margin=1.0)[3] == pytest.approx(9.0)
    assert patch_extents(V4, H, rect, mask, margin=1.0, max_res=0.07)[3] < 1.0
    # a side whose next cells are complete (another rectangle's) is not extended
    full = mask.copy()
    full[:, j1] = True
    assert patch_extents(V, H, rect, full, margin=1.0)[3] == 0.0


def _split_line(direction, c, w, gap):
    """A NetLine with no data inside ``gap`` (two intervals, one curve each)."""
    a, b = w[w <= gap[0]], w[w >= gap[1]]
    la, lb = _netline(direction, c, a), _netline(direction, c, b)
    return NetLine(direction, float(c), 0, 0, np.r_[a, b], np.r_[la.points, lb.points],
                   np.array([a[0], b[0]]), np.array([a[-1], b[-1]]), la.curves + lb.curves)


def test_cell_with_one_side_missing():
    """A vertical line has a gap in its data from 110 to 130 px, across the horizontal lines
    at 112 and 128: it covers none of its three spans from 96 to 144 px, and the six cells
    beside them miss one side each. With
    ``one_side_missing`` they are complete, the patch closes the side through the crossings
    and follows the true surface; a corner only one line covers must lie ``own_margin``
    inside that line's data, and a cell missing two sides stays out."""
    cu = np.arange(100.0, 260, 16)
    cv = np.arange(80.0, 240, 16)
    V = [_netline("vertical", c, np.linspace(70, 250, 300)) for c in cu]
    H = [_netline("horizontal", c, np.linspace(90, 270, 300)) for c in cv]
    V[4] = _split_line("vertical", cu[4], np.linspace(70, 250, 300), (110.0, 130.0))
    assert cv[2] == 112.0 and cv[3] == 128.0
    mask, _ = complete_cells(V, H)
    assert not mask[3:5, 1:4].any() and mask.sum() == mask.size - 6
    mask, _ = complete_cells(V, H, one_side_missing=True)
    assert mask.all()
    rect = rectangles(mask, 2)[0]
    assert rect == (0, len(cu) - 1, 0, len(cv) - 1)
    p = gordon_patch(V, H, rect)
    assert _true_error(p) < 1e-3
    # the missing side: the cubic through the crossings, on the true surface
    w = np.linspace(cv[1], cv[4], 20)
    side = p.gordon.evaluate(np.full(20, cu[4]), w)
    assert np.max(np.linalg.norm(side - _surface(np.full(20, cu[4]), w), axis=1)) < 1e-3
    # the real curves are still interpolated, the split line on its data too
    for ln, ww in ((V[3], np.linspace(cv[0], cv[-1], 40)), (V[4], np.linspace(cv[0], 108, 20))):
        on = p.gordon.evaluate(np.full(len(ww), ln.coord), ww)
        k = 0 if ww[-1] <= ln.ends[0] else len(ln.curves) - 1
        assert np.max(np.linalg.norm(on - ln.curves[k].evaluate(ww), axis=1)) < 1e-4
    # the horizontal line at 112 ends 5 px past the gap's line: the corner (cu[4], 112) is
    # then too near its data end for own_margin 16 px, not for 4 px
    H2 = list(H)
    H2[2] = _netline("horizontal", cv[2], np.linspace(90, cu[4] + 5.0, 200))
    m16, _ = complete_cells(V, H2, one_side_missing=True)
    m4, _ = complete_cells(V, H2, one_side_missing=True, own_margin=4.0)
    assert not m16[3, 2] and m4[3, 2]
    # the cell right of the gap misses two sides (V[4] and H2[2] beyond cu[4] + 5)
    assert not m4[4, 2] and not m4[4, 1]
    # a corner both lines cover must agree: the horizontal line at 112 lifted by 0.2 mm
    H3 = list(H)
    c = H[2].curves[0]
    H3[2] = NetLine("horizontal", cv[2], 0, 0, H[2].w, H[2].points, H[2].starts, H[2].ends,
                    [NurbsCurve(c.degree, c.knots, c.control_points + [0.0, 0.0, 0.2])])
    assert not complete_cells(V, H3, one_side_missing=True)[0][3, 2]


def test_side_short_of_its_crossing_is_closed_through_the_crossings():
    """A line whose data stop short of a crossing by less than the reach but more than the
    margin allows (a side missing, as the cell test judges it): the patch closes that side
    through the crossings instead of running the line's biased last pixels on along its
    tangent (0.11 mm off at the corner)."""
    cu = np.arange(100.0, 260, 16)
    cv = np.arange(80.0, 240, 16)
    w = np.linspace(70, 250, 600)
    H = [_netline("horizontal", c, np.linspace(90, 270, 300)) for c in cv]
    V = [_netline("vertical", c, np.linspace(70, 250, 300)) for c in cu]
    # V[4]: data stop at 220.5, 3.5 px short of the last crossing (at 224: within reach 4,
    # not with margin 1 beyond), its last 6 px biased by 0.1 mm
    a = w[w <= 220.5]
    pa = _surface(np.full_like(a, cu[4]), a) + np.where((a > 214.5)[:, None], [0, 0, 0.1], 0.0)
    ka = a[0] + (a[-1] - a[0]) * uniform_knots01(int(np.ceil((a[-1] - a[0]) / 16)))
    V[4] = NetLine("vertical", float(cu[4]), 0, 0, a, pa, np.array([a[0]]), np.array([a[-1]]),
                   [lstsq_spline(a, pa, ka)])
    assert cv[-1] == 224.0
    mask, _ = complete_cells(V, H, reach=4.0)
    assert not mask[3:5, -1].any() and mask.sum() == mask.size - 2
    mask, _ = complete_cells(V, H, reach=4.0, one_side_missing=True)
    assert mask.all()
    p = gordon_patch(V, H, rectangles(mask, 2)[0], reach=4.0)
    corner = p.gordon.evaluate(np.array([cu[4]]), np.array([224.0]))[0]
    assert np.linalg.norm(corner - _surface(cu[4], 224.0)) < 0.01


def test_patch_corner_of_two_extended_sides():
    """Both families run on past a corner: the corner is the Boolean sum of the two curves
    next to it plus the last cell's twist, and the extended patch follows the true surface
    there too (0.0016 mm; 0.035 mm without the twist term)."""
    cu = np.sort(np.r_[np.arange(100.0, 200, 16), np.arange(106.0, 200, 16)])
    cv = np.sort(np.r_[np.arange(80.0, 180, 16), np.arange(86.0, 180, 16)])
    V = [_netline("vertical", c, np.linspace(70, 186, 300)) for c in cu]
    H = [_netline("horizontal", c, np.linspace(90, 206, 300)) for c in cv]
    rect = (0, len(cu) - 3, 0, len(cv) - 3)  # lines beyond it exist but are left out
    ext = patch_extents(V, H, rect, None, margin=1.0)
    assert ext[1] == pytest.approx(cu[-2] - cu[-3] - 1.0)
    assert ext[3] == pytest.approx(cv[-2] - cv[-3] - 1.0)
    p = gordon_patch(V, H, rect, extend=ext)
    assert _true_error(p) < 3e-3
    # the corner point itself
    corner = p.gordon.evaluate(np.array([p.vertical[1]]), np.array([p.horizontal[1]]))[0]
    assert np.linalg.norm(corner - _surface(p.vertical[1], p.horizontal[1])) < 3e-3



def test_drop_occluded_removes_the_samples_beside_a_nearer_surface(rig):
    """Two horizontal-edge chains seen by the camera: one on a plane at 600 mm, one on a plane
    20 mm in front whose end lies 2 px beside the first chain's end in the image. The far
    chain's samples within 3 px of the near chain go (exactly those, by their pixel
    distance); the near chain and a chain 10 px away keep all their samples."""
    from nurbscan.reconstruct.triangulate import Line3D, drop_occluded

    cam = rig.camera

    def chain(u, v, z):  # pixels (u, v) on the plane Z = z
        o, d = cam.back_project(np.stack([u, v], 1))
        P = o + d * ((z - o[2]) / d[:, 2])[:, None]  # o: the camera centre
        return Line3D("horizontal", 0, 0, 0.0, np.zeros(8), np.zeros((4, 2)), 0.0,
                      np.arange(len(u), dtype=float), P)

    u = np.arange(500.0, 540.0)
    far = chain(u, np.full(40, 300.0), 600.0)
    near = chain(np.arange(538.0, 560.0), np.full(22, 302.0), 580.0)  # starts 2 px beside
    apart = chain(u, np.full(40, 312.0), 600.0)
    out = drop_occluded([far, near, apart], cam, radius=3.0, depth=1.0)
    assert len(out) == 3 and out[1] is near and out[2] is apart
    px_far, px_near = cam.project(far.points), cam.project(near.points)
    gap = np.min(np.linalg.norm(px_far[:, None] - px_near[None], axis=2), axis=1)
    assert np.array_equal(out[0].w, far.w[gap >= 3.0])
    assert 0 < len(far.w) - len(out[0].w) <= 4
    # nothing nearer by more than depth: nothing dropped
    same = chain(np.arange(538.0, 560.0), np.full(22, 302.0), 600.5)
    assert drop_occluded([far, same], cam, radius=3.0, depth=1.0)[0] is far
