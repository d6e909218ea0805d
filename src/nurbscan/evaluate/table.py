"""The paper's Table I: errors of the reconstructed curves and surfaces against the truth.

Computed as the paper does (method.md section 6): every curve or patch is sampled at 100
points (curves uniformly in their parameter, patches on a 10 x 10 parameter grid), each sample's
distance to the true surface is the exact closest-point distance
(:meth:`nurbscan.simulate.scenes.Scene.closest_point`, object frame); a curve's or patch's error
is the mean of its samples; the row gives mean, standard deviation, minimum and maximum over
curves or patches, mm. The largest single-sample distance (``max_sample_mm``) is reported too:
it is the honest worst case that per-patch averaging hides.

``coverage``: the share of the turntable-visible true surface covered by Gordon patches. The
true surface is sampled area-uniformly (:meth:`Scene.sample_surface`); a sample is visible when
some view's camera sees it (a truth pixel point of that view lies within twice the pixel
footprint); it is covered when a dense sample of some Gordon patch (samples about 0.35 mm apart,
:func:`gordon_cloud`) lies within ``cover_tol`` mm.

``fused`` (:func:`fused_row`, when the model has a fused mesh): the same figures for the one
mesh of the object, over area-uniform samples of the mesh instead of entities, its coverage
(exact point-to-mesh distances of the true samples), connected parts, and its area against the
true area it covers (no doubled layers: a surface seen twice counts twice in the mesh's area,
once in the truth's).

``cad`` (:func:`cad_row`, ``evaluate_model(..., cad=True)``, ``nurbscan evaluate --cad``): the
CAD surface set (:func:`nurbscan.merge.cad.cad_set`, what ``export --format 3dm|igs|step``
writes) sampled at 3 x 3 points per kept cell (corners included), each sample's exact
distance to the true surface.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from .._parallel import in_background
from ..errors import NurbscanError
from ..io.atomic import read_json
from ..io.npz import read_npz

#: The paper's Table I (real teapot), mm: mean, std, min, max (method.md section 6).
PAPER = {
    "horizontal_lines": (0.110745, 0.0986030, 0.00179233, 0.465082),
    "vertical_lines": (0.0538629, 0.025974, 0.00384417, 0.110581),
    "horizontal_skin": (0.0940525, 0.0792902, 0.000346476, 0.558296),
    "vertical_skin": (0.121947, 0.0884404, 0.000663184, 0.449805),
    "gordon": (0.0305820, 0.0391224, 0.0000217415, 1.05252),
}
ROWS = {
    "horizontal_lines": ("curve", "horizontal_line", "horizontal grid lines"),
    "vertical_lines": ("curve", "vertical_line", "vertical grid lines"),
    "horizontal_skin": ("surface", "horizontal_skin", "horizontal skin surface"),
    "vertical_skin": ("surface", "vertical_skin", "vertical skin surface"),
    "gordon": ("surface", "gordon", "Gordon surface"),
}


def sample_entity(kind: str, obj, n: int = 100) -> np.ndarray:
    """100 samples (n, 3) of a curve (uniform in its parameter) or a surface (square grid)."""
    if kind == "curve":
        return obj.evaluate(np.linspace(*obj.domain, n))
    k = int(round(np.sqrt(n)))
    (u0, u1), (v0, v1) = obj.domain
    uu, vv = np.meshgrid(np.linspace(u0, u1, k), np.linspace(v0, v1, k), indexing="ij")
    return obj.evaluate(uu.ravel(), vv.ravel())


def _stats(per: np.ndarray, samples_max: float | None) -> dict:
    if per.size == 0:
        return {"n": 0, "mean_mm": None, "std_mm": None, "min_mm": None, "max_mm": None,
                "max_sample_mm": None}
    return {"n": int(per.size), "mean_mm": float(per.mean()), "std_mm": float(per.std()),
            "min_mm": float(per.min()), "max_mm": float(per.max()),
            "max_sample_mm": samples_max}


def _distance_job(spec: dict, points: np.ndarray) -> np.ndarray:
    from ..simulate.scenes import scene_from_dict

    return scene_from_dict(spec).closest_point(points)[1]


def entity_errors(model, scene, n: int = 100, spec: dict | None = None,
                  share: float = 0.0) -> dict:
    """Per-entity mean errors and sample maxima for every Table I row, and per view.

    All rows' samples go to one closest-point query; with the scene's ``spec`` and ``share``
    > 0 the first ``share`` of them is measured in a spawned process beside this one
    (:func:`nurbscan._parallel.in_background`; the same exact distances).

    Returns
    -------
    dict row -> {"mean": (E,), "max": (E,), "view": (E,)} in mm.
    """
    out, parts = {}, []
    for row, (what, kind, _) in ROWS.items():
        items = model.curves_of(kind) if what == "curve" else model.surfaces_of(kind)
        key = "curve" if what == "curve" else "surface"
        S = (np.concatenate([sample_entity(what, it[key], n) for it in items]) if items
             else np.zeros((0, 3)))
        parts.append((row, items, S))
    S = np.concatenate([p[2] for p in parts])
    cut = int(len(S) * share) if spec is not None else 0
    job = in_background(_distance_job, spec, S[:cut]) if cut else None
    d = scene.closest_point(S[cut:])[1] if cut < len(S) else np.zeros(0)
    if job is not None:
        d = np.concatenate([job(), d])
    at = 0
    for row, items, Sr in parts:
        dr = d[at:at + len(Sr)].reshape(len(items), n)
        at += len(Sr)
        out[row] = {"mean": dr.mean(1), "max": dr.max(1),
                    "view": np.array([it["view"] for it in items], dtype=int)}
    return out


def _visible_job(spec: dict, truth_dir: Path, n: int):
    from ..simulate.scenes import scene_from_dict

    return visible_samples(scene_from_dict(spec), truth_dir, n)


def visible_samples(scene, truth_dir: Path, n: int = 20000, seed: int = 0):
    """Area-uniform samples of the true surface, and which views' cameras see each one.

    Returns
    -------
    points : ndarray (n, 3) mm, object frame
    seen : ndarray bool (n, V)
    index : list of int
        View index of each column (from the file names ``view_XX.npz``).
    """
    P, _, _ = scene.sample_surface(n, seed=seed)
    files = sorted(truth_dir.glob("view_*.npz"))
    index = [int(f.stem.split("_")[1]) for f in files]
    seen = np.zeros((len(P), len(files)), bool)
    for k, f in enumerate(files):
        z = read_npz(f, ("surface_id", "point_obj"), "truth file")
        sid = z["surface_id"]
        if z["point_obj"].shape != sid.shape + (3,):
            raise NurbscanError(f"{f}: not a truth file (point_obj {z['point_obj'].shape} "
                                f"for surface_id {sid.shape})")
        q = z["point_obj"][sid >= 0]
        if len(q) < 2:
            continue
        tree = cKDTree(q)
        # pixel footprint: spacing of neighbouring truth points
        sub = q[:: max(1, len(q) // 2000)]
        dd, _ = tree.query(sub, k=2)
        foot = float(np.median(dd[:, 1]))
        dist, _ = tree.query(P, k=1, distance_upper_bound=4 * foot)
        seen[:, k] = dist <= 2.0 * foot
    return P, seen, index


def gordon_cloud(model, spacing: float = 0.35, max_per_side: int = 1500):
    """Dense samples (N, 3) of every Gordon patch, about ``spacing`` mm apart, and their views.

    The number of samples along each parameter follows the length of the control polygon (an
    upper bound of the curve length), so every point of a patch lies within about
    ``spacing / sqrt(2)`` of a sample.
    """
    pts, views = [], []
    for s in model.surfaces_of("gordon"):
        srf = s["surface"]
        P = np.asarray(srf.control_points)
        lu = np.linalg.norm(np.diff(P, axis=0), axis=2).sum(0).max()
        lv = np.linalg.norm(np.diff(P, axis=1), axis=2).sum(1).max()
        nu = int(min(max(np.ceil(lu / spacing), 1), max_per_side)) + 1
        nv = int(min(max(np.ceil(lv / spacing), 1), max_per_side)) + 1
        (u0, u1), (v0, v1) = srf.domain
        pts.append(srf.evaluate_grid(np.linspace(u0, u1, nu),
                                     np.linspace(v0, v1, nv)).reshape(-1, 3))
        views.append(np.full(nu * nv, s["view"]))
    if not pts:
        return np.zeros((0, 3)), np.zeros(0, int)
    return np.concatenate(pts), np.concatenate(views)


def mesh_distances(vertices: np.ndarray, faces: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Exact unsigned distances (N,) of points to a triangle mesh, mm (Open3D ray-casting
    scene, a BVH over the triangles)."""
    from ..merge._open3d import import_open3d, raycasting_scene

    o3d = import_open3d("evaluation")
    scene = raycasting_scene(vertices, faces, "evaluation")
    return scene.compute_distance(o3d.core.Tensor(np.asarray(points, np.float32))).numpy()


def fused_row(fused, scene, P: np.ndarray, vis: np.ndarray, gordon_covered: np.ndarray,
              cover_tol: float = 0.5, n_samples: int = 100000, area_tol: float = 0.1,
              seed: int = 0) -> dict:
    """Table I figures, coverage and area of a fused mesh against the truth.

    Parameters
    ----------
    fused : FusedMesh
        ``vertices`` (V, 3) mm, ``faces`` (F, 3), object frame.
    scene : Scene
        The truth.
    P, vis : ndarray (n, 3), (n,) bool
        Area-uniform true samples and whether a view sees each (:func:`visible_samples`).
    gordon_covered : ndarray (n,) bool
        True samples within ``cover_tol`` of a Gordon patch sample.
    n_samples : int
        Area-uniform samples of the mesh, each measured by its exact closest-point distance to
        the true surface: ``mean_mm``, ``std_mm``, ``min_mm``, ``max_mm`` over them (the mean
        of Table I's per-entity means is an average over equal-sized sample groups; here the
        groups are area elements of the mesh), ``max_sample_mm`` = ``max_mm``.
    area_tol : float
        Distance (mm) within which a true sample counts as covered by the mesh for its area.

    Returns
    -------
    dict
        The row's figures and ``coverage`` (share of the visible true samples within
        ``cover_tol`` of the mesh, exact distances), ``whole_coverage`` (the same share of
        the whole true surface, seen or not: what several passes add up to), ``parts``
        (connected components of faces sharing vertices), ``area_mm2`` (the mesh's),
        ``true_area_mm2`` (the whole true surface), ``true_covered_area_mm2`` (true area
        within ``area_tol`` of the mesh, less the band of width ``area_tol`` outside the
        mesh's open border: perimeter times ``area_tol``), ``area_ratio`` (mesh area over
        it: 2 for a doubled layer), ``gordon_covered_area_mm2`` (true area within
        ``cover_tol`` of the Gordon patches, as ``coverage`` counts it) and
        ``area_ratio_gordon``.
    """
    import trimesh

    from ..merge.fusion import count_parts

    V, F = np.asarray(fused.vertices, float), np.asarray(fused.faces, np.int64)
    tm = trimesh.Trimesh(V, F, process=False)
    S, _ = trimesh.sample.sample_surface(tm, n_samples, seed=seed)
    d = scene.closest_point(S)[1]
    dt = mesh_distances(V, F, P)
    covered = dt <= cover_tol
    A_true = float(scene.mesh().area)
    # open border: edges of one face
    e = np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1)
    ue, cnt = np.unique(e, axis=0, return_counts=True)
    border = ue[cnt == 1]
    perimeter = float(np.linalg.norm(V[border[:, 0]] - V[border[:, 1]], axis=1).sum())
    cov_area = A_true * float((dt <= area_tol).mean()) - perimeter * area_tol
    g_area = A_true * float(gordon_covered.mean())
    area = float(tm.area)
    return {"label": "fused mesh", "n": int(len(d)), "mean_mm": float(d.mean()),
            "std_mm": float(d.std()), "min_mm": float(d.min()), "max_mm": float(d.max()),
            "max_sample_mm": float(d.max()), "p99_mm": float(np.percentile(d, 99)),
            "faces": int(len(F)), "vertices": int(len(V)), "parts": count_parts(F, len(V)),
            "coverage": float((covered & vis).sum() / max(vis.sum(), 1)),
            "whole_coverage": float(covered.mean()),
            "area_mm2": area, "true_area_mm2": A_true, "perimeter_mm": perimeter,
            "area_tolerance_mm": area_tol, "true_covered_area_mm2": cov_area,
            "area_ratio": area / max(cov_area, 1e-9), "gordon_covered_area_mm2": g_area,
            "area_ratio_gordon": area / max(g_area, 1e-9)}


def cad_samples(cad) -> tuple[np.ndarray, np.ndarray]:
    """Samples of a CAD set's kept cells: ``(points (9 n, 3) mm, cell (9 n,) int)``, 3 x 3 per
    kept cell (its corners, edge midpoints and centre in the parameter plane), ``cell``
    numbering the kept cells of ``cad.patches`` in order."""
    pts, ids, at = [], [], 0
    t = np.array([0.0, 0.5, 1.0])
    for p in cad.patches:
        S, u, v = p["surface"], np.asarray(p["u"], float), np.asarray(p["v"], float)
        i, j = np.nonzero(p["keep"])
        uu = (u[i][:, None] + t[None] * (u[i + 1] - u[i])[:, None])[:, :, None]
        vv = (v[j][:, None] + t[None] * (v[j + 1] - v[j])[:, None])[:, None, :]
        uu, vv = np.broadcast_arrays(uu, vv)
        pts.append(S.evaluate(uu.ravel(), vv.ravel()))
        ids.append(np.repeat(np.arange(at, at + len(i)), 9))
        at += len(i)
    if not pts:
        return np.zeros((0, 3)), np.zeros(0, int)
    return np.concatenate(pts), np.concatenate(ids)


def cad_row(cad, scene, limit: float = 0.2, chunk: int = 200_000) -> dict:
    """Distances of the CAD surface set to the truth (:func:`cad_samples`, exact closest
    points): ``n`` samples, ``mean_mm``, ``std_mm``, ``p99_mm``, ``max_sample_mm``,
    ``over_limit`` (samples farther than ``limit`` mm) and ``cells_over_limit`` (kept cells
    with such a sample), ``cells``, ``surfaces`` (rectangles, 3dm/igs), ``regions`` (trimmed
    faces, STEP) and ``area_mm2`` (kept cells)."""
    from ..merge.cad import outline

    X, cell = cad_samples(cad)
    # in chunks: the closest-point query's candidate arrays grow with the samples
    d = np.concatenate([scene.closest_point(X[a:a + chunk])[1]
                        for a in range(0, len(X), chunk)] or [np.zeros(0)])
    over = d > limit
    if not len(d):
        return {"label": "CAD surface set", "n": 0, "mean_mm": None, "std_mm": None,
                "p99_mm": None, "max_sample_mm": None, "over_limit": 0,
                "cells_over_limit": 0, "limit_mm": limit, "cells": 0,
                "surfaces": len(cad.surfaces), "regions": 0, "area_mm2": 0.0}
    return {"label": "CAD surface set", "n": int(len(d)), "mean_mm": float(d.mean()),
            "std_mm": float(d.std()), "p99_mm": float(np.percentile(d, 99)),
            "max_sample_mm": float(d.max()), "over_limit": int(over.sum()),
            "cells_over_limit": int(len(np.unique(cell[over]))), "limit_mm": limit,
            "cells": int(cell.max() + 1), "surfaces": len(cad.surfaces),
            "regions": int(sum(len(outline(p["keep"])) for p in cad.patches)),
            "area_mm2": float(cad.info.get("area_mm2", 0.0))}


def evaluate_model(model, truth_dir: str | os.PathLike, n_samples: int = 100,
                   n_coverage: int = 20000, cover_tol: float = 0.5, workers: int = 1,
                   progress=None, cad: bool = False) -> dict:
    """Table I figures, coverage and a per-view breakdown of a model against the truth.

    Parameters
    ----------
    model : Model
        The reconstruction (object frame).
    truth_dir : path-like
        The scan's ``truth/`` folder (``scene.json`` and ``view_*.npz``).
    n_samples : int
        Samples per curve or patch (100 as in the paper).
    n_coverage : int
        True-surface samples for the coverage.
    cover_tol : float
        Largest distance (mm) from a true sample to a Gordon patch sample to count as covered.
    workers : int
        1 computes everything here; otherwise what the views see (:func:`visible_samples`)
        is computed in a second process beside the entity errors. The figures do not depend
        on it.
    progress : callable, optional
        ``progress(message)`` at each step (the command line prints it).
    cad : bool
        Also build the CAD surface set (:func:`nurbscan.merge.cad.cad_set`, the scan's rig
        when found) and add its row ``cad`` (:func:`cad_row`).

    Returns
    -------
    dict
        ``rows`` (the five Table I rows: ``n``, ``mean_mm``, ``std_mm``, ``min_mm``,
        ``max_mm``, ``max_sample_mm``, ``paper``), ``coverage`` in [0, 1], ``views``
        (per view: rows' means and coverage of what that view sees).
    """
    from ..simulate.scenes import scene_from_dict

    truth = Path(truth_dir)
    if not (truth / "scene.json").exists():
        raise NurbscanError(f"{truth}: no scene.json (expected a scan's truth/ folder)")
    spec = read_json(truth / "scene.json")
    try:
        scene = scene_from_dict(spec)
    except NurbscanError as exc:
        raise NurbscanError(f"{truth / 'scene.json'}: {exc}") from None
    except (TypeError, ValueError, KeyError) as exc:  # fields of the wrong kind
        raise NurbscanError(f"{truth / 'scene.json'}: not a nurbscan scene ({exc})") from None
    have = {f.stem.split("_")[1] for f in truth.glob("view_*.npz")}
    # else left out of the coverage; the views of a merged model's further passes
    # (nurbscan.merge.passes: ``pass`` >= 1) have their truth in their own scan, not here
    for idx in (int(v["index"]) for v in model.views if int(v.get("pass", 0)) == 0):
        if f"{idx:02d}" not in have:
            raise NurbscanError(f"{truth / f'view_{idx:02d}.npz'}: no truth file of the "
                                f"model's view {idx}")
    say = progress or (lambda _msg: None)
    say(f"errors of {len(model.curves)} curves and {len(model.surfaces)} surfaces against the "
        f"true {spec.get('name', 'scene')}, {n_samples} samples each")
    # which true points the views see (reads every view's truth) runs beside the entity errors
    seen_job = in_background(_visible_job, spec, truth, n_coverage, parallel=workers != 1)
    # about half the samples in a second process (teapot demo: evaluate 17.8 -> 15.0 s)
    errs = entity_errors(model, scene, n_samples, spec, share=0.45 if workers != 1 else 0.0)
    rows = {}
    for row, e in errs.items():
        st = _stats(e["mean"], float(e["max"].max()) if e["max"].size else None)
        st["label"] = ROWS[row][2]
        st["paper"] = dict(zip(("mean_mm", "std_mm", "min_mm", "max_mm"), PAPER[row], strict=True))
        rows[row] = st
    say(f"coverage: {n_coverage} true surface samples against the Gordon patches")
    P, seen, vindex = seen_job()
    G, gv = gordon_cloud(model)
    vis = seen.any(1)
    covered = np.zeros(len(P), bool)
    per_view_cov = {}
    if len(G):
        tree = cKDTree(G)
        d, i = tree.query(P, k=1, distance_upper_bound=cover_tol)
        covered = np.isfinite(d) & (d <= cover_tol)
        for v in np.unique(gv):
            t = cKDTree(G[gv == v])
            dv, _ = t.query(P, k=1, distance_upper_bound=cover_tol)
            per_view_cov[int(v)] = np.isfinite(dv)
    coverage = float((covered & vis).sum() / max(vis.sum(), 1))
    fused = None
    if getattr(model, "fused", None) is not None and len(model.fused.faces):
        say(f"the fused mesh ({len(model.fused.faces)} triangles)")
        fused = fused_row(model.fused, scene, P, vis, covered, cover_tol)
    views = []
    for v in model.views:
        idx = int(v["index"])
        k = vindex.index(idx) if idx in vindex else -1
        entry = {"index": idx, "table_angle": v.get("table_angle")}
        for row, e in errs.items():
            sel = e["view"] == idx
            entry[row] = float(e["mean"][sel].mean()) if sel.any() else None
            entry[row + "_n"] = int(sel.sum())
        if k >= 0 and seen[:, k].any():
            cv = per_view_cov.get(idx, np.zeros(len(P), bool))
            entry["coverage"] = float((cv & seen[:, k]).sum() / seen[:, k].sum())
        else:
            entry["coverage"] = None
        views.append(entry)
    out = {"type": "nurbscan.evaluation", "version": 1, "rows": rows, "coverage": coverage,
           "visible_share": float(vis.mean()), "coverage_tolerance_mm": cover_tol,
           "samples_per_entity": n_samples, "views": views}
    if fused is not None:
        out["fused"] = fused
    if cad:
        from ..export import find_rig
        from ..merge.cad import cad_set

        say("the CAD surface set")
        out["cad"] = cad_row(cad_set(model, find_rig(model), progress=progress), scene)
    return out


def _f(x, nd=6):
    return "-" if x is None else f"{x:.{nd}f}"


def format_table(ev: dict) -> str:
    """The evaluation as Markdown: Table I (ours beside the paper's), coverage, per view."""
    lines = ["# Reconstruction error (the paper's Table I)", "",
             "Distance to the true surface, mm: per curve or patch the mean of 100 samples; "
             "then mean, std, min, max over curves or patches. Paper: real teapot.", "",
             "| object | n | mean | std | min | max | max sample | paper mean | paper max |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in ev["rows"].values():
        lines.append(f"| {r['label']} | {r['n']} | {_f(r['mean_mm'])} | {_f(r['std_mm'])} | "
                     f"{_f(r['min_mm'], 7)} | {_f(r['max_mm'])} | {_f(r['max_sample_mm'], 4)} "
                     f"| {r['paper']['mean_mm']:.6f} | {r['paper']['max_mm']:.6f} |")
    fu = ev.get("fused")
    if fu is not None:
        lines.append(f"| {fu['label']} ({fu['faces']} triangles) | {fu['n']} samples | "
                     f"{_f(fu['mean_mm'])} | {_f(fu['std_mm'])} | {_f(fu['min_mm'], 7)} | "
                     f"{_f(fu['max_mm'])} | {_f(fu['max_sample_mm'], 4)} | - | - |")
    ca = ev.get("cad")
    if ca is not None and ca["n"]:
        lines.append(f"| {ca['label']} ({ca['regions']} faces) | {ca['n']} samples | "
                     f"{_f(ca['mean_mm'])} | {_f(ca['std_mm'])} | - | - | "
                     f"{_f(ca['max_sample_mm'], 4)} | - | - |")
    lines += ["", f"Coverage of the turntable-visible true surface by Gordon patches: "
              f"{100 * ev['coverage']:.1f} % (within {ev['coverage_tolerance_mm']} mm).", ""]
    if fu is not None:
        whole = fu.get("whole_coverage")
        lines += [f"Fused mesh: coverage {100 * fu['coverage']:.1f} % (within "
                  f"{ev['coverage_tolerance_mm']} mm)"
                  + ("" if whole is None else f", {100 * whole:.1f} % of the whole true surface")
                  + f", {fu['parts']} connected parts, area "
                  f"{fu['area_mm2']:.0f} mm^2 = {fu['area_ratio']:.3f} x the true area it covers "
                  f"({fu['true_covered_area_mm2']:.0f} mm^2), {fu['area_ratio_gordon']:.3f} x "
                  f"the true area the Gordon patches cover "
                  f"({fu['gordon_covered_area_mm2']:.0f} mm^2).", ""]
    if ca is not None and ca["n"]:
        lines += [f"CAD surface set: {ca['over_limit']} of {ca['n']} samples (in "
                  f"{ca['cells_over_limit']} of {ca['cells']} cells) farther than "
                  f"{ca['limit_mm']} mm from the truth, p99 {ca['p99_mm']:.4f} mm, "
                  f"{ca['area_mm2']:.0f} mm^2 in {ca['regions']} trimmed faces "
                  f"({ca['surfaces']} rectangles).", ""]
    lines += ["## Per view", "",
              "| view | table (deg) | h lines | v lines | h skin | v skin | Gordon (n) | "
              "coverage |", "|---|---|---|---|---|---|---|---|"]
    for v in ev["views"]:
        ang = v.get("table_angle")
        cov = v.get("coverage")
        lines.append(
            f"| {v['index']} | {'-' if ang is None else f'{np.degrees(ang):.1f}'} | "
            f"{_f(v['horizontal_lines'], 4)} | {_f(v['vertical_lines'], 4)} | "
            f"{_f(v['horizontal_skin'], 4)} | {_f(v['vertical_skin'], 4)} | "
            f"{_f(v['gordon'], 4)} ({v['gordon_n']}) | "
            f"{'-' if cov is None else f'{100 * cov:.1f} %'} |")
    return "\n".join(lines) + "\n"
