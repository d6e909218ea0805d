"""NURBS core: evaluation, derivatives and knot operations against independent oracles.

Oracles: geomdl (NURBS-Python) for evaluation, derivatives and knot insertion of rational curves
and surfaces; scipy's BSpline for the basis functions; the unchanged geometry (exact identities)
for degree elevation, split, removal of an inserted knot, reparametrisation and reversal.
geomdl's own ``remove_knot`` is not used as an oracle: it does not restore an inserted knot
(NURBS-Python issues #135, #153, #176, still open as #188).
"""

import copy
import json

import numpy as np
import pytest
from scipy.interpolate import BSpline

from nurbscan.errors import NurbscanError
from nurbscan.nurbs import (
    NurbsCurve,
    NurbsSurface,
    basis_function_derivatives,
    evaluate_many,
    find_span,
    uniform_knots,
)
from nurbscan.nurbs.curve import evaluate_pieces

geomdl = pytest.importorskip("geomdl")
from geomdl import NURBS, operations  # noqa: E402


def random_knots(rng, n_ctrl, p):
    inner = np.sort(rng.uniform(0.0, 1.0, n_ctrl - p - 1))
    return np.concatenate([np.zeros(p + 1), inner, np.ones(p + 1)])


def random_curve(rng, p=3, n_ctrl=9, d=3, rational=True):
    w = rng.uniform(0.3, 3.0, n_ctrl) if rational else None
    return NurbsCurve(p, random_knots(rng, n_ctrl, p), rng.normal(size=(n_ctrl, d)) * 10, w)


def to_geomdl_curve(c: NurbsCurve):
    g = NURBS.Curve()
    g.degree = c.degree
    g.ctrlptsw = c.homogeneous.tolist()
    g.knotvector = c.knots.tolist()
    return g


def random_surface(rng, p=3, q=2, nu=7, nv=6, rational=True):
    w = rng.uniform(0.3, 3.0, (nu, nv)) if rational else None
    return NurbsSurface(
        p, q, random_knots(rng, nu, p), random_knots(rng, nv, q),
        rng.normal(size=(nu, nv, 3)) * 10, w,
    )


def to_geomdl_surface(s: NurbsSurface):
    g = NURBS.Surface()
    g.degree_u, g.degree_v = s.degree_u, s.degree_v
    g.ctrlpts_size_u, g.ctrlpts_size_v = s.shape
    g.ctrlptsw = s.homogeneous.reshape(-1, s.dimension + 1).tolist()
    g.knotvector_u = s.knots_u.tolist()
    g.knotvector_v = s.knots_v.tolist()
    return g


# --------------------------------------------------------------------------- basis
@pytest.mark.parametrize("p", [1, 2, 3, 5])
def test_basis_derivatives_match_scipy(p):
    rng = np.random.default_rng(p)
    n_ctrl = 11
    U = random_knots(rng, n_ctrl, p)
    u = rng.uniform(0, 1, 200)
    span = find_span(n_ctrl - 1, p, u, U)
    D = basis_function_derivatives(span, u, p, p + 1, U)
    assert D.shape == (p + 2, 200, p + 1)
    np.testing.assert_allclose(D[0].sum(axis=1), 1.0, atol=1e-14)
    for j in range(p + 1):
        cols = span - p + j
        for k in range(p + 2):
            ref = np.empty(u.size)
            for i in np.unique(cols):
                c = np.zeros(n_ctrl)
                c[i] = 1.0
                b = BSpline(U, c, p)
                sel = cols == i
                if k > p:
                    ref[sel] = 0.0
                else:
                    ref[sel] = b.derivative(k)(u[sel]) if k else b(u[sel])
            scale = max(1.0, np.abs(ref).max())
            np.testing.assert_allclose(D[k, :, j], ref, atol=1e-9 * scale)


# --------------------------------------------------------------------------- curves
@pytest.mark.parametrize("p,d", [(1, 2), (2, 3), (3, 3), (4, 2)])
def test_curve_evaluation_and_derivatives_match_geomdl(p, d):
    rng = np.random.default_rng(10 + p)
    c = random_curve(rng, p=p, n_ctrl=p + 6, d=d)
    g = to_geomdl_curve(c)
    u = np.concatenate([[0.0, 1.0], rng.uniform(0, 1, 50), c.knots[p + 1 : -p - 1]])
    np.testing.assert_allclose(c.evaluate(u), np.array(g.evaluate_list(u.tolist())), atol=1e-10)
    D = c.derivatives(u, 3)
    ref = np.array([g.derivatives(float(t), order=3) for t in u]).transpose(1, 0, 2)
    for k in range(4):
        scale = max(1.0, np.abs(ref[k]).max())
        np.testing.assert_allclose(D[k], ref[k], atol=1e-10 * scale)
    # shape contract for (...,) parameters
    uu = u[:50].reshape(2, 25)
    assert c.evaluate(uu).shape == (2, 25, d)
    np.testing.assert_array_equal(c.evaluate(uu)[1], c.evaluate(uu[1]))
    assert c.derivatives(uu, 2).shape == (3, 2, 25, d)


@pytest.mark.parametrize("r", [1, 2, 3])
def test_insert_knot_matches_geomdl_and_removal_restores(r):
    rng = np.random.default_rng(20 + r)
    for _ in range(3):
        c = random_curve(rng, p=3, n_ctrl=8)
        t = float(rng.uniform(0.05, 0.95))
        ci = c.insert_knot(t, r)
        g = to_geomdl_curve(c)
        operations.insert_knot(g, [t], [r])
        np.testing.assert_allclose(ci.knots, g.knotvector, atol=1e-12)
        np.testing.assert_allclose(ci.homogeneous, np.array(g.ctrlptsw), atol=1e-10)
        # removing the inserted knot restores the original curve exactly
        cr, removed = ci.remove_knot(t, num=r, tol=1e-9)
        assert removed == r
        np.testing.assert_allclose(cr.knots, c.knots, atol=1e-12)
        np.testing.assert_allclose(cr.homogeneous, c.homogeneous, atol=1e-10)
        # also from geomdl's inserted curve
        cg = NurbsCurve.from_homogeneous(3, g.knotvector, g.ctrlptsw)
        cr2, removed2 = cg.remove_knot(t, num=r, tol=1e-9)
        assert removed2 == r
        np.testing.assert_allclose(cr2.homogeneous, c.homogeneous, atol=1e-10)


def test_insert_existing_knot_and_refinement():
    rng = np.random.default_rng(3)
    c = random_curve(rng, p=3, n_ctrl=9)
    t = float(c.knots[5])
    ci = c.insert_knot(t, 2)
    g = to_geomdl_curve(c)
    operations.insert_knot(g, [t], [2])
    np.testing.assert_allclose(ci.homogeneous, np.array(g.ctrlptsw), atol=1e-10)
    u = np.linspace(0, 1, 301)
    cr = c.insert_knots([0.1, 0.2, 0.2, 0.77])
    assert cr.n_ctrl == c.n_ctrl + 4
    np.testing.assert_allclose(cr.evaluate(u), c.evaluate(u), atol=1e-12)
    with pytest.raises(NurbscanError):
        c.insert_knot(t, 3)  # multiplicity would exceed the degree
    with pytest.raises(NurbscanError):
        c.insert_knot(1.5)


def test_remove_knot_tolerance_bounds_the_deviation():
    rng = np.random.default_rng(4)
    c = random_curve(rng, p=3, n_ctrl=10, rational=False)
    t = float(c.knots[6])
    same, k = c.remove_knot(t, 1, tol=1e-9)
    assert k == 0 and same is c  # a generic knot is not removable within 1e-9
    u = np.linspace(0, 1, 2001)
    for tol in (0.5, 2.0, 20.0):
        cr, k = c.remove_knot(t, 1, tol=tol)
        dev = np.abs(cr.evaluate(u) - c.evaluate(u)).max()
        if k:
            assert cr.n_ctrl == c.n_ctrl - 1
            assert dev <= tol + 1e-12
    assert k == 1  # with tol = 20 (control points ~10) the knot goes
    # rational: eq. 5.30 tolerance still bounds the geometric deviation
    cw = random_curve(rng, p=2, n_ctrl=8, rational=True)
    tw = float(cw.knots[4])
    crw, kw = cw.remove_knot(tw, 1, tol=100.0)
    if kw:
        assert np.linalg.norm(crw.evaluate(u) - cw.evaluate(u), axis=1).max() <= 100.0


@pytest.mark.parametrize("p,t", [(1, 1), (2, 1), (3, 2)])
def test_degree_elevation_keeps_geometry(p, t):
    rng = np.random.default_rng(30 + p)
    c = random_curve(rng, p=p, n_ctrl=p + 5)
    e = c.elevate_degree(t)
    segments = np.unique(c.knots).size - 1
    assert e.degree == p + t and e.n_ctrl == c.n_ctrl + t * segments
    u = np.linspace(0, 1, 777)
    np.testing.assert_allclose(e.evaluate(u), c.evaluate(u), atol=1e-12)
    np.testing.assert_allclose(e.derivatives(u[1:-1], 1)[1], c.derivatives(u[1:-1], 1)[1],
                               rtol=1e-9, atol=1e-9)


def test_split_reverse_reparametrize_keep_geometry():
    rng = np.random.default_rng(5)
    c = random_curve(rng, p=3, n_ctrl=9)
    for s in (0.3, float(c.knots[5])):
        a, b = c.split(s)
        assert a.domain == (0.0, s) and b.domain == (s, 1.0)
        ua = np.linspace(0, s, 200)
        ub = np.linspace(s, 1, 200)
        np.testing.assert_allclose(a.evaluate(ua), c.evaluate(ua), atol=1e-12)
        np.testing.assert_allclose(b.evaluate(ub), c.evaluate(ub), atol=1e-12)
    u = np.linspace(0, 1, 101)
    r = c.reverse()
    np.testing.assert_allclose(r.evaluate(1 - u), c.evaluate(u), atol=1e-12)
    m = c.reparametrize(-2.0, 5.0)
    assert m.domain == (-2.0, 5.0)
    np.testing.assert_allclose(m.evaluate(-2 + 7 * u), c.evaluate(u), atol=1e-11)
    with pytest.raises(NurbscanError):
        c.split(1.0)


def test_curve_json_round_trip_and_validation():
    rng = np.random.default_rng(6)
    c = random_curve(rng, p=2, n_ctrl=6, d=2)
    d = json.loads(json.dumps(c.to_dict()))
    assert d["type"] == "nurbscan.nurbs_curve"
    c2 = NurbsCurve.from_dict(d)
    assert c2.degree == c.degree
    np.testing.assert_array_equal(c2.knots, c.knots)
    np.testing.assert_array_equal(c2.control_points, c.control_points)
    np.testing.assert_array_equal(c2.weights, c.weights)
    with pytest.raises(NurbscanError):
        NurbsCurve.from_dict({**d, "type": "other"})
    with pytest.raises(NurbscanError):
        NurbsCurve(2, [0, 0, 0, 1, 1], np.zeros((3, 2)))  # wrong knot count
    with pytest.raises(NurbscanError):
        NurbsCurve(2, [0, 0, 0, 1, 1, 1], np.zeros((3, 2)), [1, -1, 1])
    with pytest.raises(NurbscanError):
        NurbsCurve(2, [0, 0, 0.5, 0.2, 1, 1], np.zeros((3, 2)))
    assert c.is_rational and not NurbsCurve(1, [0, 0, 1, 1], np.eye(2)).is_rational


def test_evaluate_many_matches_single_curves():
    rng = np.random.default_rng(7)
    p, n_ctrl = 3, 12
    U = uniform_knots(n_ctrl, p)
    P = rng.normal(size=(5, n_ctrl, 2))
    W = rng.uniform(0.5, 2, (5, n_ctrl))
    u = rng.uniform(0, 1, 64)
    out = evaluate_many(p, U, P, u, W)
    out0 = evaluate_many(p, U, P, u)
    for i in range(5):
        np.testing.assert_allclose(out[i], NurbsCurve(p, U, P[i], W[i]).evaluate(u), atol=1e-12)
        np.testing.assert_allclose(out0[i], NurbsCurve(p, U, P[i]).evaluate(u), atol=1e-12)


def test_evaluate_pieces_is_bit_for_bit_single_curve_evaluation():
    """Curves of one degree, different knots, sizes and weights, each at its own params
    (some beyond the domain, one empty set, one above the chunk size): identical bits."""
    rng = np.random.default_rng(11)
    curves, params = [], []
    for k, n_ctrl in enumerate((4, 9, 23, 6, 15)):
        U = random_knots(rng, n_ctrl, 3) * rng.uniform(10, 500) + rng.uniform(-100, 100)
        W = rng.uniform(0.5, 2, n_ctrl) if k % 2 else None
        curves.append(NurbsCurve(3, U, rng.normal(size=(n_ctrl, 3)) * 100, W))
        m = (0, 50, 20000, 7, 300)[k]
        params.append(rng.uniform(U[0] - 2, U[-1] + 2, m))
    got = evaluate_pieces(curves, params)
    assert [g.shape for g in got] == [(len(u), 3) for u in params]
    for c, u, g in zip(curves, params, got, strict=True):
        assert np.array_equal(g, c.evaluate(u))
    with pytest.raises(NurbscanError):
        evaluate_pieces([curves[0], NurbsCurve(2, uniform_knots(5, 2), np.ones((5, 3)))],
                        [params[1], params[1]])


# --------------------------------------------------------------------------- surfaces
def test_surface_evaluation_derivatives_insertion_match_geomdl():
    rng = np.random.default_rng(8)
    s = random_surface(rng)
    g = to_geomdl_surface(s)
    u = rng.uniform(0, 1, 40)
    v = rng.uniform(0, 1, 40)
    u[:2] = [0.0, 1.0]
    v[:2] = [1.0, 0.0]
    ref = np.array(g.evaluate_list(list(zip(u.tolist(), v.tolist(), strict=True))))
    np.testing.assert_allclose(s.evaluate(u, v), ref, atol=1e-10)
    D = s.derivatives(u, v, 2)
    # geomdl: (k, 3, 3, d)
    refd = np.array([g.derivatives(a, b, order=2) for a, b in zip(u, v, strict=True)])
    for k in range(3):
        for ll in range(3 - k):
            r = refd[:, k, ll]
            np.testing.assert_allclose(D[k, ll], r, atol=1e-10 * max(1.0, np.abs(r).max()))
    grid = s.evaluate_grid(u[:7], v[:5])
    np.testing.assert_allclose(grid, s.evaluate(u[:7, None] + 0 * v[:5], v[:5] + 0 * u[:7, None]),
                               atol=1e-12)
    for direction, param in (("u", [0.37, None]), ("v", [None, 0.61])):
        t = 0.37 if direction == "u" else 0.61
        si = s.insert_knot(direction, t, 2)
        gi = copy.deepcopy(g)
        operations.insert_knot(gi, [param[0] or 0.0, param[1] or 0.0],
                               [2 if direction == "u" else 0, 2 if direction == "v" else 0])
        np.testing.assert_allclose(si.knots_u, gi.knotvector_u, atol=1e-12)
        np.testing.assert_allclose(si.knots_v, gi.knotvector_v, atol=1e-12)
        np.testing.assert_allclose(si.homogeneous.reshape(-1, 4), np.array(gi.ctrlptsw),
                                   atol=1e-10)


def test_surface_elevation_isocurves_json():
    rng = np.random.default_rng(9)
    s = random_surface(rng, p=2, q=1, nu=5, nv=4)
    e = s.elevate_degree("u", 1).elevate_degree("v", 2)
    assert (e.degree_u, e.degree_v) == (3, 3)
    u = rng.uniform(0, 1, 300)
    v = rng.uniform(0, 1, 300)
    np.testing.assert_allclose(e.evaluate(u, v), s.evaluate(u, v), atol=1e-12)
    for t in (0.0, 0.42, 1.0):
        cu = s.iso_curve("u", t)  # runs in u at v = t
        np.testing.assert_allclose(cu.evaluate(u), s.evaluate(u, np.full_like(u, t)), atol=1e-12)
        cv = s.iso_curve("v", t)  # runs in v at u = t
        np.testing.assert_allclose(cv.evaluate(v), s.evaluate(np.full_like(v, t), v), atol=1e-12)
    d = json.loads(json.dumps(s.to_dict()))
    assert d["type"] == "nurbscan.nurbs_surface"
    s2 = NurbsSurface.from_dict(d)
    np.testing.assert_array_equal(s2.evaluate(u, v), s.evaluate(u, v))
    with pytest.raises(NurbscanError):
        s.iso_curve("w", 0.5)
    with pytest.raises(NurbscanError):
        NurbsSurface.from_dict(NurbsCurve(1, [0, 0, 1, 1], np.eye(2)).to_dict())


def test_normals_plane_and_degenerate_cone():
    # a flat patch z = 0 whose u = 0 row collapses to one point (triangle): normal +z everywhere
    P = np.zeros((3, 4, 3))
    for i, r in enumerate((0.0, 0.5, 1.0)):
        P[i, :, 0] = r
        P[i, :, 1] = r * np.linspace(-1, 1, 4)
    tri = NurbsSurface(2, 3, [0, 0, 0, 1, 1, 1], [0, 0, 0, 0, 1, 1, 1, 1], P)
    u = np.array([0.0, 0.0, 0.3, 1.0, 0.0])
    v = np.array([0.0, 0.5, 0.5, 1.0, 1.0])
    n = tri.normal(u, v)
    np.testing.assert_allclose(n, np.tile([0.0, 0.0, 1.0], (5, 1)), atol=1e-9)
    # a cone with its apex at u = 1: the normal is constant along each generator
    ang = np.linspace(0, np.pi, 5)
    C = np.zeros((2, 5, 3))
    C[0, :, 0], C[0, :, 1] = np.cos(ang), np.sin(ang)
    C[1] = [0.0, 0.0, 1.0]
    cone = NurbsSurface(1, 3, [0, 0, 1, 1], [0, 0, 0, 0, 0.5, 1, 1, 1, 1], C)
    vs = np.linspace(0, 1, 9)
    n_apex = cone.normal(np.ones_like(vs), vs)
    n_mid = cone.normal(np.full_like(vs, 0.4), vs)
    np.testing.assert_allclose(n_apex, n_mid, atol=1e-7)
    np.testing.assert_allclose(np.linalg.norm(n_apex, axis=1), 1.0, atol=1e-12)
