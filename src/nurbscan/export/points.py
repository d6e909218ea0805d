"""The merged point cloud (``points.npz``) as a PLY file with normals and colours (issue #35).

The points are the model's samples of its Gordon patches in the object frame, mm, with unit
normals (docs/model-format.md). Each point is coloured from the white-light image of the view
it comes from: ``X_rig = turntable.to_rig(X, table_angle)``, its Tsai projection
(:meth:`nurbscan.camera.Camera.project`), bilinear sample. Points outside that image, or all
points when the rig or the white images cannot be found, are neutral grey.

The file is binary little-endian PLY 1.0 with one ``vertex`` element of the properties
``x y z nx ny nz`` (float32, mm) and ``red green blue`` (uchar), the layout Open3D
(``read_point_cloud``), MeshLab, CloudCompare and trimesh read.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..errors import NurbscanError
from ..io.atomic import atomic_path
from .mesh import NEUTRAL, _bilinear

__all__ = ["point_colours", "ply_points_bytes", "write_points"]


def point_colours(model, rig=None, images: dict | None = None) -> tuple[np.ndarray, str]:
    """RGB uint8 colours (N, 3) of the model's points from their own view's white image.

    Parameters
    ----------
    model : Model
        With ``points`` (N, 3) mm, object frame, ``point_view`` (N,) and ``views``.
    rig : Rig, optional
    images : dict, optional
        ``{view index: white image (H, W, 3) float RGB in [0, 1]}``.

    Returns
    -------
    colours : ndarray, shape (N, 3), uint8
    source : str
        What the colours come from.
    """
    P = np.asarray(model.points, float).reshape(-1, 3)
    out = np.tile(NEUTRAL, (len(P), 1))
    if rig is None or not images or not len(P):
        return out, "neutral (no rig or white images)"
    view = np.asarray(model.point_view, int).reshape(-1)
    angles = {int(v["index"]): float(v["table_angle"]) for v in model.views}
    seen = np.zeros(len(P), bool)
    for k, img in images.items():
        idx = np.flatnonzero(view == k)
        if k not in angles or not len(idx):
            continue
        h, w = img.shape[:2]
        if (w, h) != (rig.camera.width, rig.camera.height):
            raise NurbscanError(f"white image of view {k}: {w} x {h} px, but the camera is "
                                f"{rig.camera.width} x {rig.camera.height}")
        px, ok = rig.camera.project(rig.turntable.to_rig(P[idx], angles[k]), return_valid=True)
        ok &= (px[:, 0] >= 0) & (px[:, 0] <= w - 1) & (px[:, 1] >= 0) & (px[:, 1] <= h - 1)
        idx, px = idx[ok], px[ok]
        rgb = _bilinear(img, px)[:, :3]
        out[idx] = np.clip(np.round(rgb * 255.0), 0, 255).astype(np.uint8)
        seen[idx] = True
    return out, f"white-light images ({seen.mean():.1%} of points seen)"


def ply_points_bytes(points, normals, colours) -> bytes:
    """Binary little-endian PLY of points (N, 3), unit normals (N, 3) and RGB uint8 (N, 3)."""
    P = np.asarray(points, float).reshape(-1, 3)
    N = np.asarray(normals, float).reshape(-1, 3)
    C = np.asarray(colours, np.uint8).reshape(-1, 3)
    if not (len(P) == len(N) == len(C)):
        raise NurbscanError(f"point cloud: {len(P)} points, {len(N)} normals, {len(C)} colours")
    dt = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("nx", "<f4"), ("ny", "<f4"),
                   ("nz", "<f4"), ("red", "u1"), ("green", "u1"), ("blue", "u1")])
    v = np.empty(len(P), dt)
    for i, key in enumerate(("x", "y", "z")):
        v[key] = P[:, i]
        v["n" + key] = N[:, i]
    for i, key in enumerate(("red", "green", "blue")):
        v[key] = C[:, i]
    head = ("ply\nformat binary_little_endian 1.0\ncomment nurbscan point cloud, units: mm, "
            f"object frame\nelement vertex {len(P)}\n"
            + "".join(f"property float {k}\n" for k in ("x", "y", "z", "nx", "ny", "nz"))
            + "".join(f"property uchar {k}\n" for k in ("red", "green", "blue"))
            + "end_header\n")
    return head.encode("ascii") + v.tobytes()


def write_points(model, path: str | os.PathLike, rig=None, images: dict | None = None) -> Path:
    """Write the model's point cloud as PLY (points, normals, colours), atomically."""
    if not len(model.points):
        where = model.meta.get("_folder", "model") if isinstance(model.meta, dict) else "model"
        raise NurbscanError(f"{where}: no points to export (points.npz missing or empty)")
    colours, _ = point_colours(model, rig, images)
    data = ply_points_bytes(model.points, model.normals, colours)
    path = Path(path)
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return path
