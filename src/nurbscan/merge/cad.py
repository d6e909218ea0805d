"""The CAD surface set: every part of the covered surface on exactly one NURBS surface (#32).

The views' Gordon patches lie in about 2.5 coincident layers. The CAD set keeps, where layers
coincide, only the best patch, and cuts every patch back to its measured data:

1. **Cells.** Each Gordon patch's parameter domain is cut into a grid of cells about
   ``cell_mm`` wide on the surface; each cell is represented by its centre (point, unit
   normal).
2. **Support (patch borders).** A cell whose centre lies farther than ``support_pitch``
   pitches from every triangulated edge point of its own view (the measured data) is cut: a
   patch's border rows can run past the data (a curve extrapolated below a base contour).
   So is a cell whose nearest own edge points lie off it by more than ``residual_sigma``
   robust standard deviations of its view's residuals (the surface does not follow its
   data there); a better-scored cell of another view then takes its place.
   With the model's fused mesh (:mod:`nurbscan.merge.fusion`: screened Poisson of all
   views' samples, trimmed to where data is), a cell whose centre or one of its corners lies
   farther than ``fused_mm`` from the fused mesh (exact point-to-triangle distance) is cut
   too: it departs from the surface all views agree on, or runs where the fused mesh has no
   surface (past the data).
3. **Score.** Each patch gets one score, ``cos(theta) - rms / pitch``: ``theta`` the mean
   angle between its normals and the directions to its view's camera (most frontal first),
   ``rms`` the RMS point-to-plane distance of its view's edge points to it (the fit's own
   residual). One score per patch keeps the partition's seams on few patches.
4. **Ownership.** A cell is kept when no cell of a better patch (of any view: a view's
   patches overlap one another too, 22 % of their area on a 1024 x 768 scan) lies on it:
   within ``cover_mm`` in space, normals within 60 degrees (one k-nearest query for all
   cells). Two views' layers then meet at a staircase seam one cell wide.
5. **Cross-view consistency.** A kept cell over which other views' supported cells lie
   (within ``cell_mm`` along the surface, normals within 60 degrees) but none of them within
   ``consistent_mm`` along its normal disagrees with every other view that saw the place: it
   is cut, and ownership is settled again without it, so that another view's cell takes its
   place. Repeated ``consistency_rounds`` times (the replacing cell is checked in turn).
6. **Rectangles.** Each patch's kept cells lose one cell at every pinch corner
   (:func:`unpinched`) and are merged into maximal rectangles (runs of rows with the same
   kept columns), and each rectangle becomes the exact sub-surface of the Gordon surface over
   it (knots inserted to multiplicity ``p`` at its ends, Piegl and Tiller A5.1 per row): no
   refit, the geometry is the patch's (``CadSet.surfaces``, for 3dm and IGES). The kept
   cells themselves are ``CadSet.patches``: :mod:`nurbscan.export.step` makes one trimmed
   face per region of them (its :func:`outline` as the trimming wires) and sews the faces
   into shells (OpenCASCADE).

Units: mm, object frame.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from ..errors import NurbscanError
from ..nurbs import NurbsSurface
from ..nurbs.curve import insert_knot_h

__all__ = ["CadOptions", "CadSet", "cad_set", "outline", "overlap_area", "sub_surface",
           "unpinched"]


@dataclass(frozen=True)
class CadOptions:
    """Settings of :func:`cad_set`.

    Attributes
    ----------
    cell_mm : float
        Size of the ownership cells on the surface, mm (the seams' resolution).
    support_pitch : float
        Cells farther than this many pitches from their view's edge points are cut.
    residual_sigma : float or None
        Cells whose own edge points lie farther from them (local median point-to-plane
        distance) than this many robust standard deviations of their view's are cut: the
        surface there does not follow its data (None: no such cut).
    cover_mm : float
        A cell lies on another patch's cell when their centres are this close (mm): more
        than ``cell_mm / sqrt(2)`` (a layer's cells are offset anywhere), less than
        ``cell_mm`` (the cells either side of two patches' common border are a cell apart).
    neighbours : int
        Cells of other patches examined per cell.
    max_cells : int
        Largest number of cells along one side of a patch.
    consistent_mm : float or None
        A kept cell is cut when other views' cells lie over it but none within this distance
        along its normal (None: no such cut). The views' layers lie a robust standard
        deviation of 0.03 mm apart on the 1024 x 768 teapot scan: 0.1 mm is 3.3 of them.
    consistency_rounds : int
        Rounds of the cross-view cut (each followed by the ownership step).
    fused_mm : float or None
        With the model's fused mesh, cells with their centre or a corner farther than this
        from it (mm) are cut before ownership (step 2; None: no such cut). The fused mesh is
        the views' layers averaged: 0.1 mm is ``consistent_mm``'s 3.3 robust standard
        deviations of the layers' spread.
    """

    cell_mm: float = 0.3
    support_pitch: float = 0.5
    residual_sigma: float | None = 4.0
    cover_mm: float = 0.24
    neighbours: int = 12
    max_cells: int = 400
    consistent_mm: float | None = 0.1
    consistency_rounds: int = 2
    fused_mm: float | None = 0.1

    def __post_init__(self) -> None:
        if not (self.cell_mm > 0 and self.support_pitch > 0 and self.cover_mm > 0):
            raise NurbscanError("CAD set: cell_mm, support_pitch and cover_mm must be > 0")

    def to_dict(self) -> dict:
        """JSON-ready dict."""
        return asdict(self)


@dataclass(frozen=True)
class CadSet:
    """The CAD surface set.

    Attributes
    ----------
    surfaces : list of dict
        ``view``, ``patch``, ``rect`` (``[u0, u1, v0, v1]``, the Gordon patch's parameters)
        and ``surface`` (the exact sub-surface, NurbsSurface).
    patches : list of dict
        One per kept Gordon patch: ``view``, ``patch``, ``surface`` (the whole Gordon
        surface), ``u`` (nu + 1,) and ``v`` (nv + 1,) its cell boundaries and ``keep``
        (nu, nv) bool, its kept cells (the surfaces above are their rectangles).
    info : dict
        Counts and areas: ``patches``, ``patches_kept``, ``surfaces``, ``cells``,
        ``cells_kept``, ``cells_unsupported``, ``cells_off_fused`` (cut by the fused mesh),
        ``cells_covered``, ``area_mm2`` (kept cells),
        ``pitch_mm``, ``options``.
    """

    surfaces: list
    info: dict = field(default_factory=dict)
    patches: list = field(default_factory=list)


def cad_set(model, rig=None, options: CadOptions | None = None, progress=None) -> CadSet:
    """The non-overlapping CAD surface set of a merged model (module notes, steps 1-6).

    Parameters
    ----------
    model : nurbscan.reconstruct.Model
        Registered views in the object frame, with their edge points.
    rig : nurbscan.camera.Rig, optional
        For the cameras' centres (frontality); without it patches are ranked by residual.
    options : CadOptions, optional
    progress : callable, optional

    Returns
    -------
    CadSet
    """
    from .fusion import _camera_centres, _pitch

    opt = options or CadOptions()
    say = progress or (lambda _m: None)
    gordon = model.surfaces_of("gordon")
    if not gordon:
        raise NurbscanError("CAD set: the model has no Gordon patches")
    pitch = _pitch(model)
    cells = [_cells(s["surface"], opt) for s in gordon]
    P = np.concatenate([c["points"] for c in cells])
    N = np.concatenate([c["normals"] for c in cells])
    owner = np.concatenate([np.full(len(c["points"]), k) for k, c in enumerate(cells)])
    view = np.array([int(s["view"]) for s in gordon])
    supported = _supported(model, P, N, view[owner], opt.support_pitch * pitch,
                           opt.residual_sigma)
    witness = supported.copy()  # the cross-view cut's witnesses keep the fused-mesh cut's
    fused = getattr(model, "fused", None)
    off_fused = np.zeros(len(P), bool)
    if opt.fused_mm is not None and fused is not None and len(fused.faces):
        off_fused = _off_fused(cells, fused, opt.fused_mm) & supported
        supported &= ~off_fused
    score = _scores(model, rig, gordon, cells, P, N, owner, view, pitch, _camera_centres)
    covered = _covered(P, N, owner, view, score, supported, opt)
    keep = supported & ~covered
    inconsistent = np.zeros(len(P), bool)
    for _ in range(opt.consistency_rounds if opt.consistent_mm is not None else 0):
        cut = _inconsistent(P, N, view[owner], keep, witness & ~inconsistent, opt)
        if not cut.any():
            break
        inconsistent |= cut
        covered = _covered(P, N, owner, view, score, supported & ~inconsistent, opt)
        keep = supported & ~inconsistent & ~covered
    out, kept, at = [], [], 0
    for s, c in zip(gordon, cells, strict=True):
        n = len(c["points"])
        mask = unpinched(keep[at:at + n].reshape(c["shape"]))
        keep[at:at + n] = mask.ravel()
        at += n
        if mask.any():
            kept.append({"view": int(s["view"]), "patch": int(s["patch"]),
                         "surface": s["surface"], "u": c["u"], "v": c["v"], "keep": mask})
        for (i0, i1, j0, j1) in _rectangles(mask):
            rect = [float(c["u"][i0]), float(c["u"][i1]), float(c["v"][j0]), float(c["v"][j1])]
            out.append({"view": int(s["view"]), "patch": int(s["patch"]), "rect": rect,
                        "surface": sub_surface(s["surface"], rect[:2], rect[2:])})
    area = np.concatenate([c["area"] for c in cells])
    info = {"patches": len(gordon), "patches_kept": len({(d["view"], d["patch"]) for d in out}),
            "surfaces": len(out), "cells": int(len(P)), "cells_kept": int(keep.sum()),
            "cells_unsupported": int((~supported & ~off_fused).sum()),
            "cells_off_fused": int(off_fused.sum()),
            "cells_covered": int((covered & supported & ~inconsistent).sum()),
            "cells_inconsistent": int(inconsistent.sum()),
            "area_mm2": float(area[keep].sum()), "area_all_mm2": float(area.sum()),
            "pitch_mm": pitch, "options": opt.to_dict()}
    say(f"CAD set: {info['surfaces']} surfaces from {info['patches_kept']} of "
        f"{info['patches']} Gordon patches; {info['cells_unsupported']} of {info['cells']} "
        f"cells past the data cut, {info['cells_off_fused']} off the fused mesh, "
        f"{info['cells_covered']} under a better view's patch, "
        f"{info['cells_inconsistent']} off the other views' cells")
    return CadSet(out, info, kept)


# ---------------------------------------------------------------------------- steps
def _cells(S: NurbsSurface, opt: CadOptions) -> dict:
    """The patch's cell grid: cell boundaries ``u`` (nu + 1,), ``v`` (nv + 1,), centres'
    points and normals (nu * nv, 3), areas (nu * nv,), ``shape`` (nu, nv) and the cells'
    corner points ``corners`` ((nu + 1) * (nv + 1), 3; row-major in ``(u, v)``)."""
    (u0, u1), (v0, v1) = S.domain
    t = np.linspace(0.0, 1.0, 9)
    G = S.evaluate_grid(u0 + (u1 - u0) * t, v0 + (v1 - v0) * t)
    lu = np.linalg.norm(np.diff(G, axis=0), axis=2).sum(0).max()
    lv = np.linalg.norm(np.diff(G, axis=1), axis=2).sum(1).max()
    nu = int(np.clip(np.ceil(lu / opt.cell_mm), 1, opt.max_cells))
    nv = int(np.clip(np.ceil(lv / opt.cell_mm), 1, opt.max_cells))
    u, v = np.linspace(u0, u1, nu + 1), np.linspace(v0, v1, nv + 1)
    uc, vc = 0.5 * (u[:-1] + u[1:]), 0.5 * (v[:-1] + v[1:])
    uu, vv = np.meshgrid(uc, vc, indexing="ij")
    D = S.derivatives(uu.ravel(), vv.ravel(), 1)
    cross = np.cross(D[1, 0], D[0, 1])
    jac = np.linalg.norm(cross, axis=1)
    Nn = cross / np.maximum(jac, 1e-300)[:, None]
    area = jac * (u[1] - u[0]) * (v[1] - v[0])
    return {"u": u, "v": v, "points": D[0, 0], "normals": Nn, "area": area,
            "shape": (nu, nv), "corners": S.evaluate_grid(u, v).reshape(-1, 3)}


def _supported(model, P: np.ndarray, N: np.ndarray, pview: np.ndarray, reach: float,
               residual_sigma: float | None) -> np.ndarray:
    """Cells within ``reach`` mm of an edge point of their own view and, with
    ``residual_sigma``, whose local residual (median point-to-plane distance of their 6
    nearest own edge points within ``reach``) is at most ``residual_sigma`` robust standard
    deviations (1.4826 times the median over the view's cells) of the view's residuals."""
    edges = np.asarray(model.edge_points, float).reshape(-1, 3)
    ev = np.asarray(model.edge_view, int)
    if len(edges) == 0:
        return np.ones(len(P), bool)
    ok = np.zeros(len(P), bool)
    for v in np.unique(pview):
        sel = np.flatnonzero(pview == v)
        E = edges[ev == v]
        if len(E) == 0:
            continue
        k = min(6, len(E))
        d, i = cKDTree(E).query(P[sel], k=k, distance_upper_bound=reach)
        d, i = d.reshape(len(sel), k), i.reshape(len(sel), k)
        near = np.isfinite(d)
        ok[sel] = near[:, 0]
        if residual_sigma is None or not near[:, 0].any():
            continue
        r = np.abs(((E[np.where(near, i, 0)] - P[sel][:, None]) * N[sel][:, None]).sum(-1))
        r = np.where(near, r, np.inf)
        cnt = near.sum(1)
        med = np.sort(r, axis=1)[np.arange(len(sel)), np.maximum((cnt - 1) // 2, 0)]
        sigma = 1.4826 * np.median(med[near[:, 0]])
        ok[sel] &= med <= residual_sigma * sigma
    return ok


def _off_fused(cells: list, fused, tol: float) -> np.ndarray:
    """Which cells (all patches' cells in order, (n,) bool) have their centre or one of their
    four corners farther than ``tol`` mm from the fused mesh (exact unsigned point-to-mesh
    distances, :func:`nurbscan.evaluate.table.mesh_distances`: Open3D's BVH)."""
    from ..evaluate.table import mesh_distances

    X = np.concatenate([c["points"] for c in cells] + [c["corners"] for c in cells])
    d = mesh_distances(fused.vertices, fused.faces, X)
    n_c = sum(len(c["points"]) for c in cells)
    far, at_c, at_k = [], 0, n_c
    for c in cells:
        nu, nv = c["shape"]
        m = len(c["points"])
        k = d[at_k:at_k + (nu + 1) * (nv + 1)].reshape(nu + 1, nv + 1) > tol
        corner = k[:-1, :-1] | k[1:, :-1] | k[:-1, 1:] | k[1:, 1:]
        far.append((d[at_c:at_c + m] > tol) | corner.ravel())
        at_c += m
        at_k += (nu + 1) * (nv + 1)
    return np.concatenate(far)


def _scores(model, rig, gordon, cells, P, N, owner, view, pitch, centres_of) -> np.ndarray:
    """Per patch ``cos(theta) - rms / pitch`` (module notes, step 3)."""
    centres = centres_of(model, rig) if rig is not None else {}
    n_p = len(gordon)
    cos = np.zeros(n_p)
    if centres:
        C = np.array([centres.get(int(v), np.full(3, np.nan)) for v in view])[owner]
        d = C - P
        d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-300)
        c = np.abs((d * N).sum(1))
        c = np.where(np.isfinite(c), c, 0.0)
        cos = np.bincount(owner, c, n_p) / np.maximum(np.bincount(owner, None, n_p), 1)
    rms = np.zeros(n_p)
    edges = np.asarray(model.edge_points, float).reshape(-1, 3)
    ev = np.asarray(model.edge_view, int)
    for v in np.unique(view):
        mine = np.flatnonzero(view[owner] == v)
        E = edges[ev == v]
        if len(E) == 0 or len(mine) == 0:
            continue
        d, i = cKDTree(P[mine]).query(E, distance_upper_bound=pitch)
        ok = np.isfinite(d)
        j = mine[i[ok]]
        r = ((E[ok] - P[j]) * N[j]).sum(1)
        s2 = np.bincount(owner[j], r * r, n_p)
        cnt = np.bincount(owner[j], None, n_p)
        has = (cnt > 0) & (view == v)
        rms[has] = np.sqrt(s2[has] / cnt[has])
    return cos - rms / pitch


def _covered(P, N, owner, view, score, supported, opt: CadOptions) -> np.ndarray:
    """Cells on which a supported cell of a better patch of another view lies."""
    idx = np.flatnonzero(supported)
    out = np.zeros(len(P), bool)
    if len(idx) < 2:
        return out
    tree = cKDTree(P[idx])
    k = min(opt.neighbours, len(idx))
    d, j = tree.query(P[idx], k=k, distance_upper_bound=opt.cover_mm)
    ok = np.isfinite(d)
    jj = idx[np.where(ok, j, 0)]
    me = idx[:, None]
    other = ok & (owner[jj] != owner[me])
    agree = (N[jj] * N[me]).sum(-1) > 0.5
    # better: higher score, ties to the lower patch number
    s_me, s_o = score[owner[me]], score[owner[jj]]
    better = (s_o > s_me) | ((s_o == s_me) & (owner[jj] < owner[me]))
    out[idx] = (other & agree & better).any(1)
    return out


def _inconsistent(P, N, pview, cells, supported, opt: CadOptions,
                  chunk: int = 65536) -> np.ndarray:
    """Which of ``cells`` (bool) have supported cells of other views over them (within
    ``cell_mm`` along the surface and ``4 max(cell_mm, consistent_mm)`` in space, normals
    within 60 degrees) but none within ``consistent_mm`` along the cell's normal (step 5)."""
    idx = np.flatnonzero(supported)
    out = np.zeros(len(P), bool)
    if len(idx) < 2:
        return out
    tree = cKDTree(P[idx])
    reach = 4.0 * max(opt.cell_mm, opt.consistent_mm)
    k = min(6 * opt.neighbours, len(idx))
    todo = np.flatnonzero(cells)
    for at in range(0, len(todo), chunk):
        me = todo[at:at + chunk]
        d, j = tree.query(P[me], k=k, distance_upper_bound=reach)
        ok = np.isfinite(d)
        jj = idx[np.where(ok, j, 0)]
        D = P[jj] - P[me][:, None]
        along = (D * N[me][:, None]).sum(-1)
        across = np.sqrt(np.maximum((D * D).sum(-1) - along ** 2, 0.0))
        other = (ok & (pview[jj] != pview[me][:, None])
                 & ((N[jj] * N[me][:, None]).sum(-1) > 0.5) & (across < opt.cell_mm))
        agree = other & (np.abs(along) <= opt.consistent_mm)
        out[me] = other.any(1) & ~agree.any(1)
    return out


def _rectangles(mask: np.ndarray) -> list[tuple[int, int, int, int]]:
    """Maximal row-run rectangles of a boolean cell mask ``(nu, nv)``: ``(i0, i1, j0, j1)``,
    cell boundary indices, covering exactly the True cells."""
    out = []
    open_runs: dict[tuple[int, int], int] = {}
    nu = mask.shape[0]
    for i in range(nu + 1):
        runs = set()
        if i < nu:
            row = np.concatenate([[False], mask[i], [False]])
            dif = np.flatnonzero(np.diff(row.astype(np.int8)))
            runs = set(zip(dif[::2].tolist(), dif[1::2].tolist(), strict=True))
        for r in list(open_runs):
            if r not in runs:
                out.append((open_runs.pop(r), i, r[0], r[1]))
        for r in runs:
            open_runs.setdefault(r, i)
    return out


def sub_surface(S: NurbsSurface, u_range, v_range) -> NurbsSurface:
    """The exact part of ``S`` over ``u_range x v_range``: knots inserted to multiplicity
    ``p`` at the ends (Piegl and Tiller A5.1 applied to every row of the homogeneous net)
    and the control net cut there."""
    Pw = S.homogeneous
    U, p = np.asarray(S.knots_u, float), S.degree_u
    Uu, Pw = _cut(p, U, Pw, *u_range)
    V, q = np.asarray(S.knots_v, float), S.degree_v
    Vv, Qw = _cut(q, V, Pw.transpose(1, 0, 2), *v_range)
    return NurbsSurface.from_homogeneous(p, q, Uu, Vv, Qw.transpose(1, 0, 2))


def _cut(p: int, U: np.ndarray, Pw: np.ndarray, a: float, b: float):
    """Knot vector and net rows of the part ``[a, b]`` of a B-spline in its first index."""
    n, m, d = Pw.shape
    flat = Pw.reshape(n, m * d)
    for t in (a, b):
        if U[p] < t < U[-p - 1]:
            s = int(np.count_nonzero(U == t))
            if s < p:
                U, flat = insert_knot_h(p, U, flat, float(t), p - s)
    i0 = int(np.searchsorted(U, a, side="right")) - 1  # last knot <= a
    i0 = min(max(i0, p), len(U) - p - 2)
    i1 = int(np.searchsorted(U, b, side="left"))  # first knot >= b
    i1 = max(min(i1, len(U) - p - 1), i0 + 1)
    # control points of the span range [U[i0], U[i1]]: indices i0 - p .. i1 - 1
    rows = flat[i0 - p:i1]
    knots = np.concatenate([[a] * (p + 1), U[i0 + 1:i1], [b] * (p + 1)])
    return knots, rows.reshape(-1, m, d)


def overlap_area(surfaces: list, n: int = 12, tol: float = 0.1) -> dict:
    """Area of the CAD surfaces that lies on another surface of the set (an oracle of the
    set's own geometry, for tests and figures).

    Every surface is sampled on an ``n x n`` grid of cell centres weighted by their areas;
    a sample lies on surface ``B`` when its closest point on ``B`` (Newton point inversion,
    Piegl and Tiller section 6.1, parameters clamped to ``B``'s domain) is within ``tol`` mm
    and strictly inside ``B``'s domain (a sample next to ``B``'s border projects onto it).

    Returns ``{"overlap_mm2", "area_mm2", "share"}``.
    """
    samples = []
    for k, d in enumerate(surfaces):
        S = d["surface"]
        (u0, u1), (v0, v1) = S.domain
        du, dv = (u1 - u0) / n, (v1 - v0) / n
        uc = u0 + du * (np.arange(n) + 0.5)
        vc = v0 + dv * (np.arange(n) + 0.5)
        uu, vv = np.meshgrid(uc, vc, indexing="ij")
        D = S.derivatives(uu.ravel(), vv.ravel(), 1)
        a = np.linalg.norm(np.cross(D[1, 0], D[0, 1]), axis=1) * du * dv
        samples.append((D[0, 0], a, np.full(n * n, k)))
    X = np.concatenate([s[0] for s in samples])
    A = np.concatenate([s[1] for s in samples])
    owner = np.concatenate([s[2] for s in samples])
    # candidate surfaces: those with a sample within reach
    reach = 2.0 * float(np.sqrt(np.median(A))) + tol
    d, j = cKDTree(X).query(X, k=16, distance_upper_bound=reach)
    ok = np.isfinite(d)
    cand = owner[np.where(ok, j, 0)]
    ok &= cand != owner[:, None]
    rows, cols = np.nonzero(ok)
    key = np.unique(np.column_stack([cand[rows, cols], rows]), axis=0)
    on = np.zeros(len(X), bool)
    starts = np.flatnonzero(np.r_[True, key[1:, 0] != key[:-1, 0]])
    for a, b in zip(starts, np.r_[starts[1:], len(key)], strict=True):
        pts = key[a:b, 1]
        pts = pts[~on[pts]]
        if len(pts):
            on[pts] |= _inside(surfaces[key[a, 0]]["surface"], X[pts], tol)
    return {"overlap_mm2": float(A[on].sum()), "area_mm2": float(A.sum()),
            "share": float(A[on].sum() / max(A.sum(), 1e-300))}


def _inside(S: NurbsSurface, X: np.ndarray, tol: float, iters: int = 12) -> np.ndarray:
    """Whether each point's closest point on ``S`` is within ``tol`` and strictly inside
    its domain (Newton on ``(S - X) . S_u = (S - X) . S_v = 0``, clamped)."""
    (u0, u1), (v0, v1) = S.domain
    k = 8
    t = (np.arange(k) + 0.5) / k
    uu, vv = np.meshgrid(u0 + (u1 - u0) * t, v0 + (v1 - v0) * t, indexing="ij")
    G = S.evaluate(uu.ravel(), vv.ravel())
    i = cKDTree(G).query(X)[1]
    u, v = uu.ravel()[i], vv.ravel()[i]
    for _ in range(iters):
        D = S.derivatives(u, v, 2)
        r = D[0, 0] - X
        Su, Sv, Suu, Suv, Svv = D[1, 0], D[0, 1], D[2, 0], D[1, 1], D[0, 2]
        f = (r * Su).sum(1)
        g = (r * Sv).sum(1)
        a = (Su * Su).sum(1) + (r * Suu).sum(1)
        b = (Su * Sv).sum(1) + (r * Suv).sum(1)
        c = (Sv * Sv).sum(1) + (r * Svv).sum(1)
        det = a * c - b * b
        det = np.where(np.abs(det) < 1e-300, 1e-300, det)
        du = (c * f - b * g) / det
        dv = (a * g - b * f) / det
        u = np.clip(u - du, u0, u1)
        v = np.clip(v - dv, v0, v1)
    d = np.linalg.norm(S.evaluate(u, v) - X, axis=1)
    eu, ev = 1e-6 * (u1 - u0), 1e-6 * (v1 - v0)
    inside = (u > u0 + eu) & (u < u1 - eu) & (v > v0 + ev) & (v < v1 - ev)
    return inside & (d < tol)


def unpinched(mask: np.ndarray) -> np.ndarray:
    """The mask without pinch corners: where a 2 x 2 block of cells is a checkerboard (two
    kept cells touching only at a corner), the block's first kept cell is dropped, until
    none is left; a trimming wire through a pinch corner would touch itself."""
    m = np.array(mask, bool)
    while True:
        a, b, c, d = m[:-1, :-1], m[1:, :-1], m[:-1, 1:], m[1:, 1:]
        main = a & d & ~b & ~c
        anti = b & c & ~a & ~d
        if not (main.any() or anti.any()):
            return m
        i, j = np.nonzero(main)
        m[i, j] = False
        i, j = np.nonzero(anti)
        m[i + 1, j] = False


def outline(mask: np.ndarray) -> list[tuple[np.ndarray, list[np.ndarray]]]:
    """The outlines of a boolean cell mask ``(nu, nv)``: per 4-connected region its outer
    loop and its holes, as corner indices ``(i, j)`` (cell boundary indices, shape (n, 2)).

    The region lies to the left of every loop (outer loops counter-clockwise in ``(i, j)``,
    holes clockwise); collinear corners are dropped. Where two cells of a region touch only
    at a corner the loop turns into the region (left), so loops never cross.
    """
    from scipy import ndimage

    labels, n = ndimage.label(mask)
    out = []
    for k in range(1, n + 1):
        loops = _loops(labels == k)
        area = np.array([_signed_area(lp) for lp in loops])
        outer = int(np.argmax(area))
        out.append((loops[outer], [lp for j, lp in enumerate(loops) if j != outer]))
    return out


def _loops(mask: np.ndarray) -> list[np.ndarray]:
    """Closed boundary loops of one region (the region on their left), corners only."""
    m = np.pad(mask, 1)
    inner = m[1:-1, 1:-1]
    i, j = np.nonzero(inner & ~m[1:-1, :-2])          # no cell below: bottom edge, +i
    segs = [np.column_stack([i, j, i + 1, j])]
    i, j = np.nonzero(inner & ~m[2:, 1:-1])           # none to the right: +j
    segs.append(np.column_stack([i + 1, j, i + 1, j + 1]))
    i, j = np.nonzero(inner & ~m[1:-1, 2:])           # none above: -i
    segs.append(np.column_stack([i + 1, j + 1, i, j + 1]))
    i, j = np.nonzero(inner & ~m[:-2, 1:-1])          # none to the left: -j
    segs.append(np.column_stack([i, j + 1, i, j]))
    E = np.concatenate(segs)
    starts: dict[tuple[int, int], list[int]] = {}
    for e, (a, b) in enumerate(zip(E[:, 0].tolist(), E[:, 1].tolist(), strict=True)):
        starts.setdefault((a, b), []).append(e)
    used = np.zeros(len(E), bool)
    loops = []
    for e0 in range(len(E)):
        if used[e0]:
            continue
        pts, e = [], e0
        while not used[e]:
            used[e] = True
            pts.append(E[e, :2])
            end = (int(E[e, 2]), int(E[e, 3]))
            nxt = [f for f in starts[end] if not used[f]] or [e0]
            if len(nxt) > 1:  # a pinch corner: turn left, into the region
                d_in = E[e, 2:] - E[e, :2]
                nxt = [f for f in nxt
                       if d_in[0] * (E[f, 3] - E[f, 1]) - d_in[1] * (E[f, 2] - E[f, 0]) > 0]
            e = nxt[0]
        loops.append(_corners(np.array(pts)))
    return loops


def _corners(P: np.ndarray) -> np.ndarray:
    """A closed polygon without its collinear vertices."""
    d_prev = P - np.roll(P, 1, axis=0)
    d_next = np.roll(P, -1, axis=0) - P
    turn = d_prev[:, 0] * d_next[:, 1] - d_prev[:, 1] * d_next[:, 0]
    return P[turn != 0]


def _signed_area(P: np.ndarray) -> float:
    x, y = P[:, 0].astype(float), P[:, 1].astype(float)
    return 0.5 * float((x * np.roll(y, -1) - np.roll(x, -1) * y).sum())
