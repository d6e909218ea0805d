"""The ``nurbscan`` command line: one sub-command per pipeline stage.

Each sub-command lives in its own module of this package with two functions:
``register(subparsers)`` adds its parser, and the handler it sets as ``func`` takes the parsed
arguments and returns an exit status. Input errors (:class:`~nurbscan.errors.NurbscanError`)
are printed as one line on stderr, with exit status 2.

The command's process sets glibc's malloc to keep the memory it frees for reuse
(:mod:`nurbscan._malloc`, :data:`~nurbscan._malloc.COMMAND_MMAP_BYTES`), as its worker
processes do.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from .. import __version__
from .._malloc import COMMAND_MMAP_BYTES, COMMAND_TRIM_BYTES, reuse_freed_memory
from ..errors import NurbscanError

#: Sub-command modules in pipeline order.
COMMANDS = (
    "pattern",
    "simulate",
    "detect",
    "calibrate",
    "rig",
    "reconstruct",
    "merge",
    "evaluate",
    "export",
    "batch",
    "report",
    "demo",
)


def build_parser() -> argparse.ArgumentParser:
    """The top-level parser with every sub-command registered."""
    parser = argparse.ArgumentParser(
        prog="nurbscan",
        description=(
            "Turn photographs of an object under a projected colour grid into 3-D NURBS "
            "curves and surfaces. Stages: pattern -> simulate (or real images) -> detect -> "
            "calibrate -> reconstruct (-> merge passes) -> evaluate -> export / report; "
            "'demo' runs them all."
        ),
    )
    parser.add_argument("--version", action="version", version=f"nurbscan {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name in COMMANDS:
        importlib.import_module(f".{name}", __name__).register(sub)
    return parser


def error_text(exc: NurbscanError | OSError) -> str:
    """The one-line message of an input error, or of a file-system failure no stage turned
    into a :class:`~nurbscan.errors.NurbscanError` (``FILE: strerror``)."""
    if isinstance(exc, NurbscanError):
        return str(exc)
    where = f"{exc.filename}: " if exc.filename else ""
    return f"{where}{exc.strerror or exc}"


def main(argv: list[str] | None = None) -> int:
    """Run the command line; return the exit status (0 success, 2 bad input)."""
    reuse_freed_memory(COMMAND_TRIM_BYTES, COMMAND_MMAP_BYTES)
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except (NurbscanError, OSError) as exc:
        print(f"nurbscan {args.command}: error: {error_text(exc)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"nurbscan {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
