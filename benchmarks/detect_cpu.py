"""CPU time of :func:`nurbscan.detect.detect_grid` per stage on bench view 0, optionally side
by side with another version of the code.

On a shared machine wall time measures the other work as much as this; the process's CPU
time (``time.process_time``, with OpenCV and the BLAS on one thread) is less disturbed.
Each stage's CPU time comes from ``detect_grid``'s ``timings`` with its clock replaced by
the CPU clock. With ``--old SRC`` (a ``src`` folder of another checkout, e.g. from
``git archive int src | tar -x -C /tmp/old``), that version is imported under another name
and the two are called alternately, so that both see the same load; the result hashes
(``detect_hash.py``) of the two are compared.

The detector runs the halves of its stages side by side in threads
(:mod:`nurbscan.detect._threads`), which the process's CPU time sums; the *path* columns
give the CPU time of the longest path (the calling thread's CPU time plus, per parallel
call, how much longer the worker's half ran: :func:`~nurbscan.detect._threads.critical_cpu`),
which is the wall time on an otherwise idle two-core machine where the GIL is free, without
depending on the load of a shared one (for a version without threads it is its CPU time).

Usage: ``PYTHONPATH=src python benchmarks/detect_cpu.py [--old /tmp/old/src] [--calls 3]
[--threads N] [--json]`` (the view cached as ``bench_detect.py`` caches it; prints one line
per stage: the minimum over the warm calls, CPU s and the longest path's CPU s; ``--threads``
sets ``NURBSCAN_DETECT_THREADS``; with ``--json`` one JSON line instead, with the old
version's total over the new one's, CPU and longest path, and the machine's load average
before and after).
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import os
import shutil
import sys
import tempfile
import time
import warnings
from pathlib import Path

for _k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_k] = "1"

import cv2  # noqa: E402
import numpy as np  # noqa: E402

HERE = Path(__file__).resolve().parent


def _load(name: str, path: Path):
    spec = importlib.util.spec_from_file_location(name, path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _path_clock(det):
    """The CPU clock of the longest path of a detect package (its ``_threads.critical_cpu``;
    the calling thread's CPU time for a version without threads)."""
    threads = sys.modules.get(det.__name__ + "._threads")
    return getattr(threads, "critical_cpu", time.thread_time)


def _cpu_clock(core_module, path_clock) -> None:
    """Replace a detect core module's stage clock by the process's CPU clock (and the
    longest path's CPU clock, in ``timings["path"]``)."""

    class _Clock:
        def __init__(self, timings):
            self.timings, self.t, self.p = timings, time.process_time(), path_clock()
            if timings is not None:
                timings.setdefault("path", {})

        def __call__(self, name, value):
            if self.timings is not None:
                t, p = time.process_time(), path_clock()
                self.timings[name] = t - self.t
                self.timings["path"][name] = p - self.p
                self.t, self.p = t, p
            return value

    core_module._Clock = _Clock


def main(argv: list[str]) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--old", type=Path, help="src folder of the version to compare with")
    ap.add_argument("--calls", type=int, default=3, help="warm calls of each version")
    ap.add_argument("--json", action="store_true", help="print one JSON line")
    ap.add_argument("--threads", type=int, help="NURBSCAN_DETECT_THREADS (default: as set, "
                    "else the detector's own choice)")
    args = ap.parse_args(argv)
    if args.threads is not None:
        os.environ["NURBSCAN_DETECT_THREADS"] = str(args.threads)
    load0 = os.getloadavg()[0]
    cv2.setNumThreads(1)
    bd = _load("bench_detect", HERE / "bench_detect.py")
    dh = _load("detect_hash", HERE / "detect_hash.py")
    import nurbscan.detect as new

    versions = [("new", new)]
    if args.old is not None:
        tmp = Path(tempfile.mkdtemp())
        shutil.copytree(args.old / "nurbscan", tmp / "nurbscan_old")
        sys.path.insert(0, str(tmp))
        versions.insert(0, ("old", importlib.import_module("nurbscan_old.detect")))
    for _, det in versions:
        _cpu_clock(sys.modules[det.__name__ + ".core"], _path_clock(det))
    z = np.load(bd.render(1.0))
    grid, white, pattern = z["grid"], z["white"], bd._pattern()
    stages = {name: [] for name, _ in versions}
    totals = {name: [] for name, _ in versions}
    paths = {name: [] for name, _ in versions}
    hashes = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for call in range(args.calls + 1):
            for name, det in versions:
                st: dict = {}
                clock = _path_clock(det)
                c, p = time.process_time(), clock()
                r = det.detect_grid(grid, pattern, white, timings=st)
                t, p = time.process_time() - c, clock() - p
                if call:  # the first call is cold
                    stages[name].append(st)
                    totals[name].append(t)
                    paths[name].append(p)
                hashes[name] = dh.result_hashes(r)[0]
    names = [n for n, _ in versions]
    keys = [k for k in stages[names[0]][0] if k != "path"]
    threads = os.environ.get("NURBSCAN_DETECT_THREADS", "default")
    if args.json:
        import json

        cpu = {n: {**{k: round(min(s[k] for s in stages[n]), 4) for k in keys},
                   "total": round(min(totals[n]), 4)} for n in names}
        path = {n: {**{k: round(min(s["path"][k] for s in stages[n]), 4) for k in keys},
                    "total": round(min(paths[n]), 4)} for n in names}
        out = {"what": f"CPU s of one thread, min of {args.calls} warm calls per stage",
               "cpu_s": cpu, "path_cpu_s": path, "threads": threads,
               "hash": hashes, "same_results": len(set(hashes.values())) == 1,
               "load_average_1min": {"before": round(load0, 2),
                                     "after": round(os.getloadavg()[0], 2)}}
        if "old" in cpu:
            out["old_total_over_new"] = round(cpu["old"]["total"] / cpu["new"]["total"], 3)
            out["old_total_over_new_path"] = round(path["old"]["total"]
                                                   / path["new"]["total"], 3)
        print(json.dumps(out))
        return
    print(f"{'stage':14s} " + " ".join(f"{n:>7s}" for n in names)
          + " " + " ".join(f"{n + ' path':>9s}" for n in names)
          + f"   CPU s, min of {args.calls} warm calls (path: the longest path's, threads "
          f"{threads})")
    for key in keys:
        print(f"{key:14s} " + " ".join(f"{min(s[key] for s in stages[n]):7.3f}"
                                       for n in names)
              + " " + " ".join(f"{min(s['path'][key] for s in stages[n]):9.3f}"
                               for n in names))
    print(f"{'total':14s} " + " ".join(f"{min(totals[n]):7.3f}" for n in names)
          + " " + " ".join(f"{min(paths[n]):9.3f}" for n in names))
    print("hash " + " ".join(f"{n}={hashes[n]}" for n in names)
          + ("" if len(set(hashes.values())) == 1 else "  DIFFERENT"))


if __name__ == "__main__":
    main(sys.argv[1:])
