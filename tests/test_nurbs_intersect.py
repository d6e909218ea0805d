"""Tests of nurbscan.nurbs.intersect against brute-force and analytic oracles."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import root

from nurbscan.errors import NurbscanError
from nurbscan.nurbs.basis import averaging_knots, basis_matrix, chord_length_params
from nurbscan.nurbs.conic import circle
from nurbscan.nurbs.curve import NurbsCurve
from nurbscan.nurbs.intersect import (
    CurveIntersections,
    LineSurfaceHits,
    closest_point_curve,
    closest_point_surface,
    closest_points_curves,
    intersect_curve_sets,
    intersect_curves,
    intersect_line_surface,
    intersect_lines_surface,
)
from nurbscan.nurbs.surface import NurbsSurface

TEAPOT = Path(__file__).resolve().parents[1] / "src" / "nurbscan" / "data" / "teapot.bpt"


def interp(Q, p=3):
    """Global cubic interpolation (A9.1) through points Q, chord-length parameters."""
    Q = np.asarray(Q, float)
    u = chord_length_params(Q)
    U = averaging_knots(u, p)
    return NurbsCurve(p, U, np.linalg.solve(basis_matrix(u, p, U, len(Q)), Q))


def line(a, b):
    return NurbsCurve(1, [0, 0, 1, 1], [a, b])


def polyline_crossings(X, Y, chunk=400):
    """Brute-force oracle: all crossings of two dense polylines (segment/segment tests)."""
    out = []
    b0, b1 = Y[None, :-1], Y[None, 1:]
    db = b1 - b0
    for s0 in range(0, len(X) - 1, chunk):
        a0, a1 = X[s0:s0 + chunk][:, None], X[s0 + 1:s0 + chunk + 1][:, None]
        a0 = a0[: len(a1)]
        da = a1 - a0
        r = b0 - a0
        den = da[..., 0] * db[..., 1] - da[..., 1] * db[..., 0]
        with np.errstate(divide="ignore", invalid="ignore"):
            s = (r[..., 0] * db[..., 1] - r[..., 1] * db[..., 0]) / den
            t = (r[..., 0] * da[..., 1] - r[..., 1] * da[..., 0]) / den
        i, j = np.nonzero((s >= 0) & (s < 1) & (t >= 0) & (t < 1))
        out.append(a0[i, 0] + s[i, j][:, None] * da[i, 0])
    return np.concatenate(out)


def sine_curve(x0=0.3, x1=5.5 * np.pi, amp=1.0, n=80):
    x = np.linspace(x0, x1, n)
    return interp(np.stack([x, amp * np.sin(x)], 1))


def test_sine_and_line_all_five_crossings_match_brute_force():
    c = sine_curve()
    ln = line([-1.0, 0.05], [19.0, 0.05])
    res = intersect_curves(c, ln)
    oracle = polyline_crossings(c.evaluate(np.linspace(0, 1, 40001)), ln.evaluate([0.0, 1.0]))
    assert len(res) == len(oracle) == 5
    # every hit is a true intersection and matches the oracle (polyline error ~1e-7)
    assert np.abs(c.evaluate(res.u) - ln.evaluate(res.v)).max() < 1e-12
    assert np.abs(np.sort(res.points[:, 0]) - np.sort(oracle[:, 0])).max() < 1e-6
    assert np.all(np.diff(res.u) > 0)


def test_two_wavy_curves_match_brute_force():
    a = sine_curve(0.0, 12.0, 1.0, 60)
    x = np.linspace(-1.0, 13.0, 50)
    b = interp(np.stack([x, 0.7 * np.cos(1.3 * x + 0.4)], 1))
    res = intersect_curves(a, b)
    oracle = polyline_crossings(a.evaluate(np.linspace(0, 1, 6001)),
                                b.evaluate(np.linspace(0, 1, 6001)))
    assert len(res) == len(oracle) >= 5
    d = np.linalg.norm(res.points[:, None] - oracle[None], axis=2).min(axis=1)
    assert d.max() < 1e-4
    assert res.distance.max() < 1e-12


@pytest.mark.parametrize("eps, n_expected",
                         [(1e-6, 2), (1e-8, 2), (1e-13, 1), (0.0, 1), (-1e-13, 1), (-1e-6, 0)])
def test_near_tangent_parabola_and_line(eps, n_expected):
    # y = 1 - x^2 on [-1, 1] as a quadratic Bezier; the line y = 1 - eps crosses at +-sqrt(eps)
    par = NurbsCurve(2, [0, 0, 0, 1, 1, 1], [[-1.0, 0.0], [0.0, 2.0], [1.0, 0.0]])
    h = 1.0 - eps
    res = intersect_curves(par, line([-3.0, h], [3.0, h]))
    assert len(res) == n_expected
    if n_expected == 2:  # conditioning: dx = ulp / (2 sqrt(eps))
        atol = 1e-12 + 1e-15 / np.sqrt(eps)
        assert np.allclose(res.points[:, 0], [-np.sqrt(eps), np.sqrt(eps)], atol=atol, rtol=0)
        assert np.allclose(res.points[:, 1], h, atol=1e-14)
    if n_expected == 1:  # (numerically) tangential touch at (0, 1): distance minimised
        assert res.distance[0] <= abs(eps) + 1e-12
        assert abs(res.points[0, 0]) < 1e-6 and abs(res.points[0, 1] - 1.0) < 1e-12


def test_rational_circles_intersections():
    c1 = circle([0.0, 0.0], 5.0)
    c2 = circle([6.0, 1.0], 4.0)
    res = intersect_curves(c1, c2)
    # analytic: radical line
    d = np.hypot(6.0, 1.0)
    a = (25.0 - 16.0 + d * d) / (2 * d)
    h = np.sqrt(25.0 - a * a)
    e = np.array([6.0, 1.0]) / d
    n = np.array([-e[1], e[0]])
    truth = np.array([a * e + h * n, a * e - h * n])
    dd = np.linalg.norm(res.points[:, None] - truth[None], axis=2)
    assert len(res) == 2 and dd.min(axis=1).max() < 1e-12
    # crossings exactly at knots (u = 1/4, 3/4) and a tangent at a knot are found once
    res = intersect_curves(c1, line([0.0, -7.0], [0.0, 7.0]))
    assert np.allclose(res.u, [0.25, 0.75], atol=1e-12)
    res = intersect_curves(c1, line([-7.0, 5.0], [7.0, 5.0]))
    assert len(res) == 1 and abs(res.u[0] - 0.25) < 1e-6 and res.distance[0] < 1e-12


def test_batch_agrees_with_pairwise():
    rng = np.random.default_rng(3)
    x = np.linspace(0.0, 100.0, 15)
    H = [interp(np.stack([x, y0 + 3 * np.sin(x / 9 + rng.uniform(0, 6))], 1))
         for y0 in np.linspace(5, 95, 9)]
    V = [interp(np.stack([x0 + 3 * np.sin(x / 7 + rng.uniform(0, 6)), x], 1))
         for x0 in np.linspace(5, 95, 8)]
    V.append(interp(np.stack([x, 50 + 40 * np.sin(x / 15)], 1)))  # a curve crossing many
    batch = intersect_curve_sets(H, V)
    total = 0
    for i, h in enumerate(H):
        for j, v in enumerate(V):
            pair = intersect_curves(h, v)
            sel = (batch.ia == i) & (batch.ib == j)
            assert sel.sum() == len(pair)
            assert np.allclose(batch.u[sel], pair.u, atol=1e-12, rtol=0)
            assert np.allclose(batch.points[sel], pair.points, atol=1e-10, rtol=0)
            total += len(pair)
    assert total == len(batch) > 72
    assert np.all(np.bincount(batch.ia[batch.ib < 8] * 8 + batch.ib[batch.ib < 8]) == 1)
    again = CurveIntersections.from_dict(batch.to_dict())
    assert np.array_equal(again.u, batch.u) and np.array_equal(again.ia, batch.ia)


def test_same_set_and_bad_input():
    a = sine_curve()
    b = line([-1.0, 0.05], [19.0, 0.05])
    res = intersect_curve_sets([a, b], [a, b], same_set=True)
    assert len(res) == 5 and np.all(res.ia < res.ib)
    with pytest.raises(NurbscanError, match="dimensions"):
        intersect_curves(a, NurbsCurve(1, [0, 0, 1, 1], [[0, 0, 0], [1, 1, 1]]))
    with pytest.raises(NurbscanError, match="A\\[0\\]"):
        intersect_curve_sets([np.zeros(3)], [a])


def test_3d_curves_meeting_within_tol_and_closest_points():
    t = np.linspace(0, 1, 30)
    a = interp(np.stack([10 * t, np.sin(3 * t), 0.5 * t**2], 1))
    # b passes 1e-4 above a(0.4) along z, crossing in x-y
    P = a.evaluate(0.4) + [0.0, 0.0, 1e-4]
    b = interp(P + np.outer(np.linspace(-1, 1, 20), [0.1, 1.0, 0.0]))
    assert len(intersect_curves(a, b, tol=1e-6)) == 0
    res = intersect_curves(a, b, tol=1e-3)
    assert len(res) == 1 and abs(res.distance[0] - 1e-4) < 2e-6
    u, v, dist = closest_points_curves(a, b)
    assert abs(u - res.u[0]) < 1e-9 and abs(dist - res.distance[0]) < 1e-12
    # brute force closest distance
    X, Y = a.evaluate(np.linspace(0, 1, 3001)), b.evaluate(np.linspace(0, 1, 3001))
    brute = np.linalg.norm(X[:, None] - Y[None], axis=2).min()
    assert dist <= brute + 1e-15 and brute - dist < 1e-6


def test_point_to_curve_on_circle():
    c = circle([1.0, 2.0, 3.0], 5.0, normal=[0.0, 0.0, 1.0])
    rng = np.random.default_rng(0)
    th = rng.uniform(0, 2 * np.pi, 500)
    rad = rng.uniform(1.0, 9.0, 500)
    z = rng.uniform(-2, 2, 500)
    P = np.stack([1 + rad * np.cos(th), 2 + rad * np.sin(th), 3 + z], 1)
    u, C, d = closest_point_curve(c, P)
    truth = np.hypot(rad - 5.0, z)
    assert np.abs(d - truth).max() < 1e-9
    ang = np.arctan2(C[:, 1] - 2, C[:, 0] - 1)
    assert np.abs(np.angle(np.exp(1j * (ang - th)))).max() < 1e-9
    with pytest.raises(NurbscanError, match="points"):
        closest_point_curve(c, np.zeros((3, 2)))


def torus(R=10.0, r=3.0):
    """NURBS torus: a rational circle of radius r revolved on a rational unit circle (A8.1)."""
    big = circle([0.0, 0.0], 1.0)
    prof = circle([R, 0.0], r)
    Cu, Cv = big.control_points, prof.control_points
    P = np.stack([Cu[:, None, 0] * Cv[None, :, 0], Cu[:, None, 1] * Cv[None, :, 0],
                  np.broadcast_to(Cv[None, :, 1], (9, 9))], axis=-1)
    return NurbsSurface(2, 2, big.knots, prof.knots, P, np.outer(big.weights, prof.weights))


def torus_roots(o, d, R, r):
    """Analytic ray/torus quartic (|p|^2 + R^2 - r^2)^2 = 4 R^2 (x^2 + y^2), |d| = 1."""
    od, K = o @ d, o @ o + R * R - r * r
    c = [1.0, 4 * od, 2 * K + 4 * od**2 - 4 * R * R * (d[0] ** 2 + d[1] ** 2),
         4 * K * od - 8 * R * R * (o[0] * d[0] + o[1] * d[1]),
         K * K - 4 * R * R * (o[0] ** 2 + o[1] ** 2)]
    rts = np.roots(c)
    rts = rts[np.abs(rts.imag) < 1e-7].real
    # polish with Newton on the quartic
    for _ in range(5):
        rts = rts - np.polyval(c, rts) / np.polyval(np.polyder(c), rts)
    return np.sort(rts)


def test_lines_torus_every_hit_against_quartic():
    R, r = 10.0, 3.0
    T = torus(R, r)
    rng = np.random.default_rng(7)
    n = 300
    O = np.column_stack([rng.uniform(-16, 16, n), rng.uniform(-16, 16, n), rng.uniform(-4, 4, n)])
    D = rng.normal(size=(n, 3))
    D[:, 2] *= 0.15
    # plus lines through the hole in the plane z ~ 0: 4 hits each
    O2 = np.column_stack([np.full(40, -20.0), rng.uniform(-2, 2, 40), rng.uniform(-1, 1, 40)])
    D2 = np.column_stack([np.ones(40), rng.uniform(-0.05, 0.05, 40), np.zeros(40)])
    O, D = np.vstack([O, O2]), np.vstack([D, D2])
    D /= np.linalg.norm(D, axis=1, keepdims=True)
    hits = intersect_lines_surface(O, D, T)
    counts = np.zeros(5, int)
    for k in range(len(O)):
        truth = torus_roots(O[k], D[k], R, r)
        mine = hits.lam[hits.line == k]
        assert mine.size == truth.size, (k, truth, mine)
        if truth.size:
            assert np.abs(mine - truth).max() < 1e-9
        counts[truth.size] += 1
    assert counts[4] >= 40 and counts[2] > 20 and counts[0] > 20
    # hits on patch boundaries and the seams, and tangent lines (touching the top circle z = r,
    # and the outer equator): one hit per contact
    for o, d, truth in [([-20, 0, 0], [1, 0, 0], [7, 13, 27, 33]),
                        ([0, -20, 0], [0, 1, 0], [7, 13, 27, 33]),
                        ([-20, 0, 3], [1, 0, 0], [10, 30]),
                        ([13, 0, -5], [0, 0, 1], [5])]:
        h = intersect_line_surface(o, d, T)
        assert np.abs(h.lam - truth).max() < (1e-9 if len(truth) == 4 else 1e-5), (o, h.lam)
        assert h.distance.max() < 1e-11
    X = hits.points
    assert np.abs((np.hypot(X[:, 0], X[:, 1]) - R) ** 2 + X[:, 2] ** 2 - r * r).max() < 1e-9
    assert np.allclose(T.evaluate(hits.u, hits.v), X, atol=1e-12)
    again = LineSurfaceHits.from_dict(hits.to_dict())
    assert np.array_equal(again.lam, hits.lam)


def teapot_patch(k):
    tok = TEAPOT.read_text().split()
    n = int(tok[0])
    vals = np.array(tok[1:], float).reshape(n, 2 + 48)
    assert np.all(vals[:, :2] == 3)
    return vals[k, 2:].reshape(4, 4, 3)


def bezier_eval(B, u, v):
    """Independent bicubic Bezier evaluation (explicit Bernstein polynomials)."""
    def bern(t):
        t = np.asarray(t, float)[..., None]
        return np.array([1, 3, 3, 1]) * t ** np.arange(4) * (1 - t) ** (3 - np.arange(4))
    return np.einsum("...i,...j,ijc->...c", bern(u), bern(v), B)


def brute_force_hits(B, o, d):
    """Oracle: sign changes of the projected patch on a 300 x 300 grid, polished by root()."""
    a = np.array([1.0, 0, 0]) if abs(d[0]) < 0.9 else np.array([0, 1.0, 0])
    e1 = np.cross(d, a)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(d, e1)
    g = np.linspace(0, 1, 301)
    X = bezier_eval(B, g[:, None], g[None, :]) - o
    f1, f2 = X @ e1, X @ e2

    def straddle(f):
        c = np.stack([f[:-1, :-1], f[1:, :-1], f[:-1, 1:], f[1:, 1:]])
        return (c.min(0) <= 0) & (c.max(0) >= 0)

    ci, cj = np.nonzero(straddle(f1) & straddle(f2))
    sols = []
    for i, j in zip(ci, cj, strict=True):
        fun = lambda x: [(bezier_eval(B, x[0], x[1]) - o) @ e1,  # noqa: E731
                         (bezier_eval(B, x[0], x[1]) - o) @ e2]
        s = root(fun, [g[i] + 0.5 / 300, g[j] + 0.5 / 300], tol=1e-14)
        if np.hypot(*fun(s.x)) < 1e-12 and np.all(s.x >= -1e-9) and np.all(s.x <= 1 + 1e-9):
            sols.append((bezier_eval(B, *s.x) - o) @ d)
    sols = np.sort(np.array(sols))
    if sols.size:
        sols = sols[np.concatenate([[True], np.diff(sols) > 1e-7])]
    return sols


def test_lines_teapot_patch_every_hit_against_brute_force():
    B = teapot_patch(4)  # a body patch
    S = NurbsSurface(3, 3, [0] * 4 + [1] * 4, [0] * 4 + [1] * 4, B)
    rng = np.random.default_rng(11)
    n = 12
    # lines through a surface point; half of them also through a second one (>= 2 hits)
    uv = rng.uniform(0.05, 0.95, (n, 2))
    P1 = bezier_eval(B, uv[:, 0], uv[:, 1])
    uv2 = rng.uniform(0.05, 0.95, (n, 2))
    P2 = bezier_eval(B, uv2[:, 0], uv2[:, 1])
    D = np.where((np.arange(n) % 2 == 0)[:, None], P2 - P1, rng.normal(size=(n, 3)))
    D /= np.linalg.norm(D, axis=1, keepdims=True)
    O = P1 - 5.0 * D
    hits = intersect_lines_surface(O, D, S)
    n_multi = 0
    for k in range(n):
        truth = brute_force_hits(B, O[k], D[k])
        mine = hits.lam[hits.line == k]
        assert truth.size >= 1 and mine.size == truth.size, (k, truth, mine)
        assert np.abs(mine - truth).max() < 1e-9
        n_multi += truth.size >= 2
    assert n_multi >= n // 2
    single = intersect_line_surface(O[0], D[0], S)
    assert np.allclose(single.lam, hits.lam[hits.line == 0], atol=1e-12)


def test_point_to_surface_on_torus():
    R, r = 10.0, 3.0
    T = torus(R, r)
    rng = np.random.default_rng(5)
    th, ph = rng.uniform(0, 2 * np.pi, (2, 400))
    rho = rng.uniform(0.5, 2.5, 400)  # inside the tube, off the centre circle
    P = np.stack([(R + rho * np.cos(ph)) * np.cos(th), (R + rho * np.cos(ph)) * np.sin(th),
                  rho * np.sin(ph)], 1)
    u, v, S, d = closest_point_surface(T, P)
    assert np.abs(d - (r - rho)).max() < 1e-9
    assert np.allclose(T.evaluate(u, v), S, atol=1e-12)


def test_box_pair_grid_hashing_matches_brute_force():
    from nurbscan.nurbs.intersect import _box_pairs

    rng = np.random.default_rng(2)
    loA = rng.uniform(0, 1000, (2500, 2))
    hiA = loA + rng.uniform(0, 40, (2500, 2))
    loB = rng.uniform(0, 1000, (2100, 2))
    hiB = loB + rng.uniform(0, 40, (2100, 2))
    ia, ib = _box_pairs(loA, hiA, loB, hiB, 0.5)  # 5.25e6 pairs: grid path
    ov = np.all((loA[:, None] <= hiB[None] + 0.5) & (loB[None] <= hiA[:, None] + 0.5), axis=2)
    bi, bj = np.nonzero(ov)
    assert ia.size == bi.size > 1000
    assert np.array_equal(np.sort(ia * 2100 + ib), np.sort(bi * 2100 + bj))
