"""Benchmark: the command-line bad-input suite (issue #34).

Every command (``pattern``, ``simulate``, ``detect``, ``calibrate``, ``reconstruct``,
``merge``, ``evaluate``, ``export``, ``batch``, ``report``, ``rig``, ``demo``) is run with
inputs of every class of damage:

* ``missing``: an input path that does not exist;
* ``empty``: a 0-byte file, or an empty folder where a folder is read;
* ``truncated``: a file cut to half its bytes (PNG, JSON, ``.npz``, ``.ply``, YAML);
* ``wrong_type``: a file of another kind (a PNG where JSON is read, JSON where an image is, a
  folder where a file is, ``/dev/zero``, a named pipe);
* ``wrong_size``: images of another size than the scan's or the rig's camera;
* ``malformed_json``: JSON with fields of the wrong type, missing keys, nested 100,000 deep;
* ``unwritable``: the output's folder read-only (``chmod 555``; as root, where the mode does
  not stop a write, ``chattr +i``: the folder immutable), the output path a folder, the
  output's folder a file, and for a command writing several files the second of them a
  folder (which shows one that writes the first and fails on the second);
* ``disk_full``: the child runs with ``resource.setrlimit(RLIMIT_FSIZE, (N, N))`` and
  ``SIGXFSZ`` ignored, so that a write past ``N`` bytes fails with ``EFBIG`` as on a full
  disk (``N`` = 0 and 16 KiB: no byte, or the small files but not the large ones; a command
  whose outputs all fit under 16 KiB rightly succeeds, and the case is left out of the
  counts). ``/dev/full`` is not
  used: a command writes a temporary beside its output, and ``/dev`` is no place for it;
* ``absurd_options``: negative, zero, NaN, infinite and huge option values, unknown names.

The inputs come from small fixtures made once: a 320 x 240 teapot scan of 2 views with a
coarse grid (pitch 64, band 24 projector px) and 7 calibration poses, its model
(reconstructed with the true rig, with a fused mesh), a copy of it for ``merge``, an
evaluation and a rig converted to OpenCV YAML. Each case runs in a folder of its own
(inputs hard-linked from the fixtures; a damaged file is replaced, never written through
the link), the output's folder holding an old output where the command writes one, as a
subprocess (``python -m nurbscan``) with a time limit (:data:`TIMEOUT_S`, a hang beyond
it). A case passes when:

* the exit status is 2;
* stderr holds no ``Traceback`` and, besides progress, usage and warning lines, exactly one
  line, ``nurbscan COMMAND: error: ...``, which names the damaged input (its file name, or
  the option: :func:`names`);
* the case's folder (inputs and outputs) is unchanged: the same names, sizes and
  modification times before and after (no partial output, no leftover temporaries or locks).

``bench()`` counts per class and per command: cases, passed, tracebacks, hangs, wrong exit,
bad message, partial outputs; and lists the failures (``$NURBSCAN_BENCH_BADINPUT_FAILS``
of them, default 60). Targets: 0 tracebacks, 0 hangs, 0 partial outputs, 0 failures.
``$NURBSCAN_BENCH_BADINPUT_DUMP``: a file to append each case's result to (JSON lines).
``$NURBSCAN_BENCH_BADINPUT`` (a comma-separated list of commands) runs only those;
``$NURBSCAN_BENCH_BADINPUT_FIXTURES`` keeps the fixtures in that folder and reuses them.
"""

# no ``from __future__ import annotations``: benchmarks/run.py loads this file without
# registering it in sys.modules, where dataclasses would look string annotations up
import contextlib
import json
import os
import re
import resource
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

SRC = Path(__file__).resolve().parents[1] / "src"
CLASSES = ("missing", "empty", "truncated", "wrong_type", "wrong_size", "malformed_json",
           "unwritable", "disk_full", "absurd_options")
#: Time limit of one case, s (a full reconstruct of the fixture takes about 10 s).
TIMEOUT_S = float(os.environ.get("NURBSCAN_BENCH_BADINPUT_TIMEOUT", "180"))
#: Limits of RLIMIT_FSIZE of the disk-full cases, bytes.
FSIZE_LIMITS = (0, 16 << 10)


# ------------------------------------------------------------------------------ fixtures
def make_fixtures(root: Path, full: bool = True) -> Path:
    """The fixtures under ``root``: ``scan/`` (with ``calibration/``), ``rig.json`` (the true
    rig), ``model/`` and ``model2/``, ``evaluation.json``, ``rig.yml``, ``lines.json``.

    ``full=False``: no rendering nor reconstruction (for a quick test): the scan's images
    are flat grey, ``model/`` is a small synthetic model; cases that need a model that
    exports or a scan that reconstructs are then left out (:attr:`Case.full`).
    """
    root.mkdir(parents=True, exist_ok=True)
    env = _env()
    scan = root / "scan"
    if full:
        _simulate(scan)
    else:
        _flat_scan(scan)
    shutil.copy(scan / "truth" / "rig.json", root / "rig.json")
    if full:
        _cli(["reconstruct", str(scan), "--calib", str(root / "rig.json"), "-o",
              str(root / "model"), "-q", "--workers", "1"], env)
        _cli(["evaluate", str(root / "model"), "--truth", str(scan / "truth"), "-o",
              str(root / "evaluation.json"), "-q"], env)
        _cli(["detect", str(scan / "views" / "view_00_grid.png"), "--pattern",
              str(scan / "pattern.json"), "-o", str(root / "lines.json")], env)
    else:
        _synthetic_model(root / "model", scan)
        (root / "evaluation.json").write_text(json.dumps({"type": "nurbscan.evaluation"}))
    shutil.copytree(root / "model", root / "model2")
    _cli(["rig", "convert", str(root / "rig.json"), "-o", str(root / "rig.yml")], env)
    return root


def _simulate(out: Path) -> None:
    import nurbscan.simulate.scan as sim_scan
    from nurbscan.pattern import Pattern
    from nurbscan.simulate import target as sim_target
    from nurbscan.simulate.render import RenderSettings
    from nurbscan.simulate.rig import default_rig, scale_camera
    from nurbscan.simulate.scenes import make_scene

    free = sim_target.FREE_POSES
    sim_target.FREE_POSES = tuple(free[i] for i in (1, 3, 7, 11))
    try:
        sim_scan.simulate_scan(make_scene("teapot"), out, views=2,
                               rig=scale_camera(default_rig(), 320, 240),
                               settings=RenderSettings(samples=2),
                               pattern=Pattern.create(1920, 1080, pitch=64, band=24))
    finally:
        sim_target.FREE_POSES = free


def _flat_scan(out: Path) -> None:
    """A scan folder of flat grey 320 x 240 images (no grid), the true rig, no truth maps."""
    import cv2
    import numpy as np

    from nurbscan.pattern import Pattern
    from nurbscan.simulate.rig import default_rig, scale_camera

    rig = scale_camera(default_rig(), 320, 240)
    (out / "views").mkdir(parents=True)
    (out / "calibration").mkdir()
    (out / "truth").mkdir()
    rig.save(out / "truth" / "rig.json")
    Pattern.create(1920, 1080, pitch=64, band=24).save(out / "pattern.png")
    img = np.full((240, 320, 3), 90, np.uint8)
    views, poses = [], []
    for k in range(2):
        for kind in ("grid", "white"):
            cv2.imwrite(str(out / "views" / f"view_{k:02d}_{kind}.png"), img)
        views.append({"index": k, "table_angle": k * 3.14159,
                      "grid": f"views/view_{k:02d}_grid.png",
                      "white": f"views/view_{k:02d}_white.png"})
    for k in range(3):
        for kind in ("grid", "white"):
            cv2.imwrite(str(out / "calibration" / f"pose_{k:02d}_{kind}.png"), img)
        poses.append({"index": k, "kind": "free", "white": f"calibration/pose_{k:02d}_white.png",
                      "grid": f"calibration/pose_{k:02d}_grid.png"})
    doc = {"type": "nurbscan.scan", "version": 1, "image_size": [320, 240], "bit_depth": 8,
           "pattern": {"image": "pattern.png", "sidecar": "pattern.json"},
           "angle_unit": "radians", "views": views,
           "calibration": {"target": {"type": "nurbscan.chessboard", "version": 1,
                                      "inner_corners": [9, 7], "square_mm": 20.0,
                                      "margin_mm": 20.0, "first_square_dark": True},
                           "poses": poses}}
    (out / "scan.json").write_text(json.dumps(doc, indent=1))


def _synthetic_model(folder: Path, scan: Path) -> None:
    import numpy as np

    from nurbscan.reconstruct import Model

    n = 50
    rng = np.random.default_rng(0)
    Model(views=[{"index": 0, "table_angle": 0.0}], points=rng.normal(size=(n, 3)) * 20,
          normals=np.tile([0.0, 0.0, 1.0], (n, 1)), point_view=np.zeros(n, int),
          meta={"source": str(scan)}).save(folder)


def _env() -> dict:
    return {**os.environ, "PYTHONPATH": str(SRC), "OMP_NUM_THREADS": "1",
            "OPENBLAS_NUM_THREADS": "1", "PYTHONDONTWRITEBYTECODE": "1"}


def _cli(argv: list[str], env: dict) -> None:
    subprocess.run([sys.executable, "-m", "nurbscan", *argv], env=env, check=True,
                   capture_output=True)


# ------------------------------------------------------------------------------ damage
def _replace(path: Path, data: bytes) -> None:
    """Replace the file (a hard link to a fixture: unlinked first, never written through)."""
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path)
    elif path.exists() or path.is_symlink():
        path.unlink()
    path.write_bytes(data)


def empty(rel: str) -> Callable[[Path], None]:
    return lambda d: _replace(d / rel, b"")


def truncated(rel: str) -> Callable[[Path], None]:
    def f(d: Path) -> None:
        data = (d / rel).read_bytes()
        _replace(d / rel, data[: len(data) // 2])
    return f


def removed(rel: str) -> Callable[[Path], None]:
    def f(d: Path) -> None:
        p = d / rel
        if p.is_dir():
            shutil.rmtree(p)
        else:
            p.unlink()
    return f


def emptied_folder(rel: str) -> Callable[[Path], None]:
    def f(d: Path) -> None:
        shutil.rmtree(d / rel)
        (d / rel).mkdir()
    return f


def other_file(rel: str, src: str) -> Callable[[Path], None]:
    """``rel`` replaced by a copy of another fixture file (a file of another kind)."""
    return lambda d: _replace(d / rel, (d / src).read_bytes())


def a_folder(rel: str) -> Callable[[Path], None]:
    def f(d: Path) -> None:
        _replace(d / rel, b"")
        (d / rel).unlink()
        (d / rel).mkdir()
    return f


def a_fifo(rel: str) -> Callable[[Path], None]:
    def f(d: Path) -> None:
        p = d / rel
        if p.exists():
            p.unlink()
        os.mkfifo(p)
    return f


def dev_zero(rel: str) -> Callable[[Path], None]:
    def f(d: Path) -> None:
        p = d / rel
        if p.exists():
            p.unlink()
        p.symlink_to("/dev/zero")
    return f


def json_edit(rel: str, change: Callable[[dict], object]) -> Callable[[Path], None]:
    """``rel`` (JSON) with ``change(doc)`` applied (returning a new document, or editing)."""
    def f(d: Path) -> None:
        doc = json.loads((d / rel).read_text())
        new = change(doc)
        _replace(d / rel, json.dumps(doc if new is None else new).encode())
    return f


def json_deep(rel: str) -> Callable[[Path], None]:
    return lambda d: _replace(d / rel, b"[" * 100_000 + b"]" * 100_000)


def image_resized(rel: str, w: int = 200, h: int = 150) -> Callable[[Path], None]:
    def f(d: Path) -> None:
        import cv2

        img = cv2.imread(str(d / rel), cv2.IMREAD_UNCHANGED)
        ok, buf = cv2.imencode(Path(rel).suffix, cv2.resize(img, (w, h)))
        _replace(d / rel, buf.tobytes())
    return f


def huge_png_header(rel: str) -> Callable[[Path], None]:
    """A PNG whose header claims 40000 x 40000 px (the data is a 1 x 1 image's)."""
    def f(d: Path) -> None:
        import zlib

        import cv2
        import numpy as np

        ok, buf = cv2.imencode(".png", np.zeros((1, 1, 3), np.uint8))
        data = bytearray(buf.tobytes())
        data[16:24] = (40000).to_bytes(4, "big") * 2
        data[29:33] = zlib.crc32(bytes(data[12:29])).to_bytes(4, "big")
        _replace(d / rel, bytes(data))
    return f


def chain(*fs: Callable[[Path], None]) -> Callable[[Path], None]:
    def f(d: Path) -> None:
        for g in fs:
            g(d)
    return f


def _set(path: list, value) -> Callable[[dict], None]:
    def change(doc):
        obj = doc
        for k in path[:-1]:
            obj = obj[k]
        obj[path[-1]] = value
    return change


def _drop(path: list) -> Callable[[dict], None]:
    def change(doc):
        obj = doc
        for k in path[:-1]:
            obj = obj[k]
        del obj[path[-1]]
    return change


# ------------------------------------------------------------------------------ cases
@dataclass
class Case:
    """One command line with one damaged input.

    ``argv`` is relative to the case's folder (inputs under ``in/``, outputs under ``out/``);
    ``setup`` damages the inputs; ``expect`` must appear in the error line (the input's name
    or the option); ``fsize``: the RLIMIT_FSIZE of a disk-full case; ``unwritable``: make
    ``out/`` read-only; ``full``: needs the full fixtures (a scan that reconstructs).
    """

    command: str
    cls: str
    name: str
    argv: list[str]
    expect: str
    setup: Callable[[Path], None] | None = None
    inputs: tuple[str, ...] = ()
    old_outputs: tuple[str, ...] = ()
    fsize: int | None = None
    unwritable: bool = False
    full: bool = False
    timeout: float = TIMEOUT_S
    extra: dict = field(default_factory=dict)

    @property
    def id(self) -> str:
        return f"{self.command}/{self.cls}/{self.name}"


def _output_cases(command: str, argv: list[str], out: str, inputs: tuple[str, ...],
                  old: tuple[str, ...], full: bool, folder: bool = False,
                  second: str | None = None) -> list[Case]:
    """The unwritable and disk-full cases of a command writing ``out`` (``old``: outputs
    present before it runs; ``second``: another file it writes beside ``out``, made a folder
    in one case: the first written, the second refused)."""
    def with_out(o: str) -> list[str]:
        return [o if a == out else a for a in argv]

    cases = [
        Case(command, "unwritable", "read-only folder", argv, "out", inputs=inputs,
             old_outputs=old, unwritable=True, full=full),
        Case(command, "unwritable", "output's folder is a file", with_out("out/afile/x"
             + Path(out).suffix), "afile", inputs=inputs, old_outputs=old + ("out/afile",),
             full=full),
    ]
    if not folder:
        cases.append(Case(command, "unwritable", "output is a folder", argv,
                          Path(out).name, inputs=inputs,
                          setup=lambda d: (d / out).mkdir(parents=True, exist_ok=True),
                          full=full))
    else:
        cases.append(Case(command, "unwritable", "output is a file", argv, Path(out).name,
                          inputs=inputs, setup=lambda d: (d / out).write_text("a file\n"),
                          full=full))
    if second is not None:
        cases.append(Case(command, "unwritable", f"{Path(second).name} is a folder", argv,
                          Path(second).name, inputs=inputs,
                          old_outputs=tuple(o for o in old if o != second),
                          setup=lambda d: (d / second).mkdir(parents=True, exist_ok=True),
                          full=full))
    for n in FSIZE_LIMITS:
        cases.append(Case(command, "disk_full", f"RLIMIT_FSIZE {n} B", argv, "out",
                          inputs=inputs, old_outputs=old, fsize=n, full=full))
    return cases


def _absurd(command: str, argv: list[str], inputs: tuple[str, ...],
            options: list[tuple[str, ...]], full: bool = False) -> list[Case]:
    return [Case(command, "absurd_options", " ".join(opt), argv + list(opt), opt[0],
                 inputs=inputs, full=full) for opt in options]


def _file_cases(command: str, argv: list[str], inputs: tuple[str, ...], rel: str, kind: str,
                other: str, full: bool = False, expect: str | None = None,
                skip: tuple[str, ...] = ()) -> list[Case]:
    """missing, empty, truncated and wrong-type cases of the input file ``rel`` (``kind``:
    json, image, npz, ply, yml; ``other``: a fixture file of another kind)."""
    name = expect or Path(rel).name
    cases = [
        Case(command, "missing", rel, argv, name, setup=removed(rel), inputs=inputs,
             full=full),
        Case(command, "empty", rel, argv, name, setup=empty(rel), inputs=inputs, full=full),
        Case(command, "truncated", rel, argv, name, setup=truncated(rel), inputs=inputs,
             full=full),
        Case(command, "wrong_type", f"{rel} is another kind of file", argv, name,
             setup=other_file(rel, other), inputs=inputs, full=full),
        Case(command, "wrong_type", f"{rel} is a folder", argv, name, setup=a_folder(rel),
             inputs=inputs, full=full),
        Case(command, "wrong_type", f"{rel} is /dev/zero", argv, name, setup=dev_zero(rel),
             inputs=inputs, full=full),
        Case(command, "wrong_type", f"{rel} is a named pipe", argv, name, setup=a_fifo(rel),
             inputs=inputs, full=full),
    ]
    if kind == "json":
        cases.append(Case(command, "malformed_json", f"{rel} nested 100000 deep", argv, name,
                          setup=json_deep(rel), inputs=inputs, full=full))
        cases.append(Case(command, "malformed_json", f"{rel} a list", argv, name,
                          setup=lambda d: _replace(d / rel, b"[1, 2, 3]"), inputs=inputs,
                          full=full))
    if kind == "image":
        cases.append(Case(command, "wrong_size", f"{rel} 40000 x 40000 px header", argv, name,
                          setup=huge_png_header(rel), inputs=inputs, full=full))
    return [c for c in cases if c.cls not in skip]


def _scan_json_cases(command: str, argv: list[str], inputs: tuple[str, ...], scan: str,
                     full: bool) -> list[Case]:
    sj = f"{scan}/scan.json"
    bad = [
        ("image_size a string", _set(["image_size"], "320x240")),
        ("views not a list", _set(["views"], {"grid": "x.png"})),
        ("views[0] without grid", _drop(["views", 0, "grid"])),
        ("views[0].grid a number", _set(["views", 0, "grid"], 7)),
        ("views[0].table_angle a string", _set(["views", 0, "table_angle"], "ninety")),
        ("views[0].index a float", _set(["views", 0, "index"], 0.5)),
        ("pattern a list", _set(["pattern"], ["pattern.png"])),
        ("calibration.poses[0] without white", _drop(["calibration", "poses", 0, "white"])),
        ("calibration.target.inner_corners [0, 0]",
         _set(["calibration", "target", "inner_corners"], [0, 0])),
        ("calibration.target.square_mm -20", _set(["calibration", "target", "square_mm"], -20)),
        ("views[0].grid leaves the folder", _set(["views", 0, "grid"], "../../../etc/passwd")),
        ("type missing", _drop(["type"])),
    ]
    if command != "calibrate":  # the target is read by calibrate only
        bad = [(n, ch) for n, ch in bad if "target" not in n]
    cases = [Case(command, "malformed_json", n, argv, "scan.json", setup=json_edit(sj, ch),
                  inputs=inputs, full=full) for n, ch in bad]
    cases += [
        Case(command, "wrong_size", "scan.json image_size 640 x 480", argv, "scan.json",
             setup=json_edit(sj, _set(["image_size"], [640, 480])), inputs=inputs, full=full),
    ]
    return cases


def _rig_json_cases(command: str, argv: list[str], inputs: tuple[str, ...], rel: str,
                    full: bool) -> list[Case]:
    bad = [
        ("camera.k1 a string", _set(["camera", "k1"], "zero")),
        ("camera without R", _drop(["camera", "R"])),
        ("camera.R 2 x 2", _set(["camera", "R"], [[1, 0], [0, 1]])),
        ("projector a number", _set(["projector"], 3)),
        ("camera.width -320", _set(["camera", "width"], -320)),
        ("turntable.direction zero", _set(["turntable", "direction"], [0, 0, 0])),
        ("camera.f NaN", _set(["camera", "f"], float("nan"))),
    ]
    return [Case(command, "malformed_json", f"{Path(rel).name} {n}", argv, Path(rel).name,
                 setup=json_edit(rel, ch), inputs=inputs, full=full) for n, ch in bad]


def _model_cases(command: str, argv: list[str], inputs: tuple[str, ...], model: str,
                 full: bool) -> list[Case]:
    mj = f"{model}/model.json"
    cases = [
        Case(command, "missing", f"{model}/", argv, Path(model).name, setup=removed(model),
             inputs=inputs, full=full),
        Case(command, "empty", f"{model}/ empty", argv, Path(model).name,
             setup=emptied_folder(model), inputs=inputs, full=full),
        Case(command, "wrong_type", f"{model} is a file", argv, Path(model).name,
             setup=lambda d: (shutil.rmtree(d / model), (d / model).write_text("x")),
             inputs=inputs, full=full),
    ]
    cases += _file_cases(command, argv, inputs, mj, "json", "in/scan/pattern.png", full,
                         skip=("missing",))
    cases += _file_cases(command, argv, inputs, f"{model}/points.npz", "npz", mj, full,
                         skip=("wrong_type",))[:3]
    cases += [
        Case(command, "malformed_json", f"model.json {n}", argv, "model.json",
             setup=json_edit(mj, ch), inputs=inputs, full=full)
        for n, ch in [("type wrong", _set(["type"], "nurbscan.scan")),
                      ("surfaces a number", _set(["surfaces"], 5)),
                      ("views a string", _set(["views"], "all")),
                      ("counts a list", _set(["counts"], [1])),
                      ("points checksum wrong",
                       lambda doc: doc.update({k: "0" * 64 for k in doc
                                               if "sha" in k or "checksum" in k}))]]
    return cases


def cases(full: bool = True) -> list[Case]:
    """Every case (``full=False``: those the quick fixtures serve)."""
    out: list[Case] = []
    # pattern ---------------------------------------------------------------------------
    gen = ["pattern", "-o", "out/pattern.png"]
    out += _output_cases("pattern", gen, "out/pattern.png", (),
                         ("out/pattern.png", "out/pattern.json"), False,
                         second="out/pattern.json")
    out += _absurd("pattern", ["pattern", "-o", "out/pattern.png"], (), [
        ("--width", "0"), ("--width", "-5"), ("--width", "100000000"), ("--height", "0"),
        ("--pitch", "0"), ("--pitch", "-16"), ("--band", "0"), ("--band", "40"),
        ("--base", "4"), ("--base", "1"), ("--base", "0"), ("--window", "0"),
        ("--window", "50"), ("--poly", "zzz"), ("--poly", "1,0,0,0")])
    fi = ["pattern", "--from-image", "in/pattern.png", "-o", "out/sidecar.json"]
    out += _file_cases("pattern", fi, ("scan/pattern.png:pattern.png",
                                       "scan/scan.json:scan.json"), "in/pattern.png",
                       "image", "in/scan.json")
    out += _output_cases("pattern", fi, "out/sidecar.json", ("scan/pattern.png:pattern.png",),
                         ("out/sidecar.json",), False)
    # simulate --------------------------------------------------------------------------
    sim = ["simulate", "teapot", "-o", "out/scan", "--views", "1", "--width", "64",
           "--height", "48", "--no-calibration", "--workers", "1"]
    out += _absurd("simulate", sim, (), [
        ("--views", "0"), ("--views", "-3"), ("--views", "100000000"), ("--noise", "nan"),
        ("--noise", "-1"), ("--seed", "-1"), ("--width", "0"), ("--height", "0"),
        ("--width", "10000000"), ("--workers", "-1"), ("--table-albedo", "2"),
        ("--table-albedo", "nan"), ("--pose", "sideways"), ("--pose", "1,2"),
        ("--bit-depth", "12")])
    out.append(Case("simulate", "absurd_options", "scene 'dragon'",
                    ["simulate", "dragon", "-o", "out/scan"], "dragon"))
    simr = sim + ["--rig", "in/rig.json"]
    out += _file_cases("simulate", simr, ("rig.json", "scan/pattern.png:pattern.png"),
                       "in/rig.json", "json", "in/pattern.png")
    out += _rig_json_cases("simulate", simr, ("rig.json",), "in/rig.json", False)
    out += _output_cases("simulate", sim, "out/scan", (), (), False, folder=True)
    # detect ----------------------------------------------------------------------------
    det_in = ("scan/views/view_00_grid.png:grid.png", "scan/views/view_00_white.png:white.png",
              "scan/pattern.json:pattern.json", "rig.json", "scan/scan.json:scan.json")
    det = ["detect", "in/grid.png", "--white", "in/white.png", "--pattern", "in/pattern.json",
           "-o", "out/lines.json", "--overlay", "out/overlay.png"]
    out += _file_cases("detect", det, det_in, "in/grid.png", "image", "in/pattern.json")
    out += _file_cases("detect", det, det_in, "in/white.png", "image", "in/pattern.json")
    out += _file_cases("detect", det, det_in, "in/pattern.json", "json", "in/grid.png")
    out += [Case("detect", "malformed_json", f"pattern.json {n}", det, "pattern.json",
                 setup=json_edit("in/pattern.json", ch), inputs=det_in)
            for n, ch in [("type missing", _drop(["type"])),
                          ("pitch a string", _set(["pitch"], "wide")),
                          ("sequence a number", lambda doc: doc.update(
                              {k: 3 for k in doc if "sequence" in k})),
                          ("width 0", _set(["width"], 0))]]
    out.append(Case("detect", "wrong_size", "white 200 x 150", det, "white.png",
                    setup=image_resized("in/white.png"), inputs=det_in))
    out.append(Case("detect", "wrong_size", "grid 200 x 150 with --calib",
                    det + ["--calib", "in/rig.json"], "grid.png",
                    setup=image_resized("in/grid.png"), inputs=det_in))
    out += _file_cases("detect", det + ["--calib", "in/rig.json"], det_in, "in/rig.json",
                       "json", "in/grid.png", skip=("wrong_size",))
    out += _absurd("detect", det, det_in, [
        ("--gamma", "0"), ("--gamma", "nan"), ("--gamma", "-2"), ("--sigma", "-1"),
        ("--sigma", "nan"), ("--sigma", "1e9")], full=True)
    out += _output_cases("detect", det, "out/lines.json", det_in,
                         ("out/lines.json", "out/overlay.png"), True,
                         second="out/overlay.png")
    # calibrate -------------------------------------------------------------------------
    cal_in = ("scan",)
    cal = ["calibrate", "in/scan/calibration", "-o", "out/calib.json", "-q", "--workers", "1"]
    out.append(Case("calibrate", "missing", "calibration folder", cal, "calibration",
                    setup=removed("in/scan/calibration"), inputs=cal_in))
    out.append(Case("calibrate", "empty", "calibration folder", cal, "pose_00",
                    setup=emptied_folder("in/scan/calibration"), inputs=cal_in))
    out.append(Case("calibrate", "wrong_type", "calibration is a file", cal, "calibration",
                    setup=lambda d: (shutil.rmtree(d / "in/scan/calibration"),
                                     (d / "in/scan/calibration").write_text("x")),
                    inputs=cal_in))
    out += _file_cases("calibrate", cal, cal_in, "in/scan/scan.json", "json",
                       "in/scan/pattern.png")
    out += _scan_json_cases("calibrate", cal, cal_in, "in/scan", False)
    out += _file_cases("calibrate", cal, cal_in, "in/scan/calibration/pose_00_white.png",
                       "image", "in/scan/scan.json", full=True)
    out += _file_cases("calibrate", cal, cal_in, "in/scan/pattern.json", "json",
                       "in/scan/pattern.png", full=True)
    out.append(Case("calibrate", "wrong_size", "pose_00_white 200 x 150", cal,
                    "pose_00_white.png",
                    setup=image_resized("in/scan/calibration/pose_00_white.png"),
                    inputs=cal_in, full=True))
    out += _absurd("calibrate", cal, cal_in, [
        ("--max-points", "-5"), ("--max-points", "0"), ("--camera-pitch", "nan"),
        ("--camera-pitch", "-1"), ("--projector-pitch", "inf"), ("--projector-weight", "0"),
        ("--workers", "-1"), ("--exclude", "0", "1", "2", "3", "4", "5", "6", "7", "8", "9",
                              "10", "11", "12", "13", "14")])
    out += _output_cases("calibrate", cal, "out/calib.json", cal_in,
                         ("out/calib.json", "out/calib_residuals.json",
                          "out/calib_residuals.png"), True,
                         second="out/calib_residuals.png")
    # reconstruct -----------------------------------------------------------------------
    rec_in = ("scan", "rig.json")
    rec = ["reconstruct", "in/scan", "--calib", "in/rig.json", "-o", "out/model", "-q",
           "--workers", "1", "--no-fuse"]
    out.append(Case("reconstruct", "missing", "scan folder", rec, "scan",
                    setup=removed("in/scan"), inputs=rec_in))
    out.append(Case("reconstruct", "empty", "scan folder", rec, "scan.json",
                    setup=emptied_folder("in/scan"), inputs=rec_in))
    out += _file_cases("reconstruct", rec, rec_in, "in/scan/scan.json", "json",
                       "in/scan/pattern.png")
    out += _scan_json_cases("reconstruct", rec, rec_in, "in/scan", False)
    out += _file_cases("reconstruct", rec, rec_in, "in/rig.json", "json",
                       "in/scan/pattern.png")
    out += _rig_json_cases("reconstruct", rec, rec_in, "in/rig.json", False)
    out += _file_cases("reconstruct", rec, rec_in, "in/scan/pattern.json", "json",
                       "in/scan/pattern.png")
    out += _file_cases("reconstruct", rec, rec_in, "in/scan/views/view_00_grid.png", "image",
                       "in/scan/scan.json", full=True)
    out.append(Case("reconstruct", "wrong_size", "view_00_grid 200 x 150", rec,
                    "view_00_grid.png", setup=image_resized("in/scan/views/view_00_grid.png"),
                    inputs=rec_in, full=True))
    out.append(Case("reconstruct", "wrong_size", "rig camera 640 x 480", rec, "rig.json",
                    setup=json_edit("in/rig.json", _set(["camera", "width"], 640)),
                    inputs=rec_in))
    out += _absurd("reconstruct", rec, rec_in, [
        ("--min-curves", "0"), ("--workers", "-1"), ("--table-margin", "nan"),
        ("--table-margin", "-1"), ("--table-radius", "-150"), ("--table-radius", "inf"),
        ("--max-triangles", "0"), ("--views", "99")])
    out.append(Case("reconstruct", "absurd_options", "--max-triangles 0 (fused)",
                    rec[:-1] + ["--max-triangles", "0"], "--max-triangles", inputs=rec_in))
    out += _output_cases("reconstruct", rec, "out/model", rec_in, ("out/model",), True,
                         folder=True)
    # export ----------------------------------------------------------------------------
    exp_in = ("model", "scan")
    exp = ["export", "in/model", "-o", "out/model.glb", "-q"]
    out += _model_cases("export", exp, exp_in, "in/model", False)
    out += _absurd("export", exp, exp_in, [
        ("--per-span", "0"), ("--per-span", "-4"), ("--max-triangles", "5"),
        ("--max-triangles", "-1"), ("--kinds", "bogus"), ("--format", "wrl"),
        ("--format", "igs")])
    out.append(Case("export", "absurd_options", "--per-span 2000 --patches",
                    exp + ["--patches", "--per-span", "2000"], "--per-span", inputs=exp_in,
                    full=True))
    out.append(Case("export", "absurd_options", "--points with glb",
                    exp + ["--points"], "--points", inputs=exp_in, full=True))
    for fmt in ("glb", "obj", "ply", "stl", "3dm", "igs"):
        e = ["export", "in/model", "-o", f"out/model.{fmt}", "-q"]
        if fmt in ("glb", "obj", "ply", "stl"):
            e.append("--patches")
        for c in _output_cases("export", e, f"out/model.{fmt}", exp_in, (f"out/model.{fmt}",),
                               True):
            c.name = f"{fmt}: {c.name}"
            out.append(c)
    # evaluate --------------------------------------------------------------------------
    ev_in = ("model", "scan")
    ev = ["evaluate", "in/model", "--truth", "in/scan/truth", "-o", "out/evaluation.json",
          "-q"]
    out += _model_cases("evaluate", ev, ev_in, "in/model", False)
    out.append(Case("evaluate", "missing", "truth folder", ev, "truth",
                    setup=removed("in/scan/truth"), inputs=ev_in))
    out.append(Case("evaluate", "empty", "truth folder", ev, "truth",
                    setup=emptied_folder("in/scan/truth"), inputs=ev_in))
    out += _file_cases("evaluate", ev, ev_in, "in/scan/truth/view_00.npz", "npz",
                       "in/scan/scan.json", full=True)
    out += _file_cases("evaluate", ev, ev_in, "in/scan/truth/scene.json", "json",
                       "in/scan/pattern.png", full=True)
    out.append(Case("evaluate", "malformed_json", "scene.json scene unknown", ev,
                    "scene.json", setup=json_edit("in/scan/truth/scene.json",
                                                  lambda doc: {"name": 5}),
                    inputs=ev_in, full=True))
    out += _absurd("evaluate", ev, ev_in, [("--cover-tol", "0"), ("--cover-tol", "nan"),
                                           ("--cover-tol", "-1")])
    out += _output_cases("evaluate", ev, "out/evaluation.json", ev_in,
                         ("out/evaluation.json", "out/evaluation.md"), True,
                         second="out/evaluation.md")
    # report ----------------------------------------------------------------------------
    rep_in = ("model", "scan", "evaluation.json")
    rep = ["report", "in/model", "-o", "out/report.html", "-q", "--no-detect",
           "--no-heat-map", "--evaluation", "in/evaluation.json"]
    out += _model_cases("report", rep, rep_in, "in/model", False)
    out += _file_cases("report", rep, rep_in, "in/evaluation.json", "json",
                       "in/scan/pattern.png")
    out.append(Case("report", "malformed_json", "evaluation.json fields of the wrong type",
                    rep, "evaluation.json",
                    setup=json_edit("in/evaluation.json",
                                    lambda doc: {k: "x" for k in doc}), inputs=rep_in))
    out += _file_cases("report", rep + ["--overlay", "in/scan/pattern.json"], rep_in,
                       "in/scan/pattern.json", "image", "in/scan/scan.json",
                       skip=("wrong_type",))
    out += _output_cases("report", rep, "out/report.html", rep_in, ("out/report.html",),
                         True)
    # merge -----------------------------------------------------------------------------
    mer_in = ("model", "model2", "scan")
    mer = ["merge", "in/model", "in/model2", "-o", "out/merged", "-q", "--trials", "1"]
    out += _model_cases("merge", mer, mer_in, "in/model2", False)
    out += _file_cases("merge", mer, mer_in, "in/model2/fused.ply", "ply",
                       "in/model2/model.json", full=True)[:4]
    out += _absurd("merge", mer, mer_in, [
        ("--trials", "0"), ("--base-margin", "nan"), ("--base-margin", "-1"),
        ("--max-misclosure", "0"), ("--max-triangles", "0")], full=True)
    out.append(Case("merge", "absurd_options", "one model", ["merge", "in/model", "-o",
                                                             "out/merged"], "model",
                    inputs=mer_in))
    out += _output_cases("merge", mer, "out/merged", mer_in, ("out/merged",), True,
                         folder=True)
    # batch -----------------------------------------------------------------------------
    bat_in = ("scan", "rig.json")
    bat = ["batch", "in/scan", "-o", "out/batch", "--calib", "in/rig.json", "--serial", "-q",
           "--export", "none", "--no-evaluate", "--no-fuse"]
    out.append(Case("batch", "missing", "scan folder", bat, "scan", setup=removed("in/scan"),
                    inputs=bat_in))
    out.append(Case("batch", "empty", "scan folder", bat, "scan",
                    setup=emptied_folder("in/scan"), inputs=bat_in))
    out += _file_cases("batch", bat, bat_in, "in/rig.json", "json", "in/scan/pattern.png")
    out += _file_cases("batch", bat, bat_in, "in/scan/scan.json", "json",
                       "in/scan/pattern.png")
    out += _absurd("batch", bat, bat_in, [
        ("--export", "wrl"), ("--workers", "-1"), ("--min-curves", "0"),
        ("--max-triangles", "-1"), ("--scheduler", "tcp://127.0.0.1:1")])
    out += _output_cases("batch", bat, "out/batch", bat_in, (), True, folder=True)
    # rig -------------------------------------------------------------------------------
    rig_in = ("rig.json", "rig.yml")
    rj = ["rig", "convert", "in/rig.json", "-o", "out/rig.yml"]
    ry = ["rig", "convert", "in/rig.yml", "-o", "out/rig.json"]
    out += _file_cases("rig", rj, rig_in, "in/rig.json", "json", "in/rig.yml")
    out += _rig_json_cases("rig", rj, rig_in, "in/rig.json", False)
    out += _file_cases("rig", ry, rig_in, "in/rig.yml", "yml", "in/rig.json")
    out.append(Case("rig", "malformed_json", "rig.yml K1 a string", ry, "rig.yml",
                    setup=lambda d: _replace(d / "in/rig.yml", (d / "in/rig.yml").read_bytes()
                                             .replace(b"K1: !!opencv-matrix", b"K1: nine\nX:"
                                                      b" !!opencv-matrix")), inputs=rig_in))
    out += _absurd("rig", ry, rig_in, [
        ("--image-size", "0", "0"), ("--image-size", "-320", "240"),
        ("--camera-pitch", "nan"), ("--projector-pitch", "-1")])
    out.append(Case("rig", "absurd_options", "json to json", ["rig", "convert", "in/rig.json",
                                                              "-o", "out/r.json"], "r.json",
                    inputs=rig_in))
    out += _output_cases("rig", rj, "out/rig.yml", rig_in, ("out/rig.yml",), False)
    out += _output_cases("rig", ry, "out/rig.json", rig_in, ("out/rig.json",), False)
    # demo ------------------------------------------------------------------------------
    demo = ["demo", "-o", "out/demo", "--views", "1", "--width", "64", "--height", "48"]
    out += _absurd("demo", demo, (), [("--views", "0"), ("--width", "0"), ("--seed", "-1"),
                                      ("--height", "-48")])
    out += [c for c in _output_cases("demo", demo, "out/demo", (), (), False, folder=True)]
    return [c for c in out if full or not c.full]


# ------------------------------------------------------------------------------ running
def _link_inputs(case_dir: Path, fixtures: Path, inputs: tuple[str, ...]) -> None:
    """Hard-link the fixtures ``inputs`` (``SRC[:NAME]``) into ``case_dir/in``."""
    dst_root = case_dir / "in"
    dst_root.mkdir(parents=True, exist_ok=True)
    for spec in inputs:
        src, _, name = spec.partition(":")
        s, d = fixtures / src, dst_root / (name or Path(src).name)
        if s.is_dir():
            shutil.copytree(s, d, copy_function=os.link, symlinks=True)
        else:
            d.parent.mkdir(parents=True, exist_ok=True)
            os.link(s, d)


def _old_outputs(case_dir: Path, fixtures: Path, old: tuple[str, ...]) -> None:
    """Outputs present before the command runs (what it must leave as they were)."""
    for rel in old:
        p = case_dir / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        if rel.endswith(("model", "merged")):
            shutil.copytree(fixtures / "model", p, copy_function=os.link)
        elif p.suffix == "":
            p.write_text("a file, not a folder\n")
        else:
            p.write_bytes(b"old output " + rel.encode() + b"\n")


def snapshot(folder: Path) -> dict:
    """Names, sizes and modification times of everything under ``folder``."""
    snap = {}
    for dirpath, dirnames, filenames in os.walk(folder):
        for n in dirnames + filenames:
            p = Path(dirpath) / n
            st = p.lstat()
            rel = str(p.relative_to(folder))
            snap[rel] = ("dir",) if p.is_dir() and not p.is_symlink() else (
                st.st_size, st.st_mtime_ns)
    return snap


def _lock(folder: Path, root: bool) -> Callable[[], None]:
    """Make ``folder`` read-only (chmod 555; as root ``chattr +i``); return the undo."""
    if not root:
        folder.chmod(0o555)
        return lambda: folder.chmod(0o755)
    subprocess.run(["chattr", "+i", str(folder)], check=True, capture_output=True)
    return lambda: subprocess.run(["chattr", "-i", str(folder)], capture_output=True)


def _preexec(fsize: int | None) -> Callable[[], None] | None:
    if fsize is None:
        return None

    def f() -> None:
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (fsize, fsize))
    return f


def error_lines(stderr: str) -> list[str]:
    """stderr less progress (``[`` ..., ``nurbscan simulate: [``), usage and warning lines."""
    keep = []
    for line in stderr.splitlines():
        s = line.strip()
        if not s or s.startswith("[") or s.startswith("usage:") or line.startswith(" "):
            continue
        if ": warning:" in s or re.search(r"(^|: )\w*Warning: ", s):  # also Python's warnings
            continue
        if s.startswith("nurbscan simulate: ") and "error:" not in s:
            continue
        keep.append(s)
    return keep


def names(line: str, case: Case) -> bool:
    """Whether an error line names the case's input: its file name, or an option (``--max-
    points``) by its flag or its name (``max-points``, ``max points``, ``max_points``; a
    library's message names the value: ``pattern width=0``)."""
    e = case.expect
    if not e.startswith("--"):
        return e in line
    n = e.lstrip("-")
    low = line.lower()
    return any(t in low for t in (e, n, n.replace("-", " "), n.replace("-", "_")))


def run_case(case: Case, fixtures: Path, work: Path, root: bool) -> dict:
    """Run one case in ``work``; the verdict and what was wrong."""
    case_dir = work
    try:
        (case_dir / "out").mkdir(parents=True)
        _link_inputs(case_dir, fixtures, case.inputs)
        _old_outputs(case_dir, fixtures, case.old_outputs)
        if case.setup is not None:
            case.setup(case_dir)
    except Exception as exc:  # a defect of the case, not of the command: reported apart
        return {"id": case.id, "command": case.command, "cls": case.cls,
                "setup_error": f"{type(exc).__name__}: {exc}"[:300]}
    undo = _lock(case_dir / "out", root) if case.unwritable else None
    try:
        return _run(case, case_dir, undo)
    finally:
        if undo is not None:
            undo()


def _run(case: Case, case_dir: Path, undo: Callable[[], None] | None) -> dict:
    before = snapshot(case_dir)
    t0 = time.monotonic()
    p = subprocess.Popen([sys.executable, "-m", "nurbscan", *case.argv], cwd=case_dir,
                         env=_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                         text=True, start_new_session=True, preexec_fn=_preexec(case.fsize))
    hang = False
    try:
        stdout, stderr = p.communicate(timeout=case.timeout)
    except subprocess.TimeoutExpired:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(p.pid, signal.SIGKILL)
        stdout, stderr = p.communicate()
        hang = True
    wall = time.monotonic() - t0
    if undo is not None:
        undo()
    after = snapshot(case_dir)
    lines = error_lines(stderr)
    problems = []
    traceback = "Traceback" in stderr
    if hang:
        problems.append(f"hang (over {case.timeout:.0f} s)")
    if traceback:
        last = [ln for ln in stderr.strip().splitlines() if ln.strip()][-1:]
        problems.append(f"traceback ({last[0][:160] if last else ''})")
    if not hang and p.returncode != 2:
        problems.append(f"exit {p.returncode}")
    ok_msg = (len(lines) == 1 and lines[0].startswith(f"nurbscan {case.command}")
              and "error:" in lines[0] and names(lines[0], case))
    if not traceback and not hang and not ok_msg:
        problems.append(f"message {lines[:3]!r}"[:300])
    changed = sorted(set(before) ^ set(after)) + sorted(
        k for k in set(before) & set(after) if before[k] != after[k])
    if changed:
        problems.append(f"changed {changed[:4]}")
    # a disk-full limit the outputs all fit under: the command rightly succeeded
    fits = bool(case.fsize) and p.returncode == 0 and not traceback and not hang
    if fits:
        problems = []
    return {"id": case.id, "fits": fits, "command": case.command, "cls": case.cls,
            "problems": problems,
            "traceback": traceback, "hang": hang, "exit": p.returncode,
            "wrong_exit": not hang and p.returncode != 2, "bad_message": not ok_msg,
            "partial": bool(changed), "wall_s": wall, "stderr": stderr[-2000:]}


def _is_root() -> bool:
    return os.geteuid() == 0


def run_cases(selected: list[Case], fixtures: Path, work: Path, workers: int = 2
              ) -> list[dict]:
    """Run ``selected`` cases, ``workers`` at a time, each in ``work/NNN``."""
    root = _is_root()
    dump = os.environ.get("NURBSCAN_BENCH_BADINPUT_DUMP")

    def one(item):
        k, c = item
        r = run_case(c, fixtures, work / f"{k:04d}", root)
        if dump:  # one JSON line per case as it ends (kept if the run is stopped)
            with open(dump, "a") as f:
                f.write(json.dumps(r) + "\n")
        return r

    with ThreadPoolExecutor(workers) as pool:
        return list(pool.map(one, enumerate(selected)))


def summarise(results: list[dict], n_fail: int = 60) -> dict:
    """Counts per class and command, totals, and the first ``n_fail`` failures."""
    def counts(rs: list[dict]) -> dict:
        return {"cases": len(rs), "passed": sum(not r["problems"] for r in rs),
                "tracebacks": sum(r["traceback"] for r in rs),
                "hangs": sum(r["hang"] for r in rs),
                "wrong_exit": sum(r["wrong_exit"] for r in rs),
                "bad_message": sum(r["bad_message"] for r in rs),
                "partial_outputs": sum(r["partial"] for r in rs)}

    setup = [r for r in results if "setup_error" in r]
    results = [r for r in results if "setup_error" not in r]
    fit = [r for r in results if r["fits"]]
    results = [r for r in results if not r["fits"]]
    total = counts(results)
    fails = [r for r in results if r["problems"]]
    return {
        "cases": total["cases"], "passed": total["passed"], "failures": len(fails),
        "tracebacks": total["tracebacks"], "hangs": total["hangs"],
        "wrong_exit": total["wrong_exit"], "bad_message": total["bad_message"],
        "partial_outputs": total["partial_outputs"],
        "per class": {c: counts([r for r in results if r["cls"] == c]) for c in CLASSES
                      if any(r["cls"] == c for r in results)},
        "per command": {m: counts([r for r in results if r["command"] == m])
                        for m in dict.fromkeys(r["command"] for r in results)},
        "disk-full cases left out (the outputs fit under the limit: exit 0)": len(fit),
        "cases whose set-up failed (a defect of the suite)": len(setup),
        "slowest case (s)": round(max((r["wall_s"] for r in results), default=0.0), 1),
        "failed cases": {r["id"]: "; ".join(r["problems"]) for r in fails[:n_fail]},
    }


def bench() -> dict:
    only = [s.strip() for s in os.environ.get("NURBSCAN_BENCH_BADINPUT", "").split(",")
            if s.strip()]
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        t0 = time.monotonic()
        keep = os.environ.get("NURBSCAN_BENCH_BADINPUT_FIXTURES")  # reused across runs
        if keep and (Path(keep) / "model2").is_dir():
            fixtures = Path(keep)
        else:
            fixtures = make_fixtures(Path(keep) if keep else tmp / "fixtures")
        t_fix = time.monotonic() - t0
        selected = [c for c in cases() if not only or c.command in only]
        t0 = time.monotonic()
        results = run_cases(selected, fixtures, tmp / "cases")
        out = summarise(results, int(os.environ.get("NURBSCAN_BENCH_BADINPUT_FAILS", "60")))
        out["fixtures_s"] = round(t_fix, 1)
        out["cases_s"] = round(time.monotonic() - t0, 1)
    return out


if __name__ == "__main__":
    print(json.dumps(bench(), indent=1))
