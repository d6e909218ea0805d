"""Benchmark of ``nurbscan batch`` (issue 36): many scans on a Dask LocalCluster.

1. Four small scans (1024 x 768 camera, 4 views each, the teapot with noise seeds 0-3) are
   run serially (every task in order in one process, :func:`nurbscan.batch.run_batch` with
   ``serial=True``) and on a ``LocalCluster`` of 2 single-threaded workers. The outputs must be
   identical (sha256 of each model's arrays), and the cluster's wall time is compared with the
   serial tasks' own time summed over 2 workers (target: within 1.2 x). Both run twice,
   alternating, and each mode's best round is compared (:data:`ROUNDS`); every round's ratio
   and the host's steal share of the CPU during each run are reported beside it. Each round
   also runs the machine's own bound without a scheduler (:func:`_serial_pair`): two serial
   processes side by side, each on half the scans, started and importing as the workers do;
   its ratio by the same measure is what any two-worker schedule of these tasks could reach
   in that round, so the cluster's excess over it is what Dask costs.
2. The per-task figures for a full-size scan: one 7.1 MP view (3072 x 2304, the default rig)
   and the finish task of a 2-view 7.1 MP scan, each run in a fresh process for its time and
   peak resident memory (``VmHWM`` reset after the imports, less the process's then), and
   the size of a view's result (what Dask sends from a view's worker to the scan's).
3. A scaling model from those figures: 1,000 scans of 24 views at 7.1 MP on N workers.

The machine may be shared (load average in the figures): the times are then the machine's
at that load, not the code's alone.

Usage: ``python benchmarks/bench_batch.py [WORKDIR]`` (scans are reused when present), or
through ``python benchmarks/run.py batch``.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

SCANS = 4
VIEWS = 4
SIZE = (1024, 768)
WORKERS = 2
#: Rounds of the small batch (serial, then the LocalCluster): on a shared VM a run's times vary
#: by 10-70 % from run to run (the host's other guests), so each mode's best round is compared.
ROUNDS = 3
MODEL_SCANS, MODEL_VIEWS = 1000, 24


def model_hash(folder) -> str:
    """sha256 of a model folder's geometry, not its times (:meth:`Model.geometry_digest`)."""
    from nurbscan.reconstruct import load_model

    return load_model(folder).geometry_digest()


def make_scans(root: Path) -> list[Path]:
    """Four 1024 x 768, 4-view teapot scans (noise seeds 0-3) and their calib.json (true rig)."""
    from nurbscan.pattern import Pattern
    from nurbscan.simulate.render import RenderSettings
    from nurbscan.simulate.rig import default_rig, scale_camera
    from nurbscan.simulate.scan import simulate_scan
    from nurbscan.simulate.scenes import make_scene

    rig = scale_camera(default_rig(), *SIZE)
    out = []
    for k in range(SCANS):
        scan = root / "scans" / f"teapot{k}"
        if not (scan / "scan.json").exists():
            simulate_scan(make_scene("teapot"), scan, views=VIEWS, rig=rig, calibration=False,
                          settings=RenderSettings(samples=2), seed=k,
                          pattern=Pattern.create(1920, 1080, pitch=32, band=12))
        out.append(scan)
    calib = root / "calib.json"
    shutil.copy(out[0] / "truth" / "rig.json", calib)
    return out


def task_seconds(summary: dict, cpu: bool = False) -> dict:
    """The tasks' own wall (or CPU) times summed over the batch, s, by kind."""
    t = {"calibration": 0.0, "plan": 0.0, "view": 0.0, "finish": 0.0}
    for r in summary["scans"]:
        k = r["tasks"]
        if cpu:
            c = k["cpu_s"]
            t["calibration"] += c["calibration"]
            t["plan"] += c["plan"]
            t["view"] += sum(c["view"])
            t["finish"] += c["finish"]
            continue
        t["calibration"] += k["calibration_s"]
        t["plan"] += k["plan_s"]
        t["view"] += sum(k["view_s"])
        t["finish"] += k["finish_s"]
    return t


def list_schedule(summary: dict, workers: int = WORKERS) -> float:
    """Makespan (s) of the batch's task graph on ``workers`` with the tasks' measured times.

    Greedy list scheduling as Dask orders the tasks (:func:`nurbscan.batch._submit_scan`):
    whenever a worker is free it takes the ready task of highest priority (earlier scans
    first, a scan's finish task after the views of the next ``finish_lead(workers)`` scans),
    ties in the order submitted (calibration, plan, views, finish); no transfer or start-up
    cost. With the serial run's times this is the wall time a perfect cluster would take for
    this graph: the part of ``wall / (serial tasks' time / 2)`` above 1 that comes from the
    graph itself (a scan's finish task runs after all its views).
    """
    import heapq

    from nurbscan.batch import finish_lead

    lead = finish_lead(workers)
    tasks = {}  # (scan, order) -> (seconds, dependencies, priority)
    for i, r in enumerate(summary["scans"]):
        k = r["tasks"]
        n = len(k["view_s"])
        tasks[(i, 0)] = (k["calibration_s"], [], -2 * i)
        tasks[(i, 1)] = (k["plan_s"], [(i, 0)], -2 * i)
        for j, t in enumerate(k["view_s"]):
            tasks[(i, 2 + j)] = (t, [(i, 1)], -2 * i)
        tasks[(i, 2 + n)] = (k["finish_s"], [(i, 2 + j) for j in range(n)], -2 * (i + lead) - 1)
    done: dict = {}
    free = [0.0] * workers
    todo = set(tasks)
    while todo:
        t = heapq.heappop(free)
        ready = [x for x in todo if all(d in done and done[d] <= t for d in tasks[x][1])]
        if not ready:  # wait for the next task to finish
            later = [v for v in done.values() if v > t]
            heapq.heappush(free, min(later) if later else t)
            continue
        x = min(ready, key=lambda x: (-tasks[x][2], x))
        todo.remove(x)
        done[x] = t + tasks[x][0]
        heapq.heappush(free, done[x])
    return max(done.values())


def loadavg() -> str:
    return " ".join(f"{x:.1f}" for x in os.getloadavg())


def cpu_ticks() -> tuple[int, int]:
    """(steal, all) CPU ticks of this machine so far (``/proc/stat``; (0, 0) elsewhere): the
    steal share is the time the host gave the machine's cores to other guests, which makes a
    run's times grow without the code changing (on this VM from 2 to 15 % run to run)."""
    try:
        with open("/proc/stat") as f:
            ticks = [int(x) for x in f.readline().split()[1:]]
    except (OSError, ValueError):
        return 0, 0
    return (ticks[7] if len(ticks) > 7 else 0), sum(ticks[:8])


def steal_share(before: tuple[int, int]) -> float:
    """The steal share of the CPU ticks since ``before`` (:func:`cpu_ticks`)."""
    s, a = cpu_ticks()
    return round((s - before[0]) / max(a - before[1], 1), 4)


def small_batch(root: Path) -> dict:
    """Part 1: serial vs LocalCluster of 2 on four 1024 x 768 scans."""
    from nurbscan.batch import BatchOptions, run_batch

    scans = make_scans(root)
    opts = BatchOptions(exports=("glb",), evaluate=False)
    out = {}
    rounds = []
    for _ in range(ROUNDS):  # alternating, so that both modes see the machine's changes
        runs = {}
        for mode in ("serial", "dask"):
            dest = root / f"out_{mode}"
            shutil.rmtree(dest, ignore_errors=True)
            load0, ticks0 = loadavg(), cpu_ticks()
            t0 = time.perf_counter()
            s = run_batch(scans, dest, calib=root / "calib.json", options=opts,
                          serial=mode == "serial", workers=WORKERS)
            wall = time.perf_counter() - t0
            assert s["ok"] == SCANS, s
            runs[mode] = {"wall": wall, "tasks": task_seconds(s),
                          "load": f"{load0} -> {loadavg()}", "steal": steal_share(ticks0),
                          "start": s.get("cluster_start_s", 0.0),
                          "cpu": task_seconds(s, cpu=True),
                          "hashes": [model_hash(dest / p.name / "model") for p in scans],
                          "summary": s}
        runs["pair"] = _serial_pair(scans, root)
        rounds.append(runs)
    # the best round of each mode (the serial one by its tasks' time, the figure's reference)
    runs = {"serial": min((r["serial"] for r in rounds), key=lambda r: sum(r["tasks"].values())),
            "dask": min((r["dask"] for r in rounds), key=lambda r: r["wall"])}
    out["rounds (serial then LocalCluster, alternating); the best of each below"] = ROUNDS
    out["each round: wall / (serial tasks' time / 2)"] = [
        round(r["dask"]["wall"] / (sum(r["serial"]["tasks"].values()) / WORKERS), 3)
        for r in rounds]
    out["each round: two serial processes side by side (half the scans each), wall / (serial "
        "tasks' time / 2): the machine's bound"] = [
        round(r["pair"]["wall"] / (sum(r["serial"]["tasks"].values()) / WORKERS), 3)
        for r in rounds]
    out["each round: the cluster's wall over the side-by-side pair's"] = [
        round(r["dask"]["wall"] / r["pair"]["wall"], 3) for r in rounds]
    out["each round: the side-by-side pair's tasks' time over the serial run's"] = [
        round(sum(r["pair"]["tasks"].values()) / sum(r["serial"]["tasks"].values()), 3)
        for r in rounds]
    out["each round: the host's steal share of the CPU (serial, cluster, pair)"] = [
        [round(r[m]["steal"], 4) for m in ("serial", "dask", "pair")] for r in rounds]
    out["every run's models identical"] = all(
        r[m]["hashes"] == rounds[0]["serial"]["hashes"] for r in rounds for m in r)
    runs["serial_one_core"] = _serial_one_core(scans, root)
    ser, dk = runs["serial"], runs["dask"]
    t_ser = sum(ser["tasks"].values())
    t_dk = sum(dk["tasks"].values())
    out["scans x views, camera"] = f"{SCANS} x {VIEWS}, {SIZE[0]} x {SIZE[1]}"
    out["outputs identical to the serial run (models' sha256)"] = ser["hashes"] == dk["hashes"]
    out["serial: wall (s)"] = ser["wall"]
    out["serial: tasks' own time summed (s)"] = t_ser
    out["serial: per task kind summed (s)"] = {k: round(v, 3) for k, v in ser["tasks"].items()}
    out["serial: load average (1, 5, 15 min) before -> after"] = ser["load"]
    out["serial: the host's steal share of the CPU"] = ser["steal"]
    out[f"LocalCluster({WORKERS}): wall (s)"] = dk["wall"]
    out[f"LocalCluster({WORKERS}): tasks' own time summed (s)"] = t_dk
    out[f"LocalCluster({WORKERS}): load average before -> after"] = dk["load"]
    out[f"LocalCluster({WORKERS}): the host's steal share of the CPU"] = dk["steal"]
    out[f"LocalCluster({WORKERS}): of which starting the cluster (s)"] = dk["start"]
    out["serial: tasks' CPU time summed (s)"] = sum(ser["cpu"].values())
    out[f"LocalCluster({WORKERS}): tasks' CPU time summed (s)"] = sum(dk["cpu"].values())
    out["wall / (serial tasks' time / 2)"] = dk["wall"] / (t_ser / WORKERS)
    out["wall less the cluster's start / (serial tasks' time / 2)"] = (
        (dk["wall"] - dk["start"]) / (t_ser / WORKERS))
    out["wall / (cluster tasks' time / 2)"] = dk["wall"] / (t_dk / WORKERS)
    one = runs["serial_one_core"]
    t_one = sum(one["tasks"].values())
    out["serial on one core: outputs identical"] = one["hashes"] == dk["hashes"]
    out["serial on one core: tasks' own time summed (s)"] = t_one
    out["serial on one core: load average before -> after"] = one["load"]
    out["serial on one core: the host's steal share of the CPU"] = one["steal"]
    out["wall / (serial on one core / 2)"] = dk["wall"] / (t_one / WORKERS)
    out["wall less the cluster's start / (serial on one core / 2)"] = (
        (dk["wall"] - dk["start"]) / (t_one / WORKERS))
    best = list_schedule(ser["summary"])
    out[f"the graph on {WORKERS} perfect workers with the serial tasks' times (s)"] = best
    out["that / (serial tasks' time / 2): the graph's own bound"] = best / (t_ser / WORKERS)
    return out


SERIAL_CHILD = """
import sys
from nurbscan.batch import BatchOptions, run_batch
scans, out, calib = sys.argv[1].split("|"), sys.argv[2], sys.argv[3]
s = run_batch(scans, out, calib=calib, options=BatchOptions(exports=("glb",), evaluate=False),
              serial=True)
assert s["ok"] == len(scans), s
"""


def _serial_pair(scans: list[Path], root: Path) -> dict:
    """Two serial runs side by side, in fresh processes, on alternate scans (half each; the
    scans are alike, so the halves are balanced): the time two processes of this machine take
    for the batch with no scheduler, no transfers and no task placement, from their start
    (interpreter and imports included, as a worker's) to the later one's end. Its wall time
    bounds what a two-worker cluster can reach on the machine at that moment; its tasks' time
    over the serial run's measures how much slower the tasks run when both cores work."""
    dests = [root / f"out_pair_{i}" for i in range(WORKERS)]
    for d in dests:
        shutil.rmtree(d, ignore_errors=True)
    load0, ticks0 = loadavg(), cpu_ticks()
    t0 = time.perf_counter()
    procs = [subprocess.Popen([sys.executable, "-c", SERIAL_CHILD,
                               "|".join(map(str, scans[i::WORKERS])), str(d),
                               str(root / "calib.json")],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                              env=os.environ.copy())
             for i, d in enumerate(dests)]
    errs = [p.communicate()[1] for p in procs]
    wall = time.perf_counter() - t0
    for p, err in zip(procs, errs, strict=True):
        if p.returncode:
            raise RuntimeError(f"serial run side by side failed: {err[-2000:]}")
    tasks: dict[str, float] = {}
    hashes = {}
    for i, d in enumerate(dests):
        for k, v in task_seconds(json.loads((d / "batch.json").read_text())).items():
            tasks[k] = tasks.get(k, 0.0) + v
        for p in scans[i::WORKERS]:
            hashes[p.name] = model_hash(d / p.name / "model")
    return {"wall": wall, "tasks": tasks, "load": f"{load0} -> {loadavg()}",
            "steal": steal_share(ticks0), "hashes": [hashes[p.name] for p in scans]}


def _serial_one_core(scans: list[Path], root: Path) -> dict:
    """The serial run in a process bound to one core (``sched_setaffinity`` before exec, so
    that OpenCV's and Open3D's threads share it): the time one worker's core takes for the
    tasks, the reference of a cluster whose workers each have one core (the in-process serial
    run may use the second core in OpenCV's filters and Open3D's Poisson solver)."""
    dest = root / "out_serial_one_core"
    shutil.rmtree(dest, ignore_errors=True)
    load0, ticks0 = loadavg(), cpu_ticks()
    t0 = time.perf_counter()
    r = subprocess.run([sys.executable, "-c", SERIAL_CHILD, "|".join(map(str, scans)),
                        str(dest), str(root / "calib.json")], capture_output=True, text=True,
                       env=os.environ.copy(), preexec_fn=lambda: os.sched_setaffinity(0, {0}))
    wall = time.perf_counter() - t0
    if r.returncode:
        raise RuntimeError(f"serial run on one core failed: {r.stderr[-2000:]}")
    s = json.loads((dest / "batch.json").read_text())
    return {"wall": wall, "tasks": task_seconds(s), "load": f"{load0} -> {loadavg()}",
            "steal": steal_share(ticks0),
            "hashes": [model_hash(dest / p.name / "model") for p in scans], "summary": s}


CHILD = """
import json, sys, time, pickle
import warnings; warnings.simplefilter("ignore")
from pathlib import Path
from nurbscan.batch import BatchOptions
from nurbscan.batch.tasks import ScanJob, calibration_task, plan_task, view_task, finish_task
from nurbscan.merge.fusion import fuse_model  # noqa: F401 (import cost outside the task)
from nurbscan.evaluate import evaluate_model  # noqa: F401
from nurbscan.export import export_model  # noqa: F401
what, scan, calib, out = sys.argv[1], Path(sys.argv[2]), Path(sys.argv[3]), Path(sys.argv[4])
opts = BatchOptions(exports=("glb", "3dm"), evaluate=True)
job = ScanJob(scan.name, scan, out / scan.name, calib)
c = calibration_task(job); p = plan_task(job, c, opts)
if what == "finish":  # the views' results come from a file written by an earlier run
    views = pickle.loads((out / "views.pkl").read_bytes())
def hwm():  # peak resident memory of this process, MB (VmHWM; ru_maxrss survives exec)
    for ln in open("/proc/self/status"):
        if ln.startswith("VmHWM:"):
            return int(ln.split()[1]) / 1024.0
def rss():
    for ln in open("/proc/self/status"):
        if ln.startswith("VmRSS:"):
            return int(ln.split()[1]) / 1024.0
try:  # reset the peak to the present (Linux >= 4.0), so that the peak is this task's
    open("/proc/self/clear_refs", "w").write("5")
except OSError:
    pass
base = rss()
t0 = time.perf_counter()
if what == "view":
    v = view_task(p, 0)
    assert v.ok, v.value
    res = {"seconds": v.seconds, "cpu_seconds": v.cpu_seconds,
           "bytes": len(pickle.dumps(v, protocol=5))}
    views = [v] + [view_task(p, k) for k in range(1, len(p.value.tasks))]
    (out / "views.pkl").write_bytes(pickle.dumps(views, protocol=5))
else:
    r = finish_task(job, opts, c, p, *views)
    assert r["status"] == "ok", r
    res = {"seconds": time.perf_counter() - t0, "parts": r["tasks"]["finish_parts_s"],
           "cpu_seconds": r["tasks"]["cpu_s"]["finish"],
           "patches": r["counts"]["gordon"]}
res["peak_mb"] = hwm()
res["base_mb"] = base
print("@@" + json.dumps(res))
"""


def _child(what: str, scan: Path, calib: Path, out: Path) -> dict:
    r = subprocess.run([sys.executable, "-c", CHILD, what, str(scan), str(calib), str(out)],
                       capture_output=True, text=True, env=os.environ.copy())
    line = [ln for ln in r.stdout.splitlines() if ln.startswith("@@")]
    if r.returncode or not line:
        raise RuntimeError(f"{what} task failed: {r.stderr[-2000:]}")
    return json.loads(line[-1][2:])


def full_size_tasks(root: Path) -> dict:
    """Part 2: a 7.1 MP view task and the finish task of a 2-view 7.1 MP scan."""
    from nurbscan.simulate.scan import simulate_scan
    from nurbscan.simulate.scenes import make_scene

    scan = root / "full" / "teapot"
    if not (scan / "scan.json").exists():
        simulate_scan(make_scene("teapot"), scan, views=2, calibration=False)
    calib = root / "full" / "calib.json"
    shutil.copy(scan / "truth" / "rig.json", calib)
    out = root / "full" / "out"
    shutil.rmtree(out, ignore_errors=True)
    out.mkdir(parents=True)
    view = _child("view", scan, calib, out)
    fin = _child("finish", scan, calib, out)
    return {"view": view, "finish": fin, "load": loadavg()}


def scaling_model(small: dict, full: dict) -> dict:
    """Part 3: 1,000 scans of 24 views at 7.1 MP on N workers, from the measured task times.

    Work W = scans x (views x t_view + t_finish(views)); the finish task's time is taken as
    linear in the views (measured on 2 views: t_finish(24) = 12 t_finish(2)), without its
    evaluation (a real scan has no truth). T(N) = W / N while the views of the
    scans outnumber the workers (24,000 view tasks here): Dask keeps every worker busy, and
    the measured LocalCluster overhead (wall / (tasks / 2)) is applied as is.
    """
    # CPU seconds: on this shared machine the wall time is mostly the others' load; a worker
    # with a core of its own runs a task in about its CPU time (less where OpenCV threads)
    v, f = full["view"], full["finish"]
    tv = v.get("cpu_seconds", v["seconds"])
    # a real scan has no truth/: its finish task does not evaluate (its share of the wall time
    # is taken off the CPU time)
    share = 1.0 - f["parts"].get("evaluate_s", 0.0) / max(f["seconds"], 1e-9)
    tf = f.get("cpu_seconds", f["seconds"]) * share * MODEL_VIEWS / 2
    per_scan = MODEL_VIEWS * tv + tf
    W = MODEL_SCANS * per_scan
    cpu_ser = small.get("serial: tasks' CPU time summed (s)")
    cpu_dk = small.get(f"LocalCluster({WORKERS}): tasks' CPU time summed (s)")
    # the extra CPU the same tasks took on the cluster (its scheduling costs a few ms a task)
    over = max(1.0, cpu_dk / cpu_ser) if cpu_ser else max(
        1.0, small["wall / (serial tasks' time / 2)"])
    table = {}
    for n in (1, 2, 8, 32, 128, 512):
        hours = W * over / n / 3600
        table[f"N = {n}"] = {"hours": round(hours, 2),
                             "scans per hour": round(MODEL_SCANS / hours, 1)}
    return {"per view task, CPU (s)": tv,
            "per scan finish task without evaluation, 24 views, CPU (s, linear model)": tf,
            "per scan, all tasks (s)": per_scan, "work for 1,000 scans (CPU h)": W / 3600,
            "overhead factor applied (cluster / serial CPU, >= 1)": over,
            "time on N workers": table}


def bench(workdir: str | None = None) -> dict:
    root = Path(workdir or os.environ.get("NURBSCAN_BENCH_BATCH_DIR")
                or tempfile.mkdtemp(prefix="nurbscan-bench-batch-"))
    root.mkdir(parents=True, exist_ok=True)
    small = small_batch(root)
    full = full_size_tasks(root)
    v, f = full["view"], full["finish"]
    res = {"small batch": small,
           "7.1 MP tasks": {
               "view task (s)": v["seconds"],
               "view task CPU (s)": v.get("cpu_seconds"),
               "view task: peak RSS above the imports (MB)": v["peak_mb"] - v["base_mb"],
               "view task: process peak RSS (MB)": v["peak_mb"],
               "view result sent to the scan's worker (MB)": v["bytes"] / 2**20,
               "finish task, 2 views (s)": f["seconds"],
               "finish task, 2 views, CPU (s)": f.get("cpu_seconds"),
               "finish task parts (s)": f["parts"],
               "finish task: peak RSS above the imports (MB)": f["peak_mb"] - f["base_mb"],
               "finish task: process peak RSS (MB)": f["peak_mb"],
               "load average at the end": full["load"]},
           "scaling model": scaling_model(small, full)}
    return res


if __name__ == "__main__":
    print(json.dumps(bench(sys.argv[1] if len(sys.argv) > 1 else None), indent=1,
                     default=float))
