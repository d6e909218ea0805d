"""Worker processes (nurbscan._parallel): they die with their parent."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytestmark = pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs Linux /proc")


def _stat(pid: int) -> tuple[str, int] | None:
    """(state, parent pid) of a process, None when it is gone."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    fields = text[text.rindex(")") + 2:].split()
    return fields[0], int(fields[1])


def _workers_of(parent: int) -> list[int]:
    """The spawned worker processes whose parent is ``parent``."""
    out = []
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        st = _stat(int(d.name))
        try:
            cmd = (d / "cmdline").read_bytes()
        except OSError:
            continue
        if st and st[1] == parent and b"spawn_main" in cmd:
            out.append(int(d.name))
    return out


def _alive(pid: int) -> bool:
    st = _stat(pid)
    return st is not None and st[0] not in ("Z", "X")


def test_workers_die_with_their_parent():
    """kill -9 of a process running a two-worker batch: its workers are gone within seconds
    (before the change they slept on for the job's whole 60 s)."""
    code = ("import time; from nurbscan._parallel import process_map; "
            "process_map(time.sleep, [60, 60], workers=2)")
    parent = subprocess.Popen([sys.executable, "-c", code])
    try:
        workers: list[int] = []
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and len(workers) < min(2, os.cpu_count() or 1):
            time.sleep(0.2)
            workers = _workers_of(parent.pid)
        assert workers, "no worker process started"
        time.sleep(1.0)  # the workers are in their jobs
        parent.kill()
        parent.wait()
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline and any(_alive(p) for p in workers):
            time.sleep(0.1)
        assert not any(_alive(p) for p in workers), "workers outlived their parent"
    finally:
        if parent.poll() is None:
            parent.kill()


def _in_heap(nbytes: int) -> bool:
    """Whether a fresh numpy array of ``nbytes`` lies in this process's brk heap (glibc's
    ``[heap]`` in /proc/self/maps), i.e. came from malloc's heap rather than its own mmap."""
    import numpy as np

    a = np.empty(nbytes, np.uint8)
    addr = a.ctypes.data
    for line in Path("/proc/self/maps").read_text().splitlines():
        if line.endswith("[heap]"):
            lo, hi = (int(x, 16) for x in line.split()[0].split("-"))
            if lo <= addr < hi:
                return True
    return False


def test_workers_reuse_freed_memory():
    """A worker sets malloc's thresholds at glibc's maxima (nurbscan._malloc): a 20 MB array,
    which glibc's defaults map afresh (threshold 128 kB until a large block is freed), comes
    from the heap in a worker; in this process, without the setting, it does not."""
    import ctypes.util

    from nurbscan._parallel import process_map

    if "libc.so" not in (ctypes.util.find_library("c") or ""):
        pytest.skip("glibc's malloc only")
    here = str(Path(__file__).parent)
    probe = [sys.executable, "-c", f"import sys; sys.path.insert(0, {here!r}); "
             "import test_parallel as t; print(t._in_heap(20 << 20))"]
    plain = subprocess.run(probe, capture_output=True, text=True, check=True).stdout.split()
    assert plain == ["False"]
    assert process_map(_in_heap, [20 << 20, 20 << 20], 2) == [True, True]


def test_command_reuses_freed_memory():
    """The command line's process sets malloc's thresholds higher than the workers'
    (nurbscan._malloc.COMMAND_MMAP_BYTES): a 100 MB array, above the workers' 32 MiB, comes
    from the heap after ``nurbscan.cli.main``; in a worker it does not, nor in a plain
    process."""
    import ctypes.util

    from nurbscan._parallel import process_map

    if "libc.so" not in (ctypes.util.find_library("c") or ""):
        pytest.skip("glibc's malloc only")
    here = str(Path(__file__).parent)
    head = f"import sys; sys.path.insert(0, {here!r}); import test_parallel as t; "
    command = head + ("from nurbscan.cli import main\n"
                      "try:\n    main(['--version'])\nexcept SystemExit:\n    pass\n"
                      "print(t._in_heap(100 << 20))")
    plain = head + "print(t._in_heap(100 << 20))"
    outs = [subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                           check=True).stdout.split()[-1] for code in (command, plain)]
    assert outs == ["True", "False"]
    assert process_map(_in_heap, [100 << 20, 100 << 20], 2) == [False, False]
