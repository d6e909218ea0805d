"""Measuring a detection against the simulator's truth (per-pixel projector coordinates).

The truth field F (``proj_x`` for vertical-band edges, ``proj_y`` for horizontal ones) is
interpolated bilinearly at each detected point p; the true edge of projector coordinate c near p
is the level set F = c, and to first order the distance from p to it, in camera px, is
``(F(p) - c) / |grad F(p)|`` (gradient by central differences of the interpolant, +-0.5 px).
Only points whose four surrounding pixels lie on one lit surface are measured.

:func:`evaluate_detection` gives the figures of a detection; its parts serve other
measurements too (``benchmarks/bench_detect_bound.py``): :func:`point_truth` (the true edge
nearest each point and the distance to it), :func:`true_edges` (the true visible edges,
sampled once per pixel row or column) and :func:`edges_found` (which of those a detection
covers).
"""

from __future__ import annotations

import os
from collections.abc import Mapping

import numpy as np

from ..errors import NurbscanError
from .decode import bilinear
from .result import DetectionResult


def _load_truth(truth) -> Mapping[str, np.ndarray]:
    if isinstance(truth, str | os.PathLike):
        from ..io.npz import read_npz

        z = read_npz(truth, ("proj_x", "proj_y", "lit", "surface_id"), "truth .npz")
        shapes = {v.shape for v in z.values()}
        if len(shapes) != 1 or len(next(iter(shapes))) != 2:
            raise NurbscanError(f"{truth}: not a truth .npz (maps of shapes "
                                f"{sorted(shapes)})")
        return z
    return truth


def _good_cells(truth) -> np.ndarray:
    """(H, W) bool: the cell [x, x+1] x [y, y+1] has four lit pixels of one surface."""
    sid = np.asarray(truth["surface_id"])
    ok = (np.asarray(truth["lit"]).astype(bool) & (sid >= 0) & np.isfinite(truth["proj_x"])
          & np.isfinite(truth["proj_y"]))
    g = np.zeros_like(ok)
    g[:-1, :-1] = (ok[:-1, :-1] & ok[1:, :-1] & ok[:-1, 1:] & ok[1:, 1:]
                   & (sid[:-1, :-1] == sid[1:, :-1]) & (sid[:-1, :-1] == sid[:-1, 1:])
                   & (sid[:-1, :-1] == sid[1:, 1:]))
    return g


def _field_at(f: np.ndarray, x: np.ndarray, y: np.ndarray):
    v = bilinear(f, x, y)
    fx = bilinear(f, x + 0.5, y) - bilinear(f, x - 0.5, y)
    fy = bilinear(f, x, y + 0.5) - bilinear(f, x, y - 0.5)
    return v, fx, fy


def _nearest_edge(edges: np.ndarray, f: np.ndarray) -> np.ndarray:
    """Index into the flattened (nbands*2) edge table of the edge nearest each value."""
    flat = edges.reshape(-1)
    o = np.argsort(flat)
    s = flat[o]
    j = np.clip(np.searchsorted(s, f), 1, len(s) - 1)
    pick = np.where(np.abs(s[j] - f) < np.abs(s[j - 1] - f), j, j - 1)
    return o[pick]


def _corner_distance(ff, oo, cc, r, c, ov, pattern, other: str) -> np.ndarray:
    """Camera px along the edge from each true crossing to the nearest band of the other
    direction (where the edge meets a crossing band's corner).

    ``ff`` / ``oo``: the edge's and the other direction's projector coordinate fields in the
    frame where the crossings were searched along axis 1, ``cc`` its good cells; the crossing
    of row ``r`` lies between columns ``c`` and ``c + 1``, with the other coordinate ``ov``.
    The distance in projector px to the nearest boundary of the other direction's bands, over
    the rate of the other coordinate along the edge: ``|grad G . t|``, ``t`` the unit tangent
    of the edge (perpendicular to ``grad F``), by differences of the fields (one-sided where
    the row above lies off the surface).
    """
    a = 0 if other == "vertical" else 1
    u = np.mod(ov - (pattern.offsets[a] - 0.5), pattern.pitch) - pattern.band
    gap = pattern.pitch - pattern.band
    dc = np.minimum(u, gap - u)  # projector px, inside the gap
    # the crossing's cell holds rows r and r + 1; row r - 1 only where its cell is good too
    r0 = np.where((r > 0) & cc[np.maximum(r - 1, 0), c], r - 1, r)
    r1 = r + 1
    span = r1 - r0
    fr = (ff[r1, c] - ff[r0, c]) / span
    fc = ff[r, c + 1] - ff[r, c]
    gr = (oo[r1, c] - oo[r0, c]) / span
    gc = oo[r, c + 1] - oo[r, c]
    with np.errstate(divide="ignore", invalid="ignore"):
        rate = np.abs(gr * fc - gc * fr) / np.hypot(fr, fc)
        return np.where(rate > 0, dc / rate, np.inf)


def true_edges(truth, pattern) -> dict[str, np.ndarray]:
    """The true, lit, visible band edges of a view, sampled once per pixel row or column.

    A vertical-band edge of projector coordinate c is sampled where it crosses a pixel row:
    between two horizontally adjacent pixel centres of one good cell (four lit pixels of one
    surface) whose ``proj_x`` lie on either side of c, at the linear interpolation of the
    crossing; a horizontal-band edge likewise along pixel columns with ``proj_y``. A sample is
    visible where the other coordinate lies outside every band of the other direction (inside
    a crossing band the edge has no contrast).

    Parameters
    ----------
    truth : path of a truth ``.npz`` or mapping with ``proj_x``, ``proj_y`` (H, W) projector px,
        ``lit`` (H, W) and ``surface_id`` (H, W)
    pattern : nurbscan.pattern.Pattern

    Returns
    -------
    dict of (M,) arrays
        ``x``, ``y`` (camera px), ``direction`` (0 vertical-band edge, 1 horizontal), ``band``
        and ``edge`` (0 rising, 1 falling), ``corner_px`` (camera px along the edge to the
        nearest band of the other direction, :func:`_corner_distance`) and ``band_px`` (the
        band's width across the edge along the pixel row or column, camera px: the pattern's
        band width over the local rate of the coordinate).
    """
    t = _load_truth(truth)
    cells = _good_cells(t)
    fx0 = np.nan_to_num(np.asarray(t["proj_x"], np.float64))
    fy0 = np.nan_to_num(np.asarray(t["proj_y"], np.float64))
    parts = []
    for dd, f, edges, other, oname in ((0, fx0, pattern.vertical_edges, fy0, "horizontal"),
                                       (1, fy0, pattern.horizontal_edges, fx0, "vertical")):
        ff = f if dd == 0 else f.T
        oo = other if dd == 0 else other.T
        cc = cells if dd == 0 else cells.T
        flat = np.sort(edges.reshape(-1))
        e0 = np.searchsorted(flat, ff[:, :-1])
        e1 = np.searchsorted(flat, ff[:, 1:])
        # the pair (i, i + 1) along the row inside one good cell
        r, c = np.nonzero(cc[:, :-1] & (np.abs(e0 - e1) == 1))
        ce = flat[np.minimum(e0[r, c], e1[r, c])]
        a, b = ff[r, c], ff[r, c + 1]
        sub = c + (ce - a) / (b - a)
        ov = oo[r, c] + (oo[r, c + 1] - oo[r, c]) * (sub - c)
        vis = pattern.stripe_field(ov, oname) < 0
        r, c, sub, ce, ov, rate = r[vis], c[vis], sub[vis], ce[vis], ov[vis], np.abs(b - a)[vis]
        bi = _nearest_edge(edges, ce)
        rf = r.astype(np.float64)
        parts.append({"x": sub if dd == 0 else rf, "y": rf if dd == 0 else sub,
                      "direction": np.full(len(r), dd, np.int64), "band": bi // 2,
                      "edge": bi % 2,
                      "corner_px": _corner_distance(ff, oo, cc, r, c, ov, pattern, oname),
                      "band_px": pattern.band / np.maximum(rate, 1e-12)})
    return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}


def edges_found(result: DetectionResult, edges: Mapping[str, np.ndarray],
                match_radius: float = 1.0) -> np.ndarray:
    """(M,) bool: a detected point of the same direction, band and edge lies within
    ``match_radius`` camera px of each true edge sample (``edges``: :func:`true_edges`)."""
    from scipy.spatial import cKDTree

    w, h = result.image_size
    span = max(w, h) + 10  # one family's points lie apart from every other's
    if not len(result.x) or not len(edges["x"]):
        return np.zeros(len(edges["x"]), bool)
    fam_det = result.point_direction * 100000 + result.point_band * 2 + result.point_edge
    fam_true = edges["direction"] * 100000 + edges["band"] * 2 + edges["edge"]
    det = np.c_[result.x + fam_det * span, result.y]
    dist, _ = cKDTree(det).query(np.c_[edges["x"] + fam_true * span, edges["y"]],
                                 distance_upper_bound=match_radius)
    return np.isfinite(dist)


def point_truth(x: np.ndarray, y: np.ndarray, direction: np.ndarray, truth, pattern
                ) -> dict[str, np.ndarray]:
    """The true edge nearest each edge point, and the point's distance to it.

    The truth field F (``proj_x`` for ``direction`` 0, ``proj_y`` for 1) is interpolated
    bilinearly at the point; the nearest true edge is the pattern edge of coordinate c nearest
    F, and the distance to it is ``(F - c) / |grad F|`` camera px (module docstring).

    Parameters
    ----------
    x, y : (N,) float
        Points, camera px.
    direction : (N,) int
        0 for vertical-band edges, 1 for horizontal ones.
    truth, pattern
        As in :func:`true_edges`.

    Returns
    -------
    dict of (N,) arrays
        ``measured`` (bool: the point's surrounding pixels lie on one lit surface, at least
        1 px inside the image), ``band`` and ``edge`` of the nearest true edge and
        ``error_px``, the signed distance to it (camera px); -1 and NaN where not measured.
    """
    t = _load_truth(truth)
    cells = _good_cells(t)
    h, w = cells.shape
    x = np.asarray(x, np.float64)
    y = np.asarray(y, np.float64)
    d = np.asarray(direction)
    xi = np.clip(np.floor(x).astype(np.int64), 0, w - 1)
    yi = np.clip(np.floor(y).astype(np.int64), 0, h - 1)
    xl = np.clip(np.floor(x - 0.5).astype(np.int64), 0, w - 1)
    yl = np.clip(np.floor(y - 0.5).astype(np.int64), 0, h - 1)
    meas = cells[yi, xi] & cells[yl, xl] & (x > 1) & (y > 1) & (x < w - 2) & (y < h - 2)
    band = np.full(len(x), -1, np.int64)
    edge = np.full(len(x), -1, np.int64)
    err = np.full(len(x), np.nan)
    for dd, name, edges in ((0, "proj_x", pattern.vertical_edges),
                            (1, "proj_y", pattern.horizontal_edges)):
        k = np.nonzero(meas & (d == dd))[0]
        v, gx, gy = _field_at(np.nan_to_num(np.asarray(t[name], np.float64)), x[k], y[k])
        ne = _nearest_edge(edges, v)
        band[k], edge[k] = ne // 2, ne % 2
        err[k] = (v - edges.reshape(-1)[ne]) / np.maximum(np.hypot(gx, gy), 1e-12)
    return {"measured": meas, "band": band, "edge": edge, "error_px": err}


def evaluate_detection(result: DetectionResult, truth, pattern, match_radius: float = 1.0,
                       corner_px: float = 2.0) -> dict[str, float]:
    """Accuracy, labelling and coverage of a detection against the truth of its view.

    Parameters
    ----------
    result : DetectionResult
    truth : path of a truth ``.npz`` or mapping with ``proj_x``, ``proj_y`` (H, W) projector px,
        ``lit`` (H, W) and ``surface_id`` (H, W)
    pattern : nurbscan.pattern.Pattern
    match_radius : float
        Largest distance (camera px) from a true edge crossing to a detected point of the same
        label for the crossing to count as covered.
    corner_px : float
        The coverage is also given apart for the true edge within this distance (camera px,
        along the edge) of a band of the other direction, where the edge meets the crossing
        band's corner (``coverage_corner``), and the rest (``coverage_open``).

    Returns
    -------
    dict
        ``rms_px`` (RMS distance of correctly labelled measured points to their true edge,
        camera px), ``median_abs_px``, ``p95_abs_px``, ``measured`` (points measured),
        ``label_rate`` (share of measured points with the right band and edge),
        ``wrong_lines_over_20px`` (lines longer than 20 px labelled wrongly), ``coverage``
        (share of the true, lit, visible edge length detected with the right label; a true
        edge is sampled where it crosses a pixel row (vertical-band edges) or column), ``true``
        crossings, ``corner_share`` (share of them within ``corner_px`` of a crossing band),
        ``coverage_corner`` and ``coverage_open`` (the coverage of those and of the others),
        ``intersections`` and their ``intersection_rms_px``.
    """
    t = _load_truth(truth)
    fxf = np.asarray(t["proj_x"], np.float64)
    fyf = np.asarray(t["proj_y"], np.float64)
    h, w = fxf.shape
    if tuple(result.image_size) != (w, h):
        raise NurbscanError(f"truth: size {w}x{h} does not match the detection's "
                            f"{result.image_size[0]}x{result.image_size[1]}")
    out: dict[str, float] = {}
    # --- edge points
    x, y = result.x, result.y
    pt = point_truth(x, y, result.point_direction, t, pattern)
    m, dist = pt["measured"], pt["error_px"]
    # correct: measured, with the band and edge of the nearest true edge (then ``dist`` is
    # the distance to the labelled edge)
    ok = correct = m & (pt["band"] == result.point_band) & (pt["edge"] == result.point_edge)
    out["measured"] = float(m.sum())
    out["label_rate"] = float(correct[m].mean()) if m.any() else float("nan")
    out["rms_px"] = float(np.sqrt(np.mean(dist[ok] ** 2))) if ok.any() else float("nan")
    out["median_abs_px"] = float(np.median(np.abs(dist[ok]))) if ok.any() else float("nan")
    out["p95_abs_px"] = float(np.percentile(np.abs(dist[ok]), 95)) if ok.any() else float("nan")
    # wrong lines: most measured points wrong; length = arc length of the polyline
    nl = result.nlines
    if nl:
        wrong = np.bincount(result.line[m & ~correct], minlength=nl)
        tot = np.bincount(result.line[m], minlength=nl)
        length = result.line_lengths()
        out["wrong_lines"] = float(np.sum(wrong > 0.5 * np.maximum(tot, 1)))
        out["wrong_lines_over_20px"] = float(np.sum((wrong > 0.5 * np.maximum(tot, 1))
                                                    & (length > 20)))
    else:
        out["wrong_lines"] = out["wrong_lines_over_20px"] = 0.0
    # --- coverage of the true visible edges
    te = true_edges(t, pattern)
    hit = edges_found(result, te, match_radius)
    near = te["corner_px"] < corner_px
    total, found = len(hit), int(hit.sum())
    n_corner, found_corner = int(near.sum()), int((hit & near).sum())
    out["true"] = float(total)
    out["coverage"] = float(found / total) if total else float("nan")
    out["corner_share"] = float(n_corner / total) if total else float("nan")
    out["coverage_corner"] = float(found_corner / n_corner) if n_corner else float("nan")
    out["coverage_open"] = (float((found - found_corner) / (total - n_corner))
                            if total > n_corner else float("nan"))
    # --- intersections
    cells = _good_cells(t)
    fx0, fy0 = np.nan_to_num(fxf), np.nan_to_num(fyf)
    n = len(result.cam)
    out["intersections"] = float(n)
    if n:
        cx, cy = result.cam[:, 0], result.cam[:, 1]
        xi = np.clip(np.floor(cx).astype(np.int64), 0, w - 1)
        yi = np.clip(np.floor(cy).astype(np.int64), 0, h - 1)
        good = cells[yi, xi] & (cx >= 0) & (cy >= 0) & (cx <= w - 1) & (cy <= h - 1)
        vx, gxx, gxy = _field_at(fx0, cx, cy)
        vy, gyx, gyy = _field_at(fy0, cx, cy)
        jac = np.stack([np.c_[gxx, gxy], np.c_[gyx, gyy]], 1)
        res = np.c_[result.proj[:, 0] - vx, result.proj[:, 1] - vy]
        with np.errstate(all="ignore"):
            delta = np.linalg.solve(jac[good] + 1e-12 * np.eye(2), res[good][..., None])[..., 0]
        e = np.hypot(delta[:, 0], delta[:, 1])
        e = e[np.isfinite(e)]
        out["intersection_rms_px"] = float(np.sqrt(np.mean(e**2))) if len(e) else float("nan")
        out["intersection_p95_px"] = float(np.percentile(e, 95)) if len(e) else float("nan")
    else:
        out["intersection_rms_px"] = out["intersection_p95_px"] = float("nan")
    return out
