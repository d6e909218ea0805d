"""``nurbscan rig convert``: a rig to and from OpenCV's FileStorage YAML."""

from __future__ import annotations

import argparse
import math
import warnings
from pathlib import Path

from ..errors import NurbscanError

_OPENCV = (".yml", ".yaml", ".xml")


def register(sub) -> argparse.ArgumentParser:
    """Add the ``rig`` sub-command (one action: ``convert``)."""
    p = sub.add_parser(
        "rig", help="Convert a calibrated rig to or from OpenCV's calibration YAML",
        description=(
            "Convert a calibration between nurbscan's rig JSON (calib.json, Tsai's model) and "
            "OpenCV's FileStorage YAML as stereoCalibrate writes it (camera = first camera, "
            "projector = second: K1, D1, K2, D2, R, T, E, F; also read: camK, camKc, prjK, "
            "prjKc, M1, M2, cameraMatrix1, distCoeffs1, ...). The direction follows the file "
            "names: INPUT .yml/.yaml/.xml gives a rig JSON, INPUT .json gives YAML. Tsai's "
            "single radial term k1 and OpenCV's distortion are fitted to each other by least "
            "squares over the whole image; the conversion's RMS and largest error in px are "
            "printed. OpenCV's file holds no turntable: it is taken from --turntable RIG.json, "
            "from nurbscan's own keys when the file was written by nurbscan, else a "
            "placeholder (fine for single views; calibrate the table for a turntable scan)."))
    actions = p.add_subparsers(dest="action", metavar="ACTION")
    actions.required = True
    c = actions.add_parser("convert", help="Convert INPUT to OUTPUT (direction from the names)",
                           description="Convert INPUT to OUTPUT; see 'nurbscan rig -h'.")
    c.add_argument("input", type=Path, metavar="INPUT", help="calib.json or OpenCV .yml")
    c.add_argument("-o", "--output", type=Path, required=True, metavar="OUTPUT",
                   help="file to write: .yml/.yaml for OpenCV, .json for nurbscan")
    c.add_argument("--image-size", type=int, nargs=2, metavar=("W", "H"), default=None,
                   help="from OpenCV: the camera's image size, px (if not in the file)")
    c.add_argument("--projector-size", type=int, nargs=2, metavar=("W", "H"), default=None,
                   help="from OpenCV: the projector's image size, px (if not in the file)")
    c.add_argument("--camera-pitch", type=float, default=None, metavar="MM",
                   help="from OpenCV: camera pixel pitch, mm (default: the file's, else 0.0025; "
                        "no projection in px depends on it)")
    c.add_argument("--projector-pitch", type=float, default=None, metavar="MM",
                   help="from OpenCV: projector pixel pitch, mm (as --camera-pitch)")
    c.add_argument("--turntable", type=Path, default=None, metavar="RIG_JSON",
                   help="from OpenCV: take the turntable from this rig JSON")
    c.add_argument("--style", choices=("stereo", "procam"), default="stereo",
                   help="to OpenCV: key names K1, D1, K2, D2 (stereo, default) or camK, camKc, "
                        "prjK, prjKc (procam)")
    c.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    """Convert ``args.input`` to ``args.output``."""
    from ..calibrate.opencv import read_opencv, write_opencv
    from ..camera import load_rig

    for name in ("camera_pitch", "projector_pitch"):
        v = getattr(args, name)
        if v is not None and not (math.isfinite(v) and v > 0):  # NaN and inf too
            raise NurbscanError(f"--{name.replace('_', '-')} {v}: must be a positive number "
                                "of mm")
    for name in ("image_size", "projector_size"):
        v = getattr(args, name)
        if v is not None and min(v) < 1:
            raise NurbscanError(f"--{name.replace('_', '-')} {v[0]} {v[1]}: must be positive "
                                "px")
    src, dst = args.input.suffix.lower(), args.output.suffix.lower()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the figures are printed below
        if src in _OPENCV and dst == ".json":
            table = None
            if args.turntable is not None:
                rig = load_rig(args.turntable)
                cam = rig.camera
                from ..camera import Turntable

                table = Turntable(point=cam.R @ rig.turntable.point + cam.T,
                                  direction=cam.R @ rig.turntable.direction)
            rep = read_opencv(args.input, image_size=args.image_size,
                              projector_size=args.projector_size,
                              camera_pitch=args.camera_pitch,
                              projector_pitch=args.projector_pitch, turntable=table)
            rep.rig.save(args.output)
        elif src == ".json" and dst in _OPENCV[:2]:
            rep = write_opencv(load_rig(args.input), args.output, style=args.style)
        else:
            raise NurbscanError(f"{args.input} -> {args.output}: convert .yml/.yaml/.xml to "
                                ".json, or .json to .yml/.yaml")
    print(f"nurbscan rig: wrote {args.output} ({rep.summary()})")
    return 0
