"""Whole-object reconstruction of a scan folder (method.md sections 5 and 6).

:func:`reconstruct_scan` reads ``scan.json``, the pattern and each view's grid and white
photographs (never ``truth/``), detects and decodes the grid (:func:`nurbscan.detect.detect_grid`),
reconstructs each view in the rig frame (:func:`nurbscan.reconstruct.view.reconstruct_view`),
moves it into the object frame with the calibrated turntable and the view's table angle,
collects everything into one :class:`~nurbscan.reconstruct.model.Model` and merges the views
(:func:`nurbscan.merge.merge_views`: the table left out, the views registered).
"""

from __future__ import annotations

import functools
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .._parallel import process_map
from ..detect.options import DetectOptions
from ..errors import NurbscanError
from ..io import chroma_subsampled, load_scan, read_image
from ..merge import DEFAULT_MERGE, MergeOptions, merge_views
from ..merge.frame import curve_to_object, rig_to_object, surface_to_object
from ..pattern import LinePattern
from .light import compare_light_surfaces, other_coordinate
from .model import Model
from .sanity import check_model, check_rig
from .view import ViewResult, reconstruct_view


def _patch_samples(surface, per_span: int = 4):
    """Grid samples and unit normals of a surface, ``per_span`` per knot span each way."""
    (u0, u1), (v0, v1) = surface.domain
    nu = max(2, per_span * (len(np.unique(surface.knots_u)) - 1) + 1)
    nv = max(2, per_span * (len(np.unique(surface.knots_v)) - 1) + 1)
    uu, vv = np.meshgrid(np.linspace(u0, u1, nu), np.linspace(v0, v1, nv), indexing="ij")
    X = surface.evaluate(uu.ravel(), vv.ravel())
    N = surface.normal(uu.ravel(), vv.ravel())
    return X, N


class RigFrame:
    """The rig frame as the model's frame (a turntable that does not turn): a single view
    reconstructed with a rig whose turntable is not calibrated stays where the camera saw it."""

    def to_rig(self, points, angle: float = 0.0) -> np.ndarray:
        return np.asarray(points, float)

    def from_rig(self, points, angle: float = 0.0) -> np.ndarray:
        return np.asarray(points, float)


def add_view(model: Model, res: ViewResult, rig, index: int, angle: float,
             extra: dict | None = None, frame=None) -> None:
    """Move one view's curves, surfaces and points into the object frame and add them
    (``frame``: a :class:`RigFrame` keeps them in the rig frame)."""
    tt = rig.turntable if frame is None else frame
    for direction, ln, c in res.line_curves():
        model.curves.append({"kind": f"{direction}_line", "view": index, "direction": direction,
                             "band": int(ln.band), "edge": int(ln.edge),
                             "coord": float(ln.coord),
                             "curve": curve_to_object(c, tt, angle)})
    cam_centre = -np.asarray(rig.camera.R, float).T @ np.asarray(rig.camera.T, float)
    pts, nrm = [], []
    for k, p in enumerate(res.patches):
        base = {"view": index, "patch": k, "vertical": list(p.vertical),
                "horizontal": list(p.horizontal), "n_curves": list(p.n_curves),
                "vertical_curves": list(p.vertical_curves),
                "horizontal_curves": list(p.horizontal_curves)}
        for kind in ("horizontal_skin", "vertical_skin", "gordon"):
            model.surfaces.append({"kind": kind, **base,
                                   "surface": surface_to_object(getattr(p, kind), tt, angle)})
        X, N = _patch_samples(p.gordon)
        ok = np.isfinite(N).all(1)
        X, N = X[ok], N[ok]
        N = np.where(((cam_centre - X) * N).sum(1, keepdims=True) < 0, -N, N)
        pts.append(X)
        nrm.append(N)
    if pts:
        M = rig_to_object(np.zeros(3), tt, angle)
        P = rig_to_object(np.concatenate(pts), tt, angle)
        Nn = rig_to_object(np.concatenate(nrm), tt, angle) - M
        model.points = np.concatenate([model.points, P])
        model.normals = np.concatenate([model.normals, Nn])
        model.point_view = np.concatenate([model.point_view, np.full(len(P), index)])
    E = rig_to_object(res.edge_points, tt, angle)
    model.edge_points = np.concatenate([model.edge_points, E])
    model.edge_view = np.concatenate([model.edge_view, np.full(len(E), index)])
    model.views.append({
        "index": index, "table_angle": float(angle),
        "lines": len(res.lines), "network_lines": [len(res.vlines), len(res.hlines)],
        "complete_cells": res.cells[0], "cells": res.cells[1], "patches": len(res.patches),
        "rms2d_px": float(np.median([ln.rms2d for ln in res.lines])) if res.lines else None,
        "crossing_tol_mm": round(res.crossing_tol, 4),
        **{k: round(v, 3) for k, v in res.times.items()}, **(extra or {})})


def light_surface_check(res: ViewResult, rig, n_edges: int = 12, n_points: int = 40) -> dict:
    """How far the paper's conic light surface lies from the exact one, on a view's lines.

    Uses up to ``n_edges`` lines per direction and ``n_points`` pixels of each (their fitted 2-D
    curves). Returns mm at the object and projector px, per direction
    (:func:`nurbscan.reconstruct.light.compare_light_surfaces`).
    """
    out = {}
    for direction in ("vertical", "horizontal"):
        ls = [ln for ln in res.lines if ln.direction == direction]
        if not ls:
            continue
        pick = [ls[i] for i in np.linspace(0, len(ls) - 1, min(n_edges, len(ls))).astype(int)]
        px = [ln.curve2d.evaluate(np.linspace(*ln.curve2d.domain, n_points)) for ln in pick]
        out[direction] = compare_light_surfaces(rig.projector, rig.camera, direction,
                                                [ln.coord for ln in pick], px)
    return out


def _write_overlay(path: Path, image: np.ndarray, det, pattern, width: int = 1536) -> None:
    """The detected-line picture of a view (:func:`nurbscan.detect.draw_overlay`), reduced to
    ``width`` px (area averaging)."""
    import cv2

    from ..detect import draw_line_overlay, draw_overlay
    from ..io import write_image
    from ..pattern import LinePattern

    draw = draw_line_overlay if isinstance(pattern, LinePattern) else draw_overlay
    rgb = draw(image, det, pattern)
    if rgb.shape[1] > width:
        h = round(rgb.shape[0] * width / rgb.shape[1])
        rgb = cv2.resize(rgb, (width, h), interpolation=cv2.INTER_AREA)
    write_image(path, rgb)


#: :func:`~nurbscan.detect.detect_grid` options for reconstruction with a calibrated rig (which
#: :func:`run_view` passes as ``epipolar``, :func:`~nurbscan.reconstruct.light.other_coordinate`).
#:
#: Decode with the rig's epipolar constraint too (``epipolar``), and keep the lines and
#: points that only the row-support filters would drop (``min_row_support=0``,
#: ``max_row_residual=0``, ``keep_unsupported=True``). Those filters guard the point
#: accuracy of a plain detection; here the network's 3-D crossing test
#: (:func:`~nurbscan.reconstruct.network.complete_cells`) guards the surfaces. Teapot scan
#: (7.1 MP, 8 views, rig calibrated from the images): Gordon coverage 61.1 -> 65.7 %,
#: Gordon mean 0.0043 -> 0.0047 mm, max 0.018 -> 0.019 mm; the raw triangulated edge
#: points more than 0.5 mm off the surface 0.05 -> 0.16 %; the detection itself (views
#: 0-7): coverage 0.706 -> 0.748, RMS 0.057 -> 0.092 px, 1 -> 10 wrong lines over 20 px,
#: none of which reaches a surface.
#:
#: The point filters that drop single points near the band corners and off the straight
#: line through their neighbours are off as well (``max_residual``, ``refit_residual``,
#: ``end_residual`` 0, ``partner_drops`` "none", ``min_width`` 0, ``min_strength`` 0.06),
#: and so is the one that drops lines without two points paired across a band
#: (``min_paired`` 0): the 3-D curve fits remove outliers themselves. With the looser
#: crossing test and the tangent reach of the network
#: (:func:`~nurbscan.reconstruct.view.reconstruct_view`), teapot scan: Gordon coverage
#: 72.5 -> 74.5 % (point filters; 83.4 -> 84.2 % for ``min_paired`` once the crossing test
#: allowed for obliquity), Gordon mean 0.0061 -> 0.0065 mm; detection, views 0-1:
#: coverage 0.743 -> 0.799 -> 0.805, RMS 0.10 -> 0.13 -> 0.16 px.
#:
#: The edge filter is narrower than a plain detection's (band / 10 instead of band / 8,
#: 1.0 px instead of 1.28 px on the teapot demo scan): it resolves more of the squeezed
#: bands at the bottom and on the lid, and the point noise it adds is averaged by the 3-D
#: curve fits. Gordon coverage 84.2 -> 86.2 % (fixed 0.9 px: 86.0 %, 1.1 px: 85.9 %),
#: Gordon mean 0.0089 -> 0.0084 mm.
#:
#: The labels from the family's own coordinate map (``fit_rounds``) are off: with the rig
#: the epipolar prediction labels those pieces, and both together gave teapot demo scan
#: Gordon coverage 90.09 -> 90.01 %, Gordon mean 0.0128 -> 0.0130 mm. So are the corner
#: points (``corner_dominance``): without the point filters they reach the curve fits
#: unchecked (Gordon coverage 90.09 -> 89.86 %). And so is the smoothing along the chains
#: (``smooth_reach``): it would spread the outliers that the point filters leave here over
#: their neighbours, where the 3-D fits no longer see them as outliers (Gordon mean 0.0128 ->
#: 0.0134 mm, lines 0.0083 / 0.0038 -> 0.0089 / 0.0042 mm, 974 -> 961 patches).
#:
#: The short lines that no consistent intersection confirms are kept
#: (``min_checked_length`` 0): the network's crossing test screens them, and dropping them
#: (12) cost Gordon coverage 90.24 -> 89.96 % (Gordon mean 0.0122 -> 0.0117 mm).
DETECT_OPTIONS = DetectOptions().replace(
    min_row_support=0.0, max_row_residual=0.0, keep_unsupported=True, max_residual=0.0,
    refit_residual=0.0, end_residual=0.0, partner_drops="none", min_width=0.0,
    min_strength=0.06, min_paired=0, sigma_per_band=10.0, fit_rounds=0, corner_dominance=1.0,
    smooth_reach=0, min_checked_length=0.0)


def reconstruct_detection(grid, pattern, white, rig, chroma: bool = False,
                          timings: dict | None = None):
    """:func:`~nurbscan.detect.detect_grid` as reconstruction runs it: :data:`DETECT_OPTIONS`
    and the rig's epipolar constraint (``chroma``: the grid image is a chroma-subsampled
    JPEG; ``timings`` gets the detection's stage times)."""
    from ..detect import detect_grid

    options = DETECT_OPTIONS.replace(chroma_subsampled=chroma) if chroma else DETECT_OPTIONS
    return detect_grid(grid, pattern, white, options,
                       epipolar=functools.partial(other_coordinate, rig), timings=timings)


@dataclass(frozen=True)
class ViewTask:
    """One view's task: which images to read and how to reconstruct them.

    Holds the images' paths, not the images: the process that runs the task reads them (shared
    storage), so the task is small to send to a worker (a spawned process or a Dask worker).

    Attributes
    ----------
    n : int
        Position of the view in ``scan.json``'s ``views``.
    index : int
        The view's index (``views[n].index``).
    angle : float
        Table angle, rad.
    grid, white : Path
        The grid and white-light photographs (``white`` may be None).
    rig : Rig
        The calibrated rig.
    pattern : Pattern or LinePattern
        The projected pattern.
    kwargs : dict
        Passed to :func:`~nurbscan.reconstruct.view.reconstruct_view`.
    overlay : Path or None
        Where to write the view's detected-line picture.
    """

    n: int
    index: int
    angle: float
    grid: Path
    white: Path | None
    rig: Any
    pattern: Any
    kwargs: dict = field(default_factory=dict)
    overlay: Path | None = None


@dataclass(frozen=True)
class ViewOutput:
    """What the view task returns: the view's reconstruction, its line count and times (s)."""

    result: ViewResult
    nlines: int
    times: dict


@dataclass(frozen=True)
class ScanPlan:
    """A scan folder read and checked, split into its view tasks (:func:`plan_scan`).

    Attributes
    ----------
    scan : Path
        The scan folder.
    rig : Rig
        The calibrated rig.
    tasks : tuple of ViewTask
        The views to reconstruct, in ``scan.json``'s order.
    total : int
        Views in ``scan.json`` (``tasks`` may hold fewer).
    meta : dict
        The model's first ``meta`` entries (source, pattern summary, frame).
    rig_frame : bool
        The views stay in the rig frame (a rig whose turntable is not calibrated).
    """

    scan: Path
    rig: Any
    tasks: tuple[ViewTask, ...]
    total: int
    meta: dict
    rig_frame: bool = False


def plan_scan(scan_dir: str | os.PathLike, rig, *, views: list[int] | None = None,
              overlays: str | os.PathLike | None = None, turntable_calibrated: bool = True,
              allow_outside: bool = False, **view_kwargs) -> ScanPlan:
    """Read and check a scan folder's ``scan.json`` and pattern; one task per view.

    Reads ``scan.json`` (:func:`nurbscan.io.load_scan`) and the pattern sidecar only (never
    ``truth/``, nor the images). Raises :class:`NurbscanError` for a rig that could only give
    an empty model (:func:`~nurbscan.reconstruct.sanity.check_rig`), a folder that is not a
    scan, paths that leave it (unless ``allow_outside``), a pattern that cannot be read,
    images of another size than the rig's camera, or several views with a rig whose turntable
    is not calibrated. Parameters as :func:`reconstruct_scan`.
    """
    from ..pattern import load_pattern

    check_rig(rig)  # a zero baseline or a folding lens could only give an empty model
    scan = load_scan(scan_dir, allow_outside=allow_outside)  # paths inside the folder
    pattern = load_pattern(scan.pattern_sidecar)
    size = scan.image_size
    if size != (int(rig.camera.width), int(rig.camera.height)):
        raise NurbscanError(f"{scan.folder / 'scan.json'}: images {size[0]} x {size[1]} do not "
                            f"match the calibration's camera {rig.camera.width} x "
                            f"{rig.camera.height}")
    meta = {"source": str(scan_dir), "pattern": pattern.summary()
            if hasattr(pattern, "summary") else None}
    tasks = []
    for n, v in enumerate(scan.views):
        if views is not None and v.index not in views:
            continue
        tasks.append(ViewTask(
            n=n, index=v.index, angle=v.table_angle, grid=v.grid, white=v.white, rig=rig,
            pattern=pattern, kwargs=dict(view_kwargs),
            overlay=None if overlays is None
            else Path(overlays) / f"view_{v.index:02d}_overlay.png"))
    if not turntable_calibrated:
        if len(tasks) > 1:
            from ..calibrate import TURNTABLE_NOT_CALIBRATED

            raise NurbscanError(f"{scan.folder / 'scan.json'}: {len(tasks)} views cannot be "
                                f"merged, {TURNTABLE_NOT_CALIBRATED}; reconstruct one view "
                                "(--views K)")
        meta["frame"] = "rig"
    return ScanPlan(scan=Path(scan.folder), rig=rig, tasks=tuple(tasks), total=len(scan.views),
                    meta=meta, rig_frame=not turntable_calibrated)


def run_view(task: ViewTask) -> ViewOutput:
    """The per-view task: read the view's images, detect the grid, triangulate its lines and
    build the view's curve network and patches (rig frame).

    Steps: :func:`nurbscan.io.read_image` (the file's own integer type), detection
    (:func:`reconstruct_detection`; :func:`nurbscan.detect.detect_lines` for a line
    pattern), :func:`~nurbscan.reconstruct.view.reconstruct_view`, and the overlay picture when
    ``task.overlay`` is set. Depends on nothing but ``task``: the same result in any process.
    """
    t0 = time.perf_counter()
    # the file's own integer type: detect linearises it by table look-up (7.1 MP teapot view:
    # 1.5 s instead of 2.4-2.8 s from float32 input, the same lines)
    grid = read_image(task.grid, as_float=False)
    white = read_image(task.white, as_float=False) if task.white is not None else None
    size = (int(task.rig.camera.width), int(task.rig.camera.height))
    for path, img in ((task.grid, grid), (task.white, white)):
        if img is not None and (img.shape[1], img.shape[0]) != size:
            raise NurbscanError(f"{path}: {img.shape[1]} x {img.shape[0]} px, not the "
                                f"{size[0]} x {size[1]} of the scan's camera")
    t1 = time.perf_counter()
    stages: dict = {}
    if isinstance(task.pattern, LinePattern):  # thin lines: centre-lines (edge 2)
        from ..detect import detect_lines

        det = detect_lines(grid, task.pattern, white=white)
    else:
        # a chroma-subsampled JPEG's colour channels have displaced edges (detect_grid)
        det = reconstruct_detection(grid, task.pattern, white, task.rig,
                                    chroma_subsampled(task.grid), stages)
    t2 = time.perf_counter()
    res = reconstruct_view(det, task.rig, task.pattern, **task.kwargs)
    t3 = time.perf_counter()
    if task.overlay is not None:
        _write_overlay(task.overlay, grid, det, task.pattern)
    # the detection's stages (detect_grid's timings) as detect_<stage>_s
    return ViewOutput(res, det.nlines, {
        "read_s": round(t1 - t0, 3), "detect_s": round(t2 - t1, 3),
        "image_to_gordon_s": round(t3 - t1, 3),
        **{f"detect_{k}": round(v, 3) for k, v in stages.items()}})


def view_line(task: ViewTask, out: ViewOutput, total: int) -> str:
    """The progress line of a finished view."""
    res, t = out.result, out.times
    return (f"view {task.n + 1}/{total} (table {np.degrees(task.angle):.1f} deg): "
            f"{out.nlines} lines, {res.cells[0]}/{res.cells[1]} complete cells, "
            f"{len(res.patches)} Gordon patches, {t['image_to_gordon_s']:.1f} s "
            f"(detect {t['detect_s']:.1f} s)")


def assemble_scan(plan: ScanPlan, outputs, *, merge: MergeOptions | None = DEFAULT_MERGE,
                  fusion=None, progress: Callable[[str], None] | None = None) -> Model:
    """The per-scan task: the views' results in one model, merged and fused.

    Steps: each view into the object frame (:func:`add_view`, in the tasks' order), the
    light-surface check on the first view with lines (:func:`light_surface_check`), the merge
    (:func:`nurbscan.merge.merge_views`) and the fused mesh
    (:func:`nurbscan.merge.fuse_model`), neither for views kept in the rig frame.

    Parameters
    ----------
    plan : ScanPlan
        The scan (:func:`plan_scan`).
    outputs : sequence of ViewOutput
        :func:`run_view` of each of ``plan.tasks``, in their order (a view left out is
        given with its task left out of ``plan``).
    merge, fusion, progress :
        As :func:`reconstruct_scan`.
    """
    if len(outputs) != len(plan.tasks):
        raise ValueError(f"{len(outputs)} view outputs for {len(plan.tasks)} view tasks")
    rig = plan.rig
    model = Model(meta=dict(plan.meta))
    frame = RigFrame() if plan.rig_frame else None
    for task, out in zip(plan.tasks, outputs, strict=True):
        if "light_surface" not in model.meta and out.result.lines:
            model.meta["light_surface"] = light_surface_check(out.result, rig)
        add_view(model, out.result, rig, task.index, task.angle, out.times, frame=frame)
    check_model(model, str(plan.scan / "scan.json"))  # no line in any view: refused
    if merge is not None and frame is None:  # no table plane nor axis in the rig frame
        t_merge = time.perf_counter()
        merge_views(model, rig.turntable, merge, progress)
        model.meta["merge"]["merge_s"] = round(time.perf_counter() - t_merge, 3)
    if fusion is not None and frame is None:
        from ..merge.fusion import fuse_model

        model.fused = fuse_model(model, rig, {t.index: t.white for t in plan.tasks}, fusion,
                                 progress=progress)
    return model


def reconstruct_scan(scan_dir: str | os.PathLike, rig, *,
                     progress: Callable[[str], None] | None = None,
                     views: list[int] | None = None, workers: int = 1,
                     overlays: str | os.PathLike | None = None,
                     merge: MergeOptions | None = DEFAULT_MERGE, fusion=None,
                     turntable_calibrated: bool = True, allow_outside: bool = False,
                     **view_kwargs) -> Model:
    """Reconstruct every view of a scan folder and merge them in the object frame.

    The steps are tasks that :mod:`nurbscan.batch` runs on Dask as well: :func:`plan_scan`,
    :func:`run_view` per view (here in up to ``workers`` processes,
    :func:`nurbscan._parallel.process_map`) and :func:`assemble_scan`.

    Parameters
    ----------
    scan_dir : path-like
        The scan folder (``scan.json``; docs/scan-format.md). ``truth/`` is never read.
    rig : Rig
        The calibrated rig (camera, projector, turntable).
    progress : callable, optional
        Called with one line per view.
    views : list of int, optional
        Only these view indices (default all).
    workers : int
        Processes reconstructing views side by side (0: one per CPU); the model does not
        depend on it (the per-view times do: two processes share the machine).
    overlays : path-like, optional
        Folder to write each view's detected lines into (``view_KK_overlay.png``, 1536 px
        wide), the picture a person checks the decoding on.
    merge : MergeOptions or None
        How the views are merged once all are reconstructed (:func:`nurbscan.merge.merge_views`:
        the table left out, the poses registered); None keeps every view where the turntable
        puts it, table and all.
    fusion : nurbscan.merge.FusionOptions, optional
        Fuse the merged views into one coloured mesh (``Model.fused``,
        :func:`nurbscan.merge.fuse_model`); None: no fused mesh.
    turntable_calibrated : bool
        False for a rig calibrated from free poses only
        (:func:`nurbscan.calibrate.turntable_calibrated`): a single view is reconstructed in
        the rig frame (``meta["frame"] = "rig"``); several views are refused
        (:class:`NurbscanError`), they cannot be merged without the table's axis.
    allow_outside : bool
        Accept ``scan.json`` paths that are absolute or leave the scan folder
        (:func:`nurbscan.io.load_scan`; refused by default).
    **view_kwargs
        Passed to :func:`~nurbscan.reconstruct.view.reconstruct_view`.
    """
    plan = plan_scan(scan_dir, rig, views=views, overlays=overlays,
                     turntable_calibrated=turntable_calibrated, allow_outside=allow_outside,
                     **view_kwargs)
    t_all = time.perf_counter()

    def done(i: int, out: ViewOutput) -> None:
        if progress is not None:
            progress(view_line(plan.tasks[i], out, plan.total))

    outputs = process_map(run_view, plan.tasks, workers, done=done)
    model = assemble_scan(plan, outputs, merge=merge, fusion=fusion, progress=progress)
    model.meta["total_s"] = round(time.perf_counter() - t_all, 3)
    return model
