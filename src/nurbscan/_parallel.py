"""Running independent jobs (views, calibration poses) side by side in worker processes.

The stages' hot paths are numpy, OpenCV and Embree calls that hold the GIL part of the time, so
on a 2-core machine two processes finish a batch of images sooner than threads in one. Workers
are *spawned* (not forked): the parent may hold threads (Embree, BLAS, a writer) that a fork
would copy half-way. Each job must not depend on the order the jobs run in; results come back
in the jobs' order, so the outcome does not depend on the number of workers.
"""

from __future__ import annotations

import multiprocessing as mp
import os
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from typing import Any


def worker_count(workers: int | None) -> int:
    """Processes to use: ``workers`` (0 or None: one per CPU), at most one per CPU, at least 1."""
    cpus = os.cpu_count() or 1
    return max(1, min(int(workers or 0) or cpus, cpus))


def process_map(fn: Callable[[Any], Any], items: Sequence[Any] | Iterable[Any],
                workers: int | None = 1, done: Callable[[int, Any], None] | None = None,
                initializer: Callable[..., None] | None = None, initargs: tuple = ()
                ) -> list[Any]:
    """``[fn(item) for item in items]``, in up to ``workers`` processes.

    Parameters
    ----------
    fn : callable
        A module-level function (it is pickled by name).
    items : sequence
        Its arguments, one job each (pickled to the workers).
    workers : int, optional
        Processes (see :func:`worker_count`); 1 runs every job here, in order.
    done : callable, optional
        ``done(index, result)``, called in this process as each job finishes (progress).
    initializer, initargs : optional
        Run once in each worker (and here, when ``workers`` is 1) before its first job.

    Returns
    -------
    list
        The results in the items' order. The first failed job's exception is raised.
    """
    items = list(items)
    n = min(worker_count(workers), max(len(items), 1))
    results: list[Any] = [None] * len(items)
    if n == 1:
        if initializer is not None:
            initializer(*initargs)
        for i, item in enumerate(items):
            results[i] = fn(item)
            if done is not None:
                done(i, results[i])
        return results
    with ProcessPoolExecutor(max_workers=n, mp_context=mp.get_context("spawn"),
                             initializer=initializer, initargs=initargs) as pool:
        futures = {pool.submit(fn, item): i for i, item in enumerate(items)}
        for f in as_completed(futures):
            i = futures[f]
            results[i] = f.result()
            if done is not None:
                done(i, results[i])
    return results


def in_background(fn: Callable[..., Any], *args: Any, parallel: bool = True
                  ) -> Callable[[], Any]:
    """Start ``fn(*args)`` in a spawned process; return a function that waits for its result.

    With ``parallel`` false (or one CPU) ``fn`` runs here, at once, and the returned function
    gives its result. ``fn`` and ``args`` are pickled, as for :func:`process_map`.
    """
    if not parallel or worker_count(0) < 2:
        result = fn(*args)
        return lambda: result
    pool = ProcessPoolExecutor(max_workers=1, mp_context=mp.get_context("spawn"))
    future = pool.submit(fn, *args)

    def wait() -> Any:
        try:
            return future.result()
        finally:
            pool.shutdown()

    return wait
