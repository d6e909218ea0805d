"""Several turntable passes of one object merged into one model (issue 33).

One pass sees the object from one band of elevations; the user turns the object over and
scans it again. Each pass is a model of its own (``reconstruct``: its views registered, the
table left out, a fused mesh), in its own object frame. :func:`merge_passes` puts them into
the first pass's frame and builds one model of the whole object:

1. **Surfaces.** Each pass's fused mesh sampled area-uniformly (about ``density`` points per
   mm^2) with its normals; the table and anything below the object's base (``z <=
   base_margin`` in the pass's frame: the contact zone, where the table hides the object and
   the fused surface is closed over the gap) left out (:func:`pass_surface`).
2. **Global registration** of every further pass to the passes merged before it, with no
   prior (:func:`nurbscan.merge.global_registration.align_surfaces`: FPFH features, RANSAC,
   point-to-plane ICP), checked for too small an overlap, too large a residual (an error: not
   one object) and ambiguity (a warning); near-equal candidates are told apart by the
   passes' free space when their rigs are known (:mod:`nurbscan.merge.free_space`: what
   each pass's cameras and projector saw as empty).
3. **One set of views.** Every pass's views, curves, Gordon patches and points moved by its
   transform; view ``v`` of pass ``k`` becomes view ``100 k + v``.
4. **Joint refinement** of all views of all passes (:func:`nurbscan.merge.register.register_views`:
   pairwise point-to-plane ICP over the overlaps, a pose graph; the first view of the first
   pass fixes the frame), each view moved by its correction.
5. **Fusion** of all views into one mesh (:func:`nurbscan.merge.fusion.fuse_model`),
   coloured from every pass's white-light images when they are given (each view projected
   with its own pass's rig and its pose in the merged frame, :func:`view_poses`).

The alignment is reported per pass: the transform (global and after the joint refinement, the
pass's views' mean correction), the RMS distance over the overlap (the pass's surface samples
within ``overlap_distance`` of the first pass's fused mesh, exact point-to-triangle distances:
float32, so about 1e-5 mm), the overlap share, and warnings. Units: mm; transforms 4 x 4
with ``X_first = T X_pass``.
"""

from __future__ import annotations

import copy
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from ..errors import NurbscanError
from ._open3d import import_open3d, raycasting_scene
from .frame import moved_curve, moved_points, moved_surface, view_object_from_rig
from .free_space import FreeSpace, pass_free_space
from .global_registration import (
    Alignment,
    GlobalOptions,
    align_surfaces,
    motion_difference,
)
from .register import RegistrationOptions, register_views
from .views import move_view

__all__ = ["PassOptions", "merge_passes", "pass_surface", "view_poses", "VIEW_OFFSET"]

#: View ``v`` of pass ``k`` is view ``VIEW_OFFSET * k + v`` of the merged model.
VIEW_OFFSET = 100


@dataclass(frozen=True)
class PassOptions:
    """Settings of :func:`merge_passes`, by step.

    Attributes
    ----------
    base_margin : float
        Height above each pass's table plane (mm) below which its surface is left out of the
        alignment (the table, the contact zone under the object's base).
    density : float
        Samples per mm^2 of each pass's fused mesh for the alignment.
    alignment : GlobalOptions
        The global registration.
    registration : RegistrationOptions or None
        The joint refinement of all views; None keeps the global alignment.
    fusion : FusionOptions or None
        The fused mesh of all views; None: none.
    """

    base_margin: float = 2.0
    density: float = 1.0
    alignment: GlobalOptions = field(default_factory=GlobalOptions)
    registration: RegistrationOptions | None = field(default_factory=RegistrationOptions)
    fusion: object | None = None

    def to_dict(self) -> dict:
        return {"base_margin": self.base_margin, "density": self.density,
                "alignment": self.alignment.to_dict(),
                "registration": None if self.registration is None
                else self.registration.to_dict()}


def pass_surface(model, options: PassOptions | None = None, seed: int = 0):
    """Area-uniform samples ``(points (N, 3), normals (N, 3))`` of a pass's fused mesh (its
    own object frame, mm), those at or below ``base_margin`` left out.

    Raises
    ------
    NurbscanError
        When the model has no fused mesh.
    """
    import trimesh

    opt = options or PassOptions()
    fm = getattr(model, "fused", None)
    if fm is None or len(fm.faces) == 0:
        raise NurbscanError(f"{model.meta.get('_folder', 'model')}: no fused mesh (fused.ply); "
                            "reconstruct it with fusion (without --no-fuse)")
    tm = trimesh.Trimesh(fm.vertices, fm.faces, process=False)
    n = int(np.clip(tm.area * opt.density, 1000, 400_000))
    P, fi = trimesh.sample.sample_surface(tm, n, seed=seed)
    N = tm.face_normals[fi]
    keep = P[:, 2] > opt.base_margin
    return np.asarray(P[keep], float), np.asarray(N[keep], float)


def merge_passes(models: Sequence, names: Sequence[str] | None = None,
                 options: PassOptions | None = None,
                 progress: Callable[[str], None] | None = None,
                 colour: Sequence | None = None, rigs: Sequence | None = None):
    """Merge turntable passes of one object into one model in the first pass's frame.

    Parameters
    ----------
    models : sequence of nurbscan.reconstruct.Model
        At least two passes, each with its fused mesh (not changed).
    names : sequence of str, optional
        How the passes are named in messages (default ``pass 1``, ``pass 2``, ...).
    options : PassOptions, optional
    progress : callable, optional
        Called with one line per step.
    colour : sequence of (Rig, {view index: path}), optional
        Per pass, its calibrated rig and its views' white-light images (the pass's own view
        indices), for the fused mesh's colours; None (or a pass's entry None): grey, or
        the passes that have them.
    rigs : sequence of nurbscan.camera.Rig, optional
        Per pass, its calibrated rig (default: those of ``colour``): the passes' views'
        free space chooses among near-equal alignments
        (:func:`nurbscan.merge.free_space.pass_free_space`); a pass without one (None):
        the best overlap is chosen.

    Returns
    -------
    (Model, dict)
        The merged model (``meta["passes"]`` records each pass and its alignment) and the
        alignment report (``passes``: per pass ``name``, ``global`` (:meth:`Alignment.to_dict`),
        ``refined`` (the transform after the joint refinement), ``overlap``, ``rms_mm``;
        ``registration``; ``warnings``).

    Raises
    ------
    NurbscanError
        Fewer than two passes, a pass without a fused mesh, or a pass that does not align
        (not the same object, or too little overlap).

    Notes
    -----
    See the module notes for the steps: :func:`pass_surface`, :func:`align_surfaces`,
    :func:`_combined`, :func:`register_views` with :func:`_apply_corrections`,
    :func:`_refined_transforms`, :func:`nurbscan.merge.fusion.fuse_model`.
    """
    opt = options or PassOptions()
    say = progress or (lambda _m: None)
    if len(models) < 2:
        raise NurbscanError("merge: at least two passes (model folders) are needed")
    names = list(names or [f"pass {k + 1}" for k in range(len(models))])
    t0 = time.perf_counter()
    surfaces = [pass_surface(m, opt) for m in models]
    say(f"merge: {len(models)} passes, "
        + ", ".join(f"{n}: {len(s[0])} surface samples" for n, s in zip(names, surfaces,
                                                                           strict=True)))
    transforms = [np.eye(4)]
    alignments: list[Alignment | None] = [None]
    warnings: list[str] = []
    done_P, done_N = surfaces[0]
    if rigs is None and colour is not None:
        rigs = [None if c is None else c[0] for c in colour]
    spaces = _free_spaces(models, rigs)
    for k in range(1, len(models)):
        fs = None
        if all(sp is not None for sp in spaces[:k + 1]):
            fs = (spaces[k], FreeSpace.joined([spaces[j].moved(transforms[j], j)
                                               for j in range(k)]))
        al = align_surfaces(surfaces[k], (done_P, done_N), opt.alignment, say,
                            names=(names[k], " + ".join(names[:k])), free_space=fs)
        transforms.append(al.matrix)
        alignments.append(al)
        warnings += al.warnings
        rv = Rotation.from_matrix(al.matrix[:3, :3]).as_rotvec()
        say(f"merge: {names[k]} -> {names[0]}: rotation {np.degrees(np.linalg.norm(rv)):.3f} "
            f"degrees, translation {np.round(al.matrix[:3, 3], 3).tolist()} mm, overlap "
            f"{100 * al.overlap:.1f} %, RMS {al.rms_mm:.4f} mm over the overlap"
            + ("" if al.free_space is None else
               f", free-space violation {100 * al.free_space:.2f} % (chosen by {al.chosen_by})")
            + (" (ambiguous)" if al.ambiguous else ""))
        P, N = surfaces[k]
        done_P = np.concatenate([done_P, P @ al.matrix[:3, :3].T + al.matrix[:3, 3]])
        done_N = np.concatenate([done_N, N @ al.matrix[:3, :3].T])
    t_global = time.perf_counter() - t0
    merged = _combined(models, transforms, names)
    reg_report = None
    corrections = {}
    if opt.registration is not None:
        clouds = {int(v["index"]): merged.edge_points[merged.edge_view == int(v["index"])]
                  for v in merged.views}
        reg = register_views(clouds, opt.registration, progress=say)
        reg_report = {k: v for k, v in reg.to_dict().items() if k != "corrections"}
        warnings += [f"joint refinement: {w}" for w in reg.warnings]
        if reg.applied:
            corrections = {v: c.matrix for v, c in reg.corrections.items()}
            _apply_corrections(merged, reg.corrections)
            say(f"merge: joint refinement of {len(reg.corrections)} views of "
                f"{len(models)} passes on {len(reg.pairs)} overlapping pairs")
        else:
            say("merge: the joint refinement was not applied; the passes keep their global "
                "alignment")
    refined = _refined_transforms(merged, transforms, corrections)
    report = {"passes": [], "registration": reg_report, "warnings": warnings,
              "global_s": round(t_global, 3)}
    for k, name in enumerate(names):
        entry = {"name": name, "source": models[k].meta.get("source"),
                 "view_offset": VIEW_OFFSET * k,
                 "refined_matrix": np.round(refined[k], 12).tolist()}
        if k:
            ang, tr = motion_difference(transforms[k], refined[k])
            ov, rms = mesh_overlap_rms(surfaces[k][0], refined[k], models[0].fused,
                                       opt.alignment.overlap_distance)
            entry.update({"global": alignments[k].to_dict(), "refinement_deg": round(ang, 6),
                          "refinement_mm": round(tr, 6), "overlap": round(ov, 6),
                          "rms_mm": round(rms, 6)})
            say(f"merge: {name} after the joint refinement: {ang:.4f} degrees and {tr:.4f} mm "
                f"from its global alignment; overlap {100 * ov:.1f} %, RMS {rms:.4f} mm "
                f"against {names[0]}")
        report["passes"].append(entry)
    merged.meta["passes"] = report
    if opt.fusion is not None:
        from .fusion import fuse_model

        merged.fused = fuse_model(merged, None, None, opt.fusion, progress=say)
        merged.fused.info["colour"] = "neutral (merged passes)"
        if colour is not None and any(c is not None for c in colour):
            merged.fused = _coloured(merged, colour, say)
    for w in warnings:
        say(f"merge: warning: {w}")
    report["total_s"] = round(time.perf_counter() - t0, 3)
    return merged, report


def _free_spaces(models: Sequence, rigs: Sequence | None) -> list:
    """Per pass, its free space (:func:`nurbscan.merge.free_space.pass_free_space`) in its
    own frame, or None without its rig or fused mesh."""
    if rigs is None:
        return [None] * len(models)
    return [None if r is None or getattr(m, "fused", None) is None
            else pass_free_space(m, r) for m, r in zip(models, rigs, strict=True)]


def mesh_overlap_rms(points: np.ndarray, T: np.ndarray, mesh, distance: float):
    """Share of ``points`` (N, 3), moved by ``T``, within ``distance`` (mm) of a triangle mesh
    (``vertices``, ``faces``; exact point-to-triangle distances, Open3D ``RaycastingScene``)
    and the RMS distance over that overlap (mm)."""
    o3d = import_open3d("pass overlap")
    X = np.asarray(points, float) @ T[:3, :3].T + T[:3, 3]
    scene = raycasting_scene(mesh.vertices, mesh.faces, "pass overlap")
    d = scene.compute_distance(o3d.core.Tensor(X.astype(np.float32))).numpy().astype(float)
    ok = d <= distance
    if not ok.any():
        return 0.0, float("inf")
    return float(ok.mean()), float(np.sqrt(np.mean(d[ok] ** 2)))


def _combined(models: Sequence, transforms: Sequence[np.ndarray], names: Sequence[str]):
    """One model of all passes' views in the first pass's frame (copies; views renumbered)."""
    from ..reconstruct.model import Model

    out = Model(meta={"source": models[0].meta.get("source"),
                      "calibration": models[0].meta.get("calibration"),
                      "merged_passes": [m.meta.get("source") for m in models]})
    pts, nrm, pv, ep, ev = [], [], [], [], []
    for k, (m, T) in enumerate(zip(models, transforms, strict=True)):
        R, t = T[:3, :3], T[:3, 3]
        off = VIEW_OFFSET * k
        ident = np.allclose(T, np.eye(4), rtol=0, atol=0)
        for c in m.curves:
            out.curves.append({**c, "view": int(c["view"]) + off,
                               "curve": c["curve"] if ident else moved_curve(c["curve"], R, t)})
        for s in m.surfaces:
            out.surfaces.append({**s, "view": int(s["view"]) + off,
                                 "surface": s["surface"] if ident
                                 else moved_surface(s["surface"], R, t)})
        for v in m.views:
            e = copy.deepcopy(v)
            e["index"] = int(v["index"]) + off
            e.update({"pass": k, "pass_name": names[k], "pass_view": int(v["index"]),
                      "pass_transform": np.round(T, 12).tolist()})
            out.views.append(e)
        pts.append(moved_points(np.asarray(m.points, float).reshape(-1, 3), R, t))
        nrm.append(np.asarray(m.normals, float).reshape(-1, 3) @ R.T)
        pv.append(np.asarray(m.point_view, int) + off)
        ep.append(moved_points(np.asarray(m.edge_points, float).reshape(-1, 3), R, t))
        ev.append(np.asarray(m.edge_view, int) + off)
    out.points, out.normals, out.point_view = (np.concatenate(pts), np.concatenate(nrm),
                                               np.concatenate(pv))
    out.edge_points, out.edge_view = np.concatenate(ep), np.concatenate(ev)
    return out


def _apply_corrections(model, corrections: dict) -> None:
    """Move each view's curves, surfaces, points and normals by its correction
    (``X <- R X + t``, object frame) and record it in the view's entry."""
    for entry in model.views:
        v = int(entry["index"])
        c = corrections.get(v)
        if c is None:
            continue
        R, t = c.matrix[:3, :3], c.matrix[:3, 3]
        entry["joint_registration"] = {k: val for k, val in c.to_dict().items()
                                       if k not in ("view",)}
        if np.allclose(c.matrix, np.eye(4), rtol=0, atol=0):
            continue
        move_view(model, v, R, t)


def _mean_motion(Ts: list) -> np.ndarray:
    """The mean of rigid motions (4 x 4): the rotations' chordal mean (scipy
    ``Rotation.mean``), the translations' mean."""
    out = np.eye(4)
    out[:3, :3] = Rotation.from_matrix(np.array([T[:3, :3] for T in Ts])).mean().as_matrix()
    out[:3, 3] = np.mean([T[:3, 3] for T in Ts], axis=0)
    return out


def _refined_transforms(model, transforms: Sequence[np.ndarray], corrections: dict) -> list:
    """Per pass, its transform after the joint refinement: the mean over its views of
    ``C_v T_k``, relative to the first pass's mean correction (which the anchor keeps near
    the identity)."""
    by_pass: dict[int, list] = {}
    for e in model.views:
        C = corrections.get(int(e["index"]), np.eye(4))
        by_pass.setdefault(int(e["pass"]), []).append(C @ transforms[int(e["pass"])])
    ref = np.linalg.inv(_mean_motion(by_pass.get(0, [np.eye(4)])))
    return [ref @ _mean_motion(by_pass.get(k, [transforms[k]])) for k in range(len(transforms))]


def view_poses(model, rigs: Sequence) -> dict:
    """Per view of a merged model, its pass's rig and its pose in the merged frame:
    ``{view: (rig, M)}`` with ``X_rig = M X_merged`` (4 x 4).

    A view's pose is ``(C_v T_k P_v)^-1``: ``P_v`` its pose in its pass's frame (the pass's
    registered ``object_from_rig`` where its reconstruction recorded one, else the calibrated
    turntable at its table angle), ``T_k`` the pass's transform (``pass_transform``) and
    ``C_v`` the joint refinement's correction (``joint_registration``; identity without).
    Views of passes whose rig is None are left out.
    """
    out = {}
    for e in model.views:
        rig = rigs[int(e.get("pass", 0))]
        if rig is None:
            continue
        P = view_object_from_rig(e, rig.turntable)
        T = np.asarray(e.get("pass_transform", np.eye(4)), float)
        C = np.asarray(e.get("joint_registration", {}).get("matrix", np.eye(4)), float)
        out[int(e["index"])] = (rig, np.linalg.inv(C @ T @ P))
    return out


def _coloured(model, colour: Sequence, say):
    """The merged fused mesh with vertex colours from every pass's white images
    (:func:`nurbscan.merge.fusion._vertex_colours` with the views' poses, :func:`view_poses`)."""
    from .fusion import FusedMesh, _vertex_colours

    rigs = [None if c is None else c[0] for c in colour]
    white = {}
    for e in model.views:
        c = colour[int(e.get("pass", 0))]
        if c is not None and int(e["pass_view"]) in c[1]:
            white[int(e["index"])] = c[1][int(e["pass_view"])]
    t0 = time.perf_counter()
    fm = model.fused
    rgba, source = _vertex_colours(fm.vertices, fm.faces, model, None, white,
                                   view_poses(model, rigs))
    info = {**fm.info, "colour": f"{source} of {sum(r is not None for r in rigs)} passes",
            "colour_s": round(time.perf_counter() - t0, 3)}
    say(f"merge: fused mesh coloured from the {source} ({info['colour_s']:.1f} s)")
    return FusedMesh(fm.vertices, fm.faces, rgba, info)
