"""``nurbscan report``: write a self-contained HTML scan report."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path


def register(sub) -> None:
    """Add the ``report`` sub-command."""
    p = sub.add_parser(
        "report", help="Write a self-contained HTML scan report",
        description=(
            "Write one HTML file (no network needed) with an interactive 3-D view of the model "
            "(colour and, if the scan's truth is found, an error heat map), the accuracy table "
            "beside the paper's Table I (evaluation.json), per-view figures, the detected-line "
            "overlays (*overlay*.png in the model or scan folder, or --overlay; else detected "
            "now in the scan's first views) and the model picture."))
    p.add_argument("model", type=Path, help="model folder (with model.json)")
    p.add_argument("-o", "--output", type=Path, required=True, help="output HTML file")
    p.add_argument("--overlay", type=Path, action="append", default=None,
                   help="an overlay PNG to include (repeatable; default: found in the folders)")
    p.add_argument("--evaluation", type=Path, default=None,
                   help="evaluation.json (default MODEL/evaluation.json if present)")
    p.add_argument("--no-detect", action="store_true",
                   help="without overlay pictures, do not detect the lines of the scan's first "
                        "views now (default: detect up to 4 views)")
    p.add_argument("--no-heat-map", action="store_true",
                   help="skip the per-vertex error heat map")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress lines")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Write the report of ``args.model`` to ``args.output``."""
    from ..report import write_report

    t0 = time.perf_counter()

    def say(msg: str) -> None:
        if not args.quiet:
            print(f"[{time.perf_counter() - t0:6.1f} s] {msg}", file=sys.stderr, flush=True)

    out = write_report(args.model, args.output, overlays=args.overlay,
                       evaluation=args.evaluation, heat_map=not args.no_heat_map,
                       detect=not args.no_detect, progress=say)
    print(f"wrote {out} ({out.stat().st_size} bytes)")
    return 0
