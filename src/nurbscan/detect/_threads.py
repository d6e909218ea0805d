"""Independent halves of a detection stage (the two edge families, the colour channels) side
by side in threads.

Each job is computed exactly as it would be alone, and the results come back in the jobs'
order: the detection result does not depend on the number of threads (the result hashes of
``benchmarks/detect_hash.py`` are the same with 1 and 2). The jobs are numpy, OpenCV and
cKDTree calls on arrays of 10^5 - 10^7 elements, which release the GIL while they run.

Threads: ``NURBSCAN_DETECT_THREADS`` when set (1 runs every job here, in order), else 2 on a
machine with two or more CPUs, and 1 inside a worker process (``reconstruct``,
``calibrate`` and ``batch`` already run one view per CPU). A job submitted from a worker
thread runs in that thread (no nested waits).

:func:`critical_cpu` gives the CPU time of the longest path (the calling thread's CPU time,
plus, per parallel call, how much longer the worker's job ran than the caller's own): on an
otherwise idle machine, with the GIL free, that is the wall time; unlike the wall time it
does not depend on the other load of a shared machine.
"""

from __future__ import annotations

import multiprocessing
import os
import threading
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import numpy as np

_POOL: ThreadPoolExecutor | None = None
_POOL_LOCK = threading.Lock()
_LOCAL = threading.local()
#: Per parallel call, the worker jobs' CPU time beyond the caller's own job, s (for
#: :func:`critical_cpu`).
_EXTRA = [0.0]


def thread_count() -> int:
    """Threads a stage may use (module notes)."""
    env = os.environ.get("NURBSCAN_DETECT_THREADS")
    if env:
        try:
            return max(1, int(env))
        except ValueError:
            return 1
    if multiprocessing.parent_process() is not None:
        return 1
    return 2 if (os.cpu_count() or 1) >= 2 else 1


def _pool(n: int) -> ThreadPoolExecutor:
    global _POOL
    with _POOL_LOCK:
        if _POOL is None or _POOL._max_workers < n:
            _one_arena()
            _POOL = ThreadPoolExecutor(max_workers=n, thread_name_prefix="nurbscan-detect",
                                       initializer=_mark_worker)
        return _POOL


def _one_arena() -> None:
    """glibc's malloc: new threads share the existing heap instead of each one opening its
    own (:func:`nurbscan._malloc.one_arena`). A worker thread's arena
    keeps the image-sized arrays it freed resident, where the calling thread cannot reuse
    them: bench view 0 (7.1 MP), one cold and one warm call in a fresh process, peak
    resident memory 705 MB with an arena per thread, 562-584 MB with one (one thread: 584 MB;
    the code before the threads: 526-591 MB). Affects the process's later threads too (they
    share the one heap's lock)."""
    from .._malloc import one_arena

    one_arena()


def _mark_worker() -> None:
    _LOCAL.worker = True


def _timed(fn: Callable, arg) -> tuple[Any, float]:
    t = time.thread_time()
    out = fn(arg)
    return out, time.thread_time() - t


def parallel_map(fn: Callable[[Any], Any], items: Sequence[Any]) -> list[Any]:
    """``[fn(item) for item in items]``, the first item in this thread and the others in the
    pool's (up to :func:`thread_count` at once; this thread takes those no worker has started
    when it is done with its own); results in the items' order. ``fn`` must not write to
    anything the other items read."""
    items = list(items)
    n = min(thread_count(), len(items))
    if n <= 1 or getattr(_LOCAL, "worker", False):
        return [fn(item) for item in items]
    pool = _pool(n - 1)
    futures = [pool.submit(_timed, fn, item) for item in items[1:]]
    first, own = _timed(fn, items[0])
    rest, here, theirs = [None] * len(futures), [False] * len(futures), 0.0
    for i, f in enumerate(futures):
        if f.cancel():  # not started yet: run here
            rest[i], t = _timed(fn, items[i + 1])
            here[i], own = True, own + t
    for i, f in enumerate(futures):
        if not here[i]:
            rest[i], t = f.result()
            theirs += t
    # the longest path: the slower of the two sides (the workers' jobs one after the other,
    # as on a two-core machine)
    _EXTRA[0] += max(0.0, theirs - own)
    return [first] + rest


def in_halves(fn: Callable[[slice], Any], n: int):
    """``fn(slice(0, n // 2))`` and ``fn(slice(n // 2, n))`` side by side (:func:`parallel_map`),
    their outputs joined in order (``np.concatenate``; each array of a tuple apart): for an
    ``fn`` that works element by element, ``fn(slice(0, n))``'s arrays."""
    parts = parallel_map(fn, (slice(0, n // 2), slice(n // 2, n)))
    if isinstance(parts[0], tuple):
        return tuple(np.concatenate(p) for p in zip(*parts, strict=True))
    return np.concatenate(parts)


def critical_cpu() -> float:
    """CPU time of the longest path so far (module notes), s; differences of two calls
    measure the code between them."""
    return time.thread_time() + _EXTRA[0]
