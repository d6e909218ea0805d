"""CPU time of :func:`nurbscan.detect.detect_grid` per stage on bench view 0, optionally side
by side with another version of the code.

On a shared machine wall time measures the other work as much as this; the process's CPU
time (``time.process_time``, with OpenCV and the BLAS on one thread) is less disturbed.
Each stage's CPU time comes from ``detect_grid``'s ``timings`` with its clock replaced by
the CPU clock. With ``--old SRC`` (a ``src`` folder of another checkout, e.g. from
``git archive int src | tar -x -C /tmp/old``), that version is imported under another name
and the two are called alternately, so that both see the same load; the result hashes
(``detect_hash.py``) of the two are compared.

Usage: ``PYTHONPATH=src python benchmarks/detect_cpu.py [--old /tmp/old/src] [--calls 3]
[--json]`` (the view cached as ``bench_detect.py`` caches it; prints one line per stage: the
minimum over the warm calls, CPU s; with ``--json`` one JSON line instead, with the old
version's total over the new one's and the machine's load average before and after).
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


def _cpu_clock(core_module) -> None:
    """Replace a detect core module's stage clock by the process's CPU clock."""

    class _Clock:
        def __init__(self, timings):
            self.timings, self.t = timings, time.process_time()

        def __call__(self, name, value):
            if self.timings is not None:
                t = time.process_time()
                self.timings[name] = t - self.t
                self.t = t
            return value

    core_module._Clock = _Clock


def main(argv: list[str]) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--old", type=Path, help="src folder of the version to compare with")
    ap.add_argument("--calls", type=int, default=3, help="warm calls of each version")
    ap.add_argument("--json", action="store_true", help="print one JSON line")
    args = ap.parse_args(argv)
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
        _cpu_clock(sys.modules[det.__name__ + ".core"])
    z = np.load(bd.render(1.0))
    grid, white, pattern = z["grid"], z["white"], bd._pattern()
    stages = {name: [] for name, _ in versions}
    totals = {name: [] for name, _ in versions}
    hashes = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for call in range(args.calls + 1):
            for name, det in versions:
                st: dict = {}
                c = time.process_time()
                r = det.detect_grid(grid, pattern, white, timings=st)
                t = time.process_time() - c
                if call:  # the first call is cold
                    stages[name].append(st)
                    totals[name].append(t)
                hashes[name] = dh.result_hashes(r)[0]
    names = [n for n, _ in versions]
    if args.json:
        import json

        cpu = {n: {**{k: round(min(s[k] for s in stages[n]), 4) for k in stages[n][0]},
                   "total": round(min(totals[n]), 4)} for n in names}
        out = {"what": f"CPU s of one thread, min of {args.calls} warm calls per stage",
               "cpu_s": cpu, "hash": hashes, "same_results": len(set(hashes.values())) == 1,
               "load_average_1min": {"before": round(load0, 2),
                                     "after": round(os.getloadavg()[0], 2)}}
        if "old" in cpu:
            out["old_total_over_new"] = round(cpu["old"]["total"] / cpu["new"]["total"], 3)
        print(json.dumps(out))
        return
    print(f"{'stage':14s} " + " ".join(f"{n:>7s}" for n in names) + "   CPU s, min of "
          f"{args.calls} warm calls")
    for key in stages[names[0]][0]:
        print(f"{key:14s} " + " ".join(f"{min(s[key] for s in stages[n]):7.3f}"
                                       for n in names))
    print(f"{'total':14s} " + " ".join(f"{min(totals[n]):7.3f}" for n in names))
    print("hash " + " ".join(f"{n}={hashes[n]}" for n in names)
          + ("" if len(set(hashes.values())) == 1 else "  DIFFERENT"))


if __name__ == "__main__":
    main(sys.argv[1:])
