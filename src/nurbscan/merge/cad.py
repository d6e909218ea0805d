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
   The median of 6 misses a surface that runs off its data a few cells away (its nearest
   points lie in its plane): with ``miss_sigma``, every own edge point is measured against
   each patch of its view onto which it projects (point-to-plane at the nearest cell of that
   patch), and the cells within ``miss_cells`` cells of a point farther from the patch than
   ``miss_sigma`` robust standard deviations of the view's residuals are cut as well
   (:func:`_missed`).
   Where a patch reaches past its first or last curve of a family (:func:`nurbscan.reconstruct.
   network.patch_extents`: the other family's curves go on there), the surface follows one
   family's data only, and at a corner past both none: with ``beyond_spacing``, cells whose
   centre lies farther past those curves than that share of the family's mean curve spacing
   are cut (:func:`_beyond_curves`).
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
   cells themselves are ``CadSet.patches``.
7. **Seams (STEP).** With the model's fused mesh, :func:`seams` partitions the fused mesh
   among the kept patches (each triangle to its nearest kept cell's patch, smoothed, simple
   regions, every vertex of a region within ``SeamOptions.on_mm`` of its surface) and
   returns the borders between regions as chains, each ONE polyline for both sides;
   :func:`nurbscan.export.step.seamed_faces` makes each chain one B-spline edge shared by
   the two faces. Without a fused mesh, STEP makes one trimmed face per region of a patch's
   kept cells (:func:`outline`: staircase wires, seams one cell wide).

Units: mm, object frame.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from ..errors import NurbscanError
from ..nurbs import NurbsSurface
from ..nurbs.curve import insert_knot_h
from ..nurbs.intersect import closest_point_surface

__all__ = ["CadOptions", "CadSet", "SeamOptions", "Seams", "cad_set", "outline", "overlap_area",
           "seams", "sub_surface", "unpinched"]

# Start grid of seams' point inversions onto whole Gordon patches (closest_point_surface's
# samples per knot span in each direction; the teapot's patches have up to 32 x 21 spans): 2
# is as fast as the former 16 x 16 Newton start and finds the same or nearer points.
PER_SPAN_SEAMS = 2


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
    miss_sigma : float or None
        Cells within ``miss_cells`` cells (in their patch's grid) of an own edge point that
        lies farther from the patch than this many robust standard deviations of its view's
        residuals (those of ``residual_sigma``) are cut before ownership (step 2; None: no
        such cut). On the 3072 x 2304 teapot scan the deviation is 0.0076-0.0084 mm: 15 is
        about 0.12 mm, and that scan's 28 cells over 0.2 mm all lie beside own data that
        their patch misses by 0.2-0.5 mm.
    miss_cells : int
        Reach of the ``miss_sigma`` cut, cells (3: about 1 mm at ``cell_mm`` 0.3, as far as
        a bad cell of that scan lies from the missed data).
    beyond_spacing : float or None
        Cells whose centre lies past the patch's first or last curve of either family by more
        than this share of that family's mean curve spacing (in projector px, the surface's
        parameters) are cut before ownership (step 2; None: no such cut; a model written
        before the patches recorded their curves' coordinates is not cut). On the 3072 x
        2304 teapot scan the 8 cells over 0.2 mm that ``miss_sigma`` leaves all lie 0.49-1.09
        spacings past a patch's last curve; 0.4 (on nurbscan's grid, two edges per pitch, a
        fifth of the pitch) keeps a patch within reach of its data.
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
    miss_sigma: float | None = 15.0
    miss_cells: int = 3
    beyond_spacing: float | None = 0.4

    def __post_init__(self) -> None:
        if not (self.cell_mm > 0 and self.support_pitch > 0 and self.cover_mm > 0):
            raise NurbscanError("CAD set: cell_mm, support_pitch and cover_mm must be > 0")
        if (self.miss_sigma is not None and not self.miss_sigma > 0) or self.miss_cells < 0:
            raise NurbscanError("CAD set: miss_sigma must be > 0 (or None), miss_cells >= 0")
        if self.beyond_spacing is not None and not self.beyond_spacing >= 0:
            raise NurbscanError("CAD set: beyond_spacing must be >= 0 (or None)")

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
        ``cells_kept``, ``cells_unsupported``, ``cells_beyond`` (cut by ``beyond_spacing``),
        ``cells_missed`` (cut by ``miss_sigma``),
        ``cells_off_fused`` (cut by the fused mesh),
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
    supported, sigma = _supported(model, P, N, view[owner], opt.support_pitch * pitch,
                                  opt.residual_sigma)
    beyond = np.zeros(len(P), bool)
    if opt.beyond_spacing is not None:
        beyond = np.concatenate([_beyond_curves(s, c, opt.beyond_spacing)
                                 for s, c in zip(gordon, cells, strict=True)]) & supported
        supported &= ~beyond
    missed = np.zeros(len(P), bool)
    if opt.miss_sigma is not None:
        missed = _missed(model, cells, P, N, owner, view[owner], sigma, opt) & supported
        supported &= ~missed
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
    # each round re-examines only the cells whose neighbourhood changed (the same results)
    last_cover, last_cut = (covered, supported), None
    for _ in range(opt.consistency_rounds if opt.consistent_mm is not None else 0):
        cut = _inconsistent(P, N, view[owner], keep, witness & ~inconsistent, opt, last_cut)
        last_cut = (cut, keep, witness & ~inconsistent)
        if not cut.any():
            break
        inconsistent |= cut
        covered = _covered(P, N, owner, view, score, supported & ~inconsistent, opt, last_cover)
        last_cover = (covered, supported & ~inconsistent)
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
            "cells_unsupported": int((~supported & ~off_fused & ~missed & ~beyond).sum()),
            "cells_beyond": int(beyond.sum()),
            "cells_missed": int(missed.sum()),
            "cells_off_fused": int(off_fused.sum()),
            "cells_covered": int((covered & supported & ~inconsistent).sum()),
            "cells_inconsistent": int(inconsistent.sum()),
            "area_mm2": float(area[keep].sum()), "area_all_mm2": float(area.sum()),
            "pitch_mm": pitch, "options": opt.to_dict()}
    say(f"CAD set: {info['surfaces']} surfaces from {info['patches_kept']} of "
        f"{info['patches']} Gordon patches; {info['cells_unsupported']} of {info['cells']} "
        f"cells past the data cut, {info['cells_beyond']} past the curves, "
        f"{info['cells_missed']} beside own data they miss, "
        f"{info['cells_off_fused']} off the fused mesh, "
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
               residual_sigma: float | None) -> tuple[np.ndarray, dict]:
    """Cells within ``reach`` mm of an edge point of their own view and, with
    ``residual_sigma``, whose local residual (median point-to-plane distance of their 6
    nearest own edge points within ``reach``) is at most ``residual_sigma`` robust standard
    deviations (1.4826 times the median over the view's cells) of the view's residuals.
    Returns ``(ok (n,) bool, {view: that robust standard deviation, mm})``."""
    edges = np.asarray(model.edge_points, float).reshape(-1, 3)
    ev = np.asarray(model.edge_view, int)
    if len(edges) == 0:
        return np.ones(len(P), bool), {}
    ok = np.zeros(len(P), bool)
    sigmas = {}
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
        if not near[:, 0].any():
            continue
        r = np.abs(((E[np.where(near, i, 0)] - P[sel][:, None]) * N[sel][:, None]).sum(-1))
        r = np.where(near, r, np.inf)
        cnt = near.sum(1)
        med = np.sort(r, axis=1)[np.arange(len(sel)), np.maximum((cnt - 1) // 2, 0)]
        sigma = 1.4826 * np.median(med[near[:, 0]])
        sigmas[int(v)] = float(sigma)
        if residual_sigma is not None:
            ok[sel] &= med <= residual_sigma * sigma
    return ok, sigmas


def _beyond_curves(entry: dict, cells: dict, spacing: float) -> np.ndarray:
    """Which of a patch's cells ((nu * nv,) bool, :func:`_cells`' order) have their centre
    farther past the patch's first or last curve of either family than ``spacing`` times
    that family's mean curve spacing (step 2). ``entry`` is the model's surface entry:
    ``vertical_curves`` and ``horizontal_curves`` (first, last coordinate of the real
    curves, projector px = the surface's parameters) and ``n_curves``; without them (a model
    of an earlier version) no cell."""
    nu, nv = cells["shape"]
    cu, cv, n = (entry.get(k) for k in ("vertical_curves", "horizontal_curves", "n_curves"))
    if cu is None or cv is None or n is None:
        return np.zeros(nu * nv, bool)

    def past(edges, c, count):  # (cells,) bool along one direction
        mid = 0.5 * (edges[:-1] + edges[1:])
        step = (float(c[1]) - float(c[0])) / max(int(count) - 1, 1)
        return np.maximum(float(c[0]) - mid, mid - float(c[1])) > spacing * step

    return (past(np.asarray(cells["u"]), cu, n[0])[:, None]
            | past(np.asarray(cells["v"]), cv, n[1])[None, :]).ravel()


def _missed(model, cells: list, P: np.ndarray, N: np.ndarray, owner: np.ndarray,
            pview: np.ndarray, sigma: dict, opt: CadOptions, k: int = 16) -> np.ndarray:
    """Which cells (all patches' cells in order, (n,) bool) lie within ``opt.miss_cells``
    cells of their patch's grid from an own edge point that the patch misses by more than
    ``opt.miss_sigma`` times its view's ``sigma`` (mm, from :func:`_supported`; step 2).

    Each edge point of a view is measured against every patch of that view onto which it
    projects: among its ``k`` nearest cells of the view (within ``2 cell_mm`` in space), the
    nearest cell of each patch, if the point lies within ``cell_mm`` of that cell's centre
    along the surface; its residual is the point-to-plane distance to that cell (cells are
    ``cell_mm`` wide, so the plane is the surface to a few micrometres on the teapot). A cell
    records the largest residual projected onto it; a grey dilation (maximum filter, ``2
    miss_cells + 1`` cells square) of each patch's grid spreads it. Residuals are kept in
    units of the view's ``sigma``."""
    from scipy.ndimage import maximum_filter

    edges = np.asarray(model.edge_points, float).reshape(-1, 3)
    ev = np.asarray(model.edge_view, int)
    worst = np.zeros(len(P))
    for v in np.unique(pview):
        sel = np.flatnonzero(pview == v)
        E = edges[ev == v]
        if len(E) == 0 or len(sel) == 0 or not sigma.get(int(v), 0.0) > 0:
            continue
        kk = min(k, len(sel))
        d, i = cKDTree(P[sel]).query(E, k=kk, distance_upper_bound=2.0 * opt.cell_mm)
        d, i = d.reshape(len(E), kk), i.reshape(len(E), kk)
        ok = np.isfinite(d)
        c = sel[np.where(ok, i, 0)]
        own = owner[c]
        first = ok.copy()  # the nearest cell of each patch (neighbours come nearest first)
        for a in range(1, kk):
            first[:, a] &= ~((own[:, :a] == own[:, a:a + 1]) & ok[:, :a]).any(1)
        D = E[:, None] - P[c]
        along = (D * N[c]).sum(-1)
        across = np.sqrt(np.maximum((D * D).sum(-1) - along ** 2, 0.0))
        use = first & (across < opt.cell_mm)
        np.maximum.at(worst, c[use], np.abs(along[use]) / sigma[int(v)])
    out, at = [], 0
    for cl in cells:
        n = len(cl["points"])
        w = worst[at:at + n].reshape(cl["shape"])
        if opt.miss_cells:
            w = maximum_filter(w, size=2 * opt.miss_cells + 1, mode="constant")
        out.append(w.ravel() > opt.miss_sigma)
        at += n
    return np.concatenate(out)


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


def _changed(P: np.ndarray, rows: np.ndarray, supported: np.ndarray, before: np.ndarray,
             reach: float) -> np.ndarray | None:
    """Which of the cells ``rows`` (indices) lie within ``reach`` of a cell supported
    ``before`` (bool, a superset of ``supported``) and no longer: the cells whose neighbours
    within ``reach`` among the supported ones changed. None when ``before`` is not such a
    superset (every row is to be examined)."""
    if len(before) != len(P) or (supported & ~before).any():
        return None
    gone = np.flatnonzero(before & ~supported)
    if len(gone) == 0 or len(rows) == 0:
        return np.zeros(len(rows), bool)
    d, _ = cKDTree(P[gone]).query(P[rows], distance_upper_bound=reach)
    return np.isfinite(d)


def _covered(P, N, owner, view, score, supported, opt: CadOptions,
             previous: tuple | None = None) -> np.ndarray:
    """Cells on which a supported cell of a better patch of another view lies.

    ``previous`` = ``(out, supported)`` of a call with a superset of ``supported``: only the
    cells within ``cover_mm`` of a cell no longer supported are examined again (the others'
    neighbours are the same), with the same result as a call without it."""
    idx = np.flatnonzero(supported)
    out = np.zeros(len(P), bool)
    if len(idx) < 2:
        return out
    tree = cKDTree(P[idx])
    k = min(opt.neighbours, len(idx))
    rows = idx
    again = None if previous is None else _changed(P, idx, supported, previous[1], opt.cover_mm)
    if again is not None:
        out[idx] = previous[0][idx]
        rows = idx[again]
    d, j = tree.query(P[rows], k=k, distance_upper_bound=opt.cover_mm)
    ok = np.isfinite(d)
    jj = idx[np.where(ok, j, 0)]
    me = rows[:, None]
    other = ok & (owner[jj] != owner[me])
    agree = (N[jj] * N[me]).sum(-1) > 0.5
    # better: higher score, ties to the lower patch number
    s_me, s_o = score[owner[me]], score[owner[jj]]
    better = (s_o > s_me) | ((s_o == s_me) & (owner[jj] < owner[me]))
    out[rows] = (other & agree & better).any(1)
    return out


def _inconsistent(P, N, pview, cells, supported, opt: CadOptions,
                  previous: tuple | None = None, chunk: int = 65536) -> np.ndarray:
    """Which of ``cells`` (bool) have supported cells of other views over them (within
    ``cell_mm`` along the surface and ``4 max(cell_mm, consistent_mm)`` in space, normals
    within 60 degrees) but none within ``consistent_mm`` along the cell's normal (step 5).

    ``previous`` = ``(out, cells, supported)`` of a call with a superset of ``supported``:
    the cells examined then keep their result unless a cell no longer supported lies within
    that reach of them (their neighbours are the same); the same result as without it."""
    idx = np.flatnonzero(supported)
    out = np.zeros(len(P), bool)
    if len(idx) < 2:
        return out
    tree = cKDTree(P[idx])
    reach = 4.0 * max(opt.cell_mm, opt.consistent_mm)
    k = min(6 * opt.neighbours, len(idx))
    todo = np.flatnonzero(cells)
    again = None if previous is None else _changed(P, todo, supported, previous[2], reach)
    if again is not None:
        seen = previous[1][todo]
        out[todo[seen]] = previous[0][todo[seen]]
        todo = todo[~seen | again]
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
    a sample lies on surface ``B`` when its closest point on ``B`` (point inversion, Piegl and
    Tiller section 6.1: :func:`~nurbscan.nurbs.intersect.closest_point_surface`) is within
    ``tol`` mm and strictly inside ``B``'s domain (a sample next to ``B``'s border projects
    onto it).

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
    its domain (point inversion, :func:`nurbscan.nurbs.intersect.closest_point_surface`)."""
    u, v, _, d = closest_point_surface(S, X, iters=iters)
    (u0, u1), (v0, v1) = S.domain
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


# ---------------------------------------------------------------------------- seams (STEP)
@dataclass(frozen=True)
class SeamOptions:
    """Settings of :func:`seams`.

    Attributes
    ----------
    reach_mm : float
        A fused-mesh triangle belongs to the patch of its nearest kept cell within this
        distance (centre to centroid, normals within 60 degrees); farther triangles belong to
        none (the CAD set does not cover them). A cell's half diagonal (0.21 mm) plus about
        half a fused-mesh triangle (edges about 0.45 mm on the 1024 x 768 teapot).
    smooth_rounds : int
        Rounds of the majority vote over each triangle's three neighbours.
    near_mm : float
        A fused-mesh vertex is a candidate of the patches with a kept cell centre this close.
    on_mm : float
        A triangle may belong to a patch only when its three vertices lie within this
        distance of the patch's surface (closest point, exact): the seams' vertices then lie
        this close to both surfaces either side, and the faces' edges need no larger
        tolerance. 0.1 mm is the CAD set's own limit (``CadOptions.fused_mm``,
        ``consistent_mm``: 3.3 robust standard deviations of the views' layers' spread).
    fill_mm : float
        Triangles left to no region next to a region go to it when their vertices lie
        within this distance of its surface (step 4 of :func:`seams`): the gaps where two
        views' layers part by more than ``2 on_mm`` close, the seam there needing an edge
        tolerance up to ``fill_mm``.
    min_triangles : int
        Smaller pieces of a region (and smaller uncovered holes) go to their neighbours.
    max_rounds : int
        Largest number of clean-up rounds (pieces, pinch vertices) before giving up.
    """

    reach_mm: float = 0.35
    near_mm: float = 1.0
    on_mm: float = 0.1
    fill_mm: float = 0.2
    smooth_rounds: int = 4
    min_triangles: int = 12
    max_rounds: int = 20

    def to_dict(self) -> dict:
        """JSON-ready dict."""
        return asdict(self)


@dataclass(frozen=True)
class Seams:
    """The fused mesh partitioned among the CAD set's kept patches (:func:`seams`).

    Attributes
    ----------
    points : ndarray (N, 3)
        The fused mesh's vertices.
    labels : ndarray (F,) int
        Per fused-mesh triangle the index of its patch in ``CadSet.patches``, -1 for none.
    chains : list of ndarray
        The seams: vertex indices of polylines along the mesh's edges, each between two
        junctions (vertices where three regions meet, or two meet the mesh's or the set's
        border), every one shared by the two regions either side.
    sides : ndarray (C, 2) int
        Per chain the region on its left when walked forward and the one on its right
        (-1: no region, a free border).
    loops : dict
        Per region (patch index) its boundary loops, each a list of ``(chain, forward)``
        with the region on the left seen from outside (the fused mesh's orientation); the
        outer loop first (largest area in the surface's parameter plane).
    info : dict
        Counts.
    """

    points: np.ndarray
    labels: np.ndarray
    chains: list
    sides: np.ndarray
    loops: dict
    info: dict = field(default_factory=dict)


def seams(cad: CadSet, fused, options: SeamOptions | None = None) -> Seams:
    """Partition the fused mesh among the CAD set's kept patches; the seams between regions.

    1. **Labels.** Each triangle of the fused mesh (one body, screened Poisson of all views,
       :mod:`nurbscan.merge.fusion`) goes to the patch of its nearest kept cell centre
       within ``reach_mm`` whose normal is within 60 degrees (one k-nearest query); farther
       triangles go to none.
    2. **Smoothing.** ``smooth_rounds`` of a majority vote: a triangle takes the label two
       of its three edge neighbours share.
    3. **Simple regions.** Every region keeps its largest edge-connected piece; its other
       pieces, and pieces of any label smaller than ``min_triangles``, take their
       neighbours' most frequent label (repeated until none is left). A vertex where a
       region's border passes twice (a pinch: the region would touch itself) gives that
       region's triangles there to their most frequent other neighbour. Both are repeated
       until no piece and no pinch is left (at most ``max_rounds``).
    4. **Gaps.** Triangles of no region next to a region take its label when their three
       vertices lie within ``fill_mm`` of its surface (grown until none changes), and step
       3 is run again with that tolerance: where two views' layers part by more than
       ``2 on_mm`` the seam closes with a larger edge tolerance rather than leave a gap.
    5. **Seams.** The borders between regions (mesh edges whose two triangles have two
       labels, or one) are split at junctions into chains, each ONE polyline for both
       regions either side; closed loops are split in two. Each region's boundary loops
       are its chains in order, the region on their left (the mesh is counter-clockwise
       seen from outside).

    Parameters
    ----------
    cad : CadSet
    fused : nurbscan.merge.FusedMesh
    options : SeamOptions, optional

    Returns
    -------
    Seams
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    opt = options or SeamOptions()
    V = np.asarray(fused.vertices, float)
    F = np.asarray(fused.faces, np.int64)
    if not len(F) or not cad.patches:
        raise NurbscanError("CAD seams: no fused mesh or no kept patch")
    # 1. labels: nearest kept cell centre
    Pc, Nc, own = [], [], []
    for k, p in enumerate(cad.patches):
        u, v = np.asarray(p["u"]), np.asarray(p["v"])
        i, j = np.nonzero(p["keep"])
        D = p["surface"].derivatives(0.5 * (u[i] + u[i + 1]), 0.5 * (v[j] + v[j + 1]), 1)
        n = np.cross(D[1, 0], D[0, 1])
        Pc.append(D[0, 0])
        Nc.append(n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300))
        own.append(np.full(len(i), k))
    Pc, Nc, own = np.concatenate(Pc), np.concatenate(Nc), np.concatenate(own)
    A, B, C = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    T = (A + B + C) / 3.0
    Nt = np.cross(B - A, C - A)
    Nt /= np.maximum(np.linalg.norm(Nt, axis=1, keepdims=True), 1e-300)
    tree = cKDTree(Pc)
    eligible = _eligible(cad, V, F, tree, own, opt)
    k = min(8, len(Pc))
    d, j = tree.query(T, k=k, distance_upper_bound=opt.reach_mm)
    d, j = d.reshape(len(T), k), j.reshape(len(T), k)
    ok = np.isfinite(d)
    jj = np.where(ok, j, 0)
    ok &= np.abs((Nc[jj] * Nt[:, None]).sum(-1)) > 0.5
    ok &= eligible(np.repeat(np.arange(len(T))[:, None], k, 1), own[jj])
    first = np.argmax(ok, axis=1)
    cell = jj[np.arange(len(T)), first]
    L = np.where(ok.any(1), own[cell], -1)
    # triangle adjacency: half-edge (t, e) runs F[t, e] -> F[t, (e + 1) % 3]
    a = F.ravel()
    b = F[:, [1, 2, 0]].ravel()
    key = np.minimum(a, b) * len(V) + np.maximum(a, b)
    order = np.argsort(key, kind="stable")
    ks = key[order]
    nb = np.full(len(a), -1, np.int64)
    pair = np.flatnonzero(ks[1:] == ks[:-1])
    single = np.ones(len(pair), bool)
    if len(pair) > 1:  # an edge of three or more triangles: treated as a border
        single = np.r_[True, pair[1:] != pair[:-1] + 1] & np.r_[pair[:-1] + 1 != pair[1:], True]
    pair = pair[single]
    h0, h1 = order[pair], order[pair + 1]
    nb[h0], nb[h1] = h1 // 3, h0 // 3
    nb = nb.reshape(-1, 3)
    # 2. majority vote
    for _ in range(opt.smooth_rounds):
        Ln = np.where(nb >= 0, L[np.maximum(nb, 0)], -2)
        x, y, z = Ln[:, 0], Ln[:, 1], Ln[:, 2]
        maj = np.where((x == y) | (x == z), x, np.where(y == z, y, -2))
        L = np.where((maj == -1) | ((maj >= 0) & eligible(np.arange(len(L)), maj)), maj, L)
    # 3. simple regions
    rounds = 0
    for fill in (False, True):
        if fill:  # 4. gaps: uncovered triangles next to a region within fill_mm of it
            loose = lambda t, lab: eligible(t, lab, opt.fill_mm)  # noqa: E731
            L = _grow(L, nb, loose, opt.max_rounds * 10)
        while rounds < opt.max_rounds * (1 + fill):
            rounds += 1
            L, moved = _clean_pieces(L, nb, opt.min_triangles, loose if fill else eligible,
                                     connected_components, coo_matrix)
            L, pinched = _unpinch_regions(L, nb, F, loose if fill else eligible)
            if not moved and not pinched:
                break
    # 5. seams
    chains, sides, loops = _chains(L, nb, F)
    _outer_first(cad, V, chains, loops)
    info = {"triangles": int(len(F)), "regions": int(len(loops)), "chains": len(chains),
            "triangles_none": int((L < 0).sum()), "rounds": rounds, "options": opt.to_dict()}
    return Seams(V, L, chains, np.asarray(sides, int).reshape(-1, 2), loops, info)


def _eligible(cad, V, F, tree, own, opt):
    """``eligible(t, label)``: whether triangles ``t`` may belong to patches ``label``
    (arrays of one shape): their three vertices within ``on_mm`` of the patch's surface
    (:func:`~nurbscan.nurbs.intersect.closest_point_surface`, for the vertices within
    ``near_mm`` of one of its kept cells);
    ``eligible(t, label, tol)`` with another distance (at most ``max(on_mm, fill_mm)``)."""
    n_v = len(V)
    d, j = tree.query(V, k=16, distance_upper_bound=opt.near_mm)
    ok = np.isfinite(d)
    vi = np.repeat(np.arange(n_v)[:, None], 16, 1)[ok]
    key = np.unique(own[j[ok]] * n_v + vi)
    pk, vk = key // n_v, key % n_v
    dist = np.full(len(key), np.inf)
    starts = np.flatnonzero(np.r_[True, pk[1:] != pk[:-1]])
    for a, b in zip(starts, np.r_[starts[1:], len(key)], strict=True):
        dist[a:b] = closest_point_surface(cad.patches[int(pk[a])]["surface"], V[vk[a:b]],
                                          PER_SPAN_SEAMS, 10)[3]
    keep = dist <= max(opt.on_mm, opt.fill_mm)
    key, dist = key[keep], dist[keep]

    def eligible(t, label, tol=opt.on_mm):
        t, label = np.broadcast_arrays(np.asarray(t), np.asarray(label))
        out = label >= 0
        for c in range(3):
            q = np.maximum(label, 0) * n_v + F[t, c]
            at = np.minimum(np.searchsorted(key, q), max(len(key) - 1, 0))
            out &= ((key[at] == q) & (dist[at] <= tol)) if len(key) else False
        return out

    return eligible


def _grow(L, nb, eligible, rounds):
    """Triangles of no region next to regions take their neighbours' most frequent label
    for which they are eligible, repeated (at most ``rounds``) until none changes."""
    L = L.copy()
    for _ in range(rounds):
        idx = np.flatnonzero(L == -1)
        Ln = np.where(nb[idx] >= 0, L[np.maximum(nb[idx], 0)], -3)
        Ln = np.where((Ln >= 0) & eligible(idx[:, None], Ln), Ln, -3)
        has = (Ln >= 0).any(1)
        if not has.any():
            break
        L[idx[has]] = _mode_rows(Ln[has], exclude=-3)
    return L


def _clean_pieces(L, nb, min_triangles, eligible, connected_components, coo_matrix):
    """Every label's largest piece kept (and pieces of at least ``min_triangles`` of -1);
    the other pieces take their neighbours' most frequent label. Returns (labels, moved)."""
    m = len(L)
    t = np.repeat(np.arange(m), 3)
    o = nb.ravel()
    same = (o >= 0) & (L[t] == L[np.maximum(o, 0)])
    g = coo_matrix((np.ones(same.sum()), (t[same], o[same])), shape=(m, m))
    _, comp = connected_components(g, directed=False)
    size = np.bincount(comp)
    # the largest piece of each label >= 0
    best = np.full(L.max() + 2, -1)
    order = np.argsort(size[comp], kind="stable")
    best[L[order] + 1] = comp[order]  # last write wins: the largest
    orphan = (size[comp] < min_triangles) | ((L >= 0) & (comp != best[L + 1]))
    moved = bool(orphan.any())
    for _ in range(1000):
        if not orphan.any():
            break
        Ln = np.where(nb >= 0, L[np.maximum(nb, 0)], -3)
        On = np.where(nb >= 0, orphan[np.maximum(nb, 0)], True)
        Ln = np.where(On | ((Ln >= 0) & ~eligible(np.arange(m)[:, None], Ln)), -3, Ln)
        idx = np.flatnonzero(orphan & (Ln > -3).any(1))
        if not len(idx):
            L[orphan] = -1
            break
        L[idx] = _mode_rows(Ln[idx], exclude=-3)
        orphan[idx] = False
    return L, moved


def _mode_rows(X: np.ndarray, exclude: int) -> np.ndarray:
    """Per row the most frequent value other than ``exclude`` (ties: the first)."""
    eq = (X[:, :, None] == X[:, None, :]) & (X[:, None, :] != exclude)
    cnt = np.where(X != exclude, eq.sum(2), -1)
    return X[np.arange(len(X)), np.argmax(cnt, axis=1)]


def _boundary(L, nb, F):
    """Region border half-edges: (triangle, start vertex, end vertex, other label)."""
    t = np.repeat(np.arange(len(F)), 3)
    o = nb.ravel()
    other = np.where(o >= 0, L[np.maximum(o, 0)], -1)
    on = (L[t] >= 0) & (other != L[t])
    a, b = F.ravel(), F[:, [1, 2, 0]].ravel()
    return t[on], a[on], b[on], other[on]


def _unpinch_regions(L, nb, F, eligible):
    """Regions' triangles at their pinch vertices given to their most frequent other
    neighbour (-1 when none). Returns (labels, any pinch)."""
    t, a, _, _ = _boundary(L, nb, F)
    key = L[t] * (int(F.max()) + 1) + a
    u, inv, cnt = np.unique(key, return_inverse=True, return_counts=True)
    bad = np.flatnonzero(cnt[inv] > 1)
    if not len(bad):
        return L, False
    n_v = int(F.max()) + 1
    pin = np.unique(u[inv[bad]])
    # triangles of label lab incident on vertex vert
    tri = np.repeat(np.arange(len(F)), 3)
    tk = L[tri] * n_v + F.ravel()
    hit = np.isin(tk, pin) & (L[tri] >= 0)
    sel = np.unique(tri[hit])
    Ln = np.where(nb[sel] >= 0, L[np.maximum(nb[sel], 0)], -3)
    Ln = np.where(Ln == L[sel][:, None], -3, Ln)
    Ln = np.where((Ln >= 0) & ~eligible(sel[:, None], Ln), -3, Ln)
    new = _mode_rows(Ln, exclude=-3)
    L = L.copy()
    L[sel] = np.where(new == -3, -1, new)
    return L, True


def _chains(L, nb, F):
    """Chains, their sides and the regions' loops (:func:`seams`, step 4)."""
    t, a, b, other = _boundary(L, nb, F)
    me = L[t]
    # each undirected border edge once: the half-edge of the larger label
    one = me > other
    ea, eb, el, eo = a[one], b[one], me[one], other[one]
    # junctions: border degree != 2 or two label pairs at the vertex
    n_v = int(F.max()) + 1
    deg = np.bincount(np.r_[ea, eb], minlength=n_v)
    pk = el * (L.max() + 2) + eo + 1
    lo = np.full(n_v, np.iinfo(np.int64).max)
    hi = np.full(n_v, np.iinfo(np.int64).min)
    np.minimum.at(lo, np.r_[ea, eb], np.r_[pk, pk])
    np.maximum.at(hi, np.r_[ea, eb], np.r_[pk, pk])
    junction = (deg != 2) | (lo != hi)
    # walk: forward adjacency per vertex (edge ids by start and by end)
    out_e: dict[int, list[int]] = {}
    in_e: dict[int, list[int]] = {}
    for e, (x, y) in enumerate(zip(ea.tolist(), eb.tolist(), strict=True)):
        out_e.setdefault(x, []).append(e)
        in_e.setdefault(y, []).append(e)
    used = np.zeros(len(ea), bool)
    chains, sides = [], []

    def walk(e0):
        vs = [int(ea[e0]), int(eb[e0])]
        used[e0] = True
        while not junction[vs[-1]]:
            nxt = [f for f in out_e.get(vs[-1], []) if not used[f] and pk[f] == pk[e0]]
            if not nxt:
                break
            used[nxt[0]] = True
            vs.append(int(eb[nxt[0]]))
        return vs

    def extend_back(vs, e0):
        while not junction[vs[0]]:
            prv = [f for f in in_e.get(vs[0], []) if not used[f] and pk[f] == pk[e0]]
            if not prv:
                break
            used[prv[0]] = True
            vs.insert(0, int(ea[prv[0]]))
        return vs

    for e0 in np.argsort(~junction[ea], kind="stable"):  # chains from junctions first
        if used[e0]:
            continue
        vs = extend_back(walk(int(e0)), int(e0))
        pieces = [vs]
        if vs[0] == vs[-1]:  # closed: two chains
            h = len(vs) // 2
            pieces = [vs[:h + 1], vs[h:]]
        for piece in pieces:
            chains.append(np.array(piece, np.int64))
            sides.append((int(el[e0]), int(eo[e0])))
    # loops of every region: chain uses linked end to start
    loops: dict[int, list] = {}
    uses: dict[int, dict[int, list]] = {}
    for c, (vs, (left, right)) in enumerate(zip(chains, sides, strict=True)):
        uses.setdefault(left, {}).setdefault(int(vs[0]), []).append((c, True, int(vs[-1])))
        if right >= 0:
            uses.setdefault(right, {}).setdefault(int(vs[-1]), []).append((c, False,
                                                                           int(vs[0])))
    for region, starts in uses.items():
        todo = {(c, f) for lst in starts.values() for c, f, _ in lst}
        out = []
        while todo:
            c0, f0 = min(todo)
            loop, c, f = [], c0, f0
            while (c, f) in todo:
                todo.discard((c, f))
                loop.append((c, f))
                end = int(chains[c][-1] if f else chains[c][0])
                nxt = [(c2, f2) for c2, f2, _ in starts.get(end, []) if (c2, f2) in todo]
                if not nxt:
                    break
                c, f = nxt[0]
            out.append(loop)
        loops[region] = out
    return chains, sides, loops


def _outer_first(cad, points, chains, loops):
    """Each region's loops with its outer loop first: the loop of largest area in the
    parameter plane of its surface (chain vertices projected,
    :func:`~nurbscan.nurbs.intersect.closest_point_surface`; shoelace)."""
    for region, lst in loops.items():
        if len(lst) < 2:
            continue
        area = []
        for loop in lst:
            idx = np.concatenate([chains[c][:-1] if f else chains[c][::-1][:-1]
                                  for c, f in loop])
            u, v, _, _ = closest_point_surface(cad.patches[region]["surface"], points[idx],
                                               PER_SPAN_SEAMS, 10)
            area.append(abs(float((u * np.roll(v, -1) - np.roll(u, -1) * v).sum())))
        o = int(np.argmax(area))
        loops[region] = [lst[o]] + [lp for k, lp in enumerate(lst) if k != o]
