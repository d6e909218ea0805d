"""Benchmark of Tsai's camera model: projection and back-projection of 7.1 million points.

``bench()`` returns a dict of seconds (median of 3 runs, wall clock, one process) and the
round-trip accuracy; run as a script to print it. The camera is 3072 x 2304 px (7.08 million
pixels: one ray per pixel of a full image), f = 14 mm, 2.3 um pixels, sx = 1.0031, a general
pose and k1 = 6e-4 mm^-2 (the image corners move by about 22 px), so that projection solves the
distortion cubic for every point.
"""

from __future__ import annotations

import dataclasses
import statistics
import time

import numpy as np

from nurbscan.camera import Camera


def _median_seconds(fn, repeat: int = 3):
    times, out = [], None
    for _ in range(repeat):
        t = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times), out


def bench(n_points: int = 7_100_000, k1: float = 6.0e-4, seed: int = 0) -> dict:
    """Time :meth:`Camera.back_project` and :meth:`Camera.project` on ``n_points`` points.

    Returns
    -------
    dict
        ``points``; ``back_project_s`` and ``project_s`` (median of 3, seconds);
        ``k1_zero_project_s`` (the same without distortion, no cubic);
        ``points_per_s_project``; ``max_round_trip_error_px`` (pixel -> ray -> point at a
        random depth -> pixel).
    """
    rot = np.array([[0.9362934, -0.2896295, 0.1986693],
                    [0.3129918, 0.9447025, -0.0978434],
                    [-0.1593451, 0.1537882, 0.9751703]])
    u, _, vt = np.linalg.svd(rot)  # exactly orthonormal
    cam = Camera(width=3072, height=2304, f=14.0, cx=1530.25, cy=1160.75, dx=0.0023,
                 dy=0.0023, sx=1.0031, k1=k1, R=u @ vt, T=[31.0, -22.5, 480.0])
    rng = np.random.default_rng(seed)
    px = rng.uniform([-0.5, -0.5], [cam.width - 0.5, cam.height - 0.5], (n_points, 2))
    t_bp, (origin, d) = _median_seconds(lambda: cam.back_project(px))
    pts = origin + d * rng.uniform(100.0, 3000.0, (n_points, 1))
    del d
    t_pr, back = _median_seconds(lambda: cam.project(pts))
    err = float(np.max(np.abs(back - px)))
    del back
    plain = dataclasses.replace(cam, k1=0.0)
    t_pr0, _ = _median_seconds(lambda: plain.project(pts))
    return {
        "points": n_points,
        "back_project_s": round(t_bp, 4),
        "project_s": round(t_pr, 4),
        "k1_zero_project_s": round(t_pr0, 4),
        "points_per_s_project": round(n_points / t_pr),
        "max_round_trip_error_px": err,
    }


if __name__ == "__main__":
    for key, value in bench().items():
        print(f"{key}: {value}")
