"""Triangle meshes of a model for VR: tessellation, fusion, vertex colours, glb/obj/ply/stl.

The mesh is made of the model's Gordon patches (a patch's skins stand in where it has no Gordon
surface), each tessellated on a regular grid in every knot span, oriented so that its normals
face the camera of its view (outwards), and fused by merging coincident vertices (within
``merge_tol_mm``). Patches of different views overlap rather than join, so the mesh is watertight
only when the patches themselves close up; :func:`build_mesh` reports it.

Vertex colours come from the white-light images: each vertex is projected into every view
(turntable to the rig frame, Tsai camera model), sampled bilinearly where the view sees it
(in the image, facing the camera, not occluded: a ray to the camera centre hits no other
triangle), and the samples are averaged with weights ``cos(angle to the camera)^2``; vertices
that no view sees get the mean colour.

Units: ``.obj``, ``.ply`` and ``.stl`` in millimetres; ``.glb`` in metres (glTF 2.0 specifies
metres), scaled by 0.001, with ``asset.extras`` = ``{"units": "m", "scale_from_mm": 0.001}``.
glTF's up axis is ``+y``: the object frame's ``+z`` (the turntable axis) is turned onto it by a
root node rotating -90 degrees about ``x`` (the positions stay in the object frame).
"""

from __future__ import annotations

import json
import os
import struct
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import NurbscanError
from ..io.atomic import atomic_path
from ..nurbs import NurbsSurface

__all__ = ["MESH_FORMATS", "MeshResult", "auto_per_span", "build_mesh", "colour_vertices",
           "mesh_bytes", "patch_grid", "tessellate", "write_mesh"]

MESH_FORMATS = ("glb", "obj", "ply", "stl")
NEUTRAL = np.array([180, 180, 180], np.uint8)
#: glTF node rotation (quaternion x, y, z, w) turning the object frame's z-up into glTF's y-up:
#: -90 degrees about x, (x, y, z) -> (x, z, -y)
Y_UP = [-float(np.sqrt(0.5)), 0.0, 0.0, float(np.sqrt(0.5))]


def patch_grid(s: NurbsSurface, per_span: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """Parameters of a tessellation grid: ``per_span`` intervals in every non-empty knot span.

    Returns ``(us, vs)``, each increasing and containing the domain ends.
    """
    out = []
    for U in (np.asarray(s.knots_u), np.asarray(s.knots_v)):
        k = np.unique(U)
        t = np.linspace(0.0, 1.0, per_span + 1)[:-1]
        g = (k[:-1, None] + np.diff(k)[:, None] * t[None, :]).ravel()
        out.append(np.append(g, k[-1]))
    return out[0], out[1]


def tessellate(s: NurbsSurface, per_span: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """Grid tessellation of one surface: vertices (nu * nv, 3) mm and faces (F, 3) int.

    Two triangles per grid cell, counter-clockwise about the normal ``S_u x S_v``.
    """
    us, vs = patch_grid(s, per_span)
    V = s.evaluate_grid(us, vs).reshape(-1, 3)
    nu, nv = len(us), len(vs)
    idx = np.arange(nu * nv).reshape(nu, nv)
    a, b = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel()
    c, d = idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    F = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    return V, F


@dataclass
class MeshResult:
    """A fused triangle mesh in mm with per-vertex colours and provenance.

    Attributes
    ----------
    vertices : ndarray (N, 3) float64, mm (object frame)
    faces : ndarray (F, 3) int64
    colors : ndarray (N, 4) uint8 RGBA
    vertex_view : ndarray (N,) int, view of the patch each vertex came from
    info : dict, counts, watertightness, colour source
    """

    vertices: np.ndarray
    faces: np.ndarray
    colors: np.ndarray
    vertex_view: np.ndarray
    info: dict = field(default_factory=dict)

    def trimesh(self, scale: float = 1.0):
        """A ``trimesh.Trimesh`` (vertices times ``scale``) with the vertex colours."""
        import trimesh

        return trimesh.Trimesh(self.vertices * scale, self.faces, vertex_colors=self.colors,
                               process=False)


def _patches(model) -> list[dict]:
    """The Gordon surface of each patch, or its skins where a patch has no Gordon surface."""
    by_patch: dict[tuple, dict] = {}
    for s in model.surfaces:
        by_patch.setdefault((s.get("view", 0), s.get("patch", len(by_patch))), {})[s["kind"]] = s
    out = []
    for kinds in by_patch.values():
        if "gordon" in kinds:
            out.append(kinds["gordon"])
        else:
            out += [kinds[k] for k in ("horizontal_skin", "vertical_skin") if k in kinds]
    return out


def _camera_centres(model, rig) -> dict[int, np.ndarray]:
    """Camera centre of every view in the object frame (mm), from the rig and table angles."""
    if rig is None:
        return {}
    c = np.asarray(rig.camera.center, float)
    return {int(v["index"]): rig.turntable.from_rig(c[None], float(v["table_angle"]))[0]
            for v in model.views}


#: Peak memory of :func:`build_mesh` and the mesh writers per tessellated vertex, bytes
#: (measured with ``nurbscan export --patches`` of a 320 x 240 teapot model to glb with colours:
#: peak resident set 287 MB at 102,059 vertices, 716 MB at 404,811, i.e. 1,450 B per vertex;
#: rounded up).
BYTES_PER_VERTEX = 1600
#: Default memory budget of a tessellation, bytes.
MEMORY_BUDGET = 8 << 30


def _spans(surfaces) -> np.ndarray:
    """Non-empty knot spans (u, v) of each surface, shape (S, 2)."""
    return np.array([(len(np.unique(s.knots_u)) - 1, len(np.unique(s.knots_v)) - 1)
                     for s in surfaces], float).reshape(-1, 2)


def tessellation_vertices(surfaces, per_span: int) -> int:
    """Vertices of the grid tessellation (:func:`tessellate`) of all ``surfaces`` at
    ``per_span`` intervals per knot span, before merging: the sum over surfaces of
    ``(per_span * spans_u + 1) * (per_span * spans_v + 1)``."""
    sp = _spans(surfaces)
    return int(np.sum((per_span * sp[:, 0] + 1) * (per_span * sp[:, 1] + 1)))


def memory_estimate(surfaces, per_span: int) -> int:
    """Bytes a tessellation at ``per_span`` would need at its peak (estimate:
    :func:`tessellation_vertices` times :data:`BYTES_PER_VERTEX`)."""
    return tessellation_vertices(surfaces, per_span) * BYTES_PER_VERTEX


def largest_per_span(surfaces, budget: float) -> int:
    """The largest ``per_span`` whose :func:`memory_estimate` stays within ``budget`` bytes
    (0 if not even 1 does)."""
    sp = _spans(surfaces)
    a, b, c = np.sum(sp[:, 0] * sp[:, 1]), np.sum(sp[:, 0] + sp[:, 1]), len(sp)
    # a k^2 + b k + c <= budget / BYTES_PER_VERTEX, largest integer k
    n = budget / BYTES_PER_VERTEX - c
    k = int((-b + np.sqrt(b * b + 4 * a * n)) / (2 * a)) if a > 0 and n >= 0 else 0
    while k > 0 and memory_estimate(surfaces, k) > budget:
        k -= 1
    return k


def check_memory(surfaces, per_span: int, budget: float | None, what: str = "per_span"
                 ) -> None:
    """Refuse (one-line :class:`~nurbscan.errors.NurbscanError`) a tessellation whose
    :func:`memory_estimate` exceeds ``budget`` bytes, before anything is allocated; the
    message gives the estimate and the largest ``per_span`` within the budget. ``what``
    names the setting in the message (the command line's ``--per-span``)."""
    if budget is None:
        return
    need = memory_estimate(surfaces, per_span)
    if need <= budget:
        return
    n = tessellation_vertices(surfaces, per_span)
    raise NurbscanError(
        f"{what} {per_span}: the tessellation of {len(surfaces)} surfaces would have "
        f"{n:.3g} vertices and need about {need / 2**30:.3g} GiB ({BYTES_PER_VERTEX} B per "
        f"vertex), more than the memory budget of {budget / 2**30:.3g} GiB; at most "
        f"{largest_per_span(surfaces, budget)} fits")


def auto_per_span(surfaces, max_vertices: int = 60000) -> int:
    """The largest grid density per knot span (1 to 8) keeping the tessellation of all
    ``surfaces`` within ``max_vertices`` vertices (before merging)."""
    spans = np.array([(len(np.unique(s.knots_u)) - 1, len(np.unique(s.knots_v)) - 1)
                      for s in surfaces], float)
    for k in range(8, 1, -1):
        if np.sum((k * spans[:, 0] + 1) * (k * spans[:, 1] + 1)) <= max_vertices:
            return k
    return 1


def build_mesh(model, rig=None, images: dict | None = None, per_span: int | None = 4,
               merge_tol_mm: float = 1e-6, occlusion: bool = True,
               max_vertices: int = 60000, memory_budget: float | None = MEMORY_BUDGET
               ) -> MeshResult:
    """One fused, coloured triangle mesh of the whole model.

    Parameters
    ----------
    model : nurbscan.reconstruct.Model
        The model (object frame, mm).
    rig : nurbscan.camera.Rig, optional
        The calibrated rig: orients patches towards their camera and projects vertices for the
        colours. Without it patches are oriented away from the centroid and coloured neutral.
    images : dict {view index: ndarray (H, W, 3) float in [0, 1]}, optional
        White-light image of each view (RGB).
    per_span : int or None
        Grid intervals per knot span and direction; None: :func:`auto_per_span` within
        ``max_vertices``.
    merge_tol_mm : float
        Vertices closer than this (mm, per coordinate after rounding) are merged.
    occlusion : bool
        Test visibility of each vertex by ray casting before sampling a view.
    max_vertices : int
        Vertex budget of the automatic density.
    memory_budget : float or None
        Bytes the tessellation may take (:func:`check_memory`, checked before it is built;
        default :data:`MEMORY_BUDGET`); None: no limit.
    """
    import trimesh

    entries = _patches(model)
    if not entries:
        raise NurbscanError("mesh: the model has no surfaces to tessellate")
    if per_span is None:
        per_span = auto_per_span([e["surface"] for e in entries], max_vertices)
    check_memory([e["surface"] for e in entries], per_span, memory_budget)
    centres = _camera_centres(model, rig)
    all_pts = np.concatenate([s["surface"].control_points.reshape(-1, 3) for s in entries])
    centroid = all_pts.mean(0)
    Vs, Fs, views = [], [], []
    off = 0
    for e in entries:
        V, F = tessellate(e["surface"], per_span)
        tri = V[F]
        fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        cen = tri.mean(1)
        view = int(e.get("view", 0))
        target = centres.get(view)
        out_dir = (target[None] - cen) if target is not None else (cen - centroid)
        if np.sum(np.einsum("ij,ij->i", fn, out_dir)) < 0:
            F = F[:, ::-1]
        Vs.append(V)
        Fs.append(F + off)
        views.append(np.full(len(V), view))
        off += len(V)
    V, F, vv = np.concatenate(Vs), np.concatenate(Fs), np.concatenate(views)
    digits = max(0, int(-np.floor(np.log10(merge_tol_mm))))
    key = np.round(V, digits)
    _, first, inv = np.unique(key, axis=0, return_index=True, return_inverse=True)
    inv = inv.ravel()
    V, vv = V[first], vv[first]
    F = inv[F]
    F = F[(F[:, 0] != F[:, 1]) & (F[:, 1] != F[:, 2]) & (F[:, 0] != F[:, 2])]
    tm = trimesh.Trimesh(V, F, process=False)
    colors, source = colour_vertices(tm, model, rig, images, occlusion=occlusion)
    info = {"patches": len(entries), "per_span": int(per_span), "vertices": int(len(V)),
            "faces": int(len(F)),
            "watertight": bool(tm.is_watertight), "colour": source,
            "fusion": f"coincident vertices merged (rounded to {digits} decimals, mm)",
            "units": "mm"}
    return MeshResult(V, F, colors, vv, info)


def _bilinear(img: np.ndarray, px: np.ndarray) -> np.ndarray:
    """Bilinear samples (N, C) of ``img`` (H, W, C) at pixel positions (N, 2) (x, y), pixel
    centres at integer coordinates; positions are clamped to the image."""
    h, w = img.shape[:2]
    x = np.clip(px[:, 0], 0, w - 1)
    y = np.clip(px[:, 1], 0, h - 1)
    x0 = np.minimum(np.floor(x).astype(int), w - 2 if w > 1 else 0)
    y0 = np.minimum(np.floor(y).astype(int), h - 2 if h > 1 else 0)
    x1, y1 = np.minimum(x0 + 1, w - 1), np.minimum(y0 + 1, h - 1)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    im = np.asarray(img, float)
    top = im[y0, x0] * (1 - fx) + im[y0, x1] * fx
    bot = im[y1, x0] * (1 - fx) + im[y1, x1] * fx
    return top * (1 - fy) + bot * fy


def colour_vertices(tm, model, rig=None, images: dict | None = None, occlusion: bool = True):
    """RGBA uint8 vertex colours (N, 4) from the white-light images, and a source note.

    For view k with table angle a: ``X_rig = turntable.to_rig(X, a)``, pixel = Tsai
    projection; weight ``cos^2`` of the angle between the vertex normal and the direction to
    the camera centre, zero if the vertex faces away, falls outside the image or (with
    ``occlusion``) the segment to the camera hits the mesh. Neutral grey without rig/images.
    """
    n = len(tm.vertices)
    rgba = np.empty((n, 4), np.uint8)
    rgba[:, 3] = 255
    if rig is None or not images:
        rgba[:, :3] = NEUTRAL
        return rgba, "neutral (no rig or white images)"
    V = np.asarray(tm.vertices, float)
    N = np.asarray(tm.vertex_normals, float)
    acc = np.zeros((n, 3))
    wsum = np.zeros(n)
    C = np.asarray(rig.camera.center, float)
    angles = {int(v["index"]): float(v["table_angle"]) for v in model.views}
    intersector = None
    if occlusion:
        try:
            intersector = tm.ray
        except Exception:  # pragma: no cover - no ray backend
            intersector = None
    for k, img in images.items():
        if k not in angles:
            continue
        a = angles[k]
        Cobj = rig.turntable.from_rig(C[None], a)[0]
        to_cam = Cobj[None] - V
        dist = np.linalg.norm(to_cam, axis=1)
        d = to_cam / dist[:, None]
        cos = np.einsum("ij,ij->i", N, d)
        px, valid = rig.camera.project(rig.turntable.to_rig(V, a), return_valid=True)
        h, w = img.shape[:2]
        if (w, h) != (rig.camera.width, rig.camera.height):
            raise NurbscanError(f"white image of view {k}: {w} x {h} px, but the camera is "
                                f"{rig.camera.width} x {rig.camera.height}")
        ok = valid & (cos > 0.1) & (px[:, 0] >= 0) & (px[:, 0] <= w - 1) \
            & (px[:, 1] >= 0) & (px[:, 1] <= h - 1)
        idx = np.flatnonzero(ok)
        if intersector is not None and len(idx):
            eps = 1e-3 * float(np.ptp(V, axis=0).max())
            o = V[idx] + d[idx] * eps
            hit = intersector.intersects_any(o, d[idx])
            ok[idx[hit]] = False
            idx = idx[~hit]
        if not len(idx):
            continue
        wk = cos[idx] ** 2
        acc[idx] += wk[:, None] * _bilinear(img, px[idx])
        wsum[idx] += wk
    seen = wsum > 0
    if not seen.any():
        rgba[:, :3] = NEUTRAL
        return rgba, "neutral (no vertex visible in any white image)"
    col = np.empty((n, 3))
    col[seen] = acc[seen] / wsum[seen, None]
    col[~seen] = col[seen].mean(0)
    rgba[:, :3] = np.clip(np.round(col * 255), 0, 255).astype(np.uint8)
    return rgba, f"white-light images of {len(images)} views ({seen.mean():.1%} of vertices seen)"


def _glb_with_extras(data: bytes, extras: dict) -> bytes:
    """Put ``extras`` into ``asset.extras`` of a GLB (binary glTF 2.0) and re-pack it."""
    magic, version, _ = struct.unpack_from("<4sII", data, 0)
    if magic != b"glTF" or version != 2:
        raise NurbscanError("glb: not a glTF 2.0 binary")
    jlen, jtype = struct.unpack_from("<II", data, 12)
    doc = json.loads(data[20:20 + jlen])
    rest = data[20 + jlen:]
    doc.setdefault("asset", {})["extras"] = extras
    doc["asset"]["generator"] = "nurbscan (trimesh)"
    # y up (glTF 2.0 section 3.4): one root node rotating the object frame's z onto y
    nodes = doc.setdefault("nodes", [])
    for scene in doc.get("scenes", []):
        nodes.append({"name": "object_frame_z_up", "rotation": Y_UP,
                      "children": list(scene.get("nodes", []))})
        scene["nodes"] = [len(nodes) - 1]
    # bufferView.target: ARRAY_BUFFER for vertex attributes, ELEMENT_ARRAY_BUFFER for indices
    views = doc.get("bufferViews", [])
    for m in doc.get("meshes", []):
        for prim in m.get("primitives", []):
            for acc in prim.get("attributes", {}).values():
                bv = doc["accessors"][acc].get("bufferView")
                if bv is not None:
                    views[bv]["target"] = 34962
            if "indices" in prim:
                bv = doc["accessors"][prim["indices"]].get("bufferView")
                if bv is not None:
                    views[bv]["target"] = 34963
    j = json.dumps(doc, separators=(",", ":")).encode()
    j += b" " * (-len(j) % 4)
    total = 12 + 8 + len(j) + len(rest)
    return struct.pack("<4sII", b"glTF", 2, total) + struct.pack("<II", len(j), jtype) + j + rest


def mesh_bytes(mesh: MeshResult, fmt: str) -> bytes:
    """Encode a mesh: ``glb`` in metres (with asset extras), ``obj``/``ply``/``stl`` in mm."""
    fmt = fmt.lower()
    if fmt not in MESH_FORMATS:
        raise NurbscanError(f"mesh format {fmt!r}: expected one of {', '.join(MESH_FORMATS)}")
    if fmt == "glb":
        import trimesh
        from trimesh.exchange.gltf import export_glb

        data = export_glb(trimesh.Scene(mesh.trimesh(scale=0.001)), include_normals=True)
        return _glb_with_extras(data, {"units": "m", "scale_from_mm": 0.001,
                                       "generator": "nurbscan", **{
                                           k: v for k, v in mesh.info.items()
                                           if k in ("patches", "method", "faces", "parts",
                                                     "watertight", "colour")}})
    tm = mesh.trimesh()
    if fmt == "obj":
        out = tm.export(file_type="obj", include_color=True, include_normals=True)
        return ("# nurbscan mesh, units: mm\n" + out).encode()
    if fmt == "ply":
        return tm.export(file_type="ply", encoding="binary")
    return tm.export(file_type="stl")


def write_mesh(path: str | os.PathLike, mesh: MeshResult, fmt: str | None = None) -> Path:
    """Write a mesh atomically; the format defaults to the file's extension."""
    path = Path(path)
    fmt = (fmt or path.suffix.lstrip(".")).lower()
    data = mesh_bytes(mesh, fmt)
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return path
