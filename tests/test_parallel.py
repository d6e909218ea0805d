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
