"""The merge stage on a model: the table left out, the views registered and moved.

:func:`merge_views` takes the model that :func:`nurbscan.reconstruct.reconstruct_scan` built
(every view in the object frame where the calibrated turntable and its table angle put it)
and changes it in place: the table's patches, curves and points go, each view's pose is
refined against the others (:func:`~nurbscan.merge.register.register_views`) and its curves,
patches and points move with it. Each view's entry of ``model.views`` records its correction
and registered pose; ``model.meta["merge"]`` what was removed and how the registration went.
The per-view patches stay (the paper's result): they are registered, not fused.
"""

from __future__ import annotations

import warnings as _warnings
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from .frame import moved_curve, moved_points, moved_surface, object_transform
from .register import Registration, RegistrationOptions, register_views
from .table import TableOptions, off_object, patch_off_object


class MergeWarning(UserWarning):
    """A merge step that could not do its work (the model is kept as it was)."""


@dataclass(frozen=True)
class MergeOptions:
    """Settings of :func:`merge_views`, by concern.

    Attributes
    ----------
    table : TableOptions or None
        Where the table is; None keeps everything.
    registration : RegistrationOptions or None
        How the views are registered; None keeps the turntable's poses.
    """

    table: TableOptions | None = field(default_factory=TableOptions)
    registration: RegistrationOptions | None = field(default_factory=RegistrationOptions)

    def to_dict(self) -> dict:
        """JSON-ready dict."""
        return {"table": None if self.table is None else self.table.to_dict(),
                "registration": None if self.registration is None
                else self.registration.to_dict()}


#: The default merge: the table left out, the views registered.
DEFAULT_MERGE = MergeOptions()


def merge_views(model, turntable, options: MergeOptions | None = None,
                progress: Callable[[str], None] | None = None) -> dict:
    """Leave out the table, register the views and move them (the model changes in place).

    Parameters
    ----------
    model : nurbscan.reconstruct.Model
        Every view in the object frame as the turntable puts it (``model.views`` with
        ``index`` and ``table_angle``, rad).
    turntable : nurbscan.camera.Turntable
        The calibrated turntable (for the registered poses, rig -> object).
    options : MergeOptions, optional
        Default :data:`DEFAULT_MERGE` (``MergeOptions()``).
    progress : callable, optional
        Called with one line per step; warnings also go to :func:`warnings.warn`.

    Returns
    -------
    dict
        ``model.meta["merge"]``: ``table`` (what was removed), ``registration``
        (:meth:`Registration.to_dict` without the per-view corrections, which are in
        ``model.views``), ``warnings``, ``options``.

    Notes
    -----
    1. leave out the table (:func:`leave_out_table`);
    2. register the views on their triangulated edge points (:func:`register_views`): the
       measured data, not the Gordon patches' samples, whose rows past the data would pull
       the views along the object's surface of revolution;
    3. move each view's curves, patches and points by its correction and record it
       (:func:`apply_registration`).
    """
    options = options or DEFAULT_MERGE
    say = progress or (lambda _m: None)
    out: dict = {"options": options.to_dict(), "warnings": []}
    if options.table is not None:
        out["table"] = leave_out_table(model, options.table)
        t = out["table"]
        say(f"merge: left out the table (z <= {options.table.margin:g} mm or farther than "
            f"{options.table.radius:g} mm from the axis): {t['patches_removed']} of "
            f"{t['patches']} patches, {t['curves_removed']} of {t['curves']} curves, "
            f"{t['points_removed']} of {t['points']} points")
    if options.registration is not None:
        clouds = {int(v["index"]): model.edge_points[model.edge_view == int(v["index"])]
                  for v in model.views}
        reg = register_views(clouds, options.registration, progress=say)
        apply_registration(model, reg, turntable)
        out["registration"] = {k: v for k, v in reg.to_dict().items() if k != "corrections"}
        out["warnings"] += reg.warnings
        if reg.significance is not None:
            say(f"merge: registration: {reg.significance['decision']}")
        if reg.applied:
            say(f"merge: registered {len(reg.corrections) - len(reg.unregistered)} views on "
                f"{len(reg.pairs)} overlapping pairs")
            for c in reg.corrections.values():
                say(f"merge: view {c.view}: {c.axis_angle:+.4f} degrees about the axis, "
                    f"{c.other_angle:.4f} degrees otherwise, "
                    f"{np.linalg.norm(c.translation):.4f} mm")
    for w in out["warnings"]:
        say(f"merge: warning: {w}")
        _warnings.warn(w, MergeWarning, stacklevel=2)
    model.meta["merge"] = out
    return out


def leave_out_table(model, options: TableOptions | None = None) -> dict:
    """Remove the patches, curves and points that are the table's (:mod:`.table`).

    A patch (its Gordon surface and both skins) goes when more than ``options.patch_share``
    of its Gordon surface's 9 x 9 samples are off the object; a curve likewise on 25 samples;
    points (the Gordon samples and the triangulated edge points) one by one. Returns the
    counts before and removed.
    """
    options = options or TableOptions()
    gordon = model.surfaces_of("gordon")
    grid = np.linspace(0.0, 1.0, 9)
    drop = set()
    for s in gordon:
        S = s["surface"]
        (u0, u1), (v0, v1) = S.domain
        uu, vv = np.meshgrid(u0 + (u1 - u0) * grid, v0 + (v1 - v0) * grid, indexing="ij")
        if patch_off_object(S.evaluate(uu.ravel(), vv.ravel()), options):
            drop.add((s["view"], s["patch"]))
    n_surf = len(model.surfaces)
    model.surfaces = [s for s in model.surfaces if (s["view"], s["patch"]) not in drop]
    t25 = np.linspace(0.0, 1.0, 25)
    keep_c = []
    for c in model.curves:
        a, b = c["curve"].domain
        keep_c.append(not patch_off_object(c["curve"].evaluate(a + (b - a) * t25), options))
    n_curves = len(model.curves)
    model.curves = [c for c, k in zip(model.curves, keep_c, strict=True) if k]
    n_pts, n_edge = len(model.points), len(model.edge_points)
    on = off_object(model.points, options)
    model.points, model.normals = model.points[~on], model.normals[~on]
    model.point_view = model.point_view[~on]
    on_e = off_object(model.edge_points, options)
    model.edge_points, model.edge_view = model.edge_points[~on_e], model.edge_view[~on_e]
    return {"patches": len(gordon), "patches_removed": len(drop),
            "surfaces_removed": n_surf - len(model.surfaces),
            "curves": n_curves, "curves_removed": n_curves - len(model.curves),
            "points": n_pts, "points_removed": int(on.sum()),
            "edge_points": n_edge, "edge_points_removed": int(on_e.sum())}


def apply_registration(model, reg: Registration, turntable) -> None:
    """Move each view's curves, surfaces, points and normals by its correction and record,
    per view, ``registration`` (the correction: degrees about the axis and otherwise, mm),
    ``registered_table_angle`` (rad: the table angle less the turn about the axis) and
    ``object_from_rig`` (``R``, ``t``: ``X_obj = R X_rig + t``, the registered pose)."""
    for entry in model.views:
        v = int(entry["index"])
        c = reg.corrections.get(v)
        if c is None:
            continue
        R, t = c.matrix[:3, :3], c.matrix[:3, 3]
        moved = not np.allclose(c.matrix, np.eye(4), rtol=0, atol=0)
        if moved:
            move_view(model, v, R, t)
        M, p = object_transform(turntable, float(entry["table_angle"]))
        Rp = R @ M.T
        entry["registration"] = {k: val for k, val in c.to_dict().items()
                                 if k not in ("view", "matrix")}
        entry["registered_table_angle"] = float(entry["table_angle"]
                                                - np.radians(c.axis_angle))
        entry["object_from_rig"] = {"R": Rp.tolist(), "t": (t - Rp @ p).tolist()}


def move_view(model, view: int, R: np.ndarray, t: np.ndarray) -> None:
    """Move one view's surfaces, curves, points (with normals) and edge points in place by
    ``X -> R X + t`` (R (3, 3), t (3,) mm), object frame."""
    for s in model.surfaces:
        if s["view"] == view:
            s["surface"] = moved_surface(s["surface"], R, t)
    for k in model.curves:
        if k["view"] == view:
            k["curve"] = moved_curve(k["curve"], R, t)
    sel = model.point_view == view
    model.points[sel] = moved_points(model.points[sel], R, t)
    model.normals[sel] = model.normals[sel] @ R.T
    sel = model.edge_view == view
    model.edge_points[sel] = moved_points(model.edge_points[sel], R, t)
