"""``nurbscan demo``: run the whole pipeline on the built-in teapot scene.

Simulate a turntable scan of the Utah teapot (real size), calibrate the rig from the simulated
calibration images (never from the true rig), reconstruct, export the model for VR, evaluate
against the truth and write the report.
"""

from __future__ import annotations

import argparse
import contextlib
import shutil
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
    """``nurbscan ARGV`` (module level, so that a worker process can run it); the exit status.

    An input error is raised, not printed, as a :class:`~nurbscan.errors.NurbscanError`
    prefixed with the step (``pattern: FILE: ...``), for the demo's own one-line error.
    """
    from ..errors import NurbscanError
    from . import build_parser, error_text

    args = build_parser().parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except (NurbscanError, OSError) as exc:
        raise NurbscanError(f"{argv[0]}: {error_text(exc)}") from None


def run(args: argparse.Namespace) -> int:
    """Run the demo's steps into ``args.output``; a step's input error (exit 2) removes what
    this run created there (the folder, when it made it, or the products new in it), so a
    failed demo leaves the folder as it found it but for products replaced by the steps
    that had succeeded (each written whole)."""
    from .simulate import check_scan_options

    # the options checked before anything is written (else a pattern.png left behind)
    check_scan_options(args)
    out: Path = args.output
    if out.exists() and not out.is_dir():
        from ..errors import NurbscanError

        raise NurbscanError(f"{out}: cannot write a folder there (it is a file)")
    made = not out.exists()
    before = set() if made else {p.name for p in out.iterdir()}
    try:
        out.mkdir(parents=True, exist_ok=True)
        return _run_steps(args, out)
    except BaseException:
        if made:
            shutil.rmtree(out, ignore_errors=True)
        else:
            for p in out.iterdir():
                if p.name in before:
                    continue
                if p.is_dir() and not p.is_symlink():
                    shutil.rmtree(p, ignore_errors=True)
                else:
                    p.unlink(missing_ok=True)
        raise


def _run_steps(args: argparse.Namespace, out: Path) -> int:
    """The demo's sub-commands in order (the export beside the evaluation and report)."""
    t0 = time.perf_counter()

    def step(title: str) -> None:
        print(f"[demo {time.perf_counter() - t0:6.1f} s] {title}", file=sys.stderr, flush=True)

    step("pattern")
    status = _cli(["pattern", "-o", str(out / "pattern.png")])
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
        try:
            status = _cli(argv)
        except BaseException:
            if pending is not None:  # let the export finish (or fail) before the demo stops
                with contextlib.suppress(Exception):
                    pending()
            raise
        if status:
            if pending is not None:
                pending()
            return status
    if pending is not None:
        status = pending()
        if status:
            return status
    step("done")
    return 0
