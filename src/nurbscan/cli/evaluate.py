"""``nurbscan evaluate``: measure a model against ground truth (the paper's Table I)."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path


def register(sub) -> None:
    """Add the ``evaluate`` sub-command."""
    p = sub.add_parser(
        "evaluate", help="Measure a model against ground truth (the paper's Table I)",
        description=(
            "Measure a reconstructed model against a simulated scan's truth as the paper's "
            "Table I does (100 samples per curve or patch, distance to the true surface; mean, "
            "std, min, max in mm over curves or patches), with the coverage of the visible "
            "surface by Gordon patches and a per-view breakdown. Prints the table and writes "
            "evaluation.json and evaluation.md."))
    p.add_argument("model", type=Path, help="model folder (with model.json)")
    p.add_argument("--truth", type=Path, required=True, help="the scan's truth/ folder")
    p.add_argument("-o", "--output", type=Path, default=None,
                   help="evaluation.json path (default MODEL/evaluation.json); the Markdown "
                        "table is written beside it with the suffix .md")
    p.add_argument("--cover-tol", type=float, default=0.5,
                   help="coverage tolerance, mm (0.5)")
    p.add_argument("--cad", action="store_true",
                   help="also build the CAD surface set (what export --format 3dm|igs|step "
                        "writes) and measure it: 3 x 3 samples per kept cell against the truth")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress lines")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Evaluate ``args.model`` against ``args.truth``; print and write the table."""
    from ..errors import NurbscanError
    from ..evaluate import evaluate_model, format_table
    from ..export import load_model  # the paths the model records resolve from its folder
    from ..io import atomic_paths, write_json, write_text

    if not args.cover_tol > 0:
        raise NurbscanError(f"--cover-tol {args.cover_tol}: must be positive")
    t0 = time.perf_counter()

    def say(msg: str) -> None:
        if not args.quiet:
            print(f"[{time.perf_counter() - t0:6.1f} s] {msg}", file=sys.stderr, flush=True)

    say(f"load {args.model}")
    model = load_model(args.model)
    ev = evaluate_model(model, args.truth, cover_tol=args.cover_tol, workers=2, progress=say,
                        cad=args.cad)
    out = args.output or (args.model / "evaluation.json")
    md = format_table(ev)
    with atomic_paths(out, out.with_suffix(".md")) as (t_json, t_md):  # both or neither
        write_json(t_json, ev)
        write_text(t_md, md)
    print(md, end="")
    print(f"wrote {out} and {out.with_suffix('.md')}")
    return 0
