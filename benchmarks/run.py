"""Run every benchmark in this folder and rewrite ``benchmarks/RESULTS.md``.

Each ``benchmarks/bench_*.py`` that defines ``bench() -> dict`` of measured figures (name ->
number, string or nested dict) is run, each in its own Python process, so that its peak memory
(the child's maximum resident set size) is its own; the process sets glibc's malloc as the
command line's process does (:mod:`nurbscan._malloc`). Figures are measured on every run, never
typed in. The ``bench_*.py`` without ``bench()`` take their own arguments (two prepared
turntable passes, most of an hour) and are run by hand: RESULTS.md lists them at its end.

Usage::

    python benchmarks/run.py [NAME ...] [--runs N] [--repeat N] [--budget SECONDS] [--quick]

* ``NAME``: benchmarks to run (names without ``bench_``; default all). With names, the other
  benchmarks' figures are kept from the previous run (``benchmarks/results.json``, the raw
  figures, written beside RESULTS.md) and each section says when it was measured.
* ``--runs N``: run each benchmark N times, each in a fresh process, and report the median of
  every numeric figure (strings from the last run). Default 1.
* ``--repeat N``: repetitions inside a benchmark (``NURBSCAN_BENCH_REPEAT`` for the benchmarks
  that read it; their figures are medians of N runs). Default: each benchmark's own (3).
* ``--budget SECONDS``: wall-clock budget of the whole run (default ``NURBSCAN_BENCH_BUDGET`` or
  1800 s): each benchmark may use what is left, one still running when it runs out is stopped
  and reported as such; benchmarks not started are listed as skipped.
* ``--quick``: ``NURBSCAN_BENCH_QUICK=1`` (reduced image sizes, for development).
* ``--render``: run nothing, rewrite RESULTS.md from ``results.json`` (after adding the
  figures of a benchmark run on its own, ``python benchmarks/bench_X.py``).

The file starts with the targets of the issues beside the measured figures (:data:`TARGETS`).
"""

from __future__ import annotations

import argparse
import ast
import datetime as _dt
import json
import math
import os
import platform
import re
import statistics
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent

CHILD = """
import json, resource, sys, importlib.util
from nurbscan._malloc import COMMAND_MMAP_BYTES, COMMAND_TRIM_BYTES, reuse_freed_memory
reuse_freed_memory(COMMAND_TRIM_BYTES, COMMAND_MMAP_BYTES)  # as the command line's process
spec = importlib.util.spec_from_file_location("b", sys.argv[1])
mod = importlib.util.module_from_spec(spec); spec.loader.exec_module(mod)
res = mod.bench()
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
print("@@RESULT@@" + json.dumps({"figures": res, "peak_rss_mb": peak}, default=float))
"""

#: Targets shown at the top of RESULTS.md: (target, benchmark, figure path (" / "-joined keys
#: of the flattened figures), comparison, value). A figure that is missing is "not measured".
TARGETS = [
    ("detect per 7.1 MP view, warm (s) (#30)", "pipeline",
     "one 7.1 MP view, per stage / stages / detect / median s", "<=", 0.6),
    ("detect per 7.1 MP view, warm, alternate calls with #30's code in the same run (s) "
     "(#30)", "pipeline", "against the old code / detect / new_s", "<=", 0.6),
    ("detect speed-up over #30's code, same run (1.79 -> 0.6 s: 2.98 x) (#30)", "pipeline",
     "against the old code / detect / old_over_new", ">=", 2.98),
    ("image-to-Gordon per 7.1 MP view (s) (#30)", "pipeline",
     "one 7.1 MP view, per stage / stages / image-to-Gordon (detect + reconstruct) / "
     "median s", "<=", 1.5),
    ("detection peak memory, 7.1 MP view (MB) (#30)", "detect", "peak_mb", "<=", 600),
    ("nurbscan calibrate peak memory, its processes, shared pages once (MB) (#30)",
     "calibrate",
     "nurbscan calibrate / peak memory, the same, shared pages counted once (PSS, MB)", "<=",
     1500),
    ("registration: table angles perturbed by up to 2 deg, recovered to (deg) (#32)", "merge",
     "perturbed angles: registered - true table angle, max |.| (deg)", "<=", 0.02),
    ("time linear in pixels: detect, slope of log t / log px", "pipeline",
     "scaling with image size / slope log(time) / log(pixels) (1 = linear; target: linear) / "
     "detect", "~1", 1.0),
    ("time linear in pixels: image-to-Gordon, slope", "pipeline",
     "scaling with image size / slope log(time) / log(pixels) (1 = linear; target: linear) / "
     "image-to-Gordon", "~1", 1.0),
    ("nurbscan single-shot point RMS / Gray code's (median over views)", "graycode",
     "median over views / RMS ratio nurbscan / Gray code", "<=", 1.5),
    ("nurbscan single-shot point RMS / phase-shift peer's (median over views, noise 1x)",
     "peers", "median over views / noise 1x / RMS ratio nurbscan points / phase shift", "<=",
     1.5),
    ("phase-shift peer: median column error, noise 1x (projector px)", "peers",
     "median over views / noise 1x / phase shift column error median (projector px)", "<=",
     0.05),
    ("simulate one 7.1 MP view (s)", "simulate",
     "one view: grid + white image + truth (s)", "<=", 15.0),
    ("whole demo, nurbscan demo at 7.1 MP (s)", "pipeline", "whole demo / total (s)", "<=",
     300.0),
    ("demo Gordon surface mean error (mm)", "pipeline",
     "whole demo / accuracy: Table I (per curve / patch, 100 samples each) / gordon / mean mm",
     "<=", 0.015),
    ("demo coverage of the visible surface by Gordon patches", "pipeline",
     "whole demo / coverage of the visible surface by Gordon patches", ">=", 0.9),
    ("detect coverage of the true edges, 7.1 MP view, 1x noise", "detect",
     "noise1 / coverage", ">=", 0.95),
    ("detect edge RMS, 7.1 MP view, 1x noise (px)", "detect", "noise1 / rms_px", "<=", 0.05),
    ("oracle bound: coverage the edge points allow at RMS 0.05 px, 1x noise "
     "(bench_detect_bound)", "detect_bound", "noise1_refined_smoothed / coverage_at_rms_0.05",
     ">=", 0.95),
    ("oracle bound at zero noise", "detect_bound",
     "noise0_refined_smoothed / coverage_at_rms_0.05", ">=", 0.95),
    ("fused mesh mean distance to the truth (mm)", "fusion", "accuracy / fused mean mm", "<=",
     0.015),
    ("fused mesh mean / Gordon mean", "fusion", "accuracy / fused / gordon mean", "<=", 1.2),
    ("fused mesh area / true area it covers (no doubled layer)", "fusion",
     "area / fused / true covered", "<=", 1.03),
    ("fused mesh coverage less the Gordon patches'", "fusion", "coverage / fused - gordon",
     ">=", 0.0),
    ("fused mesh connected parts (teapot)", "fusion", "parts", "<=", 3),
    ("fused mesh glb size (MB)", "fusion", "glb / MB", "<=", 15.0),
    ("fused mesh fusion CPU time (s)", "fusion", "fusion / cpu s", "<=", 60.0),
    ("real photographs: grid lines on the board's white area decoded (share)", "real_detect",
     "poses_total / share", ">=", 0.95),
    ("real photographs: lines decoded with a wrong label", "real_detect", "poses_total / wrong",
     "<=", 0),
    ("real rig: camera reprojection RMS (px)", "real_calibrate",
     "calibration (poses 1-8) / camera RMS, camera-only Tsai fit (px)", "<=", 0.16),
    ("real rig: projector reprojection RMS (projector px)", "real_calibrate",
     "calibration (poses 1-8) / projector RMS per decoded coordinate (projector px)", "<=", 0.2),
    ("fuzzed images through detection (the issue: 10,000)", "fuzz", "images", ">=", 10_000),
    ("fuzzed images through detection: crashes", "fuzz", "crashes", "<=", 0),
    ("fuzzed images through detection: hangs over 10 s", "fuzz", "hangs_over_10s", "<=", 0),
    ("fuzzed images: results with more than 1 % of their lines over 20 px wrong", "fuzz",
     "wrong_results", "<=", 0),
    ("kill -9 of reconstruct / export: mixed, partial or corrupt outputs", "kill",
     "bad_outputs", "<=", 0),
    ("kill -9 of reconstruct / export: leftovers after the next run", "kill", "leftovers",
     "<=", 0),
    ("command-line bad-input suite: tracebacks", "badinput", "tracebacks", "<=", 0),
    ("command-line bad-input suite: hangs", "badinput", "hangs", "<=", 0),
    ("command-line bad-input suite: partial or changed outputs", "badinput",
     "partial_outputs", "<=", 0),
    ("command-line bad-input suite: cases not exit 2 with one line naming the input",
     "badinput", "failures", "<=", 0),
    ("CAD set (#32): overlap between the CAD surfaces (overlap_area, share of their area)",
     "cad", "overlap / share", "<=", 0.01),
    ("CAD set STEP read back (#32): shells (a few)", "cad", "step read back / shells", "<=", 5),
    ("CAD set STEP read back (#32): faces invalid (BRepCheck_Analyzer)", "cad",
     "step read back / faces invalid", "<=", 0),
    ("CAD set (#32): worst sample against the truth, nurbscan evaluate --cad (mm)", "cad",
     "evaluate --cad / worst sample mm", "<=", 0.2),
    ("batch: 4 scans (1024 x 768, 4 views), LocalCluster of 2: wall / (serial tasks' time / 2)",
     "batch", "small batch / wall / (serial tasks' time / 2)", "<=", 1.2),
    ("batch: the same, less the cluster's start-up", "batch",
     "small batch / wall less the cluster's start / (serial tasks' time / 2)", "<=", 1.2),
    ("batch: the same, against the serial run bound to one core (one worker's core)", "batch",
     "small batch / wall / (serial on one core / 2)", "<=", 1.2),
]
#: A slope counts as linear within this distance of 1.
SLOPE_TOL = 0.2


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
    if isinstance(v, bool):
        return str(v)
    if isinstance(v, float):
        return "n/a" if math.isnan(v) else f"{v:.4g}"
    if v is None:
        return "n/a"
    return str(v).replace("|", "/")


def _is_table(d: dict) -> bool:
    """A dict of >= 2 dicts of scalars sharing most keys: rendered as one table."""
    vals = list(d.values())
    if len(vals) < 2 or not all(isinstance(v, dict) and v for v in vals):
        return False
    if any(isinstance(x, dict) for v in vals for x in v.values()):
        return False
    keys = set(vals[0])
    return all(len(keys & set(v)) >= max(1, len(keys) // 2) for v in vals)


def render(d: dict, level: int = 3) -> list[str]:
    """Markdown of a figures dict: scalars as a figure | value table, dicts as sub-sections,
    dicts of like rows as one table with a column per key."""
    out: list[str] = []
    scalars = [(k, v) for k, v in d.items() if not isinstance(v, dict)]
    if scalars:
        out += ["| figure | value |", "|---|---|"]
        out += [f"| {fmt(k)} | {fmt(v)} |" for k, v in scalars]
        out.append("")
    for k, v in d.items():
        if not isinstance(v, dict):
            continue
        out += [f"{'#' * min(level, 6)} {k}", ""]
        if _is_table(v):
            cols: list[str] = []
            for row in v.values():
                cols += [c for c in row if c not in cols]
            out += ["| | " + " | ".join(fmt(c) for c in cols) + " |",
                    "|---" * (len(cols) + 1) + "|"]
            out += [f"| {fmt(name)} | " + " | ".join(fmt(row.get(c, "")) for c in cols) + " |"
                    for name, row in v.items()]
            out.append("")
        else:
            out += render(v, level + 1)
    return out


def median_results(runs: list[dict]) -> dict:
    """Median of every numeric leaf over repeated runs (others from the last run)."""
    def merge(vals):
        last = vals[-1]
        if isinstance(last, dict):
            return {k: merge([v[k] for v in vals if isinstance(v, dict) and k in v])
                    for k in last}
        nums = [v for v in vals if isinstance(v, int | float) and not isinstance(v, bool)]
        if len(nums) == len(vals) and nums:
            m = statistics.median(nums)
            return int(m) if all(isinstance(v, int) for v in nums) and m == int(m) else m
        return last
    return merge(runs)


def run_one(path: Path, timeout: float | None, env: dict) -> dict:
    print(f"[bench] {path.stem} ...", file=sys.stderr, flush=True)
    t0 = time.perf_counter()
    try:
        proc = subprocess.run([sys.executable, "-c", CHILD, str(path)], cwd=ROOT,
                              capture_output=True, text=True, timeout=timeout, env=env)
    except subprocess.TimeoutExpired:
        return {"error": f"stopped: exceeded the time budget ({timeout:.0f} s left)",
                "wall_s": time.perf_counter() - t0}
    wall = time.perf_counter() - t0
    sys.stderr.write(proc.stderr[-4000:])
    for line in proc.stdout.splitlines():
        if line.startswith("@@RESULT@@"):
            res = json.loads(line[len("@@RESULT@@"):])
            res["wall_s"] = wall
            return res
    return {"error": f"exit {proc.returncode}: {proc.stderr.strip().splitlines()[-1:]}",
            "wall_s": wall}


def lookup(results: dict, bench: str, path: str):
    res = results.get(bench)
    if not res or "figures" not in res:
        return None
    return dict(flatten(res["figures"])).get(path)


def target_rows(results: dict) -> list[str]:
    lines = ["## Targets", "", "| target | required | measured | met |", "|---|---|---|---|"]
    for label, bench, path, op, value in TARGETS:
        got = lookup(results, bench, path)
        req = f"{value:g} +- {SLOPE_TOL:g}" if op == "~1" else f"{op} {value:g}"
        if isinstance(got, int | float) and not isinstance(got, bool) and math.isfinite(got):
            ok = {"<=": got <= value, ">=": got >= value}.get(op, abs(got - value) <= SLOPE_TOL)
            lines.append(f"| {label} | {req} | {got:.4g} | {'yes' if ok else 'NO'} |")
        elif bench in results:
            lines.append(f"| {label} | {req} | not measured | - |")
    lines.append("")
    return lines


def benchmark_files() -> tuple[list[Path], list[Path]]:
    """The ``bench_*.py`` files that define ``bench()`` (run here), and those that do not: the
    measurements too long or too tied to a prepared scan for ``make bench`` (e.g. two full
    turntable passes), run by hand with their own arguments (their docstrings say how) and
    reported in ``docs/accuracy.md``."""
    files = sorted(HERE.glob("bench_*.py"))
    defines = [re.search(r"^def bench\(", f.read_text(), flags=re.M) is not None for f in files]
    return ([f for f, d in zip(files, defines, strict=True) if d],
            [f for f, d in zip(files, defines, strict=True) if not d])


def by_hand_rows(files: list[Path]) -> list[str]:
    """RESULTS.md's list of the benchmarks run by hand, with their docstrings' first lines."""
    if not files:
        return []
    lines = ["## Run by hand (not by this script)", "",
             "These take their own arguments (a prepared scan, two passes) and report in "
             "`docs/accuracy.md`:", ""]
    for f in files:
        doc = (ast.get_docstring(ast.parse(f.read_text())) or "").split("\n\n")[0]
        lines.append(f"- `{f.name}`: {' '.join(doc.split())}")
    return lines + [""]


def _load_previous(path: Path) -> dict:
    """Results of the previous run (``results.json``), to keep the benchmarks not re-run."""
    try:
        doc = json.loads(path.read_text())
        return doc.get("results", {}) if isinstance(doc, dict) else {}
    except (OSError, ValueError):
        return {}


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("names", nargs="*")
    ap.add_argument("--runs", type=int, default=1)
    ap.add_argument("--repeat", type=int, default=None)
    ap.add_argument("--budget", type=float,
                    default=float(os.environ.get("NURBSCAN_BENCH_BUDGET", "1800")))
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--render", action="store_true",
                    help="run nothing: rewrite RESULTS.md from results.json")
    args = ap.parse_args(argv)
    env = dict(os.environ)
    if args.repeat is not None:
        env["NURBSCAN_BENCH_REPEAT"] = str(args.repeat)
    if args.quick:
        env["NURBSCAN_BENCH_QUICK"] = "1"
    files, by_hand = benchmark_files()
    if args.names:
        files = [f for f in files if f.stem.removeprefix("bench_") in args.names]
    if args.render:
        files = []
    t_start = time.perf_counter()
    results: dict = {}
    stamp = _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
    rev = commit()
    for f in files:
        name = f.stem.removeprefix("bench_")
        runs = []
        for _ in range(max(1, args.runs)):
            left = args.budget - (time.perf_counter() - t_start)
            if left <= 0:
                break
            runs.append(run_one(f, left, env))
            if "error" in runs[-1]:
                break
        if not runs:
            results[name] = {"error": "skipped: the time budget was used up"}
        elif "error" in runs[-1]:
            results[name] = runs[-1]
        else:
            results[name] = {"figures": median_results([r["figures"] for r in runs]),
                             "peak_rss_mb": max(r["peak_rss_mb"] for r in runs),
                             "wall_s": sum(r["wall_s"] for r in runs), "runs": len(runs)}
        results[name].update(date=stamp, commit=rev, quick=bool(args.quick))
    total = time.perf_counter() - t_start
    lines = [
        "# Benchmark results",
        "",
        "Written by `make bench` (`python benchmarks/run.py`); every figure is measured, "
        "never typed in (each section says when).",
        "",
        f"- Machine: {machine()}",
        f"- Date: {_dt.datetime.now(_dt.UTC).strftime('%Y-%m-%d %H:%M UTC')}",
        f"- Commit: {commit()}",
        f"- Wall time of this run: {total:.0f} s (budget {args.budget:.0f} s)"
        + (", quick mode (reduced image sizes)" if args.quick else ""),
        "",
    ]
    json_path = HERE / "results.json"
    if (args.names or args.render) and not args.quick:  # keep those not re-run
        results = {**_load_previous(json_path), **results}
    lines += target_rows(results)
    failed = False
    for name in sorted(results):
        res = results[name]
        lines += [f"## {name}", ""]
        when = f" (measured {res.get('date', '?')}, commit {res.get('commit', '?')})"
        if "error" in res:
            failed = True
            lines += [f"Failed: {res['error']}{when}", ""]
            continue
        rss = res.get("peak_rss_mb")
        lines += [f"Process: {res['wall_s']:.0f} s wall time, peak memory "
                  + (f"{rss:.0f} MB (maximum resident set)" if rss is not None else
                     "not measured (run on its own, outside run.py)")
                  + (f"; medians of {res['runs']} processes" if res["runs"] > 1 else "")
                  + when, ""]
        lines += render(res["figures"])
    lines += by_hand_rows(by_hand)
    text = "\n".join(lines) + "\n"
    if not args.quick:
        (HERE / "RESULTS.md").write_text(text)
        json_path.write_text(json.dumps({"type": "nurbscan.bench_results", "version": 1,
                                         "machine": machine(), "results": results},
                                        indent=1, default=float))
    print(text)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
