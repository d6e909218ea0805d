"""Fuzz benchmark of the grid detection (issue #34): hostile and damaged photographs.

``bench()`` simulates a small scan (768 x 576 teapot, 2 views, coarse grid, with calibration
boards: 4 free poses) and derives ``$NURBSCAN_BENCH_FUZZ`` images (default 300, seeded) from
its views and boards, in eleven classes:

* ``noise``: Gaussian noise (sigma 0.02-0.3 of full scale) added;
* ``stripes``: a random sinusoidal colour stripe image (no grid);
* ``blobs``: random coloured ellipses on black (no grid);
* ``blank``: one random colour (these three at 384 x 288, ``SYNTHETIC_SIZE``);
* ``rotated``: by 90, 180 or 270 degrees, or by an angle of 30-150 degrees;
* ``flipped``: mirrored left-right, top-bottom, or transposed;
* ``cropped``: a random crop of 10-100 % of each side;
* ``occluded``: up to 4 random black, white or grey rectangles over it;
* ``gamma``: gamma 0.4-2.5 applied;
* ``jpeg``: JPEG-compressed at quality 10-90 (chroma subsampled);
* ``mixed``: a crop, a rotation or flip, noise and JPEG together.

Each image goes through :func:`nurbscan.detect.detect_grid` (with its white-light image, the
same transformation applied) in one worker process (started and its imports done before the
clock starts), with a limit of 10 s of CPU time per image: the worker measures
``time.process_time()`` (all its threads) around the detection; a detection still running
after ``WALL_LIMIT_S`` of wall time is stopped and judged by the worker's user + system time
from ``/proc``. (The machine is shared: at a load of ~14, the 60 gamma, JPEG and stripes
cases among the first 220, 4 of which were "hangs" over 10 s of wall time at a load of ~27,
took at most 1.01 s of CPU time each, and up to 29.5 s of wall time.) Over the limit is a
hang. ``$NURBSCAN_BENCH_FUZZ_SECONDS`` stops the run after
that many seconds (the figures say how many images were done). Case ``i`` is the same in
every run (one generator, seeded); ``python benchmarks/bench_fuzz.py --case i [--save DIR]``
regenerates it and times its detection on its own. A crash is any exception but
:class:`~nurbscan.errors.NurbscanError`. Where the true projector coordinates are known (the
views, transformed the same way), :func:`~nurbscan.detect.evaluate_detection` counts the
lines over 20 px labelled wrongly; a result is *wrong* when they are more than 1 % of its
lines. Targets: 0 crashes, 0 hangs, 0 wrong results.
"""

from __future__ import annotations

import collections
import functools
import multiprocessing as mp
import os
import tempfile
import time
import warnings
from pathlib import Path

import cv2
import numpy as np

CLASSES = ("noise", "stripes", "blobs", "blank", "rotated", "flipped", "cropped", "occluded",
           "gamma", "jpeg", "mixed")
TIMEOUT_S = 10.0
#: (height, width) of the images without a grid (stripes, blobs, blank): half the views' side,
#: a quarter of their work, as hostile (the 10,000-image run shares a 2-core machine).
SYNTHETIC_SIZE = (288, 384)
#: A detection still running after this wall time is stopped (and judged by its CPU time): the
#: machine is shared, and the wall time of one image under load is not its cost.
WALL_LIMIT_S = 60.0


def _scan(out: Path) -> Path:
    import nurbscan.simulate.scan as sim_scan
    from nurbscan.pattern import Pattern
    from nurbscan.simulate import target as sim_target
    from nurbscan.simulate.render import RenderSettings
    from nurbscan.simulate.rig import default_rig, scale_camera
    from nurbscan.simulate.scenes import make_scene

    free, table = sim_target.FREE_POSES, sim_scan.TABLE_POSE_ANGLES
    sim_target.FREE_POSES = tuple(free[i] for i in (1, 3, 7, 11))
    sim_scan.TABLE_POSE_ANGLES = ()
    try:
        sim_scan.simulate_scan(make_scene("teapot"), out, views=2,
                               rig=scale_camera(default_rig(), 768, 576),
                               settings=RenderSettings(samples=2),
                               pattern=Pattern.create(1920, 1080, pitch=32, band=12))
    finally:
        sim_target.FREE_POSES, sim_scan.TABLE_POSE_ANGLES = free, table
    return out


# ------------------------------------------------------------------ transformations
def _geometric(rng, a, maps, kind):
    """Apply one geometric change to the image, its white image and the truth maps."""
    H, W = a[0].shape[:2]
    if kind == "crop":
        h, w = int(rng.uniform(0.1, 1) * H) + 1, int(rng.uniform(0.1, 1) * W) + 1
        y0, x0 = int(rng.integers(0, H - h + 1)), int(rng.integers(0, W - w + 1))

        def f(x, nearest=False):
            return np.ascontiguousarray(x[y0:y0 + h, x0:x0 + w])
    elif kind in ("rot90", "rot180", "rot270"):
        k = {"rot90": 1, "rot180": 2, "rot270": 3}[kind]

        def f(x, nearest=False):
            return np.ascontiguousarray(np.rot90(x, k))
    elif kind in ("fliplr", "flipud", "transpose"):
        def f(x, nearest=False):
            y = x[:, ::-1] if kind == "fliplr" else x[::-1] if kind == "flipud" else \
                np.swapaxes(x, 0, 1)
            return np.ascontiguousarray(y)
    else:  # rotation by an angle of 30-150 degrees about the centre
        ang = float(rng.uniform(30, 150))
        M = cv2.getRotationMatrix2D(((W - 1) / 2, (H - 1) / 2), ang, 1.0)

        def f(x, nearest=False):
            flag = cv2.INTER_NEAREST if nearest else cv2.INTER_LINEAR
            y = x if x.dtype != np.bool_ else x.astype(np.uint8)
            if y.dtype == np.int32:
                y = y.astype(np.float32)
            out = cv2.warpAffine(y, M, (W, H), flags=flag, borderMode=cv2.BORDER_CONSTANT,
                                 borderValue=-1 if y.dtype.kind == "f" and nearest else 0)
            return out.astype(x.dtype) if x.dtype != np.float64 else out
    imgs = [None if x is None else f(x) for x in a]
    tm = None if maps is None else {k: f(v, nearest=True) for k, v in maps.items()}
    return imgs, tm


def _photometric(rng, img, kind):
    x = img.astype(np.float32) / 255.0
    if kind == "noise":
        x = x + rng.normal(0, rng.uniform(0.02, 0.3), x.shape).astype(np.float32)
    elif kind == "gamma":
        x = np.clip(x, 0, 1) ** rng.uniform(0.4, 2.5)
    elif kind == "occluded":
        H, W = x.shape[:2]
        for _ in range(int(rng.integers(1, 5))):
            h, w = int(rng.uniform(0.05, 0.5) * H), int(rng.uniform(0.05, 0.5) * W)
            y0, x0 = int(rng.integers(0, H - h + 1)), int(rng.integers(0, W - w + 1))
            x[y0:y0 + h, x0:x0 + w] = rng.choice([0.0, 0.5, 1.0])
    out = np.clip(np.round(x * 255), 0, 255).astype(np.uint8)
    if kind == "jpeg":
        ok, buf = cv2.imencode(".jpg", out[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY,
                                                        int(rng.integers(10, 91))])
        out = np.ascontiguousarray(cv2.imdecode(buf, cv2.IMREAD_COLOR)[..., ::-1])
    return out


def _synthetic(rng, kind, H=576, W=768):
    if kind == "blank":
        return np.full((H, W, 3), rng.integers(0, 256, 3), np.uint8)
    if kind == "stripes":
        yy, xx = np.mgrid[0:H, 0:W].astype(np.float32)
        out = np.zeros((H, W, 3), np.float32)
        for c in range(3):
            a = rng.uniform(0, np.pi)
            p = rng.uniform(6, 60)
            out[..., c] = 0.5 + 0.5 * np.sin(2 * np.pi * (np.cos(a) * xx + np.sin(a) * yy) / p)
        return (out * 255).astype(np.uint8)
    out = np.zeros((H, W, 3), np.uint8)  # blobs
    for _ in range(int(rng.integers(5, 60))):
        centre = (int(rng.integers(0, W)), int(rng.integers(0, H)))
        axes = (int(rng.integers(3, 80)), int(rng.integers(3, 80)))
        cv2.ellipse(out, centre, axes, float(rng.uniform(0, 180)), 0, 360,
                    tuple(int(v) for v in rng.integers(0, 256, 3)), -1)
    return out


def make_case(rng, bases, kind):
    """One fuzzed image: ``(name, grid, white, truth maps or None)``."""
    if kind in ("stripes", "blobs", "blank"):
        return kind, _synthetic(rng, kind, *SYNTHETIC_SIZE), None, None
    name, grid, white, maps = bases[int(rng.integers(0, len(bases)))]
    imgs, tm = [grid, white], maps
    if kind == "rotated":
        imgs, tm = _geometric(rng, imgs, tm, rng.choice(["rot90", "rot180", "rot270", "angle"]))
    elif kind == "flipped":
        imgs, tm = _geometric(rng, imgs, tm, rng.choice(["fliplr", "flipud", "transpose"]))
    elif kind == "cropped":
        imgs, tm = _geometric(rng, imgs, tm, "crop")
    elif kind == "mixed":
        imgs, tm = _geometric(rng, imgs, tm, "crop")
        imgs, tm = _geometric(rng, imgs, tm, rng.choice(["rot90", "rot180", "rot270",
                                                         "fliplr", "flipud", "angle"]))
        imgs[0] = _photometric(rng, _photometric(rng, imgs[0], "noise"), "jpeg")
    else:
        imgs[0] = _photometric(rng, imgs[0], kind)
    return name, imgs[0], imgs[1], tm


# ------------------------------------------------------------------ worker
def _detect(args):
    """In the worker: detect, and evaluate against the truth when given."""
    grid, white, maps, pattern_path = args
    from nurbscan.detect import detect_grid, evaluate_detection
    from nurbscan.errors import NurbscanError

    pat = _pattern(pattern_path)
    t0, c0 = time.perf_counter(), time.process_time()

    def took():
        return {"s": time.process_time() - c0, "wall_s": time.perf_counter() - t0}

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            det = detect_grid(grid, pat, white)
    except NurbscanError as exc:
        return {"status": "refused", "reason": str(exc), **took()}
    except Exception as exc:  # noqa: BLE001 - a crash is what is counted
        return {"status": "crash", "reason": f"{type(exc).__name__}: {exc}", **took()}
    out = {"status": "empty" if det.nlines == 0 else "lines", "lines": int(det.nlines),
           **took()}
    if det.nlines and maps is not None:
        ev = evaluate_detection(det, maps, pat)
        out["wrong20"] = int(ev["wrong_lines_over_20px"])
    return out


@functools.lru_cache(maxsize=2)
def _pattern(path: str):
    from nurbscan.pattern import load_pattern

    return load_pattern(path)


def _warm_up() -> None:
    """In a new worker: import what :func:`_detect` needs."""
    import nurbscan.detect  # noqa: F401
    import nurbscan.pattern  # noqa: F401


class _Worker:
    """One spawned worker process for the detections, replaced when one hangs."""

    def __init__(self):
        # the worker imports this file by its name (run.py loads it under another one)
        import sys

        sys.path.insert(0, str(Path(__file__).resolve().parent))
        import bench_fuzz

        self.fn, self.warm = bench_fuzz._detect, bench_fuzz._warm_up
        self.pool = self._start()

    def _start(self):
        # the worker's start (imports) is not the detection's time: a first run of 10 s
        # limits on a loaded machine counted the start of each new worker as a hang
        pool = mp.get_context("spawn").Pool(1)
        pool.apply(self.warm)
        return pool

    def _cpu_s(self) -> float:
        """CPU time (user + system) the worker process has used so far, s (Linux /proc)."""
        try:
            pid = self.pool._pool[0].pid
            fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
            return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
        except (OSError, IndexError, ValueError, AttributeError):
            return float("nan")

    def run(self, args, cpu_limit: float, wall_limit: float):
        """The detection's result; a detection still running after ``wall_limit`` s (wall) is
        stopped, and is a hang when its CPU time went over ``cpu_limit`` s."""
        cpu0 = self._cpu_s()
        r = self.pool.apply_async(self.fn, (args,))
        try:
            out = r.get(wall_limit)
        except mp.TimeoutError:
            cpu = self._cpu_s() - cpu0
            self.pool.terminate()
            self.pool.join()
            self.pool = self._start()
            return {"status": "hang", "s": cpu, "wall_s": wall_limit,
                    "reason": f"stopped after {wall_limit:.0f} s wall, {cpu:.1f} s CPU"}
        if out.get("s", 0.0) > cpu_limit:
            out = {**out, "status": "hang", "reason": f"{out['s']:.1f} s CPU",
                   "was": out["status"]}
        return out

    def close(self):
        self.pool.terminate()
        self.pool.join()


def load_bases(scan: Path) -> tuple[list, str]:
    """The images the cases are derived from: ``[(name, grid, white, truth maps or None)]``
    (the 2 views with their truth, the 4 calibration boards), and the pattern's path."""
    from nurbscan.io import read_image

    bases = []
    for v in (0, 1):
        with np.load(scan / "truth" / f"view_{v:02d}.npz") as z:
            maps = {k: z[k] for k in ("proj_x", "proj_y", "lit", "surface_id")}
        bases.append((f"view {v}", read_image(scan / "views" / f"view_{v:02d}_grid.png",
                                              as_float=False),
                      read_image(scan / "views" / f"view_{v:02d}_white.png",
                                 as_float=False), maps))
    for g in sorted((scan / "calibration").glob("pose_*_grid.png")):
        w = g.with_name(g.name.replace("_grid", "_white"))
        bases.append((f"board {g.stem}", read_image(g, as_float=False),
                      read_image(w, as_float=False), None))
    return bases, str(scan / "pattern.json")


def cases(bases, n: int):
    """The ``n`` seeded cases in order: ``(i, class, (name, grid, white, maps))``; case i is
    the same whatever ``n`` (one generator seeded 34, the classes in turn)."""
    rng = np.random.default_rng(34)
    for i in range(n):
        kind = CLASSES[i % len(CLASSES)]
        yield i, kind, make_case(rng, bases, kind)


def bench() -> dict:
    n = int(os.environ.get("NURBSCAN_BENCH_FUZZ", "300"))
    # a run that must end by a given time stops there and says how many it did
    stop_after = float(os.environ.get("NURBSCAN_BENCH_FUZZ_SECONDS", "inf"))
    with tempfile.TemporaryDirectory() as tmp:
        bases, pattern = load_bases(_scan(Path(tmp) / "scan"))
        counts = {c: {"images": 0, "lines": 0, "refused_or_empty": 0, "crash": 0, "hang": 0,
                      "with_truth": 0, "wrong_results": 0, "wrong_lines": 0,
                      "lines_with_truth": 0} for c in CLASSES}
        examples, times, walls = [], [], []
        worker = _Worker()
        t_all = time.perf_counter()
        done = 0
        try:
            for i, kind, (name, grid, white, maps) in cases(bases, n):
                if time.perf_counter() - t_all > stop_after:
                    break
                r = worker.run((grid, white, maps, pattern), TIMEOUT_S, WALL_LIMIT_S)
                done += 1
                c = counts[kind]
                c["images"] += 1
                times.append(r["s"])
                walls.append(r["wall_s"])
                if r["status"] in ("crash", "hang"):
                    c[r["status"]] += 1
                    examples.append(f"case {i}, {kind} of {name}: {r['status']} "
                                    f"{r.get('reason', '')}")
                elif r["status"] in ("refused", "empty"):
                    c["refused_or_empty"] += 1
                else:
                    c["lines"] += 1
                if "wrong20" in r:
                    c["with_truth"] += 1
                    c["lines_with_truth"] += r["lines"]
                    c["wrong_lines"] += r["wrong20"]
                    if r["wrong20"] > 0.01 * r["lines"]:
                        c["wrong_results"] += 1
                        if len(examples) < 40:
                            examples.append(f"case {i}, {kind} of {name}: {r['wrong20']} of "
                                            f"{r['lines']} lines wrong")
        finally:
            worker.close()
    tot = {k: sum(c[k] for c in counts.values()) for k in next(iter(counts.values()))}
    return {"images": done, "images_asked": n, "crashes": tot["crash"],
            "hangs_over_10s": tot["hang"], "hang_rule": "the detection's CPU time "
            "(time.process_time() in the worker; /proc user + system time when stopped after "
            f"{WALL_LIMIT_S:.0f} s wall) over {TIMEOUT_S:.0f} s",
            "wrong_results": tot["wrong_results"],
            "results_with_truth": tot["with_truth"],
            "wrong_result_share": round(tot["wrong_results"] / max(tot["with_truth"], 1), 4),
            "wrong_lines_share": round(tot["wrong_lines"] / max(tot["lines_with_truth"], 1), 4),
            "refused_or_empty": tot["refused_or_empty"],
            "max_detect_cpu_s": round(max(times, default=0.0), 2),
            "median_detect_cpu_s": round(float(np.median(times)) if times else 0.0, 3),
            "median_detect_wall_s": round(float(np.median(walls)) if walls else 0.0, 3),
            "wall_s": round(time.perf_counter() - t_all, 1),
            "per_class": counts, "examples": examples[:40]}


def one_case(index: int, scan: Path, save: Path | None = None) -> dict:
    """Regenerate case ``index`` from a cached scan (made if missing) and detect it in this
    process, timed (CPU and wall); with ``save``, write its grid and white images there."""
    if not (scan / "pattern.json").exists():
        _scan(scan)
    bases, pattern = load_bases(scan)
    # the last of the first index + 1 cases, the others dropped as they are made (memory)
    _, kind, (name, grid, white, maps) = collections.deque(cases(bases, index + 1), maxlen=1)[0]
    if save is not None:
        save.mkdir(parents=True, exist_ok=True)
        for tag, im in (("grid", grid), ("white", white)):
            cv2.imwrite(str(save / f"case_{index}_{tag}.png"), im[..., ::-1])
    r = _detect((grid, white, maps, pattern))
    return {"case": index, "class": kind, "base": name, "size": list(grid.shape[:2]), **r}


if __name__ == "__main__":
    import argparse
    import json

    ap = argparse.ArgumentParser(description="the fuzz benchmark, or one case of it")
    ap.add_argument("--case", type=int, nargs="*", help="regenerate and time these cases")
    ap.add_argument("--scan", type=Path, default=Path(tempfile.gettempdir()) / "fuzz-scan",
                    help="the simulated scan the cases derive from (made once, cached)")
    ap.add_argument("--save", type=Path, help="write the cases' images to this folder")
    a = ap.parse_args()
    if a.case is None:
        print(json.dumps(bench(), indent=1))
    for k in a.case or ():
        print(json.dumps(one_case(k, a.scan, a.save)), flush=True)
