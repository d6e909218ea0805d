"""Benchmark of ``nurbscan.detect`` on the simulator's teapot at the default 7.1 MP camera.

``bench()`` renders (once, cached in ``$NURBSCAN_BENCH_CACHE`` or the system temp folder) the
teapot view 0 at 3072 x 2304 px with the default render settings at noise 0, 1x and 3x, and
returns a dict with

* ``seconds`` / ``seconds_warm``: wall time of :func:`nurbscan.detect.detect_grid` on the 1x
  image (grid + white, uint8), first call and second call in a fresh process;
* ``cpu_seconds_warm``: the process's CPU time of the second call (less disturbed than the wall
  time by other work on a shared machine); ``path_cpu_seconds_warm`` that of its longest path
  (:func:`nurbscan.detect._threads.critical_cpu`, with ``threads`` threads);
* ``stages_warm_s``: the second call's wall time per stage (``detect_grid``'s ``timings``:
  normalise, edges, chains, reading, decoding, families, refine, intersections, checks,
  result);
* ``peak_mb``: peak resident memory of that process (``ru_maxrss``; the images themselves
  included);
* per noise level (``noise0``, ``noise1``, ``noise3``): the figures of
  :func:`nurbscan.detect.evaluate_detection` against the view's truth;
* ``cpu_per_stage``: CPU time per stage on the 1x image, OpenCV on one thread, and the CPU
  time of the detector's longest path (``path_cpu_s``: its halves of stages run side by
  side in two threads, :mod:`nurbscan.detect._threads`) (``detect_cpu.py --json``, less
  disturbed by other work than the wall times), side by side with another version of the
  code when ``NURBSCAN_BENCH_OLD_SRC`` names its ``src`` folder (with the old version's
  total over this one's, CPU and longest path, both measured in the same run);
* ``noise1_jpeg95``: the same for the 1x images saved as JPEG at quality 95 (OpenCV's
  default 4:2:0 chroma subsampling, as cameras write) and read back as ``nurbscan detect``
  reads them (``detect_grid``'s ``chroma_subsampled``, from :func:`nurbscan.io.chroma_subsampled`).

Run ``python benchmarks/bench_detect.py`` (prints JSON).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

WIDTH, HEIGHT = 3072, 2304


def _cache_dir() -> Path:
    d = Path(os.environ.get("NURBSCAN_BENCH_CACHE", Path(tempfile.gettempdir())
                            / "nurbscan_bench_detect"))
    d.mkdir(parents=True, exist_ok=True)
    return d


def _pattern():
    from nurbscan.simulate.rig import default_rig
    from nurbscan.simulate.scan import default_pattern

    return default_pattern(default_rig().projector)


def render(noise: float, width: int = WIDTH, height: int = HEIGHT) -> Path:
    """Render (or reuse) teapot view 0 at ``noise`` x the default noise; returns the .npz."""
    path = _cache_dir() / f"teapot_{width}x{height}_noise{noise:g}.npz"
    if path.exists():
        return path
    from nurbscan.simulate import make_scene
    from nurbscan.simulate.render import RenderSettings, render_view
    from nurbscan.simulate.rig import default_rig, scale_camera

    rig = default_rig()
    if (width, height) != (rig.camera.width, rig.camera.height):
        rig = scale_camera(rig, width, height)
    v = render_view(make_scene("teapot"), rig, _pattern(), 0.0,
                    RenderSettings().with_noise_scale(noise), seed=0, stream=0)
    t = v.truth
    tmp = path.with_suffix(".tmp.npz")
    np.savez(tmp, grid=v.grid, white=v.white, proj_x=t["proj_x"], proj_y=t["proj_y"],
             lit=t["lit"], surface_id=t["surface_id"])
    os.replace(tmp, path)
    return path


def _peak_mb(resource) -> float:
    """This process's peak resident memory, MB: Linux's VmHWM (``ru_maxrss`` of a process
    started by a larger one reports the parent's peak when that is higher, e.g. after
    :func:`render` ran in the parent), else ``ru_maxrss``."""
    try:
        for row in Path("/proc/self/status").read_text().splitlines():
            if row.startswith("VmHWM:"):
                return float(row.split()[1]) / 1024.0  # kB -> MB
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # kB -> MB (Linux)


def _timed_child(path: str) -> dict:
    """Detect twice on the cached view in this (fresh) process: times and peak memory."""
    import resource

    from nurbscan.detect import detect_grid
    from nurbscan.detect._threads import critical_cpu, thread_count

    z = np.load(path)
    grid, white = z["grid"], z["white"]
    pattern = _pattern()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        t0 = time.perf_counter()
        detect_grid(grid, pattern, white)
        t1 = time.perf_counter()
        stages: dict = {}
        c1, p1 = time.process_time(), critical_cpu()
        detect_grid(grid, pattern, white, timings=stages)
        t2 = time.perf_counter()
        c2, p2 = time.process_time(), critical_cpu()
    peak = _peak_mb(resource)
    return {"seconds": t1 - t0, "seconds_warm": t2 - t1, "cpu_seconds_warm": c2 - c1,
            "path_cpu_seconds_warm": p2 - p1, "threads": thread_count(), "peak_mb": peak,
            "stages_warm_s": stages}


def figures(path: Path, jpeg: int | None = None) -> dict[str, float]:
    """Detection figures of one cached view against its truth (the images through JPEG
    files at quality ``jpeg`` first, if given, read as ``nurbscan detect`` reads them)."""
    import cv2

    from nurbscan.detect import DetectOptions, detect_grid, evaluate_detection
    from nurbscan.io import chroma_subsampled, read_image

    z = np.load(path)
    truth = {k: z[k] for k in ("proj_x", "proj_y", "lit", "surface_id")}
    pattern = _pattern()
    grid, white = z["grid"], z["white"]
    subsampled = False
    if jpeg is not None:
        with tempfile.TemporaryDirectory() as tmp:
            files = [Path(tmp) / f"{k}.jpg" for k in ("grid", "white")]
            for f, img in zip(files, (grid, white), strict=True):
                cv2.imwrite(str(f), np.ascontiguousarray(img[..., ::-1]),
                            [cv2.IMWRITE_JPEG_QUALITY, jpeg])
            grid, white = (read_image(f, as_float=False) for f in files)
            subsampled = chroma_subsampled(files[0])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r = detect_grid(grid, pattern, white,
                        DetectOptions().replace(chroma_subsampled=subsampled))
    ev = evaluate_detection(r, truth, pattern)
    ev["lines"] = float(r.nlines)
    return ev


def bench(noises=(0.0, 1.0, 3.0)) -> dict:
    """Run the benchmark (module notes); returns a JSON-ready dict."""
    out: dict = {"image": f"teapot view 0, {WIDTH} x {HEIGHT} px (7.1 MP), default render"}
    paths = {n: render(n) for n in noises}
    # a fresh interpreter running this file (the runner loads it under another name, which a
    # spawned multiprocessing child could not import)
    child = subprocess.run([sys.executable, __file__, "--child",
                            str(paths[1.0 if 1.0 in paths else noises[0]])],
                           capture_output=True, text=True, check=True)
    out.update(json.loads(child.stdout.strip().splitlines()[-1]))
    cmd = [sys.executable, str(Path(__file__).resolve().parent / "detect_cpu.py"), "--json"]
    if os.environ.get("NURBSCAN_BENCH_OLD_SRC"):
        cmd += ["--old", os.environ["NURBSCAN_BENCH_OLD_SRC"]]
    cpu = subprocess.run(cmd, capture_output=True, text=True, check=True)
    out["cpu_per_stage"] = json.loads(cpu.stdout.strip().splitlines()[-1])
    for n in noises:
        out[f"noise{n:g}"] = {k: round(v, 4) for k, v in figures(paths[n]).items()}
    if 1.0 in paths:
        out["noise1_jpeg95"] = {k: round(v, 4) for k, v in figures(paths[1.0], 95).items()}
    return out


if __name__ == "__main__":
    if len(sys.argv) == 3 and sys.argv[1] == "--child":
        from nurbscan._malloc import COMMAND_MMAP_BYTES, COMMAND_TRIM_BYTES, reuse_freed_memory

        reuse_freed_memory(COMMAND_TRIM_BYTES, COMMAND_MMAP_BYTES)  # as the command's process
        sys.stdout.write(json.dumps(_timed_child(sys.argv[2])) + "\n")
    else:
        sys.stdout.write(json.dumps(bench(), indent=1) + "\n")
