"""Calibration of camera, projector and turntable from images of a planar target (issue 6).

method.md section 4. :func:`calibrate_scan` runs the whole calibration on a scan's
calibration folder and returns a :class:`CalibrationResult` whose ``rig`` is a
:class:`nurbscan.camera.Rig`; :func:`write_outputs` saves the rig, the residual figures and
their picture; :func:`compare_rigs` measures an estimated rig against the truth.

Parts: :mod:`.camera` (chessboard detection, Zhang initialisation, Tsai fit),
:mod:`.projector` (projector as an inverse camera), :mod:`.turntable` (axis from the target
on the table), :mod:`.board` (the white part of a printed board, found in the image),
:mod:`._bundle` (joint least squares), :mod:`._tsai` (vectorised model).
"""

from __future__ import annotations

from pathlib import Path

from .board import white_area
from .camera import board_points, calibrate_camera, detect_chessboard
from .pipeline import (
    TURNTABLE_NOT_CALIBRATED,
    CalibrationResult,
    Target,
    calibrate_scan,
    compare_rigs,
    held_out_error,
    residual_image,
    triangulate_edges,
    turntable_calibrated,
)
from .projector import init_projector, plane_homography
from .turntable import fit_turntable


def write_outputs(result: CalibrationResult, output: Path) -> list[Path]:
    """Write the rig (``output``), ``<stem>_residuals.json`` and ``<stem>_residuals.png``.

    The three are written together atomically (:func:`nurbscan.io.atomic_paths`): a failure
    leaves all three as they were. Returns their paths.
    """
    from ..io import atomic_paths, write_image, write_json

    output = Path(output)
    js = output.with_name(output.stem + "_residuals.json")
    png = output.with_name(output.stem + "_residuals.png")
    cam = result.rig.camera
    with atomic_paths(output, js, png) as (t_rig, t_js, t_png):
        write_json(t_rig, result.rig_dict())
        write_json(t_js, result.residuals_dict())
        write_image(t_png, residual_image(result, (int(cam.width), int(cam.height))))
    return [output, js, png]


__all__ = [
    "CalibrationResult",
    "TURNTABLE_NOT_CALIBRATED",
    "board_points",
    "calibrate_camera",
    "calibrate_scan",
    "compare_rigs",
    "detect_chessboard",
    "fit_turntable",
    "held_out_error",
    "Target",
    "init_projector",
    "plane_homography",
    "residual_image",
    "triangulate_edges",
    "turntable_calibrated",
    "white_area",
    "write_outputs",
]
