"""The command-line bad-input suite (issue #34), a sample: benchmarks/bench_badinput.py runs
every command with every class of damaged input; here one or two cases of each class run on
the quick fixtures (flat images, a synthetic model), and the export memory budget.

Each case must exit with status 2, print one line naming the damaged input (no traceback)
and leave its folder as it was (no partial output, no temporaries).
"""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path

import pytest

from _export_fixtures import sphere_model
from nurbscan.cli import main

ROOT = Path(__file__).resolve().parents[1]


def _bench():
    """benchmarks/bench_badinput.py as a module (loaded once)."""
    if "bench_badinput" not in sys.modules:
        spec = importlib.util.spec_from_file_location("bench_badinput",
                                                      ROOT / "benchmarks" / "bench_badinput.py")
        mod = importlib.util.module_from_spec(spec)
        sys.modules["bench_badinput"] = mod  # its dataclasses look their module up
        spec.loader.exec_module(mod)
    return sys.modules["bench_badinput"]


#: One or two cases of each class, over the commands (ids of bench_badinput.cases).
SAMPLE = (
    "reconstruct/missing/scan folder",
    "export/empty/in/model/model.json",
    "rig/truncated/in/rig.json",
    "detect/wrong_type/in/pattern.json is a named pipe",
    "calibrate/wrong_type/in/scan/scan.json is /dev/zero",
    "detect/wrong_size/white 200 x 150",
    "pattern/wrong_size/in/pattern.png 40000 x 40000 px header",
    "calibrate/malformed_json/calibration.target.inner_corners [0, 0]",
    "simulate/malformed_json/rig.json camera.k1 a string",
    "rig/malformed_json/in/rig.json nested 100000 deep",
    "pattern/unwritable/pattern.json is a folder",
    "rig/unwritable/read-only folder",
    "pattern/disk_full/RLIMIT_FSIZE 0 B",
    "simulate/absurd_options/--seed -1",
    "export/absurd_options/--per-span 0",
    # failing in the recorded run (a57f06a), fixed since:
    "demo/disk_full/RLIMIT_FSIZE 0 B",  # 'nurbscan pattern: error', out/demo left behind
    "batch/malformed_json/in/rig.json a list",  # two lines, OUT/batch.json written
    "batch/absurd_options/--workers -1",  # exit 0
)


@pytest.fixture(scope="module")
def suite(tmp_path_factory):
    bench = _bench()
    fixtures = bench.make_fixtures(tmp_path_factory.mktemp("badinput") / "fixtures",
                                   full=False)
    return bench, fixtures


def test_sample_of_bad_inputs_fails_cleanly(suite, tmp_path):
    bench, fixtures = suite
    by_id = {c.id: c for c in bench.cases(full=False)}
    missing = [i for i in SAMPLE if i not in by_id]
    assert not missing, missing
    results = bench.run_cases([by_id[i] for i in SAMPLE], fixtures, tmp_path)
    bad = {r["id"]: (r["problems"], r["stderr"][-600:]) for r in results if r["problems"]}
    assert not bad, json.dumps(bad, indent=1)
    summary = bench.summarise(results)
    assert summary["passed"] == len(SAMPLE) and summary["tracebacks"] == 0
    assert set(summary["per class"]) == set(bench.CLASSES)


def test_error_lines_ignore_progress_and_usage_only():
    bench = _bench()
    err = ("usage: nurbscan x [-h]\n  continued\n[  0.1 s] load m\n"
           "nurbscan x: warning: a warning\n/a/b.py:195: UserWarning: image: blank\n"
           "nurbscan x: error: m/model.json: not JSON\n")
    assert bench.error_lines(err) == ["nurbscan x: error: m/model.json: not JSON"]
    assert len(bench.error_lines(err + "Traceback (most recent call last):\n")) == 2


def test_snapshot_sees_new_changed_and_removed_files(tmp_path):
    bench = _bench()
    (tmp_path / "a").write_text("1")
    before = bench.snapshot(tmp_path)
    (tmp_path / ".a.tmp-1").write_text("x")
    assert set(bench.snapshot(tmp_path)) - set(before) == {".a.tmp-1"}
    (tmp_path / ".a.tmp-1").unlink()
    (tmp_path / "a").write_text("22")
    assert bench.snapshot(tmp_path)["a"] != before["a"]


# ---------------------------------------------------------------------- export memory budget
def test_tessellation_vertices_match_the_tessellation():
    from nurbscan.export.mesh import tessellate, tessellation_vertices

    surfaces = [s["surface"] for s in sphere_model(with_teapot=True).surfaces]
    for k in (1, 3, 7):
        assert tessellation_vertices(surfaces, k) == sum(len(tessellate(s, k)[0])
                                                         for s in surfaces)


def test_export_per_span_over_the_memory_budget_is_refused_before_allocating(tmp_path, capsys):
    """Four sphere patches (1 x 2 knot spans each) at --per-span 100: 81,204 vertices, about
    0.121 GiB at 1600 B per vertex: over a 0.1 GiB budget, refused with the estimate; the
    largest per-span the message offers is exported."""
    import resource

    from nurbscan.export.mesh import BYTES_PER_VERTEX, largest_per_span, memory_estimate

    model = sphere_model()
    model.save(tmp_path / "model")
    surfaces = [s["surface"] for s in model.surfaces if s["kind"] == "gordon"]
    assert memory_estimate(surfaces, 100) == 4 * 101 * 201 * BYTES_PER_VERTEX
    out = tmp_path / "m.glb"
    rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    assert main(["export", str(tmp_path / "model"), "--patches", "--no-colour", "--per-span",
                 "100", "--memory-budget", "0.1", "-o", str(out), "-q"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "Traceback" not in err[0], err
    assert "--per-span 100" in err[0] and "0.121 GiB" in err[0] and "0.1 GiB" in err[0], err
    assert not out.exists() and sorted(p.name for p in tmp_path.iterdir()) == ["model"]
    assert resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - rss0 < 100_000  # KiB
    k = largest_per_span(surfaces, 0.1 * 2**30)
    assert memory_estimate(surfaces, k) <= 0.1 * 2**30 < memory_estimate(surfaces, k + 1)
    assert f"at most {k} fits" in err[0]
    assert main(["export", str(tmp_path / "model"), "--patches", "--no-colour", "--per-span",
                 str(k), "--memory-budget", "0.1", "-o", str(out), "-q"]) == 0
    import trimesh

    mesh = trimesh.load(out, force="mesh")
    assert len(mesh.vertices) <= 4 * (k + 1) * (2 * k + 1)
    assert len(mesh.vertices) > 2 * (k + 1) * (2 * k + 1)  # merged seams only


@pytest.mark.parametrize("budget", ["0", "-1", "nan", "inf"])
def test_export_absurd_memory_budget_is_one_line(tmp_path, capsys, budget):
    sphere_model().save(tmp_path / "model")
    assert main(["export", str(tmp_path / "model"), "--patches", "--memory-budget", budget,
                 "-o", str(tmp_path / "m.glb"), "-q"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"--memory-budget {float(budget)}" in err[0], err
    assert not (tmp_path / "m.glb").exists()


# ---------------------------------------------------------------------- classes fixed since a57f06a
def test_evaluate_refuses_a_model_view_without_its_truth_file(tmp_path, capsys):
    """A model of views 0 and 1 against a truth folder holding view_00.npz only: one line
    naming view_01.npz, nothing written (was: exit 0, view 1 left out of the coverage). With
    the file there the same command evaluates both views."""
    import numpy as np

    from nurbscan.reconstruct import Model
    from nurbscan.simulate.scenes import make_scene

    truth = tmp_path / "truth"
    truth.mkdir()
    (truth / "scene.json").write_text(json.dumps(make_scene("sphere").to_dict()))
    sid, pts = np.full((4, 4), -1), np.zeros((4, 4, 3))
    np.savez(truth / "view_00.npz", surface_id=sid, point_obj=pts)
    n = 5
    Model(views=[{"index": 0, "table_angle": 0.0}, {"index": 1, "table_angle": 3.0}],
          points=np.ones((n, 3)), normals=np.ones((n, 3)) / 3 ** 0.5,
          point_view=np.zeros(n, int)).save(tmp_path / "m")
    argv = ["evaluate", str(tmp_path / "m"), "--truth", str(truth), "-o",
            str(tmp_path / "ev.json"), "-q"]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "view_01.npz" in err[0] and "view 1" in err[0], err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m", "truth"]
    np.savez(truth / "view_01.npz", surface_id=sid, point_obj=pts)
    assert main(argv) == 0
    capsys.readouterr()
    ev = json.loads((tmp_path / "ev.json").read_text())
    assert [v["index"] for v in ev["views"]] == [0, 1]


def test_evaluate_takes_a_merged_model_against_its_first_pass_truth(tmp_path, capsys):
    """A merged model (views 0 of pass 0, 100 of pass 1) against the first pass's truth
    (view_00.npz only): evaluated (exit 0), view 100 with coverage None, as ``demo --passes
    2`` does (the check above refused it: the demo exited 2 and removed its folder); a
    first-pass view without its file is still refused."""
    import numpy as np

    from nurbscan.reconstruct import Model
    from nurbscan.simulate.scenes import make_scene

    truth = tmp_path / "truth"
    truth.mkdir()
    (truth / "scene.json").write_text(json.dumps(make_scene("sphere").to_dict()))
    np.savez(truth / "view_00.npz", surface_id=np.full((4, 4), -1),
             point_obj=np.zeros((4, 4, 3)))
    n = 5
    views = [{"index": 0, "table_angle": 0.0, "pass": 0},
             {"index": 100, "table_angle": 0.0, "pass": 1}]
    argv = ["evaluate", str(tmp_path / "m"), "--truth", str(truth), "-o",
            str(tmp_path / "ev.json"), "-q"]
    for extra, status in (([], 0), ([{"index": 1, "table_angle": 3.0, "pass": 0}], 2)):
        Model(views=views + extra, points=np.ones((n, 3)), normals=np.ones((n, 3)) / 3 ** 0.5,
              point_view=np.zeros(n, int)).save(tmp_path / "m")
        assert main(argv) == status
        err = capsys.readouterr().err
        if status:
            assert "view_01.npz" in err and "view 100" not in err, err
    ev = json.loads((tmp_path / "ev.json").read_text())
    assert [(v["index"], v["coverage"]) for v in ev["views"]] == [(0, None), (100, None)]


@pytest.mark.parametrize("scene", ["[1, 2]", '{"type": "nurbscan.scene", "name": "dragon"}'])
def test_evaluate_names_scene_json_when_it_is_not_a_scene(tmp_path, capsys, scene):
    import numpy as np

    from nurbscan.reconstruct import Model

    truth = tmp_path / "truth"
    truth.mkdir()
    (truth / "scene.json").write_text(scene)
    Model(views=[{"index": 0}], points=np.ones((5, 3)), normals=np.ones((5, 3)) / 3 ** 0.5,
          point_view=np.zeros(5, int)).save(tmp_path / "m")
    assert main(["evaluate", str(tmp_path / "m"), "--truth", str(truth), "-o",
                 str(tmp_path / "ev.json"), "-q"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(truth / "scene.json") in err[0], err
    assert not (tmp_path / "ev.json").exists()


@pytest.mark.parametrize("data", [b'{"type": "nurbscan.model"}', b"ply\n\n\n",
                                  b"ply\nformat ascii 1.0\nelement vertex 2\nproperty float x"
                                  b"\nproperty float y\nend_header\n1 2\n3 4\n"])
def test_a_fused_ply_of_another_kind_is_one_line(tmp_path, data):
    """JSON, a bare header and 2-D vertices in fused.ply (the first was an IndexError traceback
    from trimesh's PLY parser in ``nurbscan merge``); a real one still reads."""
    import numpy as np

    from nurbscan.errors import NurbscanError
    from nurbscan.merge.fusion import FusedMesh, read_fused, write_fused

    V = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    mesh = FusedMesh(V, np.array([[0, 1, 2]]), np.full((3, 4), 200, np.uint8), {})
    good = write_fused(tmp_path, mesh)
    assert np.allclose(read_fused(good).vertices, V)
    bad = tmp_path / "bad.ply"
    bad.write_bytes(data)
    with pytest.raises(NurbscanError, match="bad.ply") as e:
        read_fused(bad)
    assert "\n" not in str(e.value)


def test_a_failed_demo_removes_what_it_wrote_into_a_folder_that_was_there(tmp_path, capsys):
    """The simulate step refused (a rig file that is not JSON) after the pattern was written:
    one 'nurbscan demo' line naming the step and the file; the folder's own file kept, the
    new pattern removed (was: 'nurbscan simulate: error', pattern.png and pattern.json left)."""
    from nurbscan.cli import demo

    out = tmp_path / "demo"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    calls = []

    def fake(argv):  # the pattern step writes, the next one fails as simulate would
        calls.append(argv[0])
        if argv[0] == "pattern":
            (out / "pattern.png").write_bytes(b"png")
            return 0
        from nurbscan.errors import NurbscanError

        raise NurbscanError(f"{argv[0]}: {out / 'scan' / 'rig.json'}: not valid JSON")

    import unittest.mock

    with unittest.mock.patch.object(demo, "_cli", fake):
        assert main(["demo", "-o", str(out), "--views", "1", "--width", "64",
                     "--height", "48"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    err = [e for e in err if not e.startswith("[")]
    assert calls == ["pattern", "simulate"]
    assert len(err) == 1 and err[0].startswith("nurbscan demo: error: simulate: "), err
    assert sorted(p.name for p in out.iterdir()) == ["notes.txt"]


def test_report_checks_an_overlay_header_before_decoding(tmp_path, capsys):
    """An --overlay PNG whose header claims 40000 x 40000 px: one line naming it, no report
    (was: OpenCV's CV_IO_MAX_IMAGE_PIXELS assertion as a cv2.error traceback)."""
    model = sphere_model()
    model.save(tmp_path / "model")
    _bench().huge_png_header("huge.png")(tmp_path)
    out = tmp_path / "r.html"
    assert main(["report", str(tmp_path / "model"), "-o", str(out), "-q", "--no-detect",
                 "--no-heat-map", "--overlay", str(tmp_path / "huge.png")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "huge.png" in err[0] and "40000 x 40000" in err[0], err
    assert not out.exists()
