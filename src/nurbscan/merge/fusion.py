"""One triangle mesh of the object for VR: the views' samples fused by screened Poisson (issue 32).

Every view contributes its Gordon patches, sampled 1/8 pitch apart with unit normals turned
towards its camera, in the object frame; samples more than half a pitch from every triangulated
edge point (the measured data) are dropped. The samples of all views are fused into one surface
by screened Poisson reconstruction (Kazhdan and Hoppe 2013, Open3D's
``create_from_point_cloud_poisson``), which averages the views' coincident layers into one. The
implicit surface is closed by construction; it is cut back to within a sample spacing of the
samples, small holes of the data are left closed, and fragments dropped. The mesh is
subdivided once and its vertices projected onto the samples (a moving-least-squares step,
Alexa et al. 2003), then decimated to a triangle budget by quadric error metrics (Garland and
Heckbert 1997, Open3D) and coloured from the views' white-light images.

Units: mm, object (turntable) frame, ``z`` up (glTF's ``y`` up is a node rotation at export).
"""

from __future__ import annotations

import io
import os
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from ..errors import NurbscanError
from ._open3d import import_open3d

__all__ = ["FusedMesh", "FusionOptions", "alignment_fusion", "decimate", "fuse_model",
           "fuse_samples", "read_fused", "write_fused"]

FUSED_FILE = "fused.ply"
#: Largest fused mesh read, bytes (a binary PLY of about 60 M triangles).
MAX_FUSED_BYTES = 4 << 30


@dataclass(frozen=True)
class FusionOptions:
    """Settings of :func:`fuse_model`, grouped by step.

    Attributes
    ----------
    samples : {"patches", "edges"}
        What is fused: the Gordon patches sampled (normals from the surfaces) or the raw
        triangulated edge points (normals estimated from 24 neighbours, turned towards their
        view's camera).
    sample_pitch : float
        Spacing of the patch samples, in pitches.
    depth : int or None
        Poisson octree depth; None: the smallest depth whose cell is at most
        ``cell_spacing`` sample spacings.
    cell_spacing : float
        Poisson cell size, in sample spacings (for ``depth=None``).
    support_pitch : float
        Patch samples farther than this many pitches from the nearest measured point (edge
        point of a network line) are not fused (border rows running past the data).
    trim_spacing : float
        Surface farther from the nearest fused sample than this many times the samples'
        spacing (the larger step of a view's sample grid) is cut away.
    hole_pitch : float
        A cut-away piece enclosed by kept surface whose points all lie within this many
        pitches of the data is a hole of the data and stays closed.
    min_part : float
        Connected parts smaller than this share of the mesh's area are dropped.
    subdivide : int
        Midpoint subdivisions of the trimmed surface before the projection (each quarters
        the triangles' chord error on curved parts; the decimation then removes the
        triangles that flat parts do not need).
    project_k : int
        Samples used by the projection of each vertex onto the samples (0: no projection).
    max_triangles : int
        Triangle budget (quadric decimation above it).
    workers : int
        Threads of the Poisson solver (0: all CPUs). One (the default) gives the same mesh,
        byte for byte, from run to run; Open3D's solver on several threads does not (its
        parallel reductions add in the order the threads finish: on the 1024 x 768 teapot
        passes' merge, 9 runs on 2 threads gave 9 different Poisson meshes, 11 runs on 1 the
        same; issue #34), for no more CPU time (3.0-3.7 s CPU on 1 thread, 3.0-4.2 s on 2;
        docs/accuracy.md "Same inputs, same bytes").
    loose_edges : float or None
        Also fuse the triangulated edge points farther than this many pitches from every
        kept patch sample (decoded lines that belong to no complete patch), with normals from
        their neighbours (:func:`_loose_edges`); None: patches only. ``nurbscan merge`` uses
        0.5 (1024 x 768 teapot passes: whole coverage 0.764 -> 0.798, mean unchanged).
    colour : bool
        Colour the vertices from the views' white-light images (False: grey; a pass's
        alignment surface, which a merge does not show, :func:`alignment_fusion`).
    purpose : str
        What the mesh is for, recorded in its summary (``model.json``'s ``"fused"``).
    """

    samples: str = "patches"
    sample_pitch: float = 0.125
    depth: int | None = None
    cell_spacing: float = 2.5
    support_pitch: float = 0.5
    trim_spacing: float = 1.0
    hole_pitch: float = 3.0
    min_part: float = 0.002
    subdivide: int = 1
    project_k: int = 12
    max_triangles: int = 300_000
    workers: int = 1
    loose_edges: float | None = None
    colour: bool = True
    purpose: str = "the object's mesh"

    def __post_init__(self):
        if self.samples not in ("patches", "edges"):
            raise NurbscanError(f"fusion samples {self.samples!r}: expected 'patches' or "
                                "'edges'")
        if self.max_triangles < 100:
            raise NurbscanError(f"--max-triangles {self.max_triangles}: must be at least 100")


@dataclass(frozen=True)
class FusedMesh:
    """The fused triangle mesh of an object.

    Attributes
    ----------
    vertices : ndarray (N, 3) float64, mm, object frame
    faces : ndarray (F, 3) int64, counter-clockwise seen from outside
    colors : ndarray (N, 4) uint8 RGBA
    info : dict
        Summary (counts, area, parts, pitch, settings, times, colour source).
    """

    vertices: np.ndarray
    faces: np.ndarray
    colors: np.ndarray
    info: dict = field(default_factory=dict)

    def trimesh(self, scale: float = 1.0):
        """A ``trimesh.Trimesh`` (vertices times ``scale``) with the vertex colours."""
        import trimesh

        return trimesh.Trimesh(self.vertices * scale, self.faces, vertex_colors=self.colors,
                               process=False)


def alignment_fusion(options: FusionOptions | None = None) -> FusionOptions:
    """The fusion of a turntable pass made only to be merged (``nurbscan reconstruct`` of
    several scans): its mesh is the surface the global registration aligns
    (:func:`nurbscan.merge.passes.pass_surface`), and the merge fuses every pass's views again
    into the model's mesh, so the pass's own is not subdivided (the Poisson surface, trimmed,
    its vertices projected onto the samples once: no decimation under the triangle budget)
    nor coloured. Measured on the 1024 x 768 teapot passes (docs/accuracy.md, "Two passes'
    CPU time"): the two passes' fusion 30.3 -> 16.1 s CPU; the merged mesh's coverage and
    mean unchanged, the alignment within the scatter of its surface sampling."""
    return replace(options or FusionOptions(), subdivide=0, colour=False,
                   purpose="a pass's alignment surface for a merge (not subdivided, grey)")


# ---------------------------------------------------------------------------- public
def fuse_model(model, rig=None, white: Mapping[int, str | os.PathLike] | None = None,
               options: FusionOptions | None = None,
               progress: Callable[[str], None] | None = None) -> FusedMesh:
    """One coloured triangle mesh of a model's views (object frame, mm).

    Parameters
    ----------
    model : nurbscan.reconstruct.Model
        The views' Gordon patches, samples (``points``, ``normals``, ``point_view``) and edge
        points in the object frame. A model without samples has its Gordon surfaces sampled.
    rig : Rig, optional
        The calibrated rig: orients normals (edge samples, surfaces without samples) towards
        the cameras and projects vertices into the white images.
    white : mapping {view index: image path}, optional
        The views' white-light photographs; without them (or the rig) the mesh is grey.
    options : FusionOptions, optional
    progress : callable, optional
        Called with a line per step.

    Notes
    -----
    1. Samples with normals (:func:`_samples`) and the grid pitch at the object.
    2. :func:`fuse_samples`: Poisson, trim, holes, parts, projection, decimation.
    3. Vertex colours from the white images (:func:`_vertex_colours`).
    """
    opt = options or FusionOptions()
    t0 = time.perf_counter()
    pitch = _pitch(model)
    P, N, spacing = _samples(model, rig, opt, pitch)
    if len(P) < 100:
        raise NurbscanError(f"fusion: {len(P)} samples, too few to fuse a surface")
    V, F, info = fuse_samples(P, N, P, pitch, opt, progress, spacing)
    t1 = time.perf_counter()
    colors, source = _vertex_colours(V, F, model, rig, white if opt.colour else None)
    if not opt.colour:
        source = "neutral (not coloured: a pass's alignment surface)"
    info.update({"purpose": opt.purpose, "colour": source, "samples": opt.samples,
                 "n_samples": int(len(P)),
                 "fuse_s": round(t1 - t0, 3), "colour_s": round(time.perf_counter() - t1, 3)})
    if progress is not None:
        progress(f"fused mesh: {info['faces']} triangles, {info['parts']} parts, "
                 f"{info['area_mm2']:.0f} mm^2, colour {source} "
                 f"({info['fuse_s']:.1f} + {info['colour_s']:.1f} s)")
    return FusedMesh(V, F, colors, info)


def fuse_samples(points: np.ndarray, normals: np.ndarray, data: np.ndarray, pitch: float,
                 options: FusionOptions | None = None,
                 progress: Callable[[str], None] | None = None, spacing: float | None = None):
    """Fuse oriented samples into one trimmed triangle mesh.

    Parameters
    ----------
    points, normals : ndarray (N, 3)
        Samples (mm) with outward unit normals.
    data : ndarray (M, 3)
        The measured points the surface may not run past (mm).
    pitch : float
        Grid pitch at the object, mm: the unit of the hole size and the projection's reach.
    spacing : float, optional
        Spacing of one view's samples, mm: the unit of the Poisson cell and the trim distance
        (default: the median
        distance from a point of ``data`` to its fourth nearest, :func:`_grid_step`).

    Returns
    -------
    vertices (V, 3), faces (F, 3), info dict.

    Notes
    -----
    1. Screened Poisson (Kazhdan and Hoppe 2013) at the depth whose cell is
       ``cell_spacing`` sample spacings.
    2. Trim: the surface more than ``trim_spacing`` sample spacings from the data is cut
       away along
       the iso-line of the distance, except enclosed pieces within ``hole_pitch`` pitches
       of it (small holes stay closed).
    3. Parts under ``min_part`` of the area go.
    4. ``subdivide`` midpoint subdivisions, then the vertices projected onto the samples
       (:func:`_project`).
    5. Quadric decimation to ``max_triangles``, then the projection again.
    """
    opt = options or FusionOptions()
    say = progress or (lambda _msg: None)
    t = time.perf_counter()
    if spacing is None:
        spacing = _grid_step(data)
    V, F, depth = _poisson(points, normals, opt.cell_spacing * spacing, opt)
    n_poisson = len(F)
    say(f"fusion: Poisson depth {depth}, {n_poisson} triangles ({time.perf_counter() - t:.1f} s)")
    V, F, holes, trim = _trim(V, F, data, pitch, opt.trim_spacing * spacing, opt)
    V, F, parts = _largest_parts(V, F, opt.min_part)
    say(f"fusion: trimmed to the data, {holes} holes closed, {len(F)} triangles in "
        f"{parts} parts ({time.perf_counter() - t:.1f} s)")
    for _ in range(opt.subdivide):
        V, F = _subdivide(V, F)
    tree = cKDTree(points)
    V = _project(V, F, points, normals, tree, opt.project_k, pitch)
    n_full = len(F)
    if len(F) > opt.max_triangles:
        V, F = decimate(V, F, opt.max_triangles)
        V = _project(V, F, points, normals, tree, opt.project_k, pitch)
        say(f"fusion: decimated {n_full} -> {len(F)} triangles "
            f"({time.perf_counter() - t:.1f} s)")
    V, F = _clean(V, F)
    area = float(_face_areas(V, F).sum())
    info = {"method": "screened Poisson (Open3D) of the Gordon samples, trimmed to them, "
                      "subdivided, projected onto the samples, quadric decimation",
            "vertices": int(len(V)), "faces": int(len(F)), "parts": count_parts(F, len(V)),
            "area_mm2": round(area, 3), "pitch_mm": round(float(pitch), 4),
            "poisson_depth": int(depth), "poisson_faces": int(n_poisson),
            "holes_closed": int(holes), "trim_mm": round(float(trim), 4),
            "before_decimation": int(n_full),
            "max_triangles": int(opt.max_triangles), "units": "mm", "frame": "object",
            "watertight": _watertight(F)}
    return V, F, info


# ---------------------------------------------------------------------------- I/O
def write_fused(folder: str | os.PathLike, mesh: FusedMesh) -> Path:
    """Write ``folder/fused.ply`` (binary PLY, mm, vertex colours) atomically."""
    from ..io.atomic import atomic_path

    data = mesh.trimesh().export(file_type="ply", encoding="binary")
    path = Path(folder) / FUSED_FILE
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return path


def read_fused(path: str | os.PathLike, info: dict | None = None) -> FusedMesh:
    """Read a fused mesh written by :func:`write_fused`."""
    import trimesh

    from ..io.atomic import read_bytes

    path = Path(path)
    data = read_bytes(path, MAX_FUSED_BYTES, "fused mesh")
    try:  # trimesh's PLY parser fails on another kind of file with any of these
        tm = trimesh.load(io.BytesIO(data), file_type="ply", process=False)
        V = np.asarray(tm.vertices, float)
        F = np.asarray(tm.faces, np.int64)
        C = np.asarray(tm.visual.vertex_colors, np.uint8)
    except (OSError, ValueError, AttributeError, KeyError, IndexError, TypeError) as exc:
        raise NurbscanError(f"{path}: not a readable fused mesh ({exc})") from None
    if V.ndim != 2 or V.shape[1] != 3 or (F.size and (F.ndim != 2 or F.shape[1] != 3)):
        raise NurbscanError(f"{path}: not a triangle mesh (vertices {V.shape}, faces {F.shape})")
    if C.shape != (len(V), 4):
        C = np.tile(np.array([180, 180, 180, 255], np.uint8), (len(V), 1))
    return FusedMesh(V, F, C, dict(info or {}))


# ---------------------------------------------------------------------------- steps
def _camera_centres(model, rig) -> dict[int, np.ndarray]:
    """Camera centre of each view in the object frame, mm."""
    if rig is None:
        return {}
    c = np.asarray(rig.camera.center, float)[None]
    return {int(v["index"]): rig.turntable.from_rig(c, float(v["table_angle"]))[0]
            for v in model.views}


def _surface_samples(model, rig, spacing: float):
    """Samples about ``spacing`` mm apart on every Gordon surface, with unit normals.

    The samples per parameter follow the length of the control polygon (an upper bound of
    the curve length), as :func:`nurbscan.evaluate.table.gordon_cloud` does. Normals are
    turned towards the view's camera (with the rig), else like the model's nearest sample
    normal (``Model.normals``, turned towards the cameras at reconstruction), else away from
    the centroid. Returns ``(points (N, 3), normals (N, 3), view (N,))``.
    """
    centres = _camera_centres(model, rig)
    pts, nrm, views = [], [], []
    for s in model.surfaces_of("gordon"):
        srf = s["surface"]
        C = np.asarray(srf.control_points)
        lu = np.linalg.norm(np.diff(C, axis=0), axis=2).sum(0).max()
        lv = np.linalg.norm(np.diff(C, axis=1), axis=2).sum(1).max()
        nu = int(min(max(np.ceil(lu / spacing), 2), 1000)) + 1
        nv = int(min(max(np.ceil(lv / spacing), 2), 1000)) + 1
        (u0, u1), (v0, v1) = srf.domain
        uu, vv = np.meshgrid(np.linspace(u0, u1, nu), np.linspace(v0, v1, nv), indexing="ij")
        pts.append(srf.evaluate(uu.ravel(), vv.ravel()))
        nrm.append(srf.normal(uu.ravel(), vv.ravel()))
        views.append(np.full(nu * nv, int(s.get("view", 0))))
    if not pts:
        return np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0, int)
    P, N, pv = np.concatenate(pts), np.concatenate(nrm), np.concatenate(views)
    ok = np.isfinite(N).all(1) & np.isfinite(P).all(1)
    P, N, pv = P[ok], N[ok], pv[ok]
    if centres:
        ref = np.array([centres.get(int(v), P.mean(0)) for v in range(pv.max() + 1)])[pv] - P
    elif len(model.points):
        ref = np.asarray(model.normals)[cKDTree(model.points).query(P)[1]]
    else:
        ref = P - P.mean(0)
    N = np.where((N * ref).sum(1, keepdims=True) < 0, -N, N)
    return P, N, pv


def _samples(model, rig, opt: FusionOptions, pitch: float):
    """``(points, normals, spacing)``: the oriented samples to fuse and their spacing (mm).

    Patches: every Gordon surface sampled ``sample_pitch`` pitches apart
    (:func:`_surface_samples`), kept only within ``support_pitch`` pitches of an edge point (a
    patch's border rows may run past the measured lines). Edges: the triangulated edge
    points, spaced half a pitch (the lines' spacing)."""
    edges = np.asarray(model.edge_points, float).reshape(-1, 3)
    if opt.samples == "edges":
        if len(edges) == 0:
            raise NurbscanError("fusion: samples 'edges' but the model has no edge points")
        P, N = _edge_normals(edges, np.asarray(model.edge_view, int), _camera_centres(model,
                                                                                      rig))
        spacing = 0.5 * pitch
    else:
        spacing = opt.sample_pitch * pitch
        P, N, _ = _surface_samples(model, rig, spacing)
    ok = np.isfinite(P).all(1) & np.isfinite(N).all(1)
    if opt.samples == "patches" and len(edges):
        d, _ = cKDTree(edges).query(P, k=1, distance_upper_bound=opt.support_pitch * pitch)
        ok &= np.isfinite(d)
    P, N = P[ok], N[ok]
    if opt.samples == "patches" and opt.loose_edges is not None and len(edges) and len(P):
        E, EN = _loose_edges(model, P, edges, opt.loose_edges * pitch,
                             _camera_centres(model, rig))
        P, N = np.concatenate([P, E]), np.concatenate([N, EN])
    N = N / np.maximum(np.linalg.norm(N, axis=1, keepdims=True), 1e-300)
    return P, N, spacing


def _loose_edges(model, P: np.ndarray, edges: np.ndarray, reach: float, centres: dict):
    """The edge points (M, 3) farther than ``reach`` mm from every patch sample ``P`` (lines
    outside every complete patch, which the patch samples miss) and their unit normals: PCA
    of their 24 nearest edge points of the same view (Hoppe et al. 1992,
    :func:`_edge_normals`), turned like the model's nearest sample normal (``Model.normals``)
    or, without samples, towards the view's camera."""
    d, _ = cKDTree(P).query(edges, distance_upper_bound=reach)
    loose = ~np.isfinite(d)
    view = np.asarray(model.edge_view, int)
    if loose.sum() < 3:
        return np.zeros((0, 3)), np.zeros((0, 3))
    # the normals of the loose points only; their neighbours from all of their view's points
    _, N = _edge_normals(edges, view, {} if len(model.points) else centres, at=loose)
    N = N[loose]
    E = edges[loose]
    if len(model.points):
        ref = np.asarray(model.normals, float)[cKDTree(model.points).query(E)[1]]
        N = np.where((N * ref).sum(1, keepdims=True) < 0, -N, N)
    return E, N


def _edge_normals(points: np.ndarray, view: np.ndarray, centres: dict, k: int = 24,
                  at: np.ndarray | None = None):
    """Unit normals of edge points by PCA of their ``k`` nearest points of the same view
    (Hoppe et al. 1992), turned towards the view's camera. ``at`` (bool (N,)): only those
    points' normals (their neighbours still from every point of their view), the others
    zero; None: all."""
    N = np.zeros_like(points)
    want = np.ones(len(points), bool) if at is None else np.asarray(at, bool)
    for v in np.unique(view[want]):
        sel = np.flatnonzero(view == v)
        Q = points[sel]
        here = want[sel]
        X = Q[here]
        _, idx = cKDTree(Q).query(X, k=min(k, len(Q)))
        nb = Q[idx] - Q[idx].mean(1, keepdims=True)
        cov = np.einsum("nki,nkj->nij", nb, nb)
        _, vec = np.linalg.eigh(cov)
        n = vec[:, :, 0]
        ref = centres.get(int(v), Q.mean(0) + 1e3) - X if centres else X - Q.mean(0)
        N[sel[here]] = np.where((n * ref).sum(1, keepdims=True) < 0, -n, n)
    return points, N


def _pitch(model) -> float:
    """The grid pitch at the object, mm.

    A Gordon patch spans ``I`` vertical and ``J`` horizontal edge curves; consecutive edges
    are half a pitch apart on average (two edges per band, band plus gap = pitch), so a
    patch's chord across its ``u`` (``v``) domain over ``(I - 1) / 2`` (``(J - 1) / 2``) is a
    pitch. The median over patches and both directions. A model without edge points
    (surfaces only) gets 1/12 of its extent.
    """
    est = []
    if len(model.edge_points):
        for s in model.surfaces_of("gordon"):
            srf, (ni, nj) = s["surface"], s.get("n_curves", (0, 0))
            (u0, u1), (v0, v1) = srf.domain
            um, vm = 0.5 * (u0 + u1), 0.5 * (v0 + v1)
            X = srf.evaluate(np.array([u0, u1, um, um]), np.array([vm, vm, v0, v1]))
            if ni > 1:
                est.append(2.0 * np.linalg.norm(X[1] - X[0]) / (ni - 1))
            if nj > 1:
                est.append(2.0 * np.linalg.norm(X[3] - X[2]) / (nj - 1))
    if est:
        return float(np.median(est))
    C = np.concatenate([np.asarray(s["surface"].control_points).reshape(-1, 3)
                        for s in model.surfaces_of("gordon")] or [np.zeros((1, 3))])
    return max(float(np.ptp(C, axis=0).max()) / 12.0, 1e-3)


def _open3d():
    """The ``open3d`` module, or a one-line error saying why it cannot be imported."""
    return import_open3d("fusion")


def _grid_step(Q: np.ndarray) -> float:
    """Median distance to the fourth nearest point (the larger step of a grid), mm."""
    sub = Q[:: max(1, len(Q) // 5000)]
    return float(np.median(cKDTree(Q).query(sub, k=min(5, len(Q)))[0][:, -1]))


def _poisson(P: np.ndarray, N: np.ndarray, cell: float, opt: FusionOptions):
    """Screened Poisson surface of oriented samples (Kazhdan and Hoppe 2013; Open3D)."""
    o3d = _open3d()

    o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)
    extent = float(np.ptp(P, axis=0).max()) * 1.1
    depth = opt.depth
    if depth is None:
        depth = int(np.clip(np.ceil(np.log2(extent / cell)), 5, 11))
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(P))
    pcd.normals = o3d.utility.Vector3dVector(N)
    mesh, _ = o3d.geometry.TriangleMesh.create_from_point_cloud_poisson(
        pcd, depth=depth, scale=1.1, linear_fit=False,
        n_threads=int(opt.workers) if opt.workers > 0 else -1)
    return np.asarray(mesh.vertices, float), np.asarray(mesh.triangles, np.int64), depth


def _face_areas(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    t = V[F]
    return 0.5 * np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1)


def _face_graph(F: np.ndarray, n_vertices: int, mask: np.ndarray | None = None):
    """Labels of the connected components of faces sharing a vertex (optionally of the
    faces in ``mask`` only): ``(count, labels)``."""
    idx = np.flatnonzero(mask) if mask is not None else np.arange(len(F))
    if len(idx) == 0:
        return 0, np.zeros(0, int), idx
    # faces and vertices in one bipartite graph
    rows = np.repeat(np.arange(len(idx)), 3)
    cols = len(idx) + F[idx].ravel()
    n = len(idx) + n_vertices
    g = coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(n, n))
    count, labels = connected_components(g, directed=False)
    lab = labels[:len(idx)]
    _, lab = np.unique(lab, return_inverse=True)
    return int(lab.max()) + 1, lab, idx


def _trim(V: np.ndarray, F: np.ndarray, data: np.ndarray, pitch: float, t: float,
          opt: FusionOptions):
    """Cut the surface back to within ``t`` mm of the data, except enclosed
    pieces within ``hole_pitch`` pitches of it (small holes of the data stay closed).

    The cut follows the iso-line of the distance to the data (linear along the edges,
    :func:`_clip`), so the border lies at the trim distance whatever the triangle size.
    Returns ``(vertices, faces, holes closed, trim distance mm)``.
    """
    d, _ = cKDTree(data).query(V, k=1, distance_upper_bound=opt.hole_pitch * pitch * 2)
    d = np.minimum(d, opt.hole_pitch * pitch * 2)
    far = (d > t)[F].any(1)
    n, lab, idx = _face_graph(F, len(V), far)
    holes = 0
    if n:
        # a far piece is a hole when all of it lies within the hole size of the data and its
        # area is under the hole size squared (Poisson's closing surface over the unseen
        # side and the pieces that reach the border of the data are far larger)
        dmax = np.zeros(n)
        np.maximum.at(dmax, lab, d[F[idx]].max(1))
        area = np.bincount(lab, weights=_face_areas(V, F[idx]), minlength=n)
        hole = (dmax <= opt.hole_pitch * pitch) & (area <= (opt.hole_pitch * pitch) ** 2)
        d[np.unique(F[idx[hole[lab]]])] = 0.0
        holes = int(hole.sum())
    # the distance is not linear along an edge: cut again with the true distances of the
    # new border points (the border then lies within a few um of t)
    tree = cKDTree(data)
    for _ in range(3):
        V, F, src = _clip(V, F, d - t)
        new = src < 0
        d = np.where(new, 0.0, d[np.maximum(src, 0)])
        if not new.any():
            break
        d[new] = tree.query(V[new], k=1)[0]
        if d[new].max() <= t * 1.01:
            break
    return V, F, holes, t


def _clip(V: np.ndarray, F: np.ndarray, f: np.ndarray):
    """The part of a mesh where the vertex function ``f`` (linear along edges) is <= 0
    (marching triangles). Faces keep their winding; points on shared edges are shared.

    Returns ``(vertices, faces, source)``: ``source`` the index in ``V`` of each vertex, -1
    for the new points on the cut edges."""
    inside = f <= 0
    n_in = inside[F].sum(1)
    keep = F[n_in == 3]
    # rotate each cut face so that its odd vertex (the one on its own side) comes first
    cut = F[(n_in == 1) | (n_in == 2)]
    cin = inside[cut]
    odd = np.where(cin.sum(1) == 1, np.argmax(cin, 1), np.argmin(cin, 1))
    r = (odd[:, None] + np.arange(3)[None, :]) % 3
    cut = np.take_along_axis(cut, r, 1)
    one = inside[cut[:, 0]]  # the odd vertex is inside: one vertex in, two out
    a, b, c = cut[:, 0], cut[:, 1], cut[:, 2]
    # new vertices on edges (a, b) and (a, c), shared between neighbouring faces
    edges = np.concatenate([np.stack([a, b], 1), np.stack([a, c], 1)])
    key = np.sort(edges, 1)
    uniq, inv = np.unique(key, axis=0, return_inverse=True)
    i, j = uniq[:, 0], uniq[:, 1]
    s = f[i] / (f[i] - f[j])
    P = V[i] + s[:, None] * (V[j] - V[i])
    ids = len(V) + inv.ravel()
    pab, pac = ids[:len(cut)], ids[len(cut):]
    tri_one = np.stack([a, pab, pac], 1)[one]
    two = ~one  # a outside, b and c inside: the quad (pab, b, c, pac)
    tri_two = np.concatenate([np.stack([pab, b, c], 1)[two], np.stack([pab, c, pac], 1)[two]])
    V2 = np.concatenate([V, P])
    F2 = np.concatenate([keep, tri_one, tri_two])
    src = np.concatenate([np.arange(len(V)), np.full(len(P), -1)])
    used = np.zeros(len(V2), bool)
    used[F2.ravel()] = True
    new = np.cumsum(used) - 1
    return V2[used], new[F2], src[used]


def _compact(V: np.ndarray, F: np.ndarray):
    """Drop unreferenced vertices."""
    used = np.zeros(len(V), bool)
    used[F.ravel()] = True
    new = np.cumsum(used) - 1
    return V[used], new[F]


def _largest_parts(V: np.ndarray, F: np.ndarray, min_part: float):
    """Drop connected parts under ``min_part`` of the total area."""
    n, lab, _ = _face_graph(F, len(V))
    if n == 0:
        return V, F, 0
    area = np.bincount(lab, weights=_face_areas(V, F), minlength=n)
    big = area >= min_part * area.sum()
    V, F = _compact(V, F[big[lab]])
    return V, F, int(big.sum())


def count_parts(F: np.ndarray, n_vertices: int) -> int:
    return _face_graph(F, n_vertices)[0]


def _vertex_normals(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Area-weighted vertex normals (unit)."""
    t = V[F]
    fn = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    N = np.zeros_like(V)
    for k in range(3):
        np.add.at(N, F[:, k], fn)
    return N / np.maximum(np.linalg.norm(N, axis=1, keepdims=True), 1e-300)


def _project(V: np.ndarray, F: np.ndarray, P: np.ndarray, N: np.ndarray, tree: cKDTree,
             k: int, pitch: float) -> np.ndarray:
    """Move each vertex onto the samples' surface along its normal (one moving-least-squares
    step, Alexa et al. 2003): the signed distances ``n_i . (v - p_i)`` of the vertex to the
    tangent planes of its ``k`` nearest samples, Gaussian-weighted by distance (sigma one
    quarter pitch) and by normal agreement, averaged; vertices with no sample within a pitch,
    or whose samples face away, stay."""
    if k <= 0 or len(V) == 0:
        return V
    nv = _vertex_normals(V, F)
    d, idx = tree.query(V, k=min(k, len(P)), distance_upper_bound=pitch)
    ok = np.isfinite(d)
    idx = np.where(ok, idx, 0)
    Pn, Nn = P[idx], N[idx]
    agree = np.einsum("nkc,nc->nk", Nn, nv)
    sigma = 0.25 * pitch
    w = np.where(ok & (agree > 0.5), np.exp(-0.5 * (np.where(ok, d, 0) / sigma) ** 2), 0.0)
    s = np.einsum("nkc,nkc->nk", Nn, V[:, None, :] - Pn)
    wsum = w.sum(1)
    move = np.where(wsum > 1e-12, (w * s).sum(1) / np.maximum(wsum, 1e-300), 0.0)
    # the plane distances are along the samples' normals: move along their weighted mean
    nm = np.einsum("nk,nkc->nc", w, Nn)
    nm /= np.maximum(np.linalg.norm(nm, axis=1, keepdims=True), 1e-300)
    move = np.clip(move, -0.5 * pitch, 0.5 * pitch)
    return V - move[:, None] * nm


def _subdivide(V: np.ndarray, F: np.ndarray):
    """One midpoint subdivision: every triangle into four, edge midpoints shared."""
    a, b, c = F[:, 0], F[:, 1], F[:, 2]
    e = np.sort(np.concatenate([np.stack([a, b], 1), np.stack([b, c], 1),
                                np.stack([c, a], 1)]), axis=1)
    uniq, inv = np.unique(e, axis=0, return_inverse=True)
    m = len(V) + inv.ravel()
    ab, bc, ca = m[:len(F)], m[len(F):2 * len(F)], m[2 * len(F):]
    V2 = np.concatenate([V, 0.5 * (V[uniq[:, 0]] + V[uniq[:, 1]])])
    F2 = np.concatenate([np.stack([a, ab, ca], 1), np.stack([ab, b, bc], 1),
                         np.stack([ca, bc, c], 1), np.stack([ab, bc, ca], 1)])
    return V2, F2


def decimate(V: np.ndarray, F: np.ndarray, target: int):
    """Quadric error decimation to at most ``target`` triangles (Garland and Heckbert 1997,
    Open3D)."""
    o3d = _open3d()

    m = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(V),
                                  o3d.utility.Vector3iVector(F.astype(np.int32)))
    m = m.simplify_quadric_decimation(target_number_of_triangles=int(target))
    return np.asarray(m.vertices, float), np.asarray(m.triangles, np.int64)


def _clean(V: np.ndarray, F: np.ndarray):
    """Drop degenerate and duplicated faces, the faces of vertices whose normal vanishes
    (faces folded onto each other: glTF wants unit normals) and unreferenced vertices."""
    ext = float(np.ptp(V, axis=0).max()) if len(V) else 1.0
    for _ in range(3):
        F = F[(F[:, 0] != F[:, 1]) & (F[:, 1] != F[:, 2]) & (F[:, 0] != F[:, 2])]
        F = F[_face_areas(V, F) > 1e-12 * ext ** 2]
        _, first = np.unique(np.sort(F, axis=1), axis=0, return_index=True)
        F = F[np.sort(first)]
        t = V[F]
        fn = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
        fn /= np.linalg.norm(fn, axis=1, keepdims=True)
        N = np.zeros_like(V)
        for k in range(3):
            np.add.at(N, F[:, k], fn)
        used = np.zeros(len(V), bool)
        used[F.ravel()] = True
        bad = used & (np.linalg.norm(N, axis=1) < 1e-3)
        if not bad.any():
            break
        F = F[~bad[F].any(1)]
    return _compact(V, F)


def _watertight(F: np.ndarray) -> bool:
    """Every edge shared by exactly two faces."""
    e = np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1)
    _, counts = np.unique(e, axis=0, return_counts=True)
    return bool(len(counts) and np.all(counts == 2))


def _vertex_colours(V: np.ndarray, F: np.ndarray, model, rig, white,
                    poses: Mapping[int, tuple] | None = None) -> tuple[np.ndarray, str]:
    """RGBA uint8 colours (N, 4) from the white-light images, and a note of their source.

    Each vertex is projected into every view (turntable to the rig frame, Tsai camera model)
    and sampled bilinearly (OpenCV ``remap``) where the view sees it: in the image, facing the
    camera (``cos > 0.1``) and not occluded (the segment to the camera centre hits no triangle
    of the mesh, trimesh ray casting). Samples are averaged with weights ``cos^2``; vertices
    no view sees get the mean colour. The images are read one at a time.

    ``poses`` (optional, ``{view: (rig, M)}``, ``M`` 4 x 4 with ``X_rig = M X``) gives a view
    its own rig and pose instead of ``rig`` and the turntable at its table angle (the views of
    several passes merged into one frame, :func:`nurbscan.merge.passes.merge_passes`).
    """
    import cv2
    import trimesh

    from ..io import read_image

    rgba = np.full((len(V), 4), 255, np.uint8)
    rgba[:, :3] = 180
    if (rig is None and not poses) or not white:
        return rgba, "neutral (no rig or white images)"
    tm = trimesh.Trimesh(V, F, process=False)
    N = _vertex_normals(V, F)
    angles = {int(v["index"]): float(v["table_angle"]) for v in model.views}
    acc, wsum = np.zeros((len(V), 3)), np.zeros(len(V))
    eps = 1e-3 * float(np.ptp(V, axis=0).max())
    used = 0
    for k, path in white.items():
        if k not in angles or path is None or not Path(path).is_file():
            continue
        if poses is not None and k not in poses:
            continue
        rig_k = rig if poses is None else poses[k][0]
        C = np.asarray(rig_k.camera.center, float)
        img = read_image(path)
        h, w = img.shape[:2]
        if (w, h) != (rig_k.camera.width, rig_k.camera.height):
            raise NurbscanError(f"{path}: white image of view {k} is {w} x {h} px, but the "
                                f"camera is {rig_k.camera.width} x {rig_k.camera.height}")
        if poses is None:
            a = angles[k]
            d = rig_k.turntable.from_rig(C[None], a)[0][None] - V
            X_rig = rig_k.turntable.to_rig(V, a)
        else:
            M = np.asarray(poses[k][1], float)
            d = (np.linalg.solve(M[:3, :3], C - M[:3, 3]))[None] - V
            X_rig = V @ M[:3, :3].T + M[:3, 3]
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        cos = np.einsum("ij,ij->i", N, d)
        px, valid = rig_k.camera.project(X_rig, return_valid=True)
        ok = valid & (cos > 0.1) & (px[:, 0] >= 0) & (px[:, 0] <= w - 1) \
            & (px[:, 1] >= 0) & (px[:, 1] <= h - 1)
        idx = np.flatnonzero(ok)
        if len(idx):
            hit = tm.ray.intersects_any(V[idx] + d[idx] * eps, d[idx])
            idx = idx[~hit]
        if not len(idx):
            continue
        # maps of 1024 columns (remap wants fewer than 32767 rows and columns)
        m = np.zeros((-(-len(idx) // 1024) * 1024, 2), np.float32)
        m[:len(idx)] = px[idx]
        m = m.reshape(-1, 1024, 2)
        col = cv2.remap(np.ascontiguousarray(img, np.float32), m[..., 0], m[..., 1],
                        cv2.INTER_LINEAR).reshape(-1, 3)[:len(idx)]
        wk = cos[idx] ** 2
        acc[idx] += wk[:, None] * col
        wsum[idx] += wk
        used += 1
    seen = wsum > 0
    if not seen.any():
        return rgba, "neutral (no vertex seen in a white image)"
    col = np.empty((len(V), 3))
    col[seen] = acc[seen] / wsum[seen, None]
    col[~seen] = col[seen].mean(0)
    rgba[:, :3] = np.clip(np.round(col * 255), 0, 255).astype(np.uint8)
    return rgba, f"white-light images of {used} views ({seen.mean():.1%} of vertices seen)"
