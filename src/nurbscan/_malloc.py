"""glibc's ``malloc`` settings for nurbscan's own processes (``mallopt``, malloc.h).

numpy takes the memory of every array over 128 kB from ``malloc``. glibc hands large
blocks out as fresh pages (``mmap``) or from its heap, and gives the heap's free top back to
the system past a trim threshold; both thresholds adapt to the blocks freed so far, up to
32 MiB and 64 MiB. Until they have grown, the image-sized temporaries of a render or a
detection are new pages each time, and a page's first touch costs a fault and its zeroing.

* :func:`reuse_freed_memory` sets the two thresholds at glibc's own adaptive maxima from the
  start (``M_MMAP_THRESHOLD`` 32 MiB, ``M_TRIM_THRESHOLD`` 64 MiB): blocks under 32 MiB come
  from the heap and are reused, larger ones are still mapped and returned when freed. It is
  set in the worker processes nurbscan starts (:mod:`nurbscan._parallel`, and Dask's workers
  through :mod:`nurbscan.batch.preload`), never by the library in a user's own process.
  Measured on the 2-core VM: one 7.1 MP teapot view rendered in one process took 29.5 and
  30.7 s wall (8.4 and 11.3 s of it system time) with glibc's defaults and 23.0 and 23.3 s
  (6.3-6.5 s) with these settings; ``nurbscan calibrate``'s peak memory (its processes' PSS
  summed) was 1464-1515 MB with the defaults and 1465-1468 MB with them (two runs each,
  alternating), and in a second such pair of runs 1498 MB against 1415 and 1463 MB.
* The command line's own process (:func:`nurbscan.cli.main`, which the ``nurbscan`` command
  and ``python -m nurbscan`` run, where glibc accepts the values) sets them higher,
  :data:`COMMAND_MMAP_BYTES` and :data:`COMMAND_TRIM_BYTES`: there detection runs on two
  threads, and its largest arrays (a 7.1 MP photograph's three float32 planes, 85 MB) lie
  above glibc's 32 MiB, so with the workers' settings they are still new pages each time.
  The benchmarks that time the command's steps in their own process set the same.
  Measured on the 2-core VM, bench view 0 (7.1 MP), 7 warm detections per fresh process,
  five processes each, alternating (05:49 UTC, 2026-12-06):
  with glibc's defaults 791-3008 page faults and 37-93 ms of system time per detection, a
  median wall time of 0.607-0.715 s (median 0.675 s); with the workers' settings 273-5644
  faults, 46-71 ms, 0.644-0.838 s (0.701 s); with these 2-3 faults, 16-29 ms, 0.556-0.710 s
  (0.629 s). The processes' peak resident memory: 515-551, 517-552 and 526-553 MB.
* :func:`one_arena` makes new threads share the main heap (``M_ARENA_MAX`` 1), so that a
  worker thread's freed image-sized arrays are not kept apart where the calling thread
  cannot reuse them (:mod:`nurbscan.detect._threads`).

Both are no-ops (returning False) where the C library is not glibc.
"""

from __future__ import annotations

import ctypes
import ctypes.util

#: glibc's mallopt parameters (malloc.h).
M_TRIM_THRESHOLD, M_MMAP_THRESHOLD, M_ARENA_MAX = -1, -3, -8
#: The values :func:`reuse_freed_memory` sets: glibc's own adaptive maxima
#: (``DEFAULT_MMAP_THRESHOLD_MAX`` on 64-bit, and twice it for the trim threshold).
TRIM_BYTES, MMAP_BYTES = 64 << 20, 32 << 20
#: The values the command line's own process sets (module notes): every array up to 512 MiB
#: from the heap, and up to 1 GiB of its free top kept for reuse.
COMMAND_TRIM_BYTES, COMMAND_MMAP_BYTES = 1 << 30, 512 << 20


def mallopt(param: int, value: int) -> bool:
    """``mallopt(param, value)`` of the C library; False where it is missing or refuses."""
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        fn = libc.mallopt
    except (OSError, AttributeError):
        return False
    return bool(fn(ctypes.c_int(param), ctypes.c_int(value)))


def reuse_freed_memory(trim_bytes: int = TRIM_BYTES, mmap_bytes: int = MMAP_BYTES) -> bool:
    """Set glibc's trim and mmap thresholds (bytes; by default :data:`TRIM_BYTES` and
    :data:`MMAP_BYTES`, the workers' values: module notes); False where there is no glibc."""
    return mallopt(M_TRIM_THRESHOLD, trim_bytes) and mallopt(M_MMAP_THRESHOLD, mmap_bytes)


def one_arena() -> bool:
    """New threads share the existing heap (``M_ARENA_MAX`` 1, as ``MALLOC_ARENA_MAX=1``)."""
    return mallopt(M_ARENA_MAX, 1)
