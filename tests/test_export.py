"""Exports (issue 8): IGES and 3dm read back by independent readers (OpenCASCADE, rhino3dm),
the fused coloured mesh, glb/obj/ply/stl, the glTF validator, the CLI and atomic writes."""

from __future__ import annotations

import importlib.util
import json
import math
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
import trimesh

from _export_fixtures import (
    ANGLES,
    CENTRE,
    R,
    camera_azimuth,
    curves,
    make_folders,
    quarter_sphere,
    small_rig,
    sphere_model,
    teapot_patch,
)
from nurbscan.cli import main
from nurbscan.errors import NurbscanError
from nurbscan.export import (
    build_mesh,
    export_model,
    find_rig,
    find_white_images,
    iges_text,
    load_model,
    write_3dm,
    write_iges,
)

ROOT = Path(__file__).resolve().parents[1]
RNG = np.random.default_rng(11)


def _surfaces():
    from nurbscan.nurbs import NurbsSurface

    rng = np.random.default_rng(5)

    wavy = NurbsSurface(3, 2, [0, 0, 0, 0, 0.3, 0.7, 1, 1, 1, 1], [2, 2, 2, 5, 9, 9, 9],
                        rng.normal(0, 40, (6, 4, 3)), rng.uniform(0.5, 2.0, (6, 4)))
    return [quarter_sphere(0), quarter_sphere(3), teapot_patch(), wavy]


@pytest.fixture(scope="module")
def folders(tmp_path_factory):
    return make_folders(tmp_path_factory.mktemp("export"))


def _samples_surface(s, n=40):
    (u0, u1), (v0, v1) = s.domain
    uv = RNG.random((n, 2))
    u, v = u0 + (u1 - u0) * uv[:, 0], v0 + (v1 - v0) * uv[:, 1]
    return u, v, s.evaluate(u, v)


def _samples_curve(c, n=40):
    a, b = c.domain
    t = a + (b - a) * RNG.random(n)
    return t, c.evaluate(t)


# ---------------------------------------------------------------------------- IGES / OCP
def test_iges_read_back_by_opencascade(tmp_path):
    ocp = pytest.importorskip("OCP")  # noqa: F841 - test-only dependency
    from OCP.BRep import BRep_Tool
    from OCP.IFSelect import IFSelect_RetDone
    from OCP.IGESControl import IGESControl_Reader
    from OCP.TopAbs import TopAbs_EDGE
    from OCP.TopExp import TopExp_Explorer
    from OCP.TopoDS import TopoDS

    cs, ss = curves(), _surfaces()
    path = write_iges(tmp_path / "m.igs", cs, ss)
    reader = IGESControl_Reader()
    assert reader.ReadFile(str(path)) == IFSelect_RetDone
    reader.TransferRoots()
    assert reader.NbShapes() == len(cs) + len(ss)
    worst = 0.0
    for k, c in enumerate(cs):
        # OpenCASCADE splits a curve at its C0 knots (the circle's double knots): a wire
        pieces = []
        ex = TopExp_Explorer(reader.Shape(k + 1), TopAbs_EDGE)
        while ex.More():
            g = BRep_Tool.Curve_s(TopoDS.Edge(ex.Current()), 0.0, 0.0)
            assert g.DynamicType().Name() == "Geom_BSplineCurve" and g.Degree() == c.degree
            pieces.append(g)
            ex.Next()
        assert len(pieces) == (4 if k == 0 else 1)
        t, p = _samples_curve(c)
        for x, px in zip(t, p, strict=True):
            g = next(g for g in pieces if g.FirstParameter() <= x <= g.LastParameter())
            q = g.Value(x)
            worst = max(worst, np.abs(np.array([q.X(), q.Y(), q.Z()]) - px).max())
    for k, s in enumerate(ss):
        g = BRep_Tool.Surface_s(TopoDS.Face(reader.Shape(len(cs) + k + 1)))
        assert g.DynamicType().Name() == "Geom_BSplineSurface"
        assert (g.UDegree(), g.VDegree()) == (s.degree_u, s.degree_v)
        assert (g.NbUPoles(), g.NbVPoles()) == s.shape
        assert g.IsURational() == s.is_rational or g.IsVRational() == s.is_rational
        u, v, p = _samples_surface(s)
        q = np.array([[g.Value(a, b).X(), g.Value(a, b).Y(), g.Value(a, b).Z()]
                      for a, b in zip(u, v, strict=True)])
        worst = max(worst, np.abs(q - p).max())
    assert worst < 1e-6


def test_iges_fixed_format():
    text = iges_text(curves(), _surfaces())
    lines = text.splitlines()
    assert all(len(line) == 80 for line in lines)
    sections = [line[72] for line in lines]
    assert sections == sorted(sections, key="SGDPT".index)  # S, G, D, P, T in order
    counts = {s: sections.count(s) for s in "SGDP"}
    term = lines[-1]
    assert term[:32] == "".join(f"{s}{counts[s]:7d}" for s in "SGDP")
    for s in "SGDP":  # sequence numbers 1..n per section
        seq = [int(line[73:]) for line in lines if line[72] == s]
        assert seq == list(range(1, len(seq) + 1))
    d = [line for line in lines if line[72] == "D"]
    assert [int(x[:8]) for x in d[::2]] == [126, 126, 128, 128, 128, 128]
    p = [line for line in lines if line[72] == "P"]
    for k in range(0, len(d), 2):  # every entity's P lines point back at its DE line
        start, count = int(d[k][8:16]), int(d[k + 1][24:32])
        assert {int(line[64:72]) for line in p[start - 1:start - 1 + count]} == {k + 1}
    glob = "".join(line[:72] for line in lines if line[72] == "G")
    assert ",2,2HMM," in glob  # units flag 2 = millimetres
    with pytest.raises(NurbscanError, match="nothing to write"):
        iges_text([], [])


# ---------------------------------------------------------------------------- 3dm
def test_3dm_read_back_by_rhino3dm(tmp_path):
    import rhino3dm

    cs, ss = curves(), _surfaces()
    path = write_3dm(tmp_path / "m.3dm", [("horizontal_line", c) for c in cs],
                     [("gordon", s) for s in ss])
    f = rhino3dm.File3dm.Read(str(path))
    assert f.Settings.ModelUnitSystem == rhino3dm.UnitSystem.Millimeters
    assert [la.Name for la in f.Layers] == ["horizontal_line", "gordon"]
    objs = list(f.Objects)
    assert len(objs) == len(cs) + len(ss)
    worst = 0.0
    for o, c in zip(objs[:len(cs)], cs, strict=True):
        g = o.Geometry
        assert isinstance(g, rhino3dm.NurbsCurve) and g.Degree == c.degree
        t, p = _samples_curve(c)
        q = np.array([[g.PointAt(x).X, g.PointAt(x).Y, g.PointAt(x).Z] for x in t])
        worst = max(worst, np.abs(q - p).max())
    for o, s in zip(objs[len(cs):], ss, strict=True):
        g = o.Geometry
        assert isinstance(g, rhino3dm.NurbsSurface) and g.IsRational == s.is_rational
        u, v, p = _samples_surface(s)
        q = np.array([[g.PointAt(a, b).X, g.PointAt(a, b).Y, g.PointAt(a, b).Z]
                      for a, b in zip(u, v, strict=True)])
        worst = max(worst, np.abs(q - p).max())
    assert worst < 1e-6


# ---------------------------------------------------------------------------- mesh
def test_mesh_of_sphere_patches_is_watertight_and_outward():
    m = sphere_model()
    mesh = build_mesh(m, small_rig(), None, per_span=8)
    tm = mesh.trimesh()
    assert mesh.info["watertight"] and tm.is_watertight and mesh.info["patches"] == 4
    r = np.linalg.norm(mesh.vertices - CENTRE, axis=1)
    assert np.abs(r - R).max() < 1e-9  # vertices lie on the surfaces
    # outward orientation: positive volume, below the sphere's by the chordal error only
    vol = 4 / 3 * math.pi * R ** 3
    assert 0.98 * vol < tm.volume < vol
    assert np.all(mesh.colors[:, :3] == 180)  # no images: neutral


def test_vertex_colours_from_white_images(folders):
    m = load_model(folders)
    rig, images = find_rig(m), find_white_images(m)
    assert rig is not None and sorted(images) == [0, 1, 2, 3]
    mesh = build_mesh(m, rig, images, per_span=8)
    colours = np.array([(200, 30, 30), (30, 200, 30), (30, 30, 200), (200, 200, 30)], float)
    # oracle: cos^2-weighted mean over the views facing each vertex, with the analytic normal
    n = (mesh.vertices - CENTRE) / R
    w = np.zeros((len(n), 4))
    for k, a in enumerate(ANGLES):
        c = rig.turntable.from_rig(np.asarray(rig.camera.center)[None], a)[0]
        d = c - mesh.vertices
        cos = np.einsum("ij,ij->i", n, d / np.linalg.norm(d, axis=1)[:, None])
        w[:, k] = np.where(cos > 0.1, cos, 0.0) ** 2
    seen = w.sum(1) > 0.2  # clear of the 0.1 cut-off
    expect = w @ colours / np.maximum(w.sum(1), 1e-12)[:, None]
    got = mesh.colors[:, :3].astype(float)
    assert seen.mean() > 0.5
    assert np.abs(got[seen] - expect[seen]).max() < 4.0
    # a vertex on the equator facing camera k takes view k's colour
    for k in range(4):
        az = camera_azimuth(k)
        target = CENTRE + R * np.array([math.cos(az), math.sin(az), 0.0])
        i = np.argmin(np.linalg.norm(mesh.vertices - target, axis=1))
        assert np.abs(got[i] - colours[k]).max() < 8


def test_image_size_must_match_camera(folders):
    m = load_model(folders)
    with pytest.raises(NurbscanError, match="white image of view 0"):
        build_mesh(m, find_rig(m), {0: np.zeros((10, 12, 3))})


def test_obj_ply_stl_in_mm(folders, tmp_path):
    """The per-view patches (``patches=True``) tessellated: watertight, on the sphere."""
    for fmt in ("obj", "ply", "stl"):
        out = export_model(folders, tmp_path / f"m.{fmt}", patches=True)
        tm = trimesh.load(out, force="mesh", process=True)
        assert tm.is_watertight, fmt
        r = np.linalg.norm(tm.vertices - CENTRE, axis=1)
        assert np.abs(r - R).max() < 1e-4, fmt  # mm (stl/obj text rounding)
    ply = trimesh.load(tmp_path / "m.ply", process=False)
    assert len(np.unique(ply.visual.vertex_colors[:, :3], axis=0)) > 4  # coloured
    assert (tmp_path / "m.obj").read_text().startswith("# nurbscan mesh, units: mm")


def _glb_json(data: bytes) -> dict:
    n = int.from_bytes(data[12:16], "little")
    return json.loads(data[20:20 + n])


def test_glb_in_metres_passes_khronos_validator(folders, tmp_path):
    out = export_model(folders, tmp_path / "m.glb", patches=True)
    data = out.read_bytes()
    doc = _glb_json(data)
    assert doc["asset"]["version"] == "2.0"
    assert doc["asset"]["extras"]["units"] == "m"
    pos = doc["accessors"][doc["meshes"][0]["primitives"][0]["attributes"]["POSITION"]]
    assert abs(max(pos["max"]) - 0.12) < 1e-6  # top of the sphere: z = 120 mm = 0.12 m
    sc = trimesh.load(out)
    assert sc.is_empty is False
    node = shutil.which("node")
    if node is None:
        pytest.skip("node (Node.js) is not installed: cannot run the Khronos glTF-Validator")
    modules = ROOT / ".venv" / "node" / "node_modules"
    assert (modules / "gltf-validator").is_dir(), (
        "gltf-validator missing: run `make test` or "
        "`npm install --prefix .venv/node gltf-validator@2.0.0-dev.3.10`")
    res = subprocess.run([node, str(ROOT / "tests" / "gltf_validate.cjs"), str(out),
                          str(modules)], capture_output=True, text=True, timeout=60)
    assert res.returncode == 0, res.stderr
    report = json.loads(res.stdout)
    assert report["issues"]["numErrors"] == 0, report["issues"]["messages"]
    assert report["issues"]["numWarnings"] == 0, report["issues"]["messages"]
    assert report["info"]["totalVertexCount"] == len(sc.geometry[next(iter(sc.geometry))]
                                                     .vertices)


# ---------------------------------------------------------------------------- CLI, atomicity
def test_cli_export_all_formats(folders, tmp_path, capsys):
    formats = ("glb", "obj", "ply", "stl", "3dm", "igs")
    if importlib.util.find_spec("OCP") is not None:
        formats += ("step",)
    for fmt in formats:
        out = tmp_path / f"x.{fmt}"
        assert main(["export", str(folders), "--format", fmt, "-o", str(out)]) == 0
        assert out.stat().st_size > 1000
    import rhino3dm

    from nurbscan.merge.cad import cad_set

    # the NURBS formats hold the CAD set by default, the per-view patches with --patches
    f = rhino3dm.File3dm.Read(str(tmp_path / "x.3dm"))
    assert len(f.Objects) == len(cad_set(load_model(folders), find_rig(load_model(folders)))
                                 .surfaces)
    assert main(["export", str(folders), "--patches", "-o", str(tmp_path / "p.3dm")]) == 0
    # 2 curves + 4 Gordon patches (the skin is not a default kind)
    assert len(rhino3dm.File3dm.Read(str(tmp_path / "p.3dm")).Objects) == 6
    assert main(["export", str(folders), "--patches", "--kinds", "all",
                 "-o", str(tmp_path / "a.3dm")]) == 0
    assert len(rhino3dm.File3dm.Read(str(tmp_path / "a.3dm")).Objects) == 7
    assert main(["export", str(folders), "-o", str(tmp_path / "x.vrml")]) == 2
    assert "unknown format 'vrml'" in capsys.readouterr().err
    assert main(["export", str(folders), "--patches", "--kinds", "bogus",
                 "-o", str(tmp_path / "b.igs")]) == 2
    assert main(["export", str(tmp_path / "nowhere"), "-o", str(tmp_path / "c.igs")]) == 2
    # a format that the file's name contradicts (wrote IGES into a .glb with exit 0)
    assert main(["export", str(folders), "--format", "igs", "-o", str(tmp_path / "m.glb")]) == 2
    assert "name the file .igs" in capsys.readouterr().err
    assert not (tmp_path / "m.glb").exists()


def test_failed_export_leaves_no_partial_file(folders, tmp_path, monkeypatch):
    import nurbscan.export.mesh as mesh_mod
    import nurbscan.export.rhino as rhino_mod

    out = tmp_path / "m.3dm"
    out.write_bytes(b"previous")
    real = rhino_mod._rhino()

    class Broken:
        def __getattr__(self, name):
            return getattr(real, name)

        class File3dm(real.File3dm):
            def Write(self, path, version):  # noqa: N802 - rhino3dm's name
                Path(path).write_bytes(b"partial")
                raise RuntimeError("disk full")

    monkeypatch.setattr(rhino_mod, "_rhino", lambda: Broken())
    with pytest.raises(RuntimeError, match="disk full"):
        export_model(folders, out)
    assert out.read_bytes() == b"previous"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.3dm"]  # no temporary left

    def broken_tm(self, scale=1.0):
        raise RuntimeError("encoder failed")

    monkeypatch.setattr(mesh_mod.MeshResult, "trimesh", broken_tm)
    with pytest.raises(RuntimeError, match="encoder failed"):
        export_model(folders, tmp_path / "n.glb")
    assert not (tmp_path / "n.glb").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.3dm"]
