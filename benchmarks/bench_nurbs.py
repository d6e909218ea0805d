"""Benchmark of the NURBS core: curve fitting to a tolerance and evaluation.

``bench()`` returns a dict of seconds (and a few figures of the result); run as a script to
print it. The fitting data are smooth image-like curves (px) of 1,000 points with 0.003 px
Gaussian noise, fitted to E = 0.01 px.
"""

from __future__ import annotations

import time

import numpy as np

from nurbscan.nurbs import NurbsCurve, NurbsSurface, uniform_knots
from nurbscan.nurbs.fit import fit_curve, fit_curves


def image_like_curves(n_curves: int, m: int = 1000, noise: float = 0.003, seed: int = 0):
    """Smooth edge-like curves across a 640 x 480 image, ``(n_curves, m, 2)`` px."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 1.0, m)
    out = np.empty((n_curves, m, 2))
    for i in range(n_curves):
        a = rng.uniform(0.5, 2.0, 3)
        ph = rng.uniform(0, 2 * np.pi, 3)
        x = 20 + 600 * t + 15 * np.sin(2 * np.pi * a[0] * t + ph[0])
        y = rng.uniform(60, 420) + 30 * np.sin(2 * np.pi * a[1] * t + ph[1]) \
            + 8 * np.sin(2 * np.pi * 3 * a[2] * t + ph[2])
        out[i, :, 0] = x
        out[i, :, 1] = y
    return out + rng.normal(0.0, noise, out.shape)


def bench(n_curves: int = 500, n_points: int = 1000, tolerance: float = 0.01) -> dict:
    """Time fitting and evaluation.

    Returns
    -------
    dict
        ``fit_seconds`` (all curves, one process, wall clock), ``fit_ms_per_curve``,
        ``fit_cpu_seconds`` (the same in CPU time of this process, a figure that does not
        depend on other load on the machine),
        ``fit_seconds_2_processes`` (:func:`fit_curves` with 2 workers), ``fit_mean_ctrl`` and
        ``fit_max_deviation_px`` (worst curve, must be <= tolerance),
        ``curve_eval_1e6_seconds`` (10^6 points of a cubic with 50 control points),
        ``surface_eval_1e6_seconds`` (10^6 scattered points of a bicubic 20 x 20 rational patch)
        and ``surface_grid_1e6_seconds`` (a 1000 x 1000 grid).
    """
    data = image_like_curves(n_curves, n_points)
    t0 = time.perf_counter()
    c0 = time.process_time()
    results = [fit_curve(q, 3, tolerance) for q in data]
    t_fit = time.perf_counter() - t0
    c_fit = time.process_time() - c0
    t0 = time.perf_counter()
    par = fit_curves(list(data), 3, tolerance, workers=2)
    t_par = time.perf_counter() - t0
    assert [c.n_ctrl for c, _ in par] == [c.n_ctrl for c, _ in results]
    rng = np.random.default_rng(1)
    curve = NurbsCurve(3, uniform_knots(50, 3), rng.normal(size=(50, 2)) * 100,
                       rng.uniform(0.5, 2, 50))
    u = rng.uniform(0, 1, 1_000_000)
    t0 = time.perf_counter()
    curve.evaluate(u)
    t_curve = time.perf_counter() - t0
    surf = NurbsSurface(3, 3, uniform_knots(20, 3), uniform_knots(20, 3),
                        rng.normal(size=(20, 20, 3)) * 10, rng.uniform(0.5, 2, (20, 20)))
    v = rng.uniform(0, 1, 1_000_000)
    t0 = time.perf_counter()
    surf.evaluate(u, v)
    t_surf = time.perf_counter() - t0
    t0 = time.perf_counter()
    surf.evaluate_grid(np.linspace(0, 1, 1000), np.linspace(0, 1, 1000))
    t_grid = time.perf_counter() - t0
    return {
        "fit_curves": n_curves,
        "fit_points_per_curve": n_points,
        "fit_tolerance_px": tolerance,
        "fit_seconds": t_fit,
        "fit_ms_per_curve": 1000 * t_fit / n_curves,
        "fit_cpu_seconds": c_fit,
        "fit_seconds_2_processes": t_par,
        "fit_mean_ctrl": float(np.mean([c.n_ctrl for c, _ in results])),
        "fit_max_deviation_px": float(max(d for _, d in results)),
        "curve_eval_1e6_seconds": t_curve,
        "surface_eval_1e6_seconds": t_surf,
        "surface_grid_1e6_seconds": t_grid,
    }


if __name__ == "__main__":
    for k, v in bench().items():
        print(f"{k}: {v:.4g}" if isinstance(v, float) else f"{k}: {v}")
