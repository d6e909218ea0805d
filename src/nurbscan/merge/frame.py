"""Views into the turntable (object) frame (method.md section 6).

The object frame (docs/conventions.md): origin at the axis point ``p``, ``z`` along the axis
``a``, ``x`` along the component of the rig's ``-z`` axis perpendicular to ``a``, ``y = z x x``. A
point of the object at table angle ``theta`` is at ``p + Rot(a, theta) [x_t y_t z_t] X_obj`` in the
rig frame. NURBS curves and surfaces are invariant under this rigid map (it is applied to the
control points; weights are unchanged).
"""

from __future__ import annotations

import numpy as np

from ..nurbs import NurbsCurve, NurbsSurface


def _rot(axis: np.ndarray, angle: float) -> np.ndarray:
    k = axis / np.linalg.norm(axis)
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle) * kx + (1 - np.cos(angle)) * kx @ kx


def object_transform(turntable, angle: float) -> tuple[np.ndarray, np.ndarray]:
    """``(M, t)`` with ``X_rig = M X_obj + t`` at table angle ``angle`` (rad).

    Uses ``turntable.to_rig`` when the turntable has it, else the conventions directly from
    ``turntable.point`` and ``turntable.direction``.
    """
    if hasattr(turntable, "to_rig"):
        pts = np.vstack([np.zeros(3), np.eye(3)])
        rig = np.asarray(turntable.to_rig(pts, float(angle)), float)
        return (rig[1:] - rig[0]).T, rig[0]
    p = np.asarray(turntable.point, float)
    a = np.asarray(turntable.direction, float)
    a = a / np.linalg.norm(a)
    x = np.array([0.0, 0.0, -1.0])
    x = x - (x @ a) * a
    x /= np.linalg.norm(x)
    y = np.cross(a, x)
    return _rot(a, float(angle)) @ np.stack([x, y, a], axis=1), p


def rig_to_object(points, turntable, angle: float) -> np.ndarray:
    """Rig-frame points (..., 3) into the object frame at table angle ``angle``, mm."""
    M, t = object_transform(turntable, angle)
    return (np.asarray(points, float) - t) @ M


def curve_to_object(curve: NurbsCurve, turntable, angle: float) -> NurbsCurve:
    """A 3-D curve moved into the object frame (control points mapped, weights kept)."""
    return NurbsCurve(curve.degree, curve.knots,
                      rig_to_object(curve.control_points, turntable, angle), curve.weights)


def surface_to_object(surface: NurbsSurface, turntable, angle: float) -> NurbsSurface:
    """A surface moved into the object frame (control points mapped, weights kept)."""
    return NurbsSurface(surface.degree_u, surface.degree_v, surface.knots_u, surface.knots_v,
                        rig_to_object(surface.control_points, turntable, angle),
                        surface.weights)


def moved_points(points, R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Points (..., 3) moved rigidly, ``R X + t`` (mm)."""
    return np.asarray(points, float) @ np.asarray(R, float).T + np.asarray(t, float)


def moved_curve(curve: NurbsCurve, R: np.ndarray, t: np.ndarray) -> NurbsCurve:
    """A curve moved rigidly (control points mapped, weights kept)."""
    return NurbsCurve(curve.degree, curve.knots, moved_points(curve.control_points, R, t),
                      curve.weights)


def moved_surface(surface: NurbsSurface, R: np.ndarray, t: np.ndarray) -> NurbsSurface:
    """A surface moved rigidly (control points mapped, weights kept)."""
    return NurbsSurface(surface.degree_u, surface.degree_v, surface.knots_u, surface.knots_v,
                        moved_points(surface.control_points, R, t), surface.weights)


def view_object_from_rig(entry: dict, turntable) -> np.ndarray:
    """A model view's pose ``P`` (4 x 4), ``X_obj = P X_rig``: its registered
    ``object_from_rig`` where its reconstruction recorded one, else the calibrated turntable
    at its ``table_angle`` (:func:`object_transform`)."""
    P = np.eye(4)
    if "object_from_rig" in entry:
        P[:3, :3] = np.asarray(entry["object_from_rig"]["R"], float)
        P[:3, 3] = np.asarray(entry["object_from_rig"]["t"], float)
    else:
        M, t = object_transform(turntable, float(entry["table_angle"]))
        P[:3, :3], P[:3, 3] = M.T, -M.T @ t
    return P
