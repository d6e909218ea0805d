"""Tests of nurbscan.merge: the table left out, the views registered (issue #32).

The registration is tested on views sampled from the exact scene surfaces (an independent
oracle: the true surface and the true table angles), then end to end on a small scan with a
visible table top."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from nurbscan.merge import (
    RegistrationOptions,
    TableOptions,
    off_object,
    register_views,
)
from nurbscan.merge.register import _chi2_quantile, _rz, twist_swing
from nurbscan.simulate.scenes import make_scene

TILT = np.radians(20.0)  # the default rig's camera looks down on the table by 20 degrees


def _views(scene_name: str, n_views: int = 8, seed: int = 0, noise: float = 0.005):
    """Points and normals of a scene seen from ``n_views`` table angles, each view its own
    random samples of the exact surface (those facing the camera), with noise along the
    normal (mm). Object frame, exact poses."""
    scene = make_scene(scene_name)
    out = {}
    for k in range(n_views):
        P, N, _ = scene.sample_surface(40000, seed=seed + k)
        theta = 2 * np.pi * k / n_views
        cam = _rz(-theta) @ np.array([np.cos(TILT), 0.0, np.sin(TILT)])
        keep = (N @ cam > 0.3) & (P[:, 2] > 0.5)
        rng = np.random.default_rng(100 + k)
        P = P[keep] + noise * rng.standard_normal(keep.sum())[:, None] * N[keep]
        out[k] = (P, N[keep])
    return out


def _perturbed(views: dict, delta_deg: dict) -> dict:
    """Each view placed with its table angle ``delta_deg`` too large: turned by -delta about
    the axis (docs/conventions.md: X_obj' = Rz(-delta) X_obj)."""
    out = {}
    for v, (P, N) in views.items():
        R = _rz(np.radians(-delta_deg[v]))
        out[v] = (P @ R.T, N @ R.T)
    return out


FAST = RegistrationOptions(voxel=2.0)


@pytest.fixture(scope="module")
def teapot_views():
    return _views("teapot")


def test_twist_swing_decomposes_a_rotation():
    S = np.array([[1, 0, 0], [0, np.cos(0.01), -np.sin(0.01)], [0, np.sin(0.01), np.cos(0.01)]])
    alpha, other = twist_swing(S @ _rz(0.3))
    assert abs(alpha - 0.3) < 1e-12 and abs(other - 0.01) < 1e-12


def test_registration_recovers_perturbed_table_angles(teapot_views):
    """Table angles off by up to 2 degrees: the corrections give them back to 0.02 degrees
    (view 0 fixes the object frame), the other rotations and translations stay small, and the
    registered views lie on the true surface as closely as with the exact angles."""
    rng = np.random.default_rng(7)
    delta = {v: 0.0 if v == 0 else float(rng.uniform(-2, 2)) for v in teapot_views}
    assert max(abs(d) for d in delta.values()) > 1.5
    reg = register_views(_perturbed(teapot_views, delta), FAST)
    assert reg.applied and reg.axis_determined and not reg.warnings, reg.warnings
    err = [reg.corrections[v].axis_angle - delta[v] for v in teapot_views]
    assert max(abs(e) for e in err) < 0.02, err
    assert max(c.other_angle for c in reg.corrections.values()) < 0.05
    assert max(np.linalg.norm(c.translation) for c in reg.corrections.values()) < 0.05
    scene = make_scene("teapot")
    for v, (P, _) in _perturbed(teapot_views, delta).items():
        C = reg.corrections[v].matrix
        Q = (P @ C[:3, :3].T + C[:3, 3])[::20]
        exact = teapot_views[v][0][::20]
        assert np.mean(scene.distance(Q)) < np.mean(scene.distance(exact)) + 0.005


def test_exact_angles_are_not_significant_turns(teapot_views):
    """Exact table angles: the turns about the axis that the pose graph finds are within their
    uncertainty (chi-square of each below the threshold, the variance factor estimated from
    the misclosures), and each turn within 3 of its standard deviations of zero."""
    reg = register_views(teapot_views, FAST)
    t = reg.significance
    assert t is not None and not t["turn_significant"], t
    for v, q in t["views"].items():
        assert q["chi2_turn"] < t["threshold_turn"]
        assert abs(reg.corrections[v].axis_angle) < 3 * q["sd_axis_deg"] + 1e-9


def test_perturbed_angles_are_significant(teapot_views):
    """One view off by 0.2 degrees (ten times the target accuracy) is found significant and
    corrected by a turn about the axis alone."""
    delta = {v: (0.2 if v == 5 else 0.0) for v in teapot_views}
    reg = register_views(_perturbed(teapot_views, delta), FAST)
    assert reg.applied and reg.significance["significant"], reg.significance
    assert abs(reg.corrections[5].axis_angle - 0.2) < 0.02
    assert max(abs(reg.corrections[v].axis_angle) for v in teapot_views if v != 5) < 0.02


def test_significance_quantiles_are_scipy_stats_chi2():
    """The significance test's chi-square quantiles (computed without importing scipy.stats)
    are scipy.stats.chi2.ppf's to the bit, at the levels the test uses."""
    from scipy.stats import chi2

    for p in (0.95, 0.99, 1 - 0.01 / 7, 1 - 0.05 / 15, 1 - 1e-6):
        for dof in (1, 5, 6):
            assert _chi2_quantile(p, dof) == float(chi2.ppf(p, dof)), (p, dof)
    assert abs(_chi2_quantile(0.95, 1) - 3.841458820694124) < 1e-12  # tables: 3.8415


def test_open3d_without_its_plotting_stack():
    """Open3D imported for nurbscan leaves Dash, Plotly and IPython out (0.4 s of its 0.8 s
    import) and still plots when asked: the deferred ``get_plotly_fig`` imports them then."""
    code = ("import sys; from nurbscan.merge._open3d import import_open3d; o3d = import_open3d(); "
            "before = [m for m in ('dash', 'plotly', 'IPython') if m in sys.modules]; "
            "pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector([[0.0, 0, 0], [1, 2, 3]])); "
            "fig = o3d.visualization.get_plotly_fig([pc]); "
            "print(before, type(fig).__module__.split('.')[0], len(fig.data))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True)
    assert out.stdout.split() == ["[]", "plotly", "1"], out.stdout + out.stderr


@pytest.mark.parametrize("scene", ["sphere", "cylinder"])
def test_revolution_surface_keeps_the_given_angles(scene):
    """A sphere or a cup on the axis cannot fix the turn about the axis: said so, angles as
    given."""
    views = _views(scene)
    delta = {v: 0.0 if v == 0 else 1.0 for v in views}
    reg = register_views(_perturbed(views, delta), FAST)
    assert not reg.axis_determined and reg.axis_information < 1e-4
    assert any("not determined" in w for w in reg.warnings), reg.warnings
    assert all(abs(c.axis_angle) < 1e-9 for c in reg.corrections.values())
    assert max(np.linalg.norm(c.translation) for c in reg.corrections.values()) < 0.1


def test_views_that_do_not_overlap_keep_their_poses(teapot_views):
    P, N = teapot_views[0]
    left, right = P[:, 1] > 15, P[:, 1] < -15
    reg = register_views({0: (P[left], N[left]), 1: (P[right], N[right])}, FAST)
    assert reg.unregistered == [1] and not reg.pairs
    assert any("overlap no view" in w for w in reg.warnings), reg.warnings
    assert np.array_equal(reg.corrections[1].matrix, np.eye(4))


def test_diverged_registration_keeps_the_unregistered_poses(teapot_views):
    """A correction over max_angle (here 0.5 degrees, default 5) is divergence: a warning and
    no view moves."""
    delta = {v: (1.5 if v == 3 else 0.0) for v in teapot_views}
    reg = register_views(_perturbed(teapot_views, delta),
                         RegistrationOptions(voxel=2.0, max_angle=0.5))
    assert not reg.applied
    assert any("diverged" in w and "3" in w for w in reg.warnings), reg.warnings
    assert all(np.array_equal(c.matrix, np.eye(4)) for c in reg.corrections.values())


def test_off_object_is_the_table_and_the_room():
    P = np.array([[0, 0, 0.4], [0, 0, 0.6], [149, 0, 10], [151, 0, 10], [0, 0, -3],
                  [np.nan, 0, 5]])
    assert off_object(P, TableOptions(margin=0.5, radius=150)).tolist() == [
        True, False, False, True, True, True]


def test_options_reject_bad_values():
    from nurbscan.errors import NurbscanError

    with pytest.raises(NurbscanError):
        TableOptions(margin=-1)
    with pytest.raises(NurbscanError):
        RegistrationOptions(voxel=0)


def test_model_json_records_the_registration(tmp_path, teapot_views):
    """merge_views on a model: corrections and registered poses per view in model.json, the
    view's points moved by its correction."""
    from nurbscan.camera import Turntable
    from nurbscan.merge import merge_views
    from nurbscan.reconstruct import Model, load_model

    rng = np.random.default_rng(3)
    delta = {v: 0.0 if v == 0 else float(rng.uniform(-1, 1)) for v in teapot_views}
    views = _perturbed(teapot_views, delta)
    tt = Turntable(point=[0, 55, 620], direction=[0, -np.cos(TILT), -np.sin(TILT)])
    m = Model(views=[{"index": v, "table_angle": 2 * np.pi * v / 8 + np.radians(delta[v])}
                     for v in views],
              points=np.concatenate([P for P, _ in views.values()]),
              normals=np.concatenate([N for _, N in views.values()]),
              point_view=np.concatenate([np.full(len(P), v) for v, (P, _) in views.items()]))
    m.edge_points, m.edge_view = m.points.copy(), m.point_view.copy()
    from nurbscan.merge import MergeOptions

    merge_views(m, tt, MergeOptions(registration=FAST))
    m.save(tmp_path / "model")
    doc = json.loads((tmp_path / "model" / "model.json").read_text())
    assert doc["meta"]["merge"]["registration"]["applied"]
    for entry in doc["views"]:
        v = entry["index"]
        assert abs(entry["registration"]["axis_angle_deg"] - delta[v]) < 0.05
        assert abs(np.degrees(entry["registered_table_angle"]) - 45 * v) < 0.05
        # the registered pose maps the rig into the object frame: a point of the object at
        # the true angle, seen in the rig, comes back to itself
        X = np.array([[30.0, -20.0, 50.0]])
        rig = tt.to_rig(X, 2 * np.pi * v / 8)
        R, t = np.array(entry["object_from_rig"]["R"]), np.array(entry["object_from_rig"]["t"])
        assert np.abs(rig @ R.T + t - X).max() < 0.05
    m2 = load_model(tmp_path / "model")
    scene = make_scene("teapot")
    assert np.mean(scene.distance(m2.points[::50])) < 0.02


# ---------------------------------------------------------------------- end to end
@pytest.fixture(scope="module")
def table_scan(tmp_path_factory):
    """A 640 x 480, 2-view teapot scan on a grey table top (albedo 0.3) with a coarse grid
    (pitch 32, band 12 projector px), reconstructed with the true rig, not merged."""
    from nurbscan.camera import load_rig
    from nurbscan.pattern import Pattern
    from nurbscan.reconstruct import reconstruct_scan
    from nurbscan.simulate.render import RenderSettings
    from nurbscan.simulate.rig import default_rig, scale_camera
    from nurbscan.simulate.scan import simulate_scan

    out = tmp_path_factory.mktemp("table") / "scan"
    simulate_scan(make_scene("teapot"), out, views=2, rig=scale_camera(default_rig(), 640, 480),
                  calibration=False, settings=RenderSettings(samples=2, table_albedo=(0.3,) * 3),
                  pattern=Pattern.create(1920, 1080, pitch=32, band=12))
    model = reconstruct_scan(out, load_rig(out / "truth" / "rig.json"), merge=None)
    return out, model


def _gordon_samples(model, k=9):
    grid = np.linspace(0, 1, k)
    out = []
    for s in model.surfaces_of("gordon"):
        S = s["surface"]
        (u0, u1), (v0, v1) = S.domain
        uu, vv = np.meshgrid(u0 + (u1 - u0) * grid, v0 + (v1 - v0) * grid, indexing="ij")
        out.append(S.evaluate(uu.ravel(), vv.ravel()))
    return out


def test_table_top_is_left_out(table_scan):
    """With a visible table top, reconstruct models the table as Gordon patches; the merge
    stage leaves every one of them out and keeps the teapot's (oracle: the exact teapot)."""
    import copy

    from nurbscan.merge import leave_out_table

    _, model = table_scan
    scene = make_scene("teapot")
    before = _gordon_samples(model)
    on_table = [np.median(X[:, 2]) < 1.0 for X in before]
    on_teapot = [np.median(scene.distance(X)) < 0.2 for X in _gordon_samples(model, 3)]
    assert sum(on_table) >= 20, sum(on_table)
    m = copy.deepcopy(model)
    counts = leave_out_table(m)
    after = _gordon_samples(m)
    assert counts["patches_removed"] >= sum(on_table) and counts["points_removed"] > 0
    assert counts["patches"] - counts["patches_removed"] == len(after)
    assert not any(np.median(X[:, 2]) < 1.0 for X in after)
    assert all(np.mean(X[:, 2] <= 0.5) <= 0.25 for X in after)
    assert len(after) >= 0.9 * sum(t and not b for t, b in zip(on_teapot, on_table,
                                                               strict=True))
    assert np.all(m.points[:, 2] > 0.5) and np.all(m.edge_points[:, 2] > 0.5)
    # three surfaces (Gordon and both skins) per patch, all of the same patches
    keys = {(s["view"], s["patch"]) for s in m.surfaces}
    assert len(m.surfaces) == 3 * len(keys) == 3 * len(after)


def test_simulate_table_albedo_renders_a_visible_table(tmp_path):
    """`simulate --table-albedo 0.3`: the table top's pixels (truth surface id -2) are ten
    times as bright as the default (albedo 0.03); outside [0, 1] is a one-line error."""
    import cv2

    from nurbscan.cli import main

    args = ["simulate", "sphere", "--views", "1", "--width", "160", "--height", "120",
            "--no-calibration", "--noise", "0", "--workers", "1"]
    assert main(args + ["-o", str(tmp_path / "dark")]) == 0
    assert main(args + ["-o", str(tmp_path / "grey"), "--table-albedo", "0.3"]) == 0
    render = json.loads((tmp_path / "grey" / "truth" / "render.json").read_text())
    assert render["table_albedo"] == [0.3, 0.3, 0.3]
    sid = np.load(tmp_path / "grey" / "truth" / "view_00.npz")["surface_id"]
    table = sid == -2
    assert table.sum() > 500
    lum = {k: cv2.imread(str(tmp_path / k / "views" / "view_00_white.png")).astype(float)
           for k in ("dark", "grey")}
    ratio = lum["grey"][table].mean() / max(lum["dark"][table].mean(), 1e-9)
    assert ratio > 2.5, ratio  # gamma 2.2: (10x)^(1/2.2) = 2.85
    assert main(args + ["-o", str(tmp_path / "bad"), "--table-albedo", "1.5"]) == 2
    assert not (tmp_path / "bad" / "scan.json").exists()


def test_cad_set_of_a_small_scan(table_scan):
    """The CAD set of a real (simulated) scan with a visible table: the surfaces overlap on
    under 1 % of their area (each surface's samples inverted onto the others), none lies on
    the table, and against the exact teapot most of it is as accurate as the patches."""
    import copy

    from nurbscan.camera import load_rig
    from nurbscan.merge import leave_out_table
    from nurbscan.merge.cad import cad_set, overlap_area

    scan, model = table_scan
    m = copy.deepcopy(model)
    leave_out_table(m)
    cad = cad_set(m, load_rig(scan / "truth" / "rig.json"))
    ov = overlap_area(cad.surfaces)
    assert ov["share"] < 0.01, ov
    X = np.concatenate([_grid7(d["surface"]) for d in cad.surfaces])
    assert X[:, 2].min() > 0.5
    d = make_scene("teapot").distance(X)
    print(f"CAD set: {len(cad.surfaces)} surfaces, overlap {ov['share']:.4%}, truth mean "
          f"{d.mean():.4f} p99 {np.percentile(d, 99):.4f} max {d.max():.4f} mm")
    assert np.percentile(d, 99) < 0.5 and np.mean(d) < 0.1


def _grid7(S):
    (u0, u1), (v0, v1) = S.domain
    g = np.linspace(0.0, 1.0, 7)
    return S.evaluate_grid(u0 + (u1 - u0) * g, v0 + (v1 - v0) * g).reshape(-1, 3)
