"""Run every benchmark in this folder and rewrite ``benchmarks/RESULTS.md``.

Each ``benchmarks/bench_*.py`` defines ``bench() -> dict`` of measured figures (name -> number,
string or nested dict). Each runs in its own Python process, so that its peak memory (the
child's maximum resident set size) is its own. Figures are measured on every run, never typed in.

Usage: ``python benchmarks/run.py [NAME ...]`` (names without ``bench_``; default all).
"""

from __future__ import annotations

import datetime as _dt
import json
import os
import platform
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent

CHILD = """
import json, resource, sys, importlib.util
spec = importlib.util.spec_from_file_location("b", sys.argv[1])
mod = importlib.util.module_from_spec(spec); spec.loader.exec_module(mod)
res = mod.bench()
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
print("@@RESULT@@" + json.dumps({"figures": res, "peak_rss_mb": peak}, default=float))
"""


def machine() -> str:
    """One line describing the machine: CPU model, cores, memory, Python."""
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    mem = ""
    try:
        kb = int(Path("/proc/meminfo").read_text().split()[1])
        mem = f", {kb / 1024**2:.0f} GiB RAM"
    except (OSError, ValueError, IndexError):
        pass
    return f"{cpu}, {os.cpu_count()} cores{mem}, Python {platform.python_version()}"


def commit() -> str:
    try:
        out = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT,
                             capture_output=True, text=True, check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"],
                               cwd=ROOT, capture_output=True, text=True).stdout.strip()
        return out + (" (with uncommitted changes)" if dirty else "")
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def flatten(d: dict, prefix: str = "") -> list[tuple[str, object]]:
    rows = []
    for k, v in d.items():
        key = f"{prefix}{k}"
        if isinstance(v, dict):
            rows += flatten(v, key + " / ")
        else:
            rows.append((key, v))
    return rows


def fmt(v: object) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v)


def run_one(path: Path) -> dict:
    print(f"[bench] {path.stem} ...", file=sys.stderr, flush=True)
    proc = subprocess.run([sys.executable, "-c", CHILD, str(path)], cwd=ROOT,
                          capture_output=True, text=True)
    sys.stderr.write(proc.stderr[-4000:])
    for line in proc.stdout.splitlines():
        if line.startswith("@@RESULT@@"):
            return json.loads(line[len("@@RESULT@@"):])
    return {"error": f"exit {proc.returncode}: {proc.stderr.strip().splitlines()[-1:]}"}


def main(argv: list[str]) -> int:
    files = sorted(HERE.glob("bench_*.py"))
    if argv:
        files = [f for f in files if f.stem.removeprefix("bench_") in argv]
    results = {f.stem.removeprefix("bench_"): run_one(f) for f in files}
    lines = [
        "# Benchmark results",
        "",
        "Written by `make bench` (`python benchmarks/run.py`); every figure is measured.",
        "",
        f"- Machine: {machine()}",
        f"- Date: {_dt.datetime.now(_dt.UTC).strftime('%Y-%m-%d %H:%M UTC')}",
        f"- Commit: {commit()}",
        "",
    ]
    failed = False
    for name, res in results.items():
        lines += [f"## {name}", ""]
        if "error" in res:
            failed = True
            lines += [f"Failed: {res['error']}", ""]
            continue
        lines += ["| figure | value |", "|---|---|"]
        lines += [f"| {k} | {fmt(v)} |" for k, v in flatten(res["figures"])]
        lines += [f"| peak memory of the benchmark process (MB) | {res['peak_rss_mb']:.0f} |", ""]
    text = "\n".join(lines)
    if not argv:
        (HERE / "RESULTS.md").write_text(text)
    print(text)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
