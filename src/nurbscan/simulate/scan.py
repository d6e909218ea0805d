"""Writing a synthetic scan folder (the layout is specified in docs/scan-format.md).

``simulate_scan`` renders every view of a scene on the turntable under the grid and under white
light, the calibration target in free poses and on the turntable, and writes the images, the
pattern, ``scan.json`` and the exact ground truth (``truth/``), each file atomically.
"""

from __future__ import annotations

import io
import math
import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import NurbscanError
from ..io import write_image, write_json
from ..io.atomic import atomic_path
from .render import RenderedView, RenderSettings, render_view
from .rig import default_rig
from .target import (
    TABLE_POSE_ANGLES,
    BoardScene,
    Chessboard,
    free_board_poses,
    table_board_pose,
)

TYPE = "nurbscan.scan"
VERSION = 1


def default_pattern(projector) -> Any:
    """The default grid for a projector: :meth:`Pattern.create` at the projector's size."""
    from ..pattern import Pattern

    return Pattern.create(width=int(projector.width), height=int(projector.height))


def write_truth(path: str | os.PathLike, view: RenderedView, angle: float) -> Path:
    """Write a view's truth arrays to an ``.npz`` atomically (see docs/scan-format.md)."""
    t = view.truth
    arrays = {
        "depth": t["depth"].astype(np.float64),
        "point_rig": t["point_rig"].astype(np.float64),
        "point_obj": t["point_obj"].astype(np.float64),
        "surface_id": t["surface_id"].astype(np.int32),
        "proj_x": t["proj_x"].astype(np.float64),
        "proj_y": t["proj_y"].astype(np.float64),
        "lit": t["lit"].astype(np.uint8),
        "table_angle": np.float64(angle),
    }
    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)
    with atomic_path(path) as tmp:
        tmp.write_bytes(buf.getvalue())
    return Path(path)


def _pose_dict(r: np.ndarray, t: np.ndarray) -> dict[str, Any]:
    return {"R": np.asarray(r, float).tolist(), "T": np.asarray(t, float).tolist()}


def simulate_scan(scene, out_dir: str | os.PathLike, views: int = 8, rig=None,
                  settings: RenderSettings | None = None, seed: int = 0,
                  progress: Callable[[str], None] | None = None, pattern=None,
                  board: Chessboard | None = None, calibration: bool = True) -> Path:
    """Render a complete synthetic scan of ``scene`` into ``out_dir``.

    Parameters
    ----------
    scene : nurbscan.simulate.scenes.Scene
        The object, in the object (table) frame.
    out_dir : path-like
        The scan folder (created; existing files of the same names are replaced).
    views : int
        Number of views, at table angles 2 pi k / views, k = 0 .. views - 1 (radians).
    rig : nurbscan.camera.Rig, optional
        Default :func:`~nurbscan.simulate.rig.default_rig`.
    settings : RenderSettings, optional
    seed : int
        Noise seed; the same seed gives the same images bit for bit.
    progress : callable, optional
        Called with one line per rendered image (with the elapsed time).
    pattern : nurbscan.pattern.Pattern, optional
        Default :func:`default_pattern` for the rig's projector.
    board : Chessboard, optional
        The calibration target (default 9 x 7 inner corners, 20 mm squares).
    calibration : bool
        Render the calibration images (default true).

    Returns
    -------
    Path of ``scan.json``.
    """
    if not isinstance(views, int | np.integer) or views < 1:
        raise NurbscanError(f"views={views!r}: must be an integer >= 1")
    rig = rig or default_rig()
    s = settings or RenderSettings()
    pattern = pattern or default_pattern(rig.projector)
    board = board or Chessboard()
    out = Path(out_dir)
    ext = ".png"
    t0 = time.perf_counter()

    def say(msg: str) -> None:
        if progress is not None:
            progress(f"[{time.perf_counter() - t0:7.1f} s] {msg}")

    pattern.save(out / "pattern.png")
    rig.save(out / "truth" / "rig.json")
    if hasattr(scene, "to_dict"):
        write_json(out / "truth" / "scene.json", scene.to_dict())
    write_json(out / "truth" / "render.json", {**s.to_dict(), "seed": int(seed)})
    cam = rig.camera
    view_list = []
    for k in range(int(views)):
        angle = 2.0 * math.pi * k / views
        r = render_view(scene, rig, pattern, angle, s, seed=seed, stream=k)
        g = f"views/view_{k:02d}_grid{ext}"
        w = f"views/view_{k:02d}_white{ext}"
        head = f"view {k + 1}/{views} (table {math.degrees(angle):.1f} deg)"
        write_image(out / g, r.grid)
        say(f"{head}: {g}")
        write_image(out / w, r.white)
        say(f"{head}: {w}")
        tr = f"truth/view_{k:02d}.npz"
        write_truth(out / tr, r, angle)
        view_list.append({"index": k, "table_angle": angle, "grid": g, "white": w})
    poses = []
    pose_truth = []
    if calibration:
        aim = np.array([0.0, 0.0, float(np.asarray(rig.turntable.to_rig(
            np.zeros((1, 3)), 0.0))[0, 2])])
        free = free_board_poses(board, aim)
        m0, t00 = _transform(rig.turntable, 0.0)
        jobs = []
        for r_b, t_b in free:  # board -> rig; the renderer wants board -> object at angle 0
            jobs.append(("free", 0.0, m0.T @ r_b, m0.T @ (t_b - t00)))
        r_t, t_t = table_board_pose(board)
        for a in TABLE_POSE_ANGLES:
            jobs.append(("turntable", math.radians(a), r_t, t_t))
        for i, (kind, angle, r_o, t_o) in enumerate(jobs):
            bs = BoardScene(board, r_o, t_o)
            ss = s if kind == "turntable" else s.replace(table=False)
            r = render_view(bs, rig, pattern, angle, ss, seed=seed, stream=1000 + i,
                            albedo=bs.albedo)
            g = f"calibration/pose_{i:02d}_grid{ext}"
            w = f"calibration/pose_{i:02d}_white{ext}"
            head = f"calibration pose {i + 1}/{len(jobs)} ({kind}" + (
                f", table {math.degrees(angle):.0f} deg)" if kind == "turntable" else ")")
            write_image(out / g, r.grid)
            say(f"{head}: {g}")
            write_image(out / w, r.white)
            say(f"{head}: {w}")
            entry = {"index": i, "kind": kind, "white": w, "grid": g}
            if kind == "turntable":
                entry["table_angle"] = angle
            poses.append(entry)
            m, t = _transform(rig.turntable, angle)
            pose_truth.append({"index": i, "kind": kind, "table_angle": angle,
                               "board_to_rig": _pose_dict(m @ r_o, m @ t_o + t),
                               "board_to_object": _pose_dict(r_o, t_o)})
        write_json(out / "truth" / "calibration.json",
                   {"type": "nurbscan.calibration_truth", "version": 1,
                    "target": board.to_dict(), "poses": pose_truth})
    doc = {
        "type": TYPE,
        "version": VERSION,
        "image_size": [int(cam.width), int(cam.height)],
        "bit_depth": int(s.bit_depth),
        "pattern": {"image": "pattern.png", "sidecar": "pattern.json"},
        "angle_unit": "radians",
        "views": view_list,
        "calibration": {"target": board.to_dict(), "poses": poses},
        "source": {"kind": "synthetic", "generator": "nurbscan simulate",
                   "scene": getattr(scene, "name", type(scene).__name__), "seed": int(seed)},
    }
    path = write_json(out / "scan.json", doc)
    say(f"wrote {path}")
    return path


def _transform(turntable, angle: float) -> tuple[np.ndarray, np.ndarray]:
    from .render import _object_transform

    return _object_transform(turntable, angle)
