"""Tests of conics (nurbscan.nurbs.conic) and surface construction (nurbscan.nurbs.construct)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from nurbscan.errors import NurbscanError
from nurbscan.nurbs.basis import averaging_knots, basis_matrix, chord_length_params
from nurbscan.nurbs.conic import circle, conic_arc, conic_weight, ellipse, elliptic_arc
from nurbscan.nurbs.construct import (
    GordonParts,
    gordon_surface,
    make_compatible,
    reparametrize_piecewise,
    ruled_surface,
    skin,
)
from nurbscan.nurbs.curve import NurbsCurve
from nurbscan.nurbs.intersect import closest_point_surface
from nurbscan.nurbs.surface import NurbsSurface

TEAPOT = Path(__file__).resolve().parents[1] / "src" / "nurbscan" / "data" / "teapot.bpt"
U = np.linspace(0.0, 1.0, 20001)


def interp(Q, p=3):
    """Global cubic interpolation (A9.1) through points Q, chord-length parameters."""
    Q = np.asarray(Q, float)
    u = chord_length_params(Q)
    K = averaging_knots(u, p)
    return NurbsCurve(p, K, np.linalg.solve(basis_matrix(u, p, K, len(Q)), Q))


# ------------------------------------------------------------------------------------ conics


def test_full_circle_is_exact():
    c = circle([1.0, -2.0, 3.0], 7.5, normal=[1.0, 2.0, 2.0])
    X = c.evaluate(U)
    n = np.array([1.0, 2.0, 2.0]) / 3.0
    assert c.degree == 2 and c.n_ctrl == 9
    assert np.abs(np.linalg.norm(X - [1.0, -2.0, 3.0], axis=1) - 7.5).max() < 1e-12
    assert np.abs((X - [1.0, -2.0, 3.0]) @ n).max() < 1e-12
    assert np.linalg.norm(X[0] - X[-1]) < 1e-14
    # it goes round once: the angle covers 2 pi monotonically
    e1 = (X[0] - [1.0, -2.0, 3.0]) / 7.5
    e2 = np.cross(n, e1)
    ang = np.unwrap(np.arctan2((X - [1, -2, 3]) @ e2, (X - [1, -2, 3]) @ e1))
    assert np.all(np.diff(ang) > 0) and abs(ang[-1] - ang[0] - 2 * np.pi) < 1e-12


def test_ellipse_and_arc_on_implicit_equation():
    e = ellipse([2.0, 1.0], 5.0, 2.0, x_axis=[np.cos(0.3), np.sin(0.3)])
    X = e.evaluate(U) - [2.0, 1.0]
    R = np.array([[np.cos(0.3), np.sin(0.3)], [-np.sin(0.3), np.cos(0.3)]])
    Y = X @ R.T
    assert np.abs((Y[:, 0] / 5.0) ** 2 + (Y[:, 1] / 2.0) ** 2 - 1.0).max() < 1e-13
    a = elliptic_arc([0.0, 0.0, 0.0], [1, 0, 0], [0, 1, 0], 3.0, 1.5, 0.4, 2.9)
    Z = a.evaluate(U)
    assert a.n_ctrl == 5  # 2.5 rad -> 2 arcs
    assert np.abs((Z[:, 0] / 3) ** 2 + (Z[:, 1] / 1.5) ** 2 - 1).max() < 1e-13
    assert np.allclose(Z[[0, -1], :2], [[3 * np.cos(0.4), 1.5 * np.sin(0.4)],
                                        [3 * np.cos(2.9), 1.5 * np.sin(2.9)]], atol=1e-14)


@pytest.mark.parametrize("kind", ["ellipse", "parabola", "hyperbola"])
def test_conic_arc_through_point_with_end_tangents(kind):
    if kind == "ellipse":  # x^2/9 + y^2/4 = 1
        t = np.array([0.2, 1.4, 0.9])
        pts = np.stack([3 * np.cos(t), 2 * np.sin(t)], 1)
        tans = np.stack([-3 * np.sin(t), 2 * np.cos(t)], 1)
        implicit = lambda X: (X[:, 0] / 3) ** 2 + (X[:, 1] / 2) ** 2 - 1  # noqa: E731
    elif kind == "parabola":  # y = x^2
        x = np.array([-1.0, 2.0, 0.5])
        pts = np.stack([x, x**2], 1)
        tans = np.stack([np.ones(3), 2 * x], 1)
        implicit = lambda X: X[:, 1] - X[:, 0] ** 2  # noqa: E731
    else:  # x y = 1
        x = np.array([0.4, 3.0, 1.3])
        pts = np.stack([x, 1 / x], 1)
        tans = np.stack([np.ones(3), -1 / x**2], 1)
        implicit = lambda X: X[:, 0] * X[:, 1] - 1  # noqa: E731
    c = conic_arc(pts[0], tans[0], pts[1], tans[1], pts[2])
    w1 = c.weights[1]
    assert {"ellipse": w1 < 1, "parabola": abs(w1 - 1) < 1e-12, "hyperbola": w1 > 1}[kind]
    X = c.evaluate(U)
    assert np.abs(implicit(X)).max() < 1e-12
    assert np.linalg.norm(X - pts[2], axis=1).min() < 1e-3  # dense sampling passes P
    _, u = conic_weight(*c.control_points, pts[2])
    assert np.linalg.norm(c.evaluate(u) - pts[2]) < 1e-13
    D = c.derivatives(np.array([0.0, 1.0]), 1)[1]
    cross = D[:, 0] * tans[:2, 1] - D[:, 1] * tans[:2, 0]
    assert np.abs(cross).max() < 1e-12 * np.abs(D).max() * np.abs(tans).max()
    assert np.all(np.einsum("ij,ij->i", D, tans[:2]) > 0)


def test_conic_bad_input():
    with pytest.raises(NurbscanError, match="parallel"):
        conic_arc([0, 0], [1, 0], [0, 1], [1, 0], [0.5, 0.5])
    with pytest.raises(NurbscanError, match="P"):
        conic_arc([0, 0], [1, 0], [1, 1], [0, 1], [2.0, -1.0])
    with pytest.raises(NurbscanError, match="rx/ry"):
        ellipse([0, 0], -1.0, 1.0)
    with pytest.raises(NurbscanError, match="center"):
        circle([0.0], 1.0)


# ------------------------------------------------------------------- compatible, ruled, skin


def test_make_compatible_keeps_geometry():
    t = np.linspace(0, 1, 9)
    a = interp(np.stack([t, np.sin(3 * t), 0 * t], 1))
    b = NurbsCurve(2, [2, 2, 2, 2.5, 3, 3, 3], [[0, 0, 1], [0.3, 1, 1], [0.7, -1, 1],
                                               [1, 0, 1]])
    c = circle([0.5, 0.0, 2.0], 0.5, normal=[0, 0, 1])
    out = make_compatible([a, b, c])
    assert len({o.degree for o in out}) == 1 and out[0].degree == 3
    assert all(np.array_equal(o.knots, out[0].knots) for o in out)
    for orig, new in zip([a, b, c], out, strict=True):
        s0, s1 = orig.domain
        assert np.abs(orig.evaluate(s0 + U * (s1 - s0)) - new.evaluate(U)).max() < 1e-12


def test_ruled_surface():
    t = np.linspace(0, 1, 12)
    c1 = interp(np.stack([2 * np.cos(2 * np.pi * t), 2 * np.sin(2 * np.pi * t), 0 * t], 1))
    c2 = NurbsCurve(2, [0, 0, 0, 0.4, 1, 1, 1], [[3, 0, 5], [0, 3, 5], [-3, 0, 5], [0, -3, 5]])
    S = ruled_surface(c1, c2)
    assert S.degree_v == 1
    assert np.abs(S.evaluate(U, 0 * U) - c1.evaluate(U)).max() < 1e-12
    assert np.abs(S.evaluate(U, 0 * U + 1) - c2.evaluate(U)).max() < 1e-12
    uu = np.linspace(0, 1, 101)
    mid = S.evaluate(uu, 0.3 + 0 * uu)  # eq. 10.7: straight rulings
    assert np.abs(mid - (0.7 * c1.evaluate(uu) + 0.3 * c2.evaluate(uu))).max() < 1e-12
    # rational boundary: the rulings join the homogeneous points; the boundaries are exact
    c3 = circle([0.0, 0.0, 5.0], 3.0)
    S = ruled_surface(c1, c3)
    assert S.is_rational
    assert np.abs(S.evaluate(U, 0 * U + 1) - c3.evaluate(U)).max() < 1e-12


def test_skin_interpolates_sections_rational_and_polynomial():
    # rational: circles of varying radius -> every section point exactly on its circle
    zs = np.array([0.0, 1.0, 2.5, 3.0, 4.2])
    rs = np.array([2.0, 2.5, 1.5, 1.8, 1.0])
    secs = [circle([0.0, 0.0, z], r) for z, r in zip(zs, rs, strict=True)]
    S = skin(secs, degree_v=3)
    # default params (eq. 10.8) follow the chords between sections
    from nurbscan.nurbs.construct import skin_params
    v = skin_params(make_compatible(secs))
    for k, sec in enumerate(secs):
        X = S.evaluate(U, np.full(U.size, v[k]))
        assert np.abs(X - sec.evaluate(U)).max() < 1e-9
        assert np.abs(np.hypot(X[:, 0], X[:, 1]) - rs[k]).max() < 1e-9
    # polynomial sections with different knots, explicit parameters
    t = np.linspace(0, 1, 11)
    secs = [interp(np.stack([t * (1 + 0.1 * k), np.sin(2 * t + k), k + 0.2 * t**2], 1))
            for k in range(4)]
    S = skin(secs, degree_v=2, params=[0.0, 0.2, 0.7, 1.0])
    assert S.degree_v == 2
    for k, vk in enumerate([0.0, 0.2, 0.7, 1.0]):
        assert np.abs(S.evaluate(U, np.full(U.size, vk)) - secs[k].evaluate(U)).max() < 1e-9
    with pytest.raises(NurbscanError, match="params"):
        skin(secs, params=[0.0, 0.5, 0.4, 1.0])


def test_reparametrize_piecewise_exact():
    t = np.linspace(0, 1, 15)
    c = interp(np.stack([t, np.sin(4 * t), t**3], 1))
    old = np.array([0.0, 0.13, 0.5, 0.77, 1.0])
    new = np.array([0.0, 0.25, 0.4, 0.8, 1.0])
    r = reparametrize_piecewise(c, old, new)
    assert np.abs(r.evaluate(new) - c.evaluate(old)).max() < 1e-13
    s = np.linspace(0, 1, 3001)
    phi = np.interp(s, new, old)
    assert np.abs(r.evaluate(s) - c.evaluate(phi)).max() < 1e-12


# ------------------------------------------------------------------------------------ Gordon


def teapot_patch(k):
    tok = TEAPOT.read_text().split()
    n = int(tok[0])
    vals = np.array(tok[1:], float).reshape(n, 50)
    assert np.all(vals[:, :2] == 3)
    return vals[k, 2:].reshape(4, 4, 3)


def network(fun, us, vs, n_dense=17, rng=None):
    """u-curves (fixed v) and v-curves (fixed u) interpolating samples of fun(u, v).

    Each curve interpolates ``n_dense`` samples (jittered per curve, so the chord-length
    parameters differ between curves and the network needs reparametrising) plus the network
    nodes, so both families meet exactly at fun(us[j], vs[i]).
    """
    rng = np.random.default_rng(0) if rng is None else rng

    def samples(nodes):
        s = np.linspace(0, 1, n_dense)
        s[1:-1] += rng.uniform(-0.3, 0.3, n_dense - 2) / (n_dense - 1)
        s = s[1:-1] * (nodes[-1] - nodes[0]) + nodes[0]
        far = np.abs(s[:, None] - nodes[None]).min(axis=1) > 0.02 * (nodes[-1] - nodes[0])
        return np.sort(np.concatenate([s[far], nodes]))

    ucs = []
    for v in vs:
        s = samples(us)
        ucs.append(interp(fun(s, np.full(s.size, v))))
    vcs = []
    for u in us:
        s = samples(vs)
        vcs.append(interp(fun(np.full(s.size, u), s)))
    return ucs, vcs


def sphere_fun(R=50.0):
    def f(th, ph):
        return R * np.stack([np.cos(ph) * np.cos(th), np.cos(ph) * np.sin(th), np.sin(ph)], -1)
    return f


def max_mean(d):
    return float(d.max()), float(d.mean())


def surface_error_sphere(S, R=50.0, n=61):
    g = np.linspace(0, 1, n)
    X = S.evaluate_grid(g, g).reshape(-1, 3)
    return max_mean(np.abs(np.linalg.norm(X, axis=1) - R))


def surface_error_to(S, T, n=61):
    g = np.linspace(0, 1, n)
    X = S.evaluate_grid(g, g).reshape(-1, 3)
    return max_mean(closest_point_surface(T, X)[3])


def network_deviation(S, curves, n=101):
    s = np.linspace(0, 1, n)
    return closest_point_surface(S, np.concatenate([c.evaluate(s) for c in curves]))[3].max()


def test_gordon_interpolates_exact_network_and_parts_are_consistent():
    B = teapot_patch(4)
    T = NurbsSurface(3, 3, [0] * 4 + [1] * 4, [0] * 4 + [1] * 4, B)
    us, vs = np.linspace(0, 1, 6), np.linspace(0, 1, 5)
    ucs, vcs = network(T.evaluate, us, vs)
    parts = gordon_surface(ucs, vcs, return_parts=True)
    G = parts.surface
    assert isinstance(parts, GordonParts) and G.degree_u == 3 and G.degree_v == 3
    # G(u, v_i) = C_i and G(u_j, v) = D_j exactly (the reparametrisation is exact)
    s = np.linspace(0, 1, 401)
    for i, c in enumerate(ucs):
        ref = closest_point_surface(G, c.evaluate(s))[3]
        assert ref.max() < 1e-9
        # the iso-curve at v_i is the (reparametrised) u-curve: same points, other speed
        iso = G.evaluate(s, np.full(s.size, parts.params_v[i]))
        assert closest_point_surface(G, iso)[3].max() < 1e-12
        assert np.linalg.norm(iso[[0, -1]] - c.evaluate([0.0, 1.0]), axis=1).max() < 1e-12
    assert network_deviation(G, ucs + vcs) < 1e-9
    # the Boolean sum: L1, L2 and T are compatible and G = L1 + L2 - T
    assert np.allclose(G.control_points, parts.skin_u.control_points
                       + parts.skin_v.control_points - parts.tensor.control_points)
    nodes = G.evaluate(parts.params_u[None, :] + 0 * parts.params_v[:, None],
                       parts.params_v[:, None] + 0 * parts.params_u[None, :])
    assert np.abs(nodes - T.evaluate(us[None, :] + 0 * vs[:, None],
                                     vs[:, None] + 0 * us[None, :])).max() < 1e-12
    assert parts.mismatch < 1e-12
    again = GordonParts.from_dict(parts.to_dict())
    assert np.array_equal(again.surface.control_points, G.control_points)


def test_gordon_input_order_and_orientation_do_not_matter():
    f = sphere_fun()
    us, vs = np.linspace(0.2, 1.4, 5), np.linspace(-0.6, 0.7, 4)
    ucs, vcs = network(f, us, vs)
    G0 = gordon_surface(ucs, vcs)
    shuffled_u = [ucs[2], ucs[0].reverse(), ucs[3], ucs[1]]
    shuffled_v = [vcs[4].reverse(), vcs[1], vcs[0], vcs[3], vcs[2].reverse()]
    G1 = gordon_surface(shuffled_u, shuffled_v)
    assert network_deviation(G1, ucs + vcs) < 1e-9
    g = np.linspace(0, 1, 31)
    assert np.abs(G0.evaluate_grid(g, g) - G1.evaluate_grid(g, g)).max() < 1e-9


def test_gordon_bad_networks():
    f = sphere_fun()
    us, vs = np.linspace(0.2, 1.4, 4), np.linspace(-0.6, 0.7, 3)
    ucs, vcs = network(f, us, vs)
    moved = NurbsCurve(vcs[1].degree, vcs[1].knots, vcs[1].control_points + [0, 0, 0.5])
    msg = r"u_curves\[\d\]/v_curves\[1\]: the curves do not meet"
    with pytest.raises(NurbscanError, match=msg):
        gordon_surface(ucs, [vcs[0], moved, vcs[2], vcs[3]], tol=1e-3)
    with pytest.raises(NurbscanError, match="rational"):
        gordon_surface(ucs + [circle([0, 0, 0], 50.0)], vcs)
    with pytest.raises(NurbscanError, match="at least 2"):
        gordon_surface(ucs[:1], vcs)


def occ_builders():
    """OpenCASCADE's GeomFill_Gordon and ocp-gordon's interpolate_curve_network, if importable."""
    ocp = pytest.importorskip("OCP")
    del ocp
    from OCP.collections import Array1_double, Array1_Geom_Curve, Array1_gp_Pnt, Array1_int
    from OCP.Geom import Geom_BSplineCurve
    from OCP.GeomFill import GeomFill_Gordon
    from OCP.gp import gp_Pnt

    def to_occ(c):
        poles = Array1_gp_Pnt(1, c.n_ctrl)
        for i, p in enumerate(c.control_points):
            poles.SetValue(i + 1, gp_Pnt(*map(float, p)))
        vals, mult = np.unique(c.knots, return_counts=True)
        K, M = Array1_double(1, len(vals)), Array1_int(1, len(vals))
        for i, (v, m) in enumerate(zip(vals, mult, strict=True)):
            K.SetValue(i + 1, float(v))
            M.SetValue(i + 1, int(m))
        return Geom_BSplineCurve(poles, K, M, c.degree, False)

    def from_occ(s):
        nu, nv = s.NbUPoles(), s.NbVPoles()
        P = np.array([[s.Pole(i, j).Coord() for j in range(1, nv + 1)]
                      for i in range(1, nu + 1)])
        W = np.array([[s.Weight(i, j) for j in range(1, nv + 1)] for i in range(1, nu + 1)])
        ku = np.repeat([s.UKnot(i) for i in range(1, s.NbUKnots() + 1)],
                       [s.UMultiplicity(i) for i in range(1, s.NbUKnots() + 1)])
        kv = np.repeat([s.VKnot(i) for i in range(1, s.NbVKnots() + 1)],
                       [s.VMultiplicity(i) for i in range(1, s.NbVKnots() + 1)])
        return NurbsSurface(s.UDegree(), s.VDegree(), ku, kv, P, W)

    def occ_gordon(ucs, vcs, tol):
        prof = Array1_Geom_Curve(1, len(ucs))
        guides = Array1_Geom_Curve(1, len(vcs))
        for i, c in enumerate(ucs):
            prof.SetValue(i + 1, to_occ(c))
        for i, c in enumerate(vcs):
            guides.SetValue(i + 1, to_occ(c))
        g = GeomFill_Gordon()
        g.Init(prof, guides, tol)
        g.Perform()
        assert g.IsDone()
        return from_occ(g.Surface())

    def ocp_gordon(ucs, vcs, tol):
        import ocp_gordon as og
        return from_occ(og.interpolate_curve_network([to_occ(c) for c in ucs],
                                                     [to_occ(c) for c in vcs], tol))

    return {"GeomFill_Gordon": occ_gordon, "ocp_gordon": ocp_gordon}


def unit_grid_error(S, err_fn, n=61):
    """Error of a surface on an n x n grid over its own domain."""
    (a0, a1), (b0, b1) = S.domain
    g = np.linspace(0, 1, n)
    X = S.evaluate_grid(a0 + g * (a1 - a0), b0 + g * (b1 - b0)).reshape(-1, 3)
    return err_fn(X)


_CASES: dict = {}
REL = 1e-9  # floating-point slack of the "at least as close" comparisons (relative)


def gordon_case(case):
    """Network, our Gordon parts and both public builders' surfaces with their grid errors.

    Built once per case (module cache). Returns ``(ucs, vcs, parts, eg, e1, e2, results)`` with
    ``e*`` = (max, mean) distance to the true surface on a 61 x 61 grid over each surface's own
    domain and ``results[name] = (degree_u, degree_v, (max, mean), surface)``.
    """
    if case in _CASES:
        return _CASES[case]
    if case == "sphere":
        R = 50.0
        f = sphere_fun(R)
        us, vs = np.linspace(0.2, 1.4, 6), np.linspace(-0.6, 0.7, 5)

        def err(X):
            return max_mean(np.abs(np.linalg.norm(X, axis=1) - R))
    else:
        T = NurbsSurface(3, 3, [0] * 4 + [1] * 4, [0] * 4 + [1] * 4, teapot_patch(4))
        f = T.evaluate
        us, vs = np.linspace(0, 1, 6), np.linspace(0, 1, 5)

        def err(X):
            return max_mean(closest_point_surface(T, X)[3])

    ucs, vcs = network(f, us, vs)
    parts = gordon_surface(ucs, vcs, return_parts=True)
    eg = unit_grid_error(parts.surface, err)
    e1 = unit_grid_error(parts.skin_u, err)
    e2 = unit_grid_error(parts.skin_v, err)
    results = {}
    for name, build in occ_builders().items():
        try:
            S = build(ucs, vcs, 1e-4)
        except ImportError as exc:  # pragma: no cover - optional dependency missing
            pytest.skip(f"{name} not importable: {exc}")
        results[name] = (S.degree_u, S.degree_v, unit_grid_error(S, err), S)
    _CASES[case] = (ucs, vcs, parts, eg, e1, e2, results)
    return _CASES[case]


@pytest.mark.parametrize("case", ["sphere", "teapot"])
def test_gordon_beats_skins_and_public_builders(case):
    ucs, vcs, parts, eg, e1, e2, results = gordon_case(case)
    print(case, "gordon", eg, "skin_u", e1, "skin_v", e2,
          {k: v[:3] for k, v in results.items()})
    # the Gordon surface is closer to the true surface than either skin (max and mean)
    assert eg[0] < 0.5 * min(e1[0], e2[0]) and eg[1] < 0.5 * min(e1[1], e2[1]), (eg, e1, e2)
    assert network_deviation(parts.surface, ucs + vcs) < 1e-9
    for name, (du, dv, _e, _) in results.items():
        # no higher degree than the public builder
        assert parts.surface.degree_u <= du and parts.surface.degree_v <= dv, (name, du, dv)
    # OpenCASCADE's builder (exact, degree 9 x 9 here): at least as close, max and mean
    _, _, e, _ = results["GeomFill_Gordon"]
    assert eg[0] <= e[0] * (1 + REL) and eg[1] <= e[1] * (1 + REL), (eg, e)
    # ocp-gordon (TiGL port): mean at least as small (the max: next test); it approximates its
    # reparametrised curves, so its surface leaves the network, ours interpolates it
    _, _, e, S = results["ocp_gordon"]
    assert eg[1] <= e[1] * (1 + REL), (eg, e)
    assert network_deviation(S, ucs + vcs) > 1e3 * network_deviation(parts.surface, ucs + vcs)


# teapot: with eq. 9.8 across the curves (no end conditions) our max was 1.57095e-5 against
# ocp-gordon's 1.56779e-5; Bessel's end conditions (construct._cross_interpolation) give 1.51254e-5
@pytest.mark.parametrize("case", ["sphere", "teapot"])
def test_gordon_max_error_not_above_ocp_gordon(case):
    _, _, _, eg, _, _, results = gordon_case(case)
    _, _, e, _ = results["ocp_gordon"]
    assert eg[0] <= e[0] * (1 + REL), (eg, e)


def test_refine_knot_vector_matches_single_insertions():
    from nurbscan.nurbs.construct import refine_knot_vector

    c = circle([1.0, 2.0, 0.5], 3.0, normal=[0.0, 1.0, 1.0])  # rational, double knots
    X = np.array([0.1, 0.2, 0.3, 0.3, 0.6, 0.7, 0.9])
    Ub, Qw = refine_knot_vector(c.degree, c.knots, c.homogeneous, X)
    r = NurbsCurve.from_homogeneous(c.degree, Ub, Qw)
    assert np.array_equal(Ub, np.sort(np.concatenate([c.knots, X])))
    assert np.abs(r.evaluate(U) - c.evaluate(U)).max() < 1e-12
    seq = c
    for x in X:
        seq = seq.insert_knot(float(x), 1)
    assert np.abs(seq.control_points - r.control_points).max() < 1e-12
    with pytest.raises(NurbscanError, match="domain"):
        refine_knot_vector(c.degree, c.knots, c.homogeneous, [1.5])


def test_gordon_approx_reparametrisation_is_small_and_close():
    T = NurbsSurface(3, 3, [0] * 4 + [1] * 4, [0] * 4 + [1] * 4, teapot_patch(4))
    us, vs = np.linspace(0, 1, 7), np.linspace(0, 1, 6)
    ucs, vcs = network(T.evaluate, us, vs, n_dense=30)
    exact = gordon_surface(ucs, vcs, return_parts=True)
    approx = gordon_surface(ucs, vcs, reparametrize="approx", approx_tol=1e-6,
                            return_parts=True)
    assert approx.surface.shape[0] * 4 < exact.surface.shape[0]
    assert approx.surface.shape[1] * 4 < exact.surface.shape[1]
    # the refit moves the network curves by less than approx_tol; the nodes are exact
    assert network_deviation(approx.surface, ucs + vcs) < 1e-6
    nodes = approx.surface.evaluate(approx.params_u[None, :] + 0 * approx.params_v[:, None],
                                    approx.params_v[:, None] + 0 * approx.params_u[None, :])
    assert np.abs(nodes - T.evaluate(us[None, :] + 0 * vs[:, None],
                                     vs[:, None] + 0 * us[None, :])).max() < 1e-12

    def err(X):
        return max_mean(closest_point_surface(T, X)[3])

    ee, ea = unit_grid_error(exact.surface, err), unit_grid_error(approx.surface, err)
    assert ea[0] < 1.05 * ee[0] and ea[1] < 1.2 * ee[1], (ee, ea)
    with pytest.raises(NurbscanError, match="reparametrize"):
        gordon_surface(ucs, vcs, reparametrize="linear")
