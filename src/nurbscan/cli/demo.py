"""``nurbscan demo``: run the whole pipeline on the built-in teapot scene.

Simulate a turntable scan of the Utah teapot (real size), calibrate the rig from the simulated
calibration images (never from the true rig), reconstruct, export the model for VR, evaluate
against the truth and write the report.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from .._parallel import in_background


def register(sub) -> None:
    """Add the ``demo`` sub-command."""
    p = sub.add_parser(
        "demo",
        help="Run the whole pipeline on the built-in teapot scene",
        description=(
            "Run the whole pipeline on the built-in teapot scene: simulate, calibrate from "
            "the calibration images, reconstruct, export, evaluate and report. Writes "
            "DIR/pattern.png, DIR/scan/ (simulated views, calibration images and truth), "
            "DIR/calib.json, DIR/model/ (model.json: the NURBS curves and surfaces, points.npz, "
            "model.png), DIR/teapot.glb (the "
            "model for VR), DIR/evaluation.json and DIR/evaluation.md (Table I against the "
            "truth) and DIR/report.html (the scan report)."
        ),
    )
    p.add_argument("-o", "--output", default="demo", type=Path, metavar="DIR",
                   help="output folder (demo/)")
    p.add_argument("--views", type=int, default=8, help="turntable views (8)")
    p.add_argument("--seed", type=int, default=0, help="random seed of the simulator (0)")
    p.add_argument("--width", type=int, default=None,
                   help="camera width in px (default 3072; smaller is a faster, coarser demo)")
    p.add_argument("--height", type=int, default=None, help="camera height in px (default 2304)")
    p.add_argument("--passes", type=int, choices=(1, 2), default=1,
                   help="turntable passes (1; 2: a second pass with the teapot on its side, "
                        "DIR/scan-side/ and DIR/model-side/, merged with the first into "
                        "DIR/merged/ and evaluated into DIR/evaluation-merged.json)")
    p.set_defaults(func=run)


def _cli(argv: list[str]) -> int:
    """``nurbscan ARGV`` (module level, so that a worker process can run it)."""
    from . import main as cli_main

    return cli_main(argv)


def run(args: argparse.Namespace) -> int:
    from . import main as cli_main
    from .simulate import check_scan_options

    # the options checked before anything is written (else a pattern.png left behind)
    check_scan_options(args)
    out: Path = args.output
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()

    def step(title: str) -> None:
        print(f"[demo {time.perf_counter() - t0:6.1f} s] {title}", file=sys.stderr, flush=True)

    step("pattern")
    status = cli_main(["pattern", "-o", str(out / "pattern.png")])
    if status:
        return status

    size = []
    for name in ("width", "height"):
        if getattr(args, name, None) is not None:
            size += [f"--{name}", str(getattr(args, name))]
    scan = out / "scan"
    calib = out / "calib.json"
    model = out / "model"
    plan = [
        ("simulate the teapot scan",
         ["simulate", "teapot", "-o", str(scan), "--views", str(args.views),
          "--seed", str(args.seed)] + size),
        ("calibrate from the calibration images",
         ["calibrate", str(scan / "calibration"), "--pattern", str(scan / "pattern.json"),
          "-o", str(calib)]),
        ("reconstruct every view",
         ["reconstruct", str(scan), "--calib", str(calib), "-o", str(model)]),
        ("export the model for VR (glb)",
         ["export", str(model), "--format", "glb", "-o", str(out / "teapot.glb")]),
        ("evaluate against the truth (Table I)",
         ["evaluate", str(model), "--truth", str(scan / "truth"),
          "-o", str(out / "evaluation.json")]),
        ("write the scan report",
         ["report", str(model), "-o", str(out / "report.html"),
          "--evaluation", str(out / "evaluation.json")]),
    ]
    if args.passes == 2:
        side = out / "scan-side"
        plan += [
            ("simulate the second pass (the teapot on its side)",
             ["simulate", "teapot", "--pose", "side", "-o", str(side), "--views",
              str(args.views), "--seed", str(args.seed), "--no-calibration"] + size),
            ("reconstruct the second pass",
             ["reconstruct", str(side), "--calib", str(calib), "-o", str(out / "model-side")]),
            ("merge the two passes (aligned without a prior)",
             ["merge", str(model), str(out / "model-side"), "-o", str(out / "merged")]),
            ("evaluate the merged model against the first pass's truth",
             ["evaluate", str(out / "merged"), "--truth", str(scan / "truth"),
              "-o", str(out / "evaluation-merged.json")]),
        ]
    pending = None  # the export runs in a second process beside the evaluation and report
    for title, argv in plan:
        if argv[0] == "export":
            step(title + " (in the background)")
            pending = in_background(_cli, argv)
            continue
        step(title)
        status = cli_main(argv)
        if status:
            if pending is not None:
                pending()  # let the export finish (or fail) before the demo stops
            return status
    if pending is not None:
        status = pending()
        if status:
            return status
    step("done")
    return 0
