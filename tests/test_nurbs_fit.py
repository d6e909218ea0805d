"""Curve fitting within a tolerance (A9.10 style) and plain least squares (A9.7).

Ground truth: noisy samples of known curves (a circle arc, a sine, a cubic B-spline). The
deviation is recomputed here from the returned curve, independently of the fitting code.
"""

import numpy as np
import pytest
from scipy.spatial import cKDTree

from nurbscan.errors import NurbscanError
from nurbscan.nurbs import NurbsCurve, chord_length_params, uniform_knots
from nurbscan.nurbs.fit import fit_curve, fit_curve_lstsq, fit_curves


def circle_arc(m, rng, noise):
    t = np.linspace(0.2, 0.2 + 0.6 * np.pi, m)
    Q = np.stack([320 + 80 * np.cos(t), 240 - 80 * np.sin(t)], axis=1)
    return Q + rng.normal(0, noise, Q.shape)


def sine(m, rng, noise):
    x = np.linspace(0, 300, m)
    Q = np.stack([x, 100 + 25 * np.sin(2 * np.pi * x / 150)], axis=1)
    return Q + rng.normal(0, noise, Q.shape)


def spline(m, rng, noise):
    P = np.array([[0, 0], [60, 90], [150, -40], [220, 60], [300, 10], [360, 80]], float)
    c = NurbsCurve(3, uniform_knots(6, 3), P)
    Q = c.evaluate(np.linspace(0, 1, m))
    return Q + rng.normal(0, noise, Q.shape)


def deviation(curve, Q, params=None):
    u = chord_length_params(Q) if params is None else params
    return np.linalg.norm(curve.evaluate(u) - Q, axis=1)


def closest_distance(curve, Q, n=40001):
    """Distance from each point to the curve: nearest segment of a dense polyline (sagitta of
    the segments < 1e-5 here)."""
    a, b = curve.domain
    S = curve.evaluate(np.linspace(a, b, n))
    i = cKDTree(S).query(Q)[1]
    best = np.full(Q.shape[0], np.inf)
    for j0 in (np.maximum(i - 1, 0), np.minimum(i, n - 2)):
        A, B = S[j0], S[j0 + 1]
        t = np.clip(np.einsum("ij,ij->i", Q - A, B - A) / np.einsum("ij,ij->i", B - A, B - A),
                    0, 1)
        best = np.minimum(best, np.linalg.norm(A + t[:, None] * (B - A) - Q, axis=1))
    return best


def lstsq_min_ctrl(Q, target, degree=3):
    """Smallest n_ctrl (bisection) for which the least-squares fit is within ``target``."""
    lo, hi = degree + 1, Q.shape[0] // 2
    while lo < hi:
        mid = (lo + hi) // 2
        try:
            ok = fit_curve_lstsq(Q, mid, degree)[1] <= target
        except NurbscanError:
            ok = False
        if ok:
            hi = mid
        else:
            lo = mid + 1
    return lo


@pytest.mark.parametrize("make", [circle_arc, sine, spline])
@pytest.mark.parametrize("E", [0.01, 0.05, 0.5])
def test_fit_respects_tolerance_and_beats_lstsq(make, E):
    rng = np.random.default_rng(int(E * 1000) + len(make.__name__))
    Q = make(600, rng, noise=E / 10)
    curve, dev, u = fit_curve(Q, degree=3, tolerance=E, return_params=True)
    assert curve.degree == 3 and not curve.is_rational
    d = deviation(curve, Q, u)
    assert dev <= E and d.max() <= E
    assert dev == pytest.approx(d.max(), rel=1e-9, abs=1e-12)
    # the reported deviation is the closest distance (projected parameters), within 1e-5
    dc = closest_distance(curve, Q)
    assert dc.max() <= E + 1e-5
    np.testing.assert_allclose(d, dc, atol=1e-5 + 0.02 * E)
    # end points are interpolated (A9.7 with fixed ends)
    np.testing.assert_allclose(curve.evaluate([0.0, 1.0]), Q[[0, -1]], atol=1e-9)
    # no more control points than least squares needs for the same maximum error
    n_lsq = lstsq_min_ctrl(Q, dev)
    assert curve.n_ctrl <= n_lsq, (curve.n_ctrl, n_lsq)
    assert curve.n_ctrl < Q.shape[0] // 5


def test_fit_exact_spline_data_is_compact():
    rng = np.random.default_rng(1)
    Q = spline(400, rng, noise=0.0)
    curve, dev = fit_curve(Q, 3, 1e-3)
    assert dev <= 1e-3
    assert closest_distance(curve, Q).max() <= 1e-3 + 1e-5
    assert curve.n_ctrl <= lstsq_min_ctrl(Q, 1e-3)
    # the curve follows the underlying spline between the samples too
    P = np.array([[0, 0], [60, 90], [150, -40], [220, 60], [300, 10], [360, 80]], float)
    truth = NurbsCurve(3, uniform_knots(6, 3), P)
    fitted = curve.evaluate(np.linspace(0, 1, 3001))
    assert closest_distance(truth, fitted).max() < 2e-3


@pytest.mark.parametrize("degree", [1, 2, 4])
def test_fit_other_degrees_and_params(degree):
    rng = np.random.default_rng(2)
    Q = sine(300, rng, noise=0.002)
    params = np.linspace(0.0, 3.0, 300)
    curve, dev, u = fit_curve(Q, degree=degree, tolerance=0.02, params=params,
                              return_params=True)
    assert curve.degree == degree
    assert curve.domain == (0.0, 3.0)
    assert u[0] == 0.0 and u[-1] == 3.0 and np.all(np.diff(u) >= 0)
    assert deviation(curve, Q, u).max() <= 0.02
    assert closest_distance(curve, Q).max() <= 0.02 + 1e-5
    assert dev <= 0.02


def test_fit_3d_points():
    rng = np.random.default_rng(3)
    t = np.linspace(0, 4 * np.pi, 500)
    Q = np.stack([10 * np.cos(t), 10 * np.sin(t), 2 * t], axis=1) + rng.normal(0, 1e-3, (500, 3))
    curve, dev = fit_curve(Q, 3, 0.01)
    assert curve.dimension == 3 and dev <= 0.01
    assert deviation(curve, Q).max() <= 0.01


def test_fit_never_returns_over_tolerance():
    rng = np.random.default_rng(4)
    Q = sine(200, rng, noise=0.05)
    try:
        curve, dev = fit_curve(Q, 3, 1e-6)
    except NurbscanError as e:
        assert "diverging fit" in str(e)
    else:
        assert dev <= 1e-6 and deviation(curve, Q).max() <= 1e-6


def test_fit_bad_input():
    with pytest.raises(NurbscanError):
        fit_curve(np.zeros((3, 2)), 3, 0.01)  # too few points for degree 3
    with pytest.raises(NurbscanError):
        fit_curve(np.array([[0, 0], [1, np.nan], [2, 0], [3, 1], [4, 0]]), 3, 0.01)
    with pytest.raises(NurbscanError):
        fit_curve(np.random.default_rng(0).normal(size=(20, 2)), 3, 0.0)
    with pytest.raises(NurbscanError):
        fit_curve(np.ones((10, 2)), 3, 0.01)  # all points coincide
    with pytest.raises(NurbscanError):
        fit_curve_lstsq(np.random.default_rng(0).normal(size=(20, 2)), 30, 3)


def test_lstsq_recovers_polynomial_and_interpolates_ends():
    # a cubic polynomial curve is reproduced exactly by any cubic B-spline space
    t = np.linspace(0, 1, 200) ** 1.3
    Q = np.stack([100 * t, 3 + 50 * t - 80 * t**2 + 40 * t**3], axis=1)
    u = np.linspace(0, 1, 200)
    Qp = np.stack([100 * u, 3 + 50 * u - 80 * u**2 + 40 * u**3], axis=1)
    curve, dev = fit_curve_lstsq(Qp, 9, 3, params=u)
    assert dev < 1e-9
    np.testing.assert_allclose(curve.evaluate(u), Qp, atol=1e-9)
    curve2, dev2 = fit_curve_lstsq(Q, 12, 3)
    np.testing.assert_allclose(curve2.evaluate([0.0, 1.0]), Q[[0, -1]], atol=1e-12)
    assert dev2 == pytest.approx(deviation(curve2, Q).max())


def test_fit_guard_when_removal_overshoots(monkeypatch):
    """If knot removal broke E (bounds made 50x too loose here), knot insertion and refits
    bring the curve back within E, or the fit is refused: never a curve over E."""
    import nurbscan.nurbs.fit as fitmod

    orig = fitmod._remove_knots
    monkeypatch.setattr(
        fitmod, "_remove_knots", lambda p, U, P, u, e, E, **k: orig(p, U, P, u, e, 50 * E)
    )
    rng = np.random.default_rng(5)
    Q = sine(400, rng, noise=0.001)
    curve, dev, u = fit_curve(Q, 3, 0.01, return_params=True)
    assert dev <= 0.01 and deviation(curve, Q, u).max() <= 0.01
    # without the insertion rounds the same fit is over E, and refused
    with pytest.raises(NurbscanError, match="diverging fit"):
        fit_curve(Q, 3, 0.01, max_refine=0)


def test_fit_curves_batch_matches_single():
    rng = np.random.default_rng(6)
    data = [sine(200, rng, 0.002), circle_arc(150, rng, 0.002), spline(180, rng, 0.002)]
    single = [fit_curve(q, 3, 0.02) for q in data]
    for workers in (1, 2):
        batch = fit_curves(data, 3, 0.02, workers=workers)
        for (c1, d1), (c2, d2) in zip(single, batch, strict=True):
            np.testing.assert_array_equal(c1.knots, c2.knots)
            np.testing.assert_allclose(c1.control_points, c2.control_points, atol=1e-12)
            assert d1 == pytest.approx(d2, abs=1e-15)
