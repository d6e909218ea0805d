"""The batch's tasks: plain functions of small arguments, run by a Dask worker or in order here.

One scan is four kinds of task (:mod:`nurbscan.batch` builds the graph):

1. :func:`calibration_task` - the rig: read ``--calib`` or the scan's ``calib.json``, or
   calibrate it from the scan's ``calibration/`` images (:func:`nurbscan.calibrate.calibrate_scan`);
2. :func:`plan_task` - ``scan.json`` and the pattern read and checked, one view task each
   (:func:`nurbscan.reconstruct.pipeline.plan_scan`);
3. :func:`view_task` - one view: read its images from the scan folder, detect, triangulate,
   view network (:func:`nurbscan.reconstruct.pipeline.run_view`, the code ``nurbscan
   reconstruct`` runs);
4. :func:`finish_task` - the scan: merge and fuse (:func:`~nurbscan.reconstruct.pipeline.
   assemble_scan`), save the model folder (:meth:`nurbscan.reconstruct.Model.save`), export,
   evaluate against ``truth/`` when the scan has one, and rename the scan's output folder into
   place: a scan's outputs appear all at once, complete, or not at all.

A task never raises for its scan's or view's own failure: it returns a :class:`TaskError`, so
that the other views and scans go on and the scan's report names the view and the error. Each
task depends on nothing but its arguments and the files they name, so that a task that Dask
runs again (its worker died) gives the same result.
"""

from __future__ import annotations

import dataclasses
import os
import pickle
import shutil
import socket
import time
import traceback
import uuid
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..errors import NurbscanError

#: The scan report's file in each scan's output folder; written last, so that its presence with
#: ``"status": "ok"`` marks a complete scan (a re-run skips it).
REPORT = "batch.json"
#: Formats exported per scan by default (:func:`nurbscan.export.export_model`).
DEFAULT_EXPORTS = ("glb", "3dm")


@dataclass(frozen=True)
class BatchOptions:
    """How each scan of a batch is reconstructed and what is written.

    Attributes
    ----------
    min_curves : int
        Smallest Gordon patch, curves per direction
        (:func:`~nurbscan.reconstruct.view.reconstruct_view`).
    fuse : bool
        Fuse the views into one coloured mesh (``fused.ply``).
    max_triangles : int
        Triangle budget of the fused mesh.
    exports : tuple of str
        Formats written beside the model folder (``model.glb``, ``model.3dm``, ...).
    evaluate : bool
        Measure the model against the scan's ``truth/`` when it has one (evaluation.json).
    overlays : bool
        Write each view's detected-line picture (``model/overlays/``).
    """

    min_curves: int = 3
    fuse: bool = True
    max_triangles: int = 300_000
    exports: tuple[str, ...] = DEFAULT_EXPORTS
    evaluate: bool = True
    overlays: bool = True

    def __post_init__(self):
        from ..cli.export import FORMATS

        if self.min_curves < 2:
            raise NurbscanError(f"--min-curves {self.min_curves}: must be at least 2")
        if self.max_triangles < 100:
            raise NurbscanError(f"--max-triangles {self.max_triangles}: must be at least 100")
        bad = [f for f in self.exports if f not in FORMATS]
        if bad:
            raise NurbscanError(f"--export {','.join(bad)}: unknown format; expected some of "
                                f"{', '.join(FORMATS)} or none")

    def fusion(self):
        """The fusion options: one Poisson thread, whose mesh is the same on every run (two
        threads' is not); the batch runs scans side by side instead."""
        from ..merge.fusion import FusionOptions

        return FusionOptions(max_triangles=self.max_triangles, workers=1) if self.fuse else None


@dataclass(frozen=True)
class ScanJob:
    """One scan of a batch.

    Attributes
    ----------
    name : str
        The scan's name: its output folder ``out / name``.
    scan : Path
        The scan folder (on storage every worker sees).
    out : Path
        The scan's output folder.
    calib : Path or None
        The rig file; None: calibrate from ``scan / "calibration"``.
    run : str
        This batch run's id (a task run again after its worker died finds its own output).
    """

    name: str
    scan: Path
    out: Path
    calib: Path | None
    run: str = field(default_factory=lambda: uuid.uuid4().hex[:12])

    @property
    def staging(self) -> Path:
        """The folder the scan's outputs are written into before it is renamed to ``out``."""
        return self.out.with_name(f".{self.name}.partial")


@dataclass(frozen=True)
class TaskError:
    """A task's failure: where (``"view 3"``, ``"calibration"``, ...) and the one-line error."""

    where: str
    message: str

    def __str__(self) -> str:
        return f"{self.where}: {self.message}"


@dataclass(frozen=True)
class Timed:
    """A task's value (or :class:`TaskError`), its wall time (s), the host it ran on and the
    CPU time of its process meanwhile (s, all threads; on a machine that others share, the
    wall time grows with their load, the CPU time much less)."""

    value: Any
    seconds: float
    host: str
    cpu_seconds: float = 0.0

    @property
    def ok(self) -> bool:
        return not isinstance(self.value, TaskError)

    def __reduce__(self):
        """Pickled as one block of bytes (:func:`_unpack_timed`), not as Dask sends a value by
        default: every numpy array as a frame of its own, each one waiting for the sending
        worker's event loop to get the interpreter lock from its task. A 1024 x 768 view's
        result holds 5568 arrays (1.4 MB): it took 0.5-1.2 s to reach the scan's worker while
        that worker's other thread computed, idling it when the scan's last view came from
        elsewhere (``benchmarks/bench_batch.py``); as one block, about 0.03 s to pickle."""
        fields = (self.value, self.seconds, self.host, self.cpu_seconds)
        return _unpack_timed, (pickle.dumps(fields, protocol=pickle.HIGHEST_PROTOCOL),)


def _unpack_timed(blob: bytes) -> Timed:
    """The :class:`Timed` that :meth:`Timed.__reduce__` packed."""
    return Timed(*pickle.loads(blob))


def _error(where: str, exc: BaseException) -> TaskError:
    """One line for an exception: a :class:`NurbscanError`'s message, else its type too."""
    if isinstance(exc, NurbscanError):
        msg = str(exc)
    else:
        last = traceback.extract_tb(exc.__traceback__)[-1:] if exc.__traceback__ else []
        at = f" (at {Path(last[0].filename).name}:{last[0].lineno})" if last else ""
        msg = f"{type(exc).__name__}: {exc}{at}"
    return TaskError(where, " ".join(msg.split()) or type(exc).__name__)


def _timed(where: str, fn, *args) -> Timed:
    """Run ``fn(*args)``; its value or its error, timed."""
    t0, c0 = time.perf_counter(), time.process_time()
    try:
        value = fn(*args)
    except Exception as exc:  # noqa: BLE001 - reported per task, the batch goes on
        value = _error(where, exc)
    return Timed(value, round(time.perf_counter() - t0, 3), socket.gethostname(),
                 round(time.process_time() - c0, 3))


# ---------------------------------------------------------------------- 1 calibration
@dataclass(frozen=True)
class Calibration:
    """The scan's rig, where it comes from, and (calibrated here) its rig document."""

    rig: Any
    turntable_calibrated: bool
    source: str
    doc: dict | None = None


def _calibrate(job: ScanJob) -> Calibration:
    from ..calibrate import calibrate_scan, turntable_calibrated
    from ..camera import Rig, load_rig
    from ..io.atomic import read_json

    if job.calib is not None:
        return Calibration(load_rig(job.calib), turntable_calibrated(read_json(job.calib)),
                           str(Path(job.calib).resolve()))
    calib_dir = job.scan / "calibration"
    if not calib_dir.is_dir():
        raise NurbscanError(f"{job.scan}: no calib.json and no calibration/ folder to "
                            "calibrate from (give --calib)")
    res = calibrate_scan(calib_dir, workers=1)
    doc = res.rig_dict()
    # the rig as calib.json gives it back (what `nurbscan reconstruct --calib` would use)
    return Calibration(Rig.from_dict(doc), turntable_calibrated(doc),
                       str((job.out / "calib.json").resolve()), doc)


def calibration_task(job: ScanJob) -> Timed:
    """The scan's rig (:class:`Calibration`): ``job.calib`` read, or calibrated from the
    scan's calibration images (:func:`nurbscan.calibrate.calibrate_scan`, one process)."""
    return _timed("calibration", _calibrate, job)


# ---------------------------------------------------------------------- 2 plan
def _plan(job: ScanJob, calib: Calibration, options: BatchOptions):
    from ..reconstruct.pipeline import plan_scan

    overlays = job.staging / "model" / "overlays" if options.overlays else None
    return plan_scan(job.scan, calib.rig, overlays=overlays,
                     turntable_calibrated=calib.turntable_calibrated,
                     min_curves=options.min_curves)


def plan_task(job: ScanJob, calib: Timed, options: BatchOptions) -> Timed:
    """The scan's :class:`~nurbscan.reconstruct.pipeline.ScanPlan` (reads ``scan.json`` and the
    pattern); a failed calibration passes through."""
    if not calib.ok:
        return Timed(calib.value, 0.0, socket.gethostname())
    return _timed("scan", _plan, job, calib.value, options)


# ---------------------------------------------------------------------- 3 view
def _view(plan, k: int):
    from ..reconstruct.pipeline import run_view

    if k >= len(plan.tasks):
        raise NurbscanError(f"{plan.scan / 'scan.json'}: view {k} is no longer in the scan "
                            f"({len(plan.tasks)} views)")
    return run_view(plan.tasks[k])


def view_task(plan: Timed, k: int) -> Timed:
    """View ``k`` of the scan (:func:`nurbscan.reconstruct.pipeline.run_view`: its images read
    from the scan folder here, detect, triangulate, view network)."""
    if not plan.ok:
        return Timed(TaskError(f"view {k}", "not run, the scan failed"), 0.0,
                     socket.gethostname())
    index = plan.value.tasks[k].index if k < len(plan.value.tasks) else k
    return _timed(f"view {index}", _view, plan.value, k)


# ---------------------------------------------------------------------- 4 finish
def read_report(folder: Path) -> dict | None:
    """The scan report in an output folder, or None (none, or unreadable)."""
    from ..io.atomic import read_json

    try:
        doc = read_json(Path(folder) / REPORT)
    except NurbscanError:
        return None
    return doc if isinstance(doc, dict) else None


def is_complete(folder: Path) -> bool:
    """True when the output folder holds a complete scan (its report says ``ok``)."""
    doc = read_report(folder)
    return doc is not None and doc.get("status") == "ok"


def _replace_folder(staging: Path, final: Path) -> None:
    """Rename ``staging`` to ``final``; an older ``final`` is moved aside first, then removed."""
    old = None
    if final.exists():
        old = final.with_name(f".{final.name}.old-{uuid.uuid4().hex[:8]}")
        os.replace(final, old)
    os.replace(staging, final)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)


def _finish(job: ScanJob, options: BatchOptions, calib: Timed, plan: Timed,
            views: tuple[Timed, ...]) -> dict:
    from ..evaluate import evaluate_model, format_table
    from ..export import export_model
    from ..io import write_json, write_text
    from ..merge import MergeWarning
    from ..reconstruct.pipeline import assemble_scan

    t0, c0 = time.perf_counter(), time.process_time()
    done = read_report(job.out)
    if done is not None and done.get("run") == job.run:  # this task ran before, its worker died
        return done
    ok = [(t, v.value) for t, v in zip(plan.value.tasks, views, strict=True) if v.ok]
    errors = [str(v.value) for v in views if not v.ok]
    if not ok:
        raise NurbscanError(f"no view reconstructed ({'; '.join(errors)})")
    sub = dataclasses.replace(plan.value, tasks=tuple(t for t, _ in ok))
    with warnings.catch_warnings():  # the merge's warnings go into the report
        warnings.simplefilter("ignore", MergeWarning)
        model = assemble_scan(sub, [o for _, o in ok], fusion=options.fusion())
    times = {"assemble_s": time.perf_counter() - t0}
    stage = job.staging
    stage.mkdir(parents=True, exist_ok=True)
    c = calib.value
    if c.doc is not None:  # calibrated here: the rig goes with the scan's outputs
        write_json(stage / "calib.json", c.doc)
    model.meta["calibration"] = str(stage / "calib.json") if c.doc is not None else c.source
    exported = []
    for fmt in options.exports:
        exported.append(export_model(model, stage / f"model.{fmt}", fmt).name)
    times["export_s"] = time.perf_counter() - t0 - sum(times.values())
    model.meta["calibration"] = c.source
    model.meta["total_s"] = round(calib.seconds + plan.seconds
                                  + sum(v.seconds for v in views), 3)
    model.save(stage / "model")
    times["save_s"] = time.perf_counter() - t0 - sum(times.values())
    report = {"type": "nurbscan.batch.scan", "version": 1, "run": job.run, "name": job.name,
              "scan": str(job.scan), "status": "ok" if not errors else "partial",
              "errors": errors, "views": len(views), "views_ok": len(ok),
              "counts": model.to_dict()["counts"], "exports": exported,
              "calibration": c.source,
              "warnings": list(model.meta.get("merge", {}).get("warnings", [])),
              "tasks": {"calibration_s": calib.seconds, "plan_s": plan.seconds,
                        "view_s": [v.seconds for v in views], "hosts": sorted(
                            {calib.host, plan.host, *(v.host for v in views)})}}
    truth = job.scan / "truth"
    if options.evaluate and (truth / "scene.json").is_file():
        ev = evaluate_model(model, truth, workers=1)
        write_json(stage / "evaluation.json", ev)
        write_text(stage / "evaluation.md", format_table(ev))
        report["evaluation"] = {"gordon_mean_mm": ev["rows"]["gordon"]["mean_mm"],
                                "coverage": ev["coverage"]}
        times["evaluate_s"] = time.perf_counter() - t0 - sum(times.values())
    report["tasks"]["finish_s"] = round(time.perf_counter() - t0, 3)
    report["tasks"]["cpu_s"] = {"calibration": calib.cpu_seconds, "plan": plan.cpu_seconds,
                                "view": [v.cpu_seconds for v in views],
                                "finish": round(time.process_time() - c0, 3)}
    report["tasks"]["finish_parts_s"] = {k: round(v, 3) for k, v in times.items()}
    write_json(stage / REPORT, report)
    _replace_folder(stage, job.out)
    return report


def finish_task(job: ScanJob, options: BatchOptions, calib: Timed, plan: Timed,
                *views: Timed) -> dict:
    """The per-scan task: merge, fuse, save, export, evaluate, rename into place.

    Returns the scan report (``status`` ``ok``, ``partial`` when some views failed: the model
    of the others is written and the errors listed, or ``failed`` with nothing written).
    """
    if not plan.ok:
        shutil.rmtree(job.staging, ignore_errors=True)
        return {"name": job.name, "scan": str(job.scan), "status": "failed",
                "errors": [str(plan.value)], "run": job.run}
    t = _timed("scan", _finish, job, options, calib, plan, views)
    if not t.ok:
        shutil.rmtree(job.staging, ignore_errors=True)
        return {"name": job.name, "scan": str(job.scan), "status": "failed",
                "errors": [str(t.value)], "run": job.run}
    return t.value
