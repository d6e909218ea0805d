"""Compiled loops (numba), loaded only when a process first runs one.

Importing numba starts LLVM: about 100 MB more resident memory per process (80 MB of it the
code of ``libllvmlite.so``, shared between processes, and 40 MB of its own), which a process
that never runs a compiled loop (``nurbscan calibrate``'s main process, which hands the
detections to its workers; ``nurbscan --help``) should not pay. :func:`njit` marks a
function like ``numba.njit`` but leaves it a plain Python function until the first call of
any marked function of its module: then numba is imported and every marked function of that
module is compiled (``cache=True``: from the on-disk cache after the first time) and put in
the module's namespace in place of its marker, so that the compiled functions call one
another. Each marked function must be a module-level function whose own name refers to it.
"""

from __future__ import annotations

import functools
import threading
from collections.abc import Callable
from typing import Any

_LOCK = threading.Lock()


def njit(**options: Any) -> Callable[[Callable], Callable]:
    """``numba.njit(**options)``, applied at the first call (module notes)."""

    def mark(fn: Callable) -> Callable:
        @functools.wraps(fn)
        def first_call(*args):
            _compile_module(fn.__globals__)
            return fn.__globals__[fn.__name__](*args)

        first_call._njit = (fn, options)
        return first_call

    return mark


def _compile_module(namespace: dict) -> None:
    """Compile every marked function of a module's ``namespace`` and put it in its place."""
    with _LOCK:
        marked = {name: obj._njit for name, obj in list(namespace.items())
                  if callable(obj) and hasattr(obj, "_njit")}
        if not marked:
            return
        import numba

        for name, (fn, options) in marked.items():
            namespace[name] = numba.njit(**options)(fn)
