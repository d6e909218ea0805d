"""``nurbscan batch``: many scans at once, on this machine or a Dask cluster."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from ..errors import NurbscanError
from .reconstruct import PARTIAL


def register(sub) -> None:
    """Add the ``batch`` sub-command."""
    p = sub.add_parser(
        "batch", help="Reconstruct, export and evaluate many scans at once (Dask)",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description=(
            "Reconstruct every scan folder given (as 'nurbscan reconstruct' does, the same\n"
            "model), export it and, where the scan has truth/, evaluate it, with Dask: one\n"
            "task per view and one per scan, on a LocalCluster of --workers processes, or on\n"
            "the cluster whose scheduler is --scheduler (every worker must see the scan and\n"
            "output folders at the same paths: docs/scaling.md). Writes OUT/NAME/ per scan\n"
            "(model/, model.glb, model.3dm, evaluation.json, batch.json), renamed into place\n"
            "when complete, and OUT/batch.json. A re-run skips the complete scans.\n\n"
            "Exit status: 0 every scan complete; 3 partial result: some scan or view failed\n"
            "(each one reported with its error, the others written, as reconstruct's 3);\n"
            "2 bad input (no such folder, unknown format, no Dask, no scheduler at the\n"
            "address) or no scan complete (the failures on the error line; nothing written)."))
    p.add_argument("scans", type=Path, nargs="+", metavar="SCAN_DIR",
                   help="scan folders (with scan.json)")
    p.add_argument("-o", "--output", type=Path, required=True, metavar="OUT",
                   help="output folder (OUT/NAME per scan)")
    p.add_argument("--calib", type=Path, default=None,
                   help="one calibrated rig for every scan (default: each scan's calib.json, "
                        "else calibrated from its calibration/ images)")
    p.add_argument("--scheduler", default=None, metavar="tcp://HOST:PORT",
                   help="a running Dask scheduler (default: a LocalCluster on this machine)")
    p.add_argument("--workers", type=int, default=2,
                   help="LocalCluster worker processes, one thread each (default 2)")
    p.add_argument("--export", default="glb,3dm",
                   help="comma-separated formats per scan, or 'none' (default glb,3dm)")
    p.add_argument("--min-curves", type=int, default=3,
                   help="smallest Gordon patch, curves per direction (3)")
    p.add_argument("--max-triangles", type=int, default=300_000,
                   help="triangle budget of the fused mesh (300000)")
    p.add_argument("--no-fuse", action="store_true", help="no fused mesh")
    p.add_argument("--no-evaluate", action="store_true",
                   help="do not evaluate the scans that have truth/")
    p.add_argument("--serial", action="store_true",
                   help="run the tasks one after the other here, without Dask")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress lines")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run the batch; 0 if every scan is complete, 3 (partial) if some failed, 2 if none is
    complete."""
    from ..batch import BatchOptions, main_report, run_batch

    exports = () if args.export.strip() == "none" else tuple(
        f.strip().lower() for f in args.export.split(",") if f.strip())
    options = BatchOptions(min_curves=args.min_curves, fuse=not args.no_fuse,
                           max_triangles=args.max_triangles, exports=exports,
                           evaluate=not args.no_evaluate)
    t0 = time.perf_counter()

    def say(msg: str) -> None:
        if not args.quiet:
            print(f"[{time.perf_counter() - t0:7.1f} s] {msg}", file=sys.stderr, flush=True)

    if args.workers < 1:
        raise NurbscanError(f"--workers {args.workers}: must be at least 1")
    if args.serial and args.scheduler:
        raise NurbscanError(f"--scheduler {args.scheduler}: not used with --serial (which "
                            "runs the tasks here); give one of them")
    summary = run_batch(args.scans, args.output, calib=args.calib, options=options,
                        scheduler=args.scheduler, workers=args.workers, serial=args.serial,
                        progress=say)
    failed = [r for r in summary["scans"] if r["status"] == "failed"]
    if len(failed) == len(summary["scans"]):  # nothing written: the one error line says why
        others = ", ".join(r["name"] for r in failed[1:])
        raise NurbscanError(f"no scan complete: {failed[0]['name']}: "
                            f"{'; '.join(failed[0]['errors'])}"
                            + (f" (and {len(failed) - 1} more failed scans: {others})"
                               if others else "") + "; nothing written")
    if args.quiet:
        for rep in summary["scans"]:
            if rep["status"] in ("failed", "partial"):
                print(f"nurbscan batch: {rep['name']}: {rep['status']}: "
                      f"{'; '.join(rep['errors'])}", file=sys.stderr)
    print(main_report(summary, args.output))
    return 0 if summary["failed"] + summary["partial"] == 0 else PARTIAL
