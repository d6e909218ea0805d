"""The model folder: ``model.json`` (index, curves, surfaces), ``points.npz``, ``model.png``,
``fused.ply`` (the fused mesh, when built).

The format is specified in docs/model-format.md. Everything is in the object (turntable)
frame, mm. The folder is written as a whole under a temporary name and renamed into place
(:func:`nurbscan.io.atomic_folder`), under a lock.
"""

from __future__ import annotations

import hashlib
import io
import os
import zipfile
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from ..errors import NurbscanError
from ..io import write_json
from ..io.atomic import atomic_folder, atomic_path, read_json
from ..nurbs import NurbsCurve, NurbsSurface

TYPE = "nurbscan.model"
VERSION = 1
CURVE_KINDS = ("horizontal_line", "vertical_line")
SURFACE_KINDS = ("horizontal_skin", "vertical_skin", "gordon")
FUSED_FILE = "fused.ply"
#: What a model folder may hold: its own files, the overlays of ``nurbscan reconstruct`` and
#: the evaluation ``nurbscan evaluate`` writes beside them. A folder holding anything else is
#: not replaced by :meth:`Model.save`.
MODEL_FILES = frozenset({"model.json", "points.npz", "model.png", FUSED_FILE, "overlays",
                         "evaluation.json", "evaluation.md"})
#: The arrays of ``points.npz``.
POINT_ARRAYS = ("points", "normals", "point_view", "edge_points", "edge_view")
#: Largest ``points.npz`` read, bytes.
MAX_POINTS_BYTES = 4 << 30


@dataclass
class Model:
    """A reconstructed object: curves and surfaces of every view in the object frame.

    Attributes
    ----------
    curves : list of dict
        ``{"kind", "view", "direction", "band", "edge", "coord", "curve": NurbsCurve}``.
    surfaces : list of dict
        ``{"kind", "view", "patch", "vertical": (c0, c1), "horizontal": (c0, c1),
        "n_curves": (I, J), "surface": NurbsSurface}``.
    views : list of dict
        Per view: ``index``, ``table_angle`` (rad), counts and times.
    points, normals : ndarray (N, 3)
        Merged point cloud sampled on the Gordon patches, with unit normals (towards the camera
        of the view the patch comes from), mm.
    point_view : ndarray (N,) int
        View of each point.
    edge_points : ndarray (M, 3)
        Triangulated edge points of the network lines, mm; ``edge_view`` (M,) their views.
    meta : dict
        Anything else (light-surface check, settings, source).
    fused : nurbscan.merge.FusedMesh or None
        The views fused into one coloured triangle mesh (``fused.ply``), if built.
    """

    curves: list = field(default_factory=list)
    surfaces: list = field(default_factory=list)
    views: list = field(default_factory=list)
    points: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    normals: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    point_view: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    edge_points: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    edge_view: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    meta: dict = field(default_factory=dict)
    fused: Any = None

    def surfaces_of(self, kind: str) -> list:
        """Surface entries of one kind."""
        return [s for s in self.surfaces if s["kind"] == kind]

    def curves_of(self, kind: str) -> list:
        """Curve entries of one kind."""
        return [c for c in self.curves if c["kind"] == kind]

    def geometry_digest(self) -> str:
        """sha256 (hex) of the model's geometry, not its times: the points, normals, point
        views, edge points and their views, every surface's and curve's control points, and
        the fused mesh's vertices, faces and colours, in that order (bytes as stored)."""
        h = hashlib.sha256()
        arrays = [self.points, self.normals, self.point_view, self.edge_points, self.edge_view]
        arrays += [s["surface"].control_points for s in self.surfaces]
        arrays += [c["curve"].control_points for c in self.curves]
        if self.fused is not None:
            arrays += [self.fused.vertices, self.fused.faces, self.fused.colors]
        for a in arrays:
            h.update(np.ascontiguousarray(a).tobytes())
        return h.hexdigest()

    # ------------------------------------------------------------------ JSON
    def to_dict(self) -> dict[str, Any]:
        """The ``model.json`` document (without the point arrays)."""
        curves = [{**{k: v for k, v in c.items() if k != "curve"},
                   "curve": c["curve"].to_dict()} for c in self.curves]
        surfaces = [{**{k: (list(v) if isinstance(v, tuple) else v) for k, v in s.items()
                        if k != "surface"}, "surface": s["surface"].to_dict()}
                    for s in self.surfaces]
        counts = {k: len(self.curves_of(k)) for k in CURVE_KINDS}
        counts.update({k: len(self.surfaces_of(k)) for k in SURFACE_KINDS})
        doc = {"type": TYPE, "version": VERSION, "frame": "object", "units": "mm",
               "counts": counts, "views": self.views, "meta": self.meta,
               "points": "points.npz", "picture": "model.png",
               "curves": curves, "surfaces": surfaces}
        if self.fused is not None:
            doc["fused"] = {"file": FUSED_FILE, **self.fused.info}
        return doc

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], source: str = "model") -> Model:
        """Inverse of :meth:`to_dict` (the point arrays are left empty)."""
        if not isinstance(d, Mapping) or d.get("type") != TYPE:
            raise NurbscanError(f"{source}: not a nurbscan model (type {TYPE!r})")
        for key, kind in (("curves", list), ("surfaces", list), ("views", list),
                          ("meta", Mapping)):
            if key not in d and key in ("views", "meta"):
                continue
            v = d.get(key)
            if not isinstance(v, kind) or (kind is list
                                           and not all(isinstance(e, Mapping) for e in v)):
                raise NurbscanError(f"{source}: {key}: expected "
                                    f"{'a list of objects' if kind is list else 'an object'}, "
                                    f"got {type(v).__name__}")
        try:
            curves = [{**c, "curve": NurbsCurve.from_dict(c["curve"])} for c in d["curves"]]
            surfaces = [{**s, "surface": NurbsSurface.from_dict(s["surface"])}
                        for s in d["surfaces"]]
        except (KeyError, TypeError, ValueError, AttributeError, IndexError) as exc:
            raise NurbscanError(f"{source}: malformed model ({type(exc).__name__}: "
                                f"{str(exc).splitlines()[0] if str(exc) else ''})") from None
        except NurbscanError as exc:
            raise NurbscanError(f"{source}: malformed model ({exc})") from None
        for c in curves:
            if c.get("kind") not in CURVE_KINDS:
                raise NurbscanError(f"{source}: unknown curve kind {c.get('kind')!r}")
        for s in surfaces:
            if s.get("kind") not in SURFACE_KINDS:
                raise NurbscanError(f"{source}: unknown surface kind {s.get('kind')!r}")
        m = cls(curves=curves, surfaces=surfaces, views=list(d.get("views", [])),
                meta=dict(d.get("meta", {})))
        if "counts" in d:  # written by to_dict from the content: a mismatch is damage
            counts = {k: len(m.curves_of(k)) for k in CURVE_KINDS}
            counts.update({k: len(m.surfaces_of(k)) for k in SURFACE_KINDS})
            if not isinstance(d["counts"], Mapping) or any(
                    d["counts"].get(k, v) != v for k, v in counts.items()):
                raise NurbscanError(f"{source}: counts {d['counts']!r} do not match the curves "
                                    "and surfaces it holds")
        if isinstance(d.get("fused"), Mapping):
            m.meta["_fused"] = dict(d["fused"])
        return m

    # ------------------------------------------------------------------ folder
    def save(self, folder: str | os.PathLike) -> Path:
        """Write the model folder ``folder`` as a whole (:func:`nurbscan.io.atomic_folder`):
        ``model.json``, ``points.npz``, ``model.png`` and (with a fused mesh) ``fused.ply``.

        The folder is written under a temporary name and renamed into place, an existing model
        folder replaced in one step; a second writer of the same folder is refused. Returns
        the path of ``model.json``.
        """
        with atomic_folder(folder, MODEL_FILES) as tmp:
            self.write_files(tmp)
        return Path(folder) / "model.json"

    def write_files(self, folder: str | os.PathLike) -> Path:
        """Write the model's files into an existing folder (the temporary folder of
        :meth:`save`; ``model.json`` last, with the SHA-256 of ``points.npz``, which
        :func:`load_model` checks)."""
        folder = Path(folder)
        buf = io.BytesIO()
        np.savez_compressed(buf, points=self.points, normals=self.normals,
                            point_view=self.point_view, edge_points=self.edge_points,
                            edge_view=self.edge_view)
        data = buf.getvalue()
        with atomic_path(folder / "points.npz") as tmp:
            tmp.write_bytes(data)
        img = render_picture(self.points, self.normals)
        ok, png = cv2.imencode(".png", img)
        if ok:
            with atomic_path(folder / "model.png") as tmp:
                tmp.write_bytes(png.tobytes())
        if self.fused is not None:
            from ..merge.fusion import write_fused

            write_fused(folder, self.fused)
        doc = self.to_dict()
        doc["checksums"] = {"points.npz": "sha256:" + hashlib.sha256(data).hexdigest()}
        return write_json(folder / "model.json", doc, indent=None)


def load_model(folder: str | os.PathLike) -> Model:
    """Read a model folder (``model.json`` and, if present, ``points.npz``).

    ``points.npz`` must match the checksum ``model.json`` records for it (a model folder
    assembled from two runs is refused), and hold the five arrays with consistent shapes;
    anything else is a one-line :class:`~nurbscan.errors.NurbscanError`.
    """
    folder = Path(folder)
    path = folder / "model.json" if folder.is_dir() else folder
    if not path.exists():
        raise NurbscanError(f"{path}: model not found (expected a folder with model.json)")
    doc = read_json(path)
    m = Model.from_dict(doc, source=str(path))
    pts = path.parent / "points.npz"
    sums = doc.get("checksums", {})
    if not isinstance(sums, Mapping):
        raise NurbscanError(f"{path}: checksums: expected an object")
    want = sums.get("points.npz")
    if want is not None and not pts.is_file():
        raise NurbscanError(f"{pts}: missing (model.json lists it)")
    if pts.exists():
        _read_points(m, pts, want)
    summary = m.meta.pop("_fused", None)
    if summary is not None and (path.parent / summary.get("file", FUSED_FILE)).is_file():
        from ..merge.fusion import read_fused

        m.fused = read_fused(path.parent / summary.get("file", FUSED_FILE), summary)
    return m


def _read_points(m: Model, pts: Path, checksum: str | None) -> None:
    """Fill ``m``'s point arrays from ``points.npz``, checked (see :func:`load_model`)."""
    from ..io.atomic import read_bytes

    data = read_bytes(pts, MAX_POINTS_BYTES)
    if checksum is not None and checksum != "sha256:" + hashlib.sha256(data).hexdigest():
        raise NurbscanError(f"{pts}: does not match model.json (its checksum differs: the "
                            "folder mixes files of two runs); reconstruct again")
    try:
        with np.load(io.BytesIO(data), allow_pickle=False) as z:
            arrays = {k: np.asarray(z[k]) for k in POINT_ARRAYS}
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as exc:
        raise NurbscanError(f"{pts}: not a model's points.npz ({exc})") from None
    n, e = len(arrays["points"]), len(arrays["edge_points"])
    ok = (all(arrays[k].ndim == 2 and arrays[k].shape[1:] == (3,)
              and arrays[k].dtype.kind == "f" for k in ("points", "normals", "edge_points"))
          and arrays["normals"].shape[0] == n
          and all(arrays[k].ndim == 1 and arrays[k].dtype.kind in "iu"
                  for k in ("point_view", "edge_view"))
          and arrays["point_view"].shape[0] == n and arrays["edge_view"].shape[0] == e)
    if not ok:
        raise NurbscanError(f"{pts}: arrays of the wrong shape or type "
                            f"({', '.join(f'{k} {a.dtype}{a.shape}' for k, a in arrays.items())})")
    m.points, m.normals = arrays["points"], arrays["normals"]
    m.point_view = arrays["point_view"]
    m.edge_points, m.edge_view = arrays["edge_points"], arrays["edge_view"]


def render_picture(points: np.ndarray, normals: np.ndarray, size: int = 480) -> np.ndarray:
    """Three orthographic, Lambert-shaded views (front, side, top) of a point cloud, BGR uint8.

    Each point is splatted as a 3 x 3 px square; a z-buffer is emulated by drawing in order of
    decreasing depth (the nearest point is drawn last).
    """
    out = np.full((size, 3 * size, 3), 255, np.uint8)
    if len(points) == 0:
        return out
    P = np.asarray(points, float)
    N = np.asarray(normals, float)
    lo, hi = P.min(0), P.max(0)
    c = 0.5 * (lo + hi)
    scale = 0.9 * size / max(float(np.max(hi - lo)), 1e-9)
    # (right, up, towards the viewer) axes of each view in the object frame (z up)
    views = [(np.array([0, 1, 0.]), np.array([0, 0, 1.]), np.array([1, 0, 0.])),
             (np.array([-1, 0, 0.]), np.array([0, 0, 1.]), np.array([0, 1, 0.])),
             (np.array([0, 1, 0.]), np.array([-1, 0, 0.]), np.array([0, 0, 1.]))]
    light = np.array([0.3, 0.3, 1.0])
    for k, (r, u, t) in enumerate(views):
        Q = P - c
        x = (Q @ r) * scale + size / 2
        y = -(Q @ u) * scale + size / 2
        z = Q @ t
        lv = 0.6 * t + 0.4 * (light[0] * r + light[1] * u)
        lv /= np.linalg.norm(lv)
        shade = np.abs(N @ lv)
        order = np.argsort(z)
        xi = np.clip(np.round(x[order]).astype(int), 1, size - 2)
        yi = np.clip(np.round(y[order]).astype(int), 1, size - 2)
        g = (40 + 215 * shade[order]).astype(np.uint8)
        col = np.stack([g, g, (g * 0.9).astype(np.uint8)], 1)
        panel = out[:, k * size:(k + 1) * size]
        for dy in (-1, 0, 1):
            for dx in (-1, 0, 1):
                panel[yi + dy, xi + dx] = col
    return out
