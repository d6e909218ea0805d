"""Many scans at once, on this machine or a cluster, with Dask (``dask.distributed``).

:func:`run_batch` reconstructs, exports and (where the scan has ``truth/``) evaluates every scan
of a list into one output folder. Each scan is a small graph of tasks
(:mod:`nurbscan.batch.tasks`): its calibration, its plan, one task per view and one that
finishes the scan. The tasks carry paths, not images: a worker reads a view's photographs from
the scan folder itself, so every worker must see the scan folders and the output folder at the
same paths (a shared folder; docs/scaling.md). Dask schedules them on a ``LocalCluster`` of
``workers`` processes, or on the cluster whose scheduler is at ``scheduler``; a worker that dies
has its tasks run again elsewhere (Dask keeps each task's inputs, ``allowed-failures``).

The view and scan tasks are the code ``nurbscan reconstruct`` runs
(:func:`nurbscan.reconstruct.pipeline.run_view`, :func:`~nurbscan.reconstruct.pipeline.
assemble_scan`), so a scan's model is the same whichever way it ran.

Output: ``OUT/NAME/`` per scan (NAME: the scan folder's name): ``model/`` (the model folder),
``model.glb``, ``model.3dm`` (``exports``), ``calib.json`` (calibrated here),
``evaluation.json`` and ``.md`` (with truth) and ``batch.json`` (the scan's report, written
last). The folder is written as ``OUT/.NAME.partial`` and renamed when complete. A re-run
skips the scans whose report says ``ok``. ``OUT/batch.json`` lists every scan's status.
"""

from __future__ import annotations

import contextlib
import logging
import os
import shutil
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path

from ..errors import NurbscanError
from .tasks import (
    BatchOptions,
    ScanJob,
    TaskError,
    Timed,
    calibration_task,
    finish_task,
    is_complete,
    plan_task,
    read_report,
    view_task,
)

__all__ = [
    "BatchOptions",
    "ScanJob",
    "TaskError",
    "Timed",
    "is_complete",
    "read_report",
    "run_batch",
    "scan_jobs",
]

#: Where to install Dask from, in the one-line error when it is missing.
NEEDS_DASK = "needs dask.distributed (pip install 'nurbscan[batch]')"

#: The LocalCluster scheduler's guess of each kind of task's time (s, by key prefix) before
#: it has seen one finish: a 1024 x 768 view task takes about 1.2 s and its 4-view scan's
#: finish task about 8 s (7.1 MP: 8 s and 44 s for 2 views); only the ratio matters, and only
#: until the first task of each kind has finished (Dask then uses the measured times). Without
#: them Dask takes 0.5 s for the finish task it has not timed yet, so that a worker that has
#: just started one looks the less busy and is handed the next scan's finish task too: the
#: small batch then ran two finish tasks one after the other on one worker while the other
#: idled at the end (``benchmarks/bench_batch.py``).
TASK_SECONDS = {"nurbscan-calibration": 0.01, "nurbscan-plan": 0.01, "nurbscan-view": 1.0,
                "nurbscan-finish": 8.0}
#: Dask settings of the ``LocalCluster``: the workers' sampling profiler (a walk of the task's
#: stack every 10 ms) is off, the tasks' times are in each scan's report; the event loops'
#: tick, which only measures how late the loop runs (for the "event loop unresponsive"
#: warning), every second instead of every 20 ms: the scheduler's process then takes 0.26 s
#: of CPU instead of 0.78 s per 10 s idle, and the small batch's 1.0-1.2 s instead of 2.0-3.2 s
#: (each worker's event loop ticked as often, taking the interpreter lock from its task 50
#: times a second); and the scheduler's guesses of the task times (:data:`TASK_SECONDS`).
CLUSTER_CONFIG = {"distributed.worker.profile.enabled": False,
                  "distributed.admin.tick.interval": "1s",
                  "distributed.scheduler.default-task-durations": {
                      k: f"{s}s" for k, s in TASK_SECONDS.items()}}
#: What each worker runs when it starts (``dask worker --preload``): glibc's memory reuse as in
#: ``nurbscan reconstruct``, and the tasks' imports (:mod:`nurbscan.batch.preload`).
WORKER_PRELOAD = ("nurbscan.batch.preload",)


def scan_jobs(scans: Sequence[str | os.PathLike], out: str | os.PathLike,
              calib: str | os.PathLike | None = None) -> list[ScanJob]:
    """One :class:`ScanJob` per scan folder: output ``out / name`` (the folder's name), rig
    ``calib``, else the scan's own ``calib.json``, else None (calibrate from its images).

    Two scans of one name are refused (:class:`NurbscanError`), as is a missing folder.
    """
    jobs, names = [], {}
    out = Path(out).resolve()
    for s in scans:
        scan = Path(s).resolve()
        if not scan.is_dir():
            raise NurbscanError(f"{s}: not a folder (expected a scan folder with scan.json)")
        if scan.name in names:
            raise NurbscanError(f"{s}: the same name as {names[scan.name]} (each scan's output "
                                f"folder is OUT/{scan.name}; rename one)")
        names[scan.name] = s
        own = scan / "calib.json"
        rig = Path(calib).resolve() if calib is not None else own if own.is_file() else None
        jobs.append(ScanJob(scan.name, scan, out / scan.name, rig))
    if calib is not None and not Path(calib).is_file():
        raise NurbscanError(f"{calib}: file not found")
    return jobs


def _view_count(job: ScanJob) -> int | TaskError:
    """Views in the scan's ``scan.json`` (the graph has one task per view), or its error."""
    from ..io.atomic import read_json

    try:
        doc = read_json(job.scan / "scan.json")
        if not isinstance(doc, dict) or not isinstance(doc.get("views"), list):
            raise NurbscanError(f"{job.scan / 'scan.json'}: not a nurbscan scan (no views)")
    except NurbscanError as exc:
        return TaskError("scan", str(exc))
    return len(doc["views"])


def require_dask():
    """The ``distributed`` module, or a one-line :class:`NurbscanError` naming the extra."""
    try:
        import distributed
    except ImportError:
        raise NurbscanError(f"nurbscan batch {NEEDS_DASK}") from None
    return distributed


@contextlib.contextmanager
def dask_client(scheduler: str | None = None, workers: int = 2) -> Iterator:
    """A ``distributed.Client``: of the cluster at ``scheduler``, or of a ``LocalCluster`` of
    ``workers`` single-threaded worker processes on this machine (closed on exit)."""
    Client, LocalCluster = require_dask().Client, require_dask().LocalCluster
    if scheduler:
        try:
            client = Client(scheduler, timeout="30s")
        except (OSError, TimeoutError) as exc:
            raise NurbscanError(f"--scheduler {scheduler}: cannot connect ({exc})") from None
        try:
            yield client
        finally:
            client.close()
        return
    if workers < 1:
        raise NurbscanError(f"--workers {workers}: must be at least 1")
    import dask

    with dask.config.set(CLUSTER_CONFIG), \
            LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                         dashboard_address=":8787", silence_logs=logging.ERROR,
                         preload=list(WORKER_PRELOAD)) as cluster, \
            Client(cluster) as client:
        yield client


def _submit_scan(client, job: ScanJob, n_views: int, options: BatchOptions, rank: int,
                 lead: int = 1):
    """The scan's tasks on the cluster; the future of its finish task.

    Priorities (Dask runs the ready task of highest priority first): earlier scans first, but
    a scan's finish task ranks after the views of the ``lead`` scans that follow it
    (:func:`finish_lead`), so that while one worker finishes a scan the others have views to
    run, and the last scans' finish tasks run side by side rather than one after the other.
    """
    key = f"{job.name}-{job.run}"
    pri = -2 * rank
    c = client.submit(calibration_task, job, key=f"nurbscan-calibration-{key}", priority=pri)
    p = client.submit(plan_task, job, c, options, key=f"nurbscan-plan-{key}", priority=pri)
    views = [client.submit(view_task, p, k, key=f"nurbscan-view-{k}-{key}", priority=pri)
             for k in range(n_views)]
    return client.submit(finish_task, job, options, c, p, *views,
                         key=f"nurbscan-finish-{key}", priority=pri - 2 * lead - 1)


def finish_lead(workers: int) -> int:
    """How many later scans' views rank before a scan's finish task: one less than the workers.

    A scan's finish task (merge, fuse, export) is long and runs after all its views; with
    earlier-scan-first order alone the last scan's finish runs by itself at the end while the
    other workers idle (on 2 workers and 4 scans of 4 views: 1.10 times the tasks' time over
    2, by list scheduling with measured task times; ``benchmarks/bench_batch.py``). Ranking
    the views of the next ``workers - 1`` scans before it keeps the workers busy to the end
    (1.00 there; 1.00-1.06 on 4 workers and 4-20 scans), at the cost of holding the view
    results of ``workers - 1`` more scans (about 9 MB per 7.1 MP view).
    """
    return max(1, workers - 1)


def _run_serial(job: ScanJob, n_views: int, options: BatchOptions) -> dict:
    """The scan's tasks one after the other in this process (the reference run)."""
    c = calibration_task(job)
    p = plan_task(job, c, options)
    return finish_task(job, options, c, p, *(view_task(p, k) for k in range(n_views)))


def _line(rep: dict, i: int, n: int) -> str:
    """The progress line of a finished scan."""
    head = f"scan {i}/{n} {rep['name']}: "
    if rep["status"] == "failed":
        return head + "FAILED: " + "; ".join(rep.get("errors", []))
    c = rep.get("counts", {})
    tasks = rep.get("tasks", {})
    busy = sum(tasks.get("view_s", [])) + tasks.get("finish_s", 0.0)
    ev = rep.get("evaluation")
    figs = (f", Gordon mean {ev['gordon_mean_mm']:.4f} mm, coverage {100 * ev['coverage']:.1f} %"
            if ev else "")
    tail = f" ({'; '.join(rep['errors'])})" if rep.get("errors") else ""
    return (head + f"{rep['status']}, {rep['views_ok']}/{rep['views']} views, "
            f"{c.get('gordon', 0)} Gordon patches{figs}, {busy:.1f} s of tasks{tail}")


def run_batch(scans: Sequence[str | os.PathLike], out: str | os.PathLike, *,
              calib: str | os.PathLike | None = None, options: BatchOptions | None = None,
              scheduler: str | None = None, workers: int = 2, serial: bool = False,
              progress: Callable[[str], None] | None = None) -> dict:
    """Reconstruct, export and evaluate many scans; write ``out``; return the batch summary.

    Parameters
    ----------
    scans : sequence of path-like
        Scan folders (each with ``scan.json``), on storage every worker sees.
    out : path-like
        Output folder: ``out / NAME`` per scan and ``out / "batch.json"`` (the summary).
    calib : path-like, optional
        One rig for every scan; default: each scan's ``calib.json``, else calibrated from its
        ``calibration/`` images.
    options : BatchOptions, optional
        What to compute and write per scan.
    scheduler : str, optional
        Address of a Dask scheduler (``tcp://HOST:PORT``); default a ``LocalCluster``.
    workers : int
        Worker processes of the ``LocalCluster`` (one thread each).
    serial : bool
        Run every task here, in order, without Dask (the reference for the same outputs).
    progress : callable, optional
        Called with one line per event (cluster, dashboard, each finished scan).

    Returns
    -------
    dict
        ``{"type": "nurbscan.batch", "scans": [scan report, ...], "ok", "partial",
        "failed", "skipped", "wall_s", "cluster_start_s"}``; each scan report has ``name``,
        ``status`` (``ok``, ``partial``, ``failed``, ``skipped``) and ``errors``. When no scan
        is complete (every one failed) nothing is written: ``out`` is left as it was (removed
        if this run made it), as when an exception stops the batch.
    """
    options = options or BatchOptions()
    if not serial:
        require_dask()
    jobs = scan_jobs(scans, out, calib)
    made = not Path(out).exists()
    try:
        summary = _run_jobs(jobs, out, options, scheduler, workers, serial, progress)
    except BaseException:
        if made:
            shutil.rmtree(out, ignore_errors=True)
        raise
    if made and summary["failed"] == len(jobs):
        shutil.rmtree(out, ignore_errors=True)
    return summary


def _run_jobs(jobs: list[ScanJob], out, options: BatchOptions, scheduler: str | None,
              workers: int, serial: bool, progress) -> dict:
    """:func:`run_batch`'s work: the scans run, ``out / "batch.json"`` written unless every
    scan failed."""
    from ..io import write_json

    say = progress or (lambda _m: None)
    t0 = time.perf_counter()
    Path(out).mkdir(parents=True, exist_ok=True)
    reports: dict[str, dict] = {}
    todo = []
    cluster_s = 0.0
    for job in jobs:
        if is_complete(job.out):
            reports[job.name] = {**read_report(job.out), "status": "skipped", "errors": []}
            say(f"scan {job.name}: complete in {job.out}, skipped")
            continue
        n = _view_count(job)
        if isinstance(n, TaskError):
            reports[job.name] = {"name": job.name, "scan": str(job.scan), "status": "failed",
                                 "errors": [str(n)]}
            say(_line(reports[job.name], len(reports), len(jobs)))
            continue
        shutil.rmtree(job.staging, ignore_errors=True)  # left by a batch that was stopped
        todo.append((job, n))
    if todo and serial:
        for job, n in todo:
            reports[job.name] = _run_serial(job, n, options)
            say(_line(reports[job.name], len(reports), len(jobs)))
    elif todo:
        cluster_s = _run_dask(todo, options, scheduler, workers, reports, len(jobs), say)
    summary = {"type": "nurbscan.batch", "version": 1,
               "scans": [reports[j.name] for j in jobs],
               **{s: sum(reports[j.name]["status"] == s for j in jobs)
                  for s in ("ok", "partial", "failed", "skipped")},
               "wall_s": round(time.perf_counter() - t0, 3),
               "cluster_start_s": round(cluster_s, 3)}
    if summary["failed"] < len(jobs):
        write_json(Path(out) / "batch.json", summary)
    return summary


def _run_dask(todo, options, scheduler, workers, reports, total, say) -> float:
    """Submit every scan's graph and collect the scans as they finish; the seconds it took to
    start (or reach) the cluster."""
    as_completed = require_dask().as_completed
    t0 = time.perf_counter()
    with dask_client(scheduler, workers) as client:
        started = time.perf_counter() - t0
        info = client.scheduler_info()
        say(f"Dask scheduler {info.get('address', scheduler)}, "
            f"{len(info.get('workers', {}))} workers; dashboard {client.dashboard_link}")
        lead = finish_lead(len(info.get("workers", {})) or workers)
        futures = {_submit_scan(client, job, n, options, r, lead): job
                   for r, (job, n) in enumerate(todo)}
        for fut in as_completed(list(futures)):
            job = futures.pop(fut)
            try:
                rep = fut.result()
            except Exception as exc:  # noqa: BLE001 - a scan Dask gave up on (KilledWorker)
                from .tasks import _error

                rep = {"name": job.name, "scan": str(job.scan), "status": "failed",
                       "errors": [str(_error("scan", exc))], "run": job.run}
                shutil.rmtree(job.staging, ignore_errors=True)
            reports[job.name] = rep
            say(_line(rep, len(reports), total))
            fut.release()
    return started


def main_report(summary: dict, out) -> str:
    """The command line's closing line."""
    n = {s: summary[s] for s in ("ok", "partial", "failed", "skipped")}
    return (f"nurbscan batch: {len(summary['scans'])} scans: {n['ok']} ok, {n['partial']} "
            f"partial, {n['failed']} failed, {n['skipped']} skipped (complete before); "
            f"{Path(out) / 'batch.json'} ({summary['wall_s']:.1f} s)")
