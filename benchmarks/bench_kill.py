"""Benchmark: ``kill -9`` at random moments of ``nurbscan reconstruct`` and ``nurbscan export``
(issue #34).

``bench()`` simulates a small scan (768 x 576, 2 views, coarse grid), runs ``reconstruct``
(2 views in 2 workers, no fused mesh) and ``export --patches`` (glb) once uninterrupted for
the reference outputs and their times, then starts each command ``$NURBSCAN_BENCH_KILLS``
times until it was killed that many times (default 50 each, as the issue asks), with SIGKILL
at a uniformly random moment of [0, 1.1] times its uninterrupted time (seeded; the time
re-measured before every tenth kill, as the machine's load changes). After each kill it
waits until the command's whole process group is gone (the workers die with their parent) and
classifies the output:

* ``absent``: no output (the first run killed before it finished);
* ``complete``: the model folder loads (:func:`nurbscan.reconstruct.load_model`, which checks
  ``points.npz`` against the checksum in ``model.json``), has one overlay per view and the
  reference's points and surfaces; the glb has the reference's bytes;
* ``bad``: anything else (a mixed, partial or corrupt output). Target: 0 (with the
  uninterrupted runs after a kill whose output is not complete: ``bad_outputs``).

Then one more uninterrupted run of each; ``leftovers`` counts what remains in the output's
folder besides the output itself (temporaries, lock files). Target: 0.
"""

from __future__ import annotations

import os
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

SRC = Path(__file__).resolve().parents[1] / "src"


def _scan(out: Path) -> Path:
    from nurbscan.pattern import Pattern
    from nurbscan.simulate.render import RenderSettings
    from nurbscan.simulate.rig import default_rig, scale_camera
    from nurbscan.simulate.scan import simulate_scan
    from nurbscan.simulate.scenes import make_scene

    rig = scale_camera(default_rig(), 768, 576)
    simulate_scan(make_scene("teapot"), out, views=2, rig=rig, calibration=False,
                  settings=RenderSettings(samples=2),
                  pattern=Pattern.create(1920, 1080, pitch=32, band=12))
    return out


def _wait_group_gone(pgid: int, timeout: float = 30.0) -> bool:
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        try:
            os.killpg(pgid, 0)
        except ProcessLookupError:
            return True
        time.sleep(0.05)
    return False


def _run(cmd: list[str], env: dict, kill_after: float | None) -> tuple[bool, bool]:
    """Run ``cmd``; kill it with SIGKILL after ``kill_after`` s. Returns (killed, group gone)."""
    p = subprocess.Popen(cmd, env=env, start_new_session=True, stdout=subprocess.DEVNULL,
                         stderr=subprocess.DEVNULL)
    try:
        p.wait(timeout=kill_after)
        killed = False
    except subprocess.TimeoutExpired:
        os.kill(p.pid, signal.SIGKILL)
        p.wait()
        killed = True
    return killed, _wait_group_gone(p.pid)


def _model_state(out: Path, ref) -> str:
    from nurbscan.errors import NurbscanError
    from nurbscan.reconstruct import load_model

    if not out.exists():
        return "absent"
    try:
        m = load_model(out)
    except NurbscanError:
        return "bad"
    ok = (len(list((out / "overlays").glob("*.png"))) == len(m.views) == len(ref.views)
          and np.array_equal(m.points, ref.points) and len(m.surfaces) == len(ref.surfaces))
    return "complete" if ok else "bad"


def _file_state(out: Path, ref: bytes) -> str:
    if not out.exists():
        return "absent"
    return "complete" if out.read_bytes() == ref else "bad"


def _timed(cmd: list[str], env: dict) -> float:
    """Wall time of one uninterrupted run of ``cmd`` (s)."""
    t0 = time.monotonic()
    _run(cmd, env, None)
    return time.monotonic() - t0


def _kills(name: str, cmd: list[str], out: Path, state, env: dict, full_s: float, n: int,
           rng: random.Random) -> dict:
    """``n`` kills of ``cmd``, each at a moment uniform in [0, 1.1] x its uninterrupted time
    (a run that finishes first is counted apart, and one more is started),
    that time re-measured (one uninterrupted run) before every tenth kill: under a varying load
    a time measured once can be shorter than every later run, and no kill would then fall in
    the command's writing (seen: 50 of 50 exports killed before they wrote)."""
    counts = {"kills": 0, "finished_before_the_kill": 0, "absent": 0, "complete": 0, "bad": 0,
              "process_groups_left": 0, "uninterrupted runs after a kill not complete": 0}
    times = [full_s]
    runs = 0
    while counts["kills"] < n and runs < 2 * n:  # n kills (a run may finish first)
        runs += 1
        if runs % 10 == 1:  # also a run after a kill: its output must be whole
            times.append(_timed(cmd, env))
            counts["uninterrupted runs after a kill not complete"] += int(
                state(out) != "complete")
        killed, gone = _run(cmd, env, rng.uniform(0.0, 1.1) * times[-1])
        counts["kills" if killed else "finished_before_the_kill"] += 1
        counts["process_groups_left"] += int(not gone)
        counts[state(out)] += 1
    counts["uninterrupted runs' time, min - max (s)"] = (f"{min(times):.2f} - "
                                                         f"{max(times):.2f}")
    killed, gone = _run(cmd, env, None)
    counts["next_run_state"] = state(out)
    counts["leftovers_after_next_run"] = len([p for p in out.parent.iterdir()
                                              if p.name != out.name])
    return counts


def bench() -> dict:
    from nurbscan.reconstruct import load_model

    n = int(os.environ.get("NURBSCAN_BENCH_KILLS", "50"))
    rng = random.Random(34)
    env = {**os.environ, "PYTHONPATH": str(SRC)}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        scan = _scan(tmp / "scan")
        (tmp / "rec").mkdir()
        (tmp / "exp").mkdir()
        model = tmp / "rec" / "model"

        def rec_cmd(folder: Path) -> list[str]:
            return [sys.executable, "-m", "nurbscan", "reconstruct", str(scan), "--calib",
                    str(scan / "truth" / "rig.json"), "-o", str(folder), "--no-fuse", "-q",
                    "--workers", "2"]

        rec = rec_cmd(model)
        t0 = time.monotonic()
        subprocess.run(rec, env=env, check=True, capture_output=True)
        rec_s = time.monotonic() - t0
        ref = load_model(model)
        shutil.rmtree(model)
        glb = tmp / "exp" / "model.glb"
        exp = [sys.executable, "-m", "nurbscan", "export", str(tmp / "ref_model"),
               "--patches", "--no-colour", "-o", str(glb), "-q"]
        subprocess.run(rec_cmd(tmp / "ref_model"), env=env, check=True, capture_output=True)
        t0 = time.monotonic()
        subprocess.run(exp, env=env, check=True, capture_output=True)
        exp_s = time.monotonic() - t0
        ref_glb = glb.read_bytes()
        glb.unlink()
        out = {"reconstruct_s": round(rec_s, 2), "export_s": round(exp_s, 2),
               "reconstruct": _kills("reconstruct", rec, model,
                                     lambda p: _model_state(p, ref), env, rec_s, n, rng),
               "export": _kills("export", exp, glb, lambda p: _file_state(p, ref_glb), env,
                                exp_s, n, rng)}
    out["bad_outputs"] = sum(out[c]["bad"] + out[c]["uninterrupted runs after a kill not complete"]
                             for c in ("reconstruct", "export"))
    out["leftovers"] = (out["reconstruct"]["leftovers_after_next_run"]
                        + out["export"]["leftovers_after_next_run"])
    return out


if __name__ == "__main__":
    import json

    print(json.dumps(bench(), indent=1))
