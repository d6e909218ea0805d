"""Reliability (issue #34): model folders written whole under a lock, killed runs, concurrent
writers, malformed inputs and absurd results as one-line errors, deterministic outputs."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from nurbscan.cli import main
from nurbscan.errors import NurbscanError
from nurbscan.io.atomic import atomic_folder, folder_lock, lock_path, stale_temporaries
from nurbscan.reconstruct import Model, load_model

SRC = Path(__file__).resolve().parents[1] / "src"


@pytest.fixture(scope="module")
def small_scan(tmp_path_factory):
    """A 768 x 576, 2-view teapot scan with a coarse grid (pitch 32, band 12 projector px)."""
    from nurbscan.pattern import Pattern
    from nurbscan.simulate.render import RenderSettings
    from nurbscan.simulate.rig import default_rig, scale_camera
    from nurbscan.simulate.scan import simulate_scan
    from nurbscan.simulate.scenes import make_scene

    out = tmp_path_factory.mktemp("scan") / "scan"
    rig = scale_camera(default_rig(), 768, 576)
    simulate_scan(make_scene("teapot"), out, views=2, rig=rig, calibration=False,
                  settings=RenderSettings(samples=2),
                  pattern=Pattern.create(1920, 1080, pitch=32, band=12))
    return out


def _model(n: int = 5, value: float = 1.0) -> Model:
    return Model(views=[{"index": 0}], points=np.full((n, 3), value),
                 normals=np.ones((n, 3)) / np.sqrt(3), point_view=np.zeros(n, int),
                 meta={"value": value})


def _one_line(capsys, *words: str) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert "Traceback" not in err[0]
    for w in words:
        assert w in err[0], err
    return err[0]


# ---------------------------------------------------------------------- atomic model folder
def test_failed_save_leaves_the_old_model_folder_as_it_was(tmp_path, monkeypatch):
    """A save that fails after points.npz was written (model.json not yet) leaves the old
    folder untouched: never an old model.json beside a new points.npz; no temporaries."""
    import nurbscan.reconstruct.model as model_mod

    out = tmp_path / "model"
    _model(5, 1.0).save(out)
    before = {p.name: p.read_bytes() for p in out.iterdir()}

    def boom(*a, **k):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(model_mod, "write_json", boom)
    with pytest.raises(NurbscanError, match="No space left"):
        _model(7, 2.0).save(out)
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["model"]
    assert len(load_model(out).points) == 5


def test_load_model_refuses_points_of_another_run(tmp_path):
    """A model.json beside the points.npz of another run (the state a kill between two file
    renames could leave before) is a one-line error, not a silently mismatched model."""
    a, b = tmp_path / "a", tmp_path / "b"
    _model(5, 1.0).save(a)
    _model(7, 2.0).save(b)
    shutil.copy(b / "points.npz", a / "points.npz")
    with pytest.raises(NurbscanError, match="does not match model.json"):
        load_model(a)
    (a / "points.npz").write_bytes(b"PK\x03\x04 not a zip")
    with pytest.raises(NurbscanError, match="points.npz"):
        load_model(a)


def test_bad_points_npz_is_a_one_line_error(tmp_path):
    """points.npz of the wrong arrays (no checksum to catch it) and model.json of wrong types."""
    out = tmp_path / "m"
    _model().save(out)
    doc = json.loads((out / "model.json").read_text())
    del doc["checksums"]
    (out / "model.json").write_text(json.dumps(doc))
    np.savez(out / "points.npz", points=np.zeros((4, 2)), normals=np.zeros((4, 3)),
             point_view=np.zeros(4, int), edge_points=np.zeros((0, 3)), edge_view=np.zeros(0))
    with pytest.raises(NurbscanError, match="wrong shape or type"):
        load_model(out)
    np.savez(out / "points.npz", points=np.zeros((4, 3)))
    with pytest.raises(NurbscanError, match="not a model's points.npz"):
        load_model(out)
    (out / "points.npz").unlink()
    for bad in ({**doc, "curves": 5}, {**doc, "views": "x"}, {**doc, "meta": [1]},
                {**doc, "surfaces": [{"kind": "gordon", "surface": {"degree_u": "a"}}]},
                {**doc, "checksums": 3}):
        (out / "model.json").write_text(json.dumps(bad))
        with pytest.raises(NurbscanError) as e:
            load_model(out)
        assert "\n" not in str(e.value) and "model.json" in str(e.value)


def test_save_refuses_to_replace_a_folder_of_other_files(tmp_path):
    """-o at a folder holding other things is refused, and nothing of it is removed."""
    docs = tmp_path / "docs"
    docs.mkdir()
    (docs / "thesis.tex").write_text("precious")
    with pytest.raises(NurbscanError, match="thesis.tex"):
        _model().save(docs)
    assert (docs / "thesis.tex").read_text() == "precious"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["docs"]


def test_second_writer_is_refused_and_a_dead_writers_lock_taken_over(tmp_path):
    out = tmp_path / "model"
    with folder_lock(out):
        with pytest.raises(NurbscanError, match=f"pid {os.getpid()} is writing"):
            _model().save(out)
    assert not out.exists() and not lock_path(out).exists()
    # a lock file and temporaries left by a process killed with -9
    p = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    lock_path(out).write_text(f"{p.pid}\n")
    (tmp_path / f".model.tmp-{p.pid}").mkdir()
    (tmp_path / f".model.tmp-{p.pid}" / "points.npz").write_bytes(b"half")
    p.kill()
    p.wait()
    _model().save(out)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["model"]
    assert stale_temporaries(out) == []


def test_atomic_folder_onto_a_file_is_a_one_line_error(tmp_path):
    f = tmp_path / "model"
    f.write_text("x")
    with pytest.raises(NurbscanError, match="it is a file"), atomic_folder(f):
        pass
    assert f.read_text() == "x"


def test_concurrent_reconstruct_is_refused(small_scan, tmp_path, capsys):
    out = tmp_path / "model"
    with folder_lock(out):
        assert main(["reconstruct", str(small_scan), "--calib",
                     str(small_scan / "truth" / "rig.json"), "-o", str(out), "-q"]) == 2
    _one_line(capsys, str(out), "is writing this folder")
    assert not out.exists()


def _wait_group_gone(pgid: int, timeout: float = 20.0) -> None:
    """Wait until no process of group ``pgid`` is left (the workers die with the parent)."""
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        try:
            os.killpg(pgid, 0)
        except ProcessLookupError:
            return
        time.sleep(0.1)
    raise AssertionError(f"processes of group {pgid} still alive {timeout} s after the kill")


def reconstruct_command(scan: Path, out: Path) -> list[str]:
    """The reconstruction the kill tests interrupt: two views in two workers, no fused mesh."""
    return [sys.executable, "-m", "nurbscan", "reconstruct", str(scan), "--calib",
            str(scan / "truth" / "rig.json"), "-o", str(out), "--views", "0", "1",
            "--no-fuse", "-q", "--workers", "2"]


def check_model_folder(out: Path, reference: Model | None) -> str:
    """``"absent"``, ``"complete"`` (loads, its arrays those of ``reference``); raises if the
    folder is anything else (partial, mixed, corrupt)."""
    if not out.exists():
        return "absent"
    names = {p.name for p in out.iterdir()}
    assert {"model.json", "points.npz", "model.png", "overlays"} <= names, names
    m = load_model(out)  # the checksum ties points.npz to model.json
    assert len(list((out / "overlays").iterdir())) == len(m.views)
    if reference is not None:
        assert np.array_equal(m.points, reference.points)
        assert len(m.surfaces) == len(reference.surfaces)
    return "complete"


def test_kill_9_during_reconstruct_never_leaves_a_mixed_model(small_scan, tmp_path):
    """kill -9 at several moments of `nurbscan reconstruct` (spread over a run's time, the
    last ones in its save): the model folder is each time absent or a complete model equal
    to an uninterrupted run's; the next run leaves no temporaries or lock."""
    env = {**os.environ, "PYTHONPATH": str(SRC)}
    out = tmp_path / "model"
    t0 = time.monotonic()
    subprocess.run(reconstruct_command(small_scan, out), env=env, check=True,
                   capture_output=True)
    full = time.monotonic() - t0
    reference = load_model(out)
    shutil.rmtree(out)
    states = []
    for frac in (0.35, 0.7, 0.9, 0.97, 1.03):
        p = subprocess.Popen(reconstruct_command(small_scan, out), env=env,
                             start_new_session=True, stdout=subprocess.DEVNULL,
                             stderr=subprocess.DEVNULL)
        try:
            p.wait(timeout=frac * full)
        except subprocess.TimeoutExpired:
            os.kill(p.pid, signal.SIGKILL)
            p.wait()
        _wait_group_gone(p.pid)
        states.append(check_model_folder(out, reference))
    assert p.returncode is not None
    subprocess.run(reconstruct_command(small_scan, out), env=env, check=True,
                   capture_output=True)
    assert check_model_folder(out, reference) == "complete"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["model"], states
