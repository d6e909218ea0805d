"""Wall time of detection and of image to Gordon surfaces, this code against another version,
in one run (issue 30's "the speed-up given as a ratio against the old code measured in the
same run").

Both versions are loaded in one process (the other one's ``src/nurbscan`` copied under the
name ``nurbscan_old``) and called alternately on the same 7.1 MP teapot view
(``bench_detect.render``, cached) with the same rig and pattern objects, each of its own
package: so both see the same machine load. Per version and task the median of the warm
calls; the ratio is old / new. The detections' result hashes (``detect_hash.py``) and the
Gordon patch counts of the two are printed as well.

Usage: ``PYTHONPATH=src python benchmarks/speedup.py --old /tmp/old/src [--calls 5]
[--json]`` (the old version e.g. from ``git archive cc42f03 src | tar -x -C /tmp/old``: the
code issue 30 was filed against, whose detector took its options as keywords).
"""

from __future__ import annotations

import argparse
import importlib
import json
import shutil
import statistics
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent


def _tasks(pkg: str, grid, white):
    """(detect, image-to-Gordon) callables of the package named ``pkg`` on one view."""
    det = importlib.import_module(f"{pkg}.detect")
    rec = importlib.import_module(f"{pkg}.reconstruct")
    pipe = importlib.import_module(f"{pkg}.reconstruct.pipeline")
    rig = importlib.import_module(f"{pkg}.simulate.rig").default_rig()
    pattern = importlib.import_module(f"{pkg}.simulate.scan").default_pattern(rig.projector)

    def detect():
        return det.detect_grid(grid, pattern, white)

    def image_to_gordon():
        if hasattr(pipe, "reconstruct_detection"):
            d = pipe.reconstruct_detection(grid, pattern, white, rig)
        else:  # (the keyword options of the single-function detector, before issue 30)
            d = det.detect_grid(grid, pattern, white, **pipe.detect_options(rig))
        return rec.reconstruct_view(d, rig, pattern)

    return detect, image_to_gordon


def main(argv: list[str]) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--old", type=Path, required=True, help="src folder of the other version")
    ap.add_argument("--calls", type=int, default=5, help="warm calls of each version and task")
    ap.add_argument("--json", action="store_true", help="print one JSON line")
    args = ap.parse_args(argv)
    from nurbscan._malloc import COMMAND_MMAP_BYTES, COMMAND_TRIM_BYTES, reuse_freed_memory

    reuse_freed_memory(COMMAND_TRIM_BYTES, COMMAND_MMAP_BYTES)  # as the command line's process
    sys.path.insert(0, str(HERE))
    import bench_detect as bd
    import detect_hash as dh
    tmp = Path(tempfile.mkdtemp())
    try:
        shutil.copytree(args.old / "nurbscan", tmp / "nurbscan_old")
        sys.path.insert(0, str(tmp))
        z = np.load(bd.render(1.0))
        grid, white = z["grid"], z["white"]
        versions = {"old": _tasks("nurbscan_old", grid, white),
                    "new": _tasks("nurbscan", grid, white)}
        times: dict = {v: {"detect": [], "image_to_gordon": []} for v in versions}
        out: dict = {"hash": {}, "patches": {}}
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            for v, (detect, i2g) in versions.items():  # cold calls (imports, compiling)
                out["hash"][v] = dh.result_hashes(detect())[0]
                out["patches"][v] = len(i2g().patches)
            for _ in range(args.calls):
                for v, fns in versions.items():
                    for name, fn in zip(("detect", "image_to_gordon"), fns, strict=True):
                        t = time.perf_counter()
                        fn()
                        times[v][name].append(time.perf_counter() - t)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    for name in ("detect", "image_to_gordon"):
        old, new = (statistics.median(times[v][name]) for v in ("old", "new"))
        out[name] = {"old_s": round(old, 4), "new_s": round(new, 4),
                     "old_over_new": round(old / new, 3), "calls": args.calls}
    if args.json:
        print(json.dumps(out))
        return
    for name in ("detect", "image_to_gordon"):
        r = out[name]
        print(f"{name:16s} old {r['old_s']:.3f} s  new {r['new_s']:.3f} s  "
              f"old/new {r['old_over_new']:.2f}  (median of {args.calls} alternate calls)")
    print(f"hash old={out['hash']['old']} new={out['hash']['new']}  "
          f"Gordon patches old={out['patches']['old']} new={out['patches']['new']}")


if __name__ == "__main__":
    main(sys.argv[1:])
