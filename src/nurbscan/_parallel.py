"""Running independent jobs (views, calibration poses) side by side in worker processes.

The stages' hot paths are numpy, OpenCV and Embree calls that hold the GIL part of the time, so
on a 2-core machine two processes finish a batch of images sooner than threads in one. Workers
are *spawned* (not forked): the parent may hold threads (Embree, BLAS, a writer) that a fork
would copy half-way. Each job must not depend on the order the jobs run in; results come back
in the jobs' order, so the outcome does not depend on the number of workers.

Workers die with their parent: each one watches its parent process (:func:`_watch_parent`) and
exits when the parent is gone, so that a ``reconstruct`` killed with ``kill -9`` leaves no worker
writing behind it. Each worker also sets glibc's malloc to reuse the memory it frees
(:func:`nurbscan._malloc.reuse_freed_memory`): a render's image-sized temporaries are then not
new pages each time.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import threading
import time
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from typing import Any

from ._malloc import reuse_freed_memory

#: How often a worker looks whether its parent is still there, s.
PARENT_POLL_S = 0.5


def _watch_parent(parent: int) -> None:
    """Exit this process at once when process ``parent`` is no longer its parent."""
    while os.getppid() == parent:
        time.sleep(PARENT_POLL_S)
    os._exit(1)


def _worker_start(parent: int, initializer: Callable[..., None] | None, initargs: tuple
                  ) -> None:
    """A worker's first step: watch the parent (daemon thread), set malloc's reuse of freed
    memory (:func:`nurbscan._malloc.reuse_freed_memory`), then the caller's initializer."""
    if os.getppid() != parent:
        os._exit(1)
    reuse_freed_memory()
    threading.Thread(target=_watch_parent, args=(parent,), daemon=True,
                     name="nurbscan-parent-watch").start()
    if initializer is not None:
        initializer(*initargs)


def _pool(workers: int, initializer: Callable[..., None] | None = None, initargs: tuple = ()
          ) -> ProcessPoolExecutor:
    """A pool of ``workers`` spawned processes that die with this one."""
    return ProcessPoolExecutor(max_workers=workers, mp_context=mp.get_context("spawn"),
                               initializer=_worker_start,
                               initargs=(os.getpid(), initializer, initargs))


def _pool_or_none(workers: int, initializer: Callable[..., None] | None = None,
                  initargs: tuple = ()) -> ProcessPoolExecutor | None:
    """:func:`_pool`, or None when the system cannot give one (no room for its semaphores in
    ``/dev/shm``, a file-size limit, no processes left): the jobs then run here."""
    try:
        return _pool(workers, initializer, initargs)
    except OSError:
        return None


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
        Processes (see :func:`worker_count`); 1 runs every job here, in order (so does a
        system that cannot start a pool, :func:`_pool_or_none`).
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
    pool = _pool_or_none(n, initializer, initargs) if n > 1 else None
    if pool is None:
        if initializer is not None:
            initializer(*initargs)
        for i, item in enumerate(items):
            results[i] = fn(item)
            if done is not None:
                done(i, results[i])
        return results
    with pool:
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
    pool = _pool_or_none(1) if parallel and worker_count(0) >= 2 else None
    if pool is None:
        result = fn(*args)
        return lambda: result
    future = pool.submit(fn, *args)

    def wait() -> Any:
        try:
            return future.result()
        finally:
            pool.shutdown()

    return wait
