"""Oracle bound: how much of the true edge length the detector's edge points can cover at a
given accuracy (the detection issue asks for 95 % coverage at an RMS of at most 0.05 px).

On the teapot view 0 at 7.1 MP (the images of ``bench_detect``), the edge points of
:func:`nurbscan.detect.detect_edge_points` are found exactly as
:func:`~nurbscan.detect.detect_grid` finds them before tracing (same normalisation, filter
scale and options, read from its signature: the Haralick zero crossings of method.md
section 2, the corner pixels included). An oracle then gives every point the label of its
nearest true edge and measures its distance to it
(:func:`~nurbscan.detect.evaluate.point_truth`), and keeps the points closer than ``t``; the
coverage of the true edges by the points kept is counted as
:func:`~nurbscan.detect.evaluate_detection` counts it
(:func:`~nurbscan.detect.evaluate.true_edges`, :func:`~nurbscan.detect.evaluate.edges_found`).

A real detector labels some points wrongly or not at all and cannot tell its exact points from
its inexact ones; keeping the points in order of their true error keeps the most points within
an RMS budget. So no labelling and no point filter can give these edge points more coverage
at a given RMS than this curve: ``coverage_at_rms_0.05`` is the most the edge points allow
at the RMS target, and ``rms_at_coverage_0.95`` the least RMS at the coverage target. The
cases ``..._refined_smoothed`` measure the points as the detector's final lines have them
(re-measured in the colour channels, smoothed along the chains): the bound of
``detect_grid`` with its own operations. Wider smoothing lowers it (``smooth_reach`` 6 / 10
instead of 3: 0.930 / 0.904 at zero noise, 0.912 / 0.888 at 1x noise, measured apart).

Figures, per case (``noise0``, ``noise1``, ``noise3``: default filter scale;
``noise1_per_band7`` / ``14``: the filter scale ``sigma`` = band width / 7 or / 14 instead of
the default / 10 at 1x noise; ``noise1_refined``: the traced points after ``detect_grid``'s
second pass, which re-measures each edge in its band's clean colour channels, given the
colours of the true labels, and the others as they are; the oracle's label stays, a point
moved to another edge counts as unmeasured; ``..._refined_smoothed``: then also smoothed
along the chains as the final lines are, after the oracle dropped the points more than
0.5 px off):

* ``sigma_px``, ``points`` (measured edge points);
* ``coverage_t0.05`` ... ``coverage_t1`` (the points closer than t px kept; at 1 px, the
  coverage's match radius, every point that can cover a true edge), and ``rms_t...`` of those;
* ``coverage_at_rms_0.05``, ``t_at_rms_0.05``; ``rms_at_coverage_0.95`` (linear between the
  ``t`` above; NaN when even all the points within 1 px do not cover 95 %).

``where`` splits the true edge samples (``noise1_refined_smoothed``, the oracle's ``t`` for an
RMS of 0.05 px) into classes: within 3 px of an occlusion or shadow boundary (of a cell that
is not four lit pixels of one surface), else on a band narrower than 5 camera px, else within 2 px
(along the edge) of a crossing band, else the rest; for each its share of the samples, its
coverage by the oracle's points and the coverage lost there (share of all samples).

Run ``python benchmarks/bench_detect_bound.py`` (prints JSON).
"""

from __future__ import annotations

import json
import sys
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

#: Errors (px) up to which the oracle keeps points; 1 px is the coverage's match radius (a
#: point farther from its edge covers nothing).
T_GRID = (0.05, 0.1, 0.15, 0.2, 0.25, 0.3, 0.4, 0.5, 0.7, 1.0)


def edge_points(grid, white, pattern, sigma_per_band: float | None = None):
    """The edge points of ``detect_grid`` before tracing, the filter scale (px), the
    normalised image and ``detect_grid``'s default options."""
    from nurbscan.detect import DetectOptions, detect_edge_points, normalize
    from nurbscan.detect.chains import SIGMA_ALONG
    from nurbscan.detect.core import (
        as_float_planes,
        auto_sigma,
        band_width_px,
        noise_level,
        per_band_for_noise,
    )

    # the default options, flat (field names are unique across the groups)
    opt = {k: v for g in DetectOptions().to_dict().values() for k, v in g.items()}
    opt["sigma_along"] = SIGMA_ALONG
    lin = as_float_planes(grid, gamma=opt["gamma"])
    wl = as_float_planes(white, "white image", gamma=opt["gamma"])
    nrm = normalize(lin, wl, window=opt["window"])
    sig = nrm.signal
    band_px = band_width_px(sig, pattern, nrm.valid)
    per_band = sigma_per_band or per_band_for_noise(noise_level(sig, nrm.valid))
    sigma = auto_sigma(band_px, per_band)
    pts = detect_edge_points(sig, sigma=sigma, threshold=opt["threshold"], valid=nrm.valid,
                             sigma_along=opt["sigma_along"],
                             dominance=min(opt["dominance"], opt["corner_dominance"]),
                             families=opt["families"], oblique=opt["oblique"],
                             fit_line=opt["fit_line"], camera_blur=opt["camera_blur"])
    return pts, sigma, nrm, opt


def refined_points(pts, nrm, opt, sigma, band, pattern, shape, truth=None):
    """The second pass of ``detect_grid`` (:func:`~nurbscan.detect.refine.refine_by_channels`:
    the edge re-measured in its band's clean colour channels) for every traced point, with
    the band's colour of its true label ``band`` (-1: no label). Returns the positions of all
    of ``pts``: re-measured where the pass could, else (untraced points too) the first
    pass's. With ``truth``, the traced points are then smoothed along their chains as
    ``detect_grid`` smooths its final lines (:func:`~nurbscan.detect.lines.smooth_chains`),
    after the oracle dropped those more than 0.5 px off their true edge, as the detector's
    filters would."""
    from nurbscan.detect import trace_lines
    from nurbscan.detect.evaluate import point_truth
    from nurbscan.detect.lines import chain_normals, smooth_chains
    from nurbscan.detect.refine import refine_by_channels

    order, line = trace_lines(pts, shape, min_length=opt["min_length"])
    keep = band[order] >= 0  # the chains keep their order
    order, line = order[keep], line[keep]
    x, y, cls = pts.x[order], pts.y[order], pts.cls[order]
    vk = cls < 2
    normal = chain_normals(x, y, vk, line)
    chn = nrm.planes()
    colour = np.asarray(pattern.rgb)[np.asarray(pattern.sequence)[band[order]]] > 127
    rx, ry, _ = refine_by_channels(chn, pts.ix[order], pts.iy[order], cls, colour, x, y,
                                   sigma, opt["sigma_along"], normal=normal,
                                   across=pts.across[order], slope=pts.slope[order])
    if truth is not None:
        e = point_truth(rx, ry, cls // 2, truth, pattern)["error_px"]
        ok = np.abs(e) <= 0.5
        a = smooth_chains(np.where(vk, ry, rx)[ok], np.where(vk, rx, ry)[ok], line[ok],
                          pts.strength[order][ok].astype(np.float64) ** 2,
                          opt["smooth_reach"])
        rx[ok] = np.where(vk[ok], a, rx[ok])
        ry[ok] = np.where(vk[ok], ry[ok], a)
    xs, ys = pts.x.copy(), pts.y.copy()
    xs[order], ys[order] = rx, ry
    return xs, ys


def labelled(x, y, direction, band, edge, pattern, size):
    """A DetectionResult of points with given labels (one line per direction, band, edge)."""
    from nurbscan.detect import DetectionResult

    key = direction * 100000 + band * 2 + edge
    u, inv = np.unique(key, return_inverse=True)
    o = np.argsort(inv, kind="stable")
    line = inv[o]
    cnt = np.bincount(line, minlength=len(u))
    ud, ub, ue = u // 100000, (u % 100000) // 2, u % 2
    coord = np.where(ud == 0,
                     pattern.vertical_edges[np.minimum(ub, len(pattern.vertical_edges) - 1),
                                            ue],
                     pattern.horizontal_edges[np.minimum(ub, len(pattern.horizontal_edges)
                                                         - 1), ue])
    z2 = np.zeros((0, 2))
    return DetectionResult(image_size=size, x=x[o], y=y[o],
                           strength=np.ones(len(x), np.float32), line=line, direction=ud,
                           band=ub, edge=ue, coord=coord, start=np.cumsum(cnt) - cnt,
                           stop=np.cumsum(cnt), votes=np.zeros(len(u), np.int64),
                           agreement=np.zeros(len(u)), cam=z2, proj=z2,
                           cross_band=z2.astype(np.int64), cross_edge=z2.astype(np.int64),
                           cross_line=z2.astype(np.int64))


def bound(grid, white, truth, pattern, sigma_per_band: float | None = None,
          where: bool = False, refined: str = "") -> dict:
    """The oracle's coverage against its RMS for one image (module docstring); ``refined``
    "pass": of the traced points after the second pass, "smoothed": and smoothed
    (:func:`refined_points`)."""
    import cv2

    from nurbscan.detect.evaluate import _good_cells, edges_found, point_truth, true_edges

    h, w = grid.shape[:2]
    pts, sigma, nrm, opt = edge_points(grid, white, pattern, sigma_per_band)
    d = (pts.cls // 2).astype(np.int64)
    pt = point_truth(pts.x, pts.y, d, truth, pattern)
    x, y = pts.x, pts.y
    if refined:
        x, y = refined_points(pts, nrm, opt, sigma, pt["band"], pattern, (h, w),
                              truth if refined == "smoothed" else None)
        pt1 = pt
        pt = point_truth(x, y, d, truth, pattern)
        # the label stays the one the oracle gave: a point moved to another edge is wrong
        pt["measured"] &= (pt["band"] == pt1["band"]) & (pt["edge"] == pt1["edge"])
    del nrm
    m = pt["measured"]
    x, y, d = x[m], y[m], d[m]
    band, edge, err = pt["band"][m], pt["edge"][m], np.abs(pt["error_px"][m])
    te = true_edges(truth, pattern)

    def kept(t):
        k = err <= t
        hit = edges_found(labelled(x[k], y[k], d[k], band[k], edge[k], pattern, (w, h)), te)
        return hit, float(np.sqrt(np.mean(err[k] ** 2))) if k.any() else float("nan")

    out = {"sigma_px": float(sigma), "points": int(len(err))}
    curve = []
    for t in T_GRID:
        hit, rms = kept(t)
        curve.append((float(hit.mean()), rms))
        out[f"coverage_t{t:g}"] = curve[-1][0]
        out[f"rms_t{t:g}"] = rms
    # the largest t whose kept points have an RMS of at most 0.05 px
    e2 = np.sort(err)
    rms_k = np.sqrt(np.cumsum(e2**2) / np.arange(1, len(e2) + 1))
    t_star = float(e2[np.nonzero(rms_k <= 0.05)[0][-1]])
    hit_star, _ = kept(t_star)
    out["t_at_rms_0.05"] = t_star
    out["coverage_at_rms_0.05"] = float(hit_star.mean())
    cov, rms = np.array(curve).T
    out["rms_at_coverage_0.95"] = (float(np.interp(0.95, cov, rms)) if cov[-1] >= 0.95
                                   else float("nan"))
    if where:
        cells = _good_cells(truth).astype(np.uint8)
        dist = cv2.distanceTransform(cells, cv2.DIST_L2, 3)
        xi = np.clip(np.round(te["x"]).astype(np.int64), 0, w - 1)
        yi = np.clip(np.round(te["y"]).astype(np.int64), 0, h - 1)
        near_boundary = dist[yi, xi] < 3
        narrow = ~near_boundary & (te["band_px"] < 5)
        corner = ~near_boundary & ~narrow & (te["corner_px"] < 2)
        rest = ~(near_boundary | narrow | corner)
        out["where"] = {
            name: {"share": float(c.mean()), "coverage": float(hit_star[c].mean()),
                   "lost_share_of_all": float((c & ~hit_star).mean())}
            for name, c in (("within 3 px of an occlusion or shadow boundary", near_boundary),
                            ("band narrower than 5 px", narrow),
                            ("within 2 px of a crossing band", corner), ("elsewhere", rest))}
    return out


def bench() -> dict:
    import bench_detect as bd

    pattern = bd._pattern()
    res = {}
    cases = (("noise0", 0.0, None, ""), ("noise1", 1.0, None, ""), ("noise3", 3.0, None, ""),
             ("noise1_per_band7", 1.0, 7.0, ""), ("noise1_per_band14", 1.0, 14.0, ""),
             ("noise1_refined", 1.0, None, "pass"),
             ("noise0_refined_smoothed", 0.0, None, "smoothed"),
             ("noise1_refined_smoothed", 1.0, None, "smoothed"))
    for name, noise, per_band, refined in cases:
        with np.load(bd.render(noise)) as z:
            truth = {k: z[k] for k in ("proj_x", "proj_y", "lit", "surface_id")}
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                r = bound(z["grid"], z["white"], truth, pattern, per_band,
                          where=name == "noise1_refined_smoothed", refined=refined)
        wh = r.pop("where", None)
        res[name] = r
        if wh:
            res["where (noise1_refined_smoothed, oracle at RMS 0.05 px)"] = wh
        print(f"[detect_bound] {name}: coverage at RMS 0.05 px "
              f"{r['coverage_at_rms_0.05']:.4f}", file=sys.stderr, flush=True)
    return res


if __name__ == "__main__":
    print(json.dumps(bench(), indent=1, default=float))
