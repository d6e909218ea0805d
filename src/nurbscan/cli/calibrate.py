"""``nurbscan calibrate``: calibrate camera, projector and turntable from target images."""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from ..errors import NurbscanError


def register(sub) -> argparse.ArgumentParser:
    """Add the ``calibrate`` sub-command."""
    p = sub.add_parser(
        "calibrate",
        help="Calibrate camera, projector and turntable from images of a planar target",
        description=(
            "Calibrate the Tsai camera, the projector (as an inverse camera), their relative "
            "pose and the turntable axis from the images of a chessboard target in "
            "CALIBRATION_DIR (white-light and projected-grid image of each pose). The target "
            "description, the pose list and the table angles are read from scan.json beside "
            "the folder. Writes the rig (OUTPUT, the same form as the simulator's "
            "truth/rig.json), the residual figures (OUTPUT with suffix _residuals.json) and a "
            "picture of the residuals (OUTPUT with suffix _residuals.png)."
        ),
    )
    p.add_argument("calibration_dir", metavar="CALIBRATION_DIR",
                   help="folder of calibration images (scan/calibration)")
    p.add_argument("--pattern", default=None,
                   help="pattern sidecar JSON (default: pattern.json beside the folder)")
    p.add_argument("-o", "--output", required=True, metavar="OUTPUT",
                   help="rig file to write, e.g. calib.json")
    p.add_argument("--camera-pitch", type=float, default=None, metavar="MM",
                   help="camera pixel pitch, mm (default: scan.json, else the default "
                        "camera's sensor width over the image width)")
    p.add_argument("--projector-pitch", type=float, default=None, metavar="MM",
                   help="projector pixel pitch, mm (default: scan.json, else the default "
                        "projector's panel width over the pattern width)")
    p.add_argument("--exclude", type=int, nargs="*", default=(), metavar="INDEX",
                   help="pose indices to leave out (e.g. a held-out pose)")
    p.add_argument("--max-points", type=int, default=1500,
                   help="projector observations kept per pose (default 1500)")
    p.add_argument("--workers", type=int, default=2,
                   help="processes reading the poses side by side, at most one per CPU "
                        "(default 2; 0 = one per CPU); the result does not depend on it")
    p.add_argument("--projector-weight", type=float, default=1.0, metavar="W",
                   help="weight of the projector residuals against the camera's corner "
                        "residuals in the joint bundle (default 1)")
    p.add_argument("--require-all", action="store_true",
                   help="refuse a pose whose white-light image shows no target (default: "
                        "leave it out with a warning)")
    p.add_argument("--allow-outside-paths", action="store_true",
                   help="accept image paths in scan.json that are absolute or leave the scan "
                        "folder (refused by default)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress lines")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    """Run the calibration and write rig, residual figures and residual picture."""
    from ..calibrate import TURNTABLE_NOT_CALIBRATED, calibrate_scan, write_outputs

    if args.workers < 0:
        raise NurbscanError(f"--workers {args.workers}: must be >= 0")
    if not args.projector_weight > 0:
        raise NurbscanError(f"--projector-weight {args.projector_weight}: must be positive")
    if args.max_points < 1:
        raise NurbscanError(f"--max-points {args.max_points}: must be at least 1")
    for name in ("camera_pitch", "projector_pitch"):
        v = getattr(args, name)
        if v is not None and not (math.isfinite(v) and v > 0):  # NaN and inf too
            raise NurbscanError(f"--{name.replace('_', '-')} {v}: must be a positive number "
                                "of mm")
    progress = None if args.quiet else (lambda m: print(m, file=sys.stderr, flush=True))
    res = calibrate_scan(args.calibration_dir, args.pattern, exclude=tuple(args.exclude),
                         camera_pitch=args.camera_pitch, projector_pitch=args.projector_pitch,
                         max_points_per_view=args.max_points, progress=progress,
                         workers=args.workers, require_all=args.require_all,
                         projector_weight=args.projector_weight,
                         allow_outside=args.allow_outside_paths)
    paths = write_outputs(res, Path(args.output))
    f = res.figures
    print(f"nurbscan calibrate: wrote {', '.join(str(p) for p in paths)} (camera RMS "
          f"{f['camera_rms_px']:.3f} px, projector RMS {f['projector_rms_px']:.3f} px, "
          f"{f['views_used']} of {f['views_given']} poses)")
    if not res.turntable_calibrated:
        print(f"nurbscan calibrate: {TURNTABLE_NOT_CALIBRATED}")
    return 0
