"""Tests of nurbscan.merge: the table left out, the views registered (issue #32).

The registration is tested on views sampled from the exact scene surfaces (an independent
oracle: the true surface and the true table angles), then end to end on a small scan with a
visible table top."""

from __future__ import annotations

import json

import numpy as np
import pytest

from nurbscan.merge import (
    RegistrationOptions,
    TableOptions,
    off_object,
    register_views,
)
from nurbscan.merge.register import _rz, twist_swing
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


def test_revolution_surface_keeps_the_given_angles():
    """A sphere on the axis cannot fix the turn about the axis: said so, angles as given."""
    views = _views("sphere")
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
        assert abs(entry["registration"]["axis_angle_deg"] - delta[v]) < 0.02
        assert abs(np.degrees(entry["registered_table_angle"]) - 45 * v) < 0.02
        # the registered pose maps the rig into the object frame: a point of the object at
        # the true angle, seen in the rig, comes back to itself
        X = np.array([[30.0, -20.0, 50.0]])
        rig = tt.to_rig(X, 2 * np.pi * v / 8)
        R, t = np.array(entry["object_from_rig"]["R"]), np.array(entry["object_from_rig"]["t"])
        assert np.abs(rig @ R.T + t - X).max() < 0.05
    m2 = load_model(tmp_path / "model")
    scene = make_scene("teapot")
    assert np.mean(scene.distance(m2.points[::50])) < 0.02
