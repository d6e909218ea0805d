"""Placeholder for sub-commands whose stage is not built yet."""

from __future__ import annotations

import argparse
import sys


def register_todo(sub, name: str, help_text: str, issue: int) -> argparse.ArgumentParser:
    """Register ``name`` as a sub-command that says it is not available yet and exits 1."""
    p = sub.add_parser(name, help=f"{help_text} (not yet available: issue {issue})",
                       description=f"{help_text}. Not yet available (issue {issue}).")
    p.add_argument("args", nargs=argparse.REMAINDER, help=argparse.SUPPRESS)

    def run(args: argparse.Namespace) -> int:
        print(f"nurbscan {name}: not yet available (issue {issue})", file=sys.stderr)
        return 1

    p.set_defaults(func=run)
    return p
