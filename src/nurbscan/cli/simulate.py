"""``nurbscan simulate``: render a synthetic scan of a scene (docs/scan-format.md)."""

from __future__ import annotations

import argparse
import sys

from ..errors import NurbscanError

#: What a simulated scan folder holds: an existing folder with only these is replaced.
SCAN_FILES = frozenset({"scan.json", "pattern.png", "pattern.json", "views", "calibration",
                        "truth"})
#: Largest camera side, px (above the largest sensors: 150 Mpx is about 14200 x 10650).
MAX_SIDE = 20_000
#: Most views (a tenth of a degree apart).
MAX_VIEWS = 3600


def register(sub) -> argparse.ArgumentParser:
    """Add the ``simulate`` sub-command."""
    p = sub.add_parser(
        "simulate",
        help="Render a synthetic scan of a scene (images, calibration, exact truth)",
        description=(
            "Render a synthetic scan: the scene on the turntable under the projected grid and "
            "under white light in several views, the chessboard target in calibration poses, "
            "and the exact ground truth, into a scan folder (docs/scan-format.md). Progress: "
            "one line per image on stderr."
        ),
    )
    p.add_argument("scene", help="teapot, blob, sphere, cylinder, torus or plane")
    p.add_argument("-o", "--output", required=True, help="scan folder to write")
    p.add_argument("--views", type=int, default=8, help="number of views (default 8)")
    p.add_argument("--rig", help="rig JSON file (default: the built-in rig)")
    p.add_argument("--noise", type=float, default=1.0,
                   help="scale of the default sensor noise (0 = none; default 1.0)")
    p.add_argument("--seed", type=int, default=0, help="noise seed (default 0)")
    p.add_argument("--width", type=int, help="camera width in px (scales the camera down)")
    p.add_argument("--height", type=int, help="camera height in px (scales the camera down)")
    p.add_argument("--bit-depth", type=int, choices=(8, 16), default=8,
                   help="bits per sample of the images (default 8)")
    p.add_argument("--table-albedo", type=float, default=None, metavar="A",
                   help="albedo of the turntable's top, a matte disc of radius 150 mm under "
                        "the object (0..1; default 0.03, nearly black; e.g. 0.3 for a grey "
                        "table the grid is seen on)")
    p.add_argument("--pose", default=None, metavar="POSE",
                   help="resting pose of the object: upright, side, upside-down or RX,RY,RZ "
                        "(degrees about x, then y, then z); the object is rotated, then set "
                        "down on the table top (lowest point on it, centred on the axis) and "
                        "the truth describes it so posed (default: the scene as defined)")
    p.add_argument("--no-calibration", action="store_true",
                   help="skip the calibration images")
    p.add_argument("--workers", type=int, default=2,
                   help="processes rendering side by side, at most one per CPU, about 2.1 GB "
                        "each at 7.1 MP (default 2; 0 = one per CPU); the images do not "
                        "depend on it")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    """Render the scan; return 0."""
    from ..io import atomic_folder
    from ..simulate.render import RenderSettings
    from ..simulate.rig import default_rig, scale_camera
    from ..simulate.scan import simulate_scan
    from ..simulate.scenes import make_scene

    if not args.noise >= 0:  # NaN too
        raise NurbscanError(f"--noise {args.noise}: must be a number >= 0")
    check_scan_options(args)
    if args.workers < 0:
        raise NurbscanError(f"--workers {args.workers}: must be >= 0")
    if args.rig:
        from ..camera import load_rig

        rig = load_rig(args.rig)
    else:
        rig = default_rig()
    if args.width is not None or args.height is not None:
        cam = rig.camera
        w = args.width or round(cam.width * args.height / cam.height)
        h = args.height or round(cam.height * args.width / cam.width)
        rig = scale_camera(rig, w, h)
    scene = make_scene(args.scene)
    if args.pose is not None:
        from ..simulate.pose import posed

        scene = posed(scene, args.pose)
    settings = RenderSettings(bit_depth=args.bit_depth).with_noise_scale(args.noise)
    if args.table_albedo is not None:
        if not 0 <= args.table_albedo <= 1:
            raise NurbscanError(f"--table-albedo {args.table_albedo}: must be in [0, 1]")
        settings = settings.replace(table_albedo=(args.table_albedo,) * 3)

    def progress(line: str) -> None:
        print(f"nurbscan simulate: {line}", file=sys.stderr, flush=True)

    pose = "" if args.pose is None else f" ({args.pose})"
    progress(f"rendering {args.scene}{pose} at {rig.camera.width} x {rig.camera.height} px, "
             f"{args.views} views, into {args.output}")
    # written whole under a temporary name (a failed run leaves no half scan), under its lock
    with atomic_folder(args.output, SCAN_FILES) as tmp:
        simulate_scan(scene, tmp, views=args.views, rig=rig, settings=settings,
                      seed=args.seed, progress=progress, calibration=not args.no_calibration,
                      workers=args.workers)
    return 0


def check_scan_options(args: argparse.Namespace) -> None:
    """``--seed``, ``--width``, ``--height`` and ``--views`` in range (simulate's and demo's),
    checked before anything is written; a one-line :class:`NurbscanError` otherwise."""
    if args.seed < 0:
        raise NurbscanError(f"--seed {args.seed}: must be >= 0")
    for name in ("width", "height"):
        v = getattr(args, name)
        if v is not None and not 16 <= v <= MAX_SIDE:
            raise NurbscanError(f"--{name} {v}: must be 16 to {MAX_SIDE} px")
    if not 1 <= args.views <= MAX_VIEWS:
        raise NurbscanError(f"--views {args.views}: must be 1 to {MAX_VIEWS}")
