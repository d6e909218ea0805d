"""Registration of the views: every view's pose refined jointly against the others.

The views start where the calibrated turntable and their table angles put them (the object
frame, :mod:`.frame`). A turntable's angles are not exact, so each view gets a rigid
correction ``C_v`` (4 x 4, object frame): ``X <- R_v X + t_v``. They are found in two steps, as
in Open3D's multiway registration (Choi, Zhou and Koltun 2015):

1. **Pairwise point-to-plane ICP** (Chen and Medioni 1992; Open3D ``registration_icp``) between
   every two views that overlap, coarse to fine, on each view's point samples (the Gordon
   patches') thinned to a voxel grid. The ICP's Gauss-Newton Hessian ``H = sum J^T J``,
   ``J = [q x n, n]`` (q a target point, n its normal; twist order rotation, translation) is
   the pair's information matrix.
2. **Pose graph** over all views (Open3D ``global_optimization``, Levenberg-Marquardt with line
   process), one node per view, one edge per overlapping pair; the first view (or
   ``anchor``) is kept as given: it fixes the object frame.

A surface of revolution about the turntable's axis (a sphere or a cylinder on the axis) does
not fix a view's turn about the axis: ICP's residuals do not change with it. That shows in the
summed Hessian: the information about the rotation about the axis that the other five motions
do not explain (its Schur complement), per matched point and with rotations in mm at the
points' RMS radius, is about zero. Below ``axis_information`` the turn about the axis is left
as given (each correction's twist about the axis removed) and the result says so. Each pair's
own correction is also kept to the motions its Hessian determines (its twist projected onto
the eigenvectors of the scaled Hessian above ``pair_information``), so that a pair's
undetermined motions (a sphere's turn about its centre) do not reach the pose graph as noise.

**Significance gate.** A correction within its uncertainty is the pairs' noise, and applying
it only carries that noise into the model (exact table angles, 1024 x 768 teapot scan: Gordon
mean 0.0373 mm kept, 0.0400 mm registered). The pose graph is tested as a least-squares
network adjustment (:func:`_significance`): the variance factor comes from the misclosures
(the pairs' real disagreement, about 4 times the ICP's nominal point-to-plane variance on
that scan), each view's turn about the axis is tested with 1 and its other five motions with
5 degrees of freedom (chi-square, Bonferroni over the views at ``significance``). Nothing
significant: every view keeps the turntable's pose. Only turns significant (a turntable's
angle error): the views get turns about the axis alone, solved from the pairs' own ICP
results (:func:`_turns`; perturbed by up to 2 degrees, same scan: Gordon mean 0.0377 mm,
0.0393 mm with the full registered poses). Other motions significant: the registered poses.

Bad input gives warnings, never an error: a view that overlaps no other view keeps its pose;
a correction over ``max_angle`` degrees or ``max_translation`` mm means the registration
diverged, and optimised poses farther than ``max_misclosure`` from a trusted pair's own ICP
result mean that the overlaps disagree (too little of the surface fixes the turn): in both
cases every view keeps its unregistered pose.
"""

from __future__ import annotations

import contextlib
from dataclasses import asdict, dataclass, field

import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from ..errors import NurbscanError
from ._open3d import import_open3d


@dataclass(frozen=True)
class RegistrationOptions:
    """Settings of :func:`register_views`.

    Attributes
    ----------
    voxel : float
        Voxel size (mm) each view's points are thinned to (Open3D ``voxel_down_sample``).
    normal_radius : float
        Radius (mm) of the neighbourhood that a point's normal is estimated from when a view
        comes without normals.
    distances : tuple of float
        The ICP's largest correspondence distance at each level, coarse to fine (mm). The
        first must exceed the views' initial misalignment (2 degrees at 80 mm from the axis:
        2.8 mm).
    iterations : int
        ICP iterations per level.
    min_overlap : float
        Two views overlap when at least this share of the smaller view's samples finds a
        partner within the finest distance (and ``min_points`` samples do).
    min_points : int
        See ``min_overlap``.
    pair_information : float
        Relative eigenvalue of a pair's scaled Hessian below which a pair's motion is taken
        as undetermined (module notes).
    axis_information : float
        Information about the turn about the axis per matched point (scaled, module notes)
        below which the turn is undetermined: about the square of the RMS normal component
        along the turn that no other motion explains. Teapot 0.01-0.02, sphere and cylinder
        1e-5.
    max_angle : float
        Largest correction (degrees, about the axis or otherwise) that is not divergence.
    max_translation : float
        Largest translation (mm) that is not divergence.
    max_misclosure : float
        Largest angle (degrees) by which the optimised poses may differ from the own ICP
        result of a pair of neighbouring views (in table angle; kept by the line process).
        Beyond it the overlaps disagree: the surface does not fix the poses (640 x 480 teapot
        scan: up to 1.15 degrees; 1024 x 768: 0.13 degrees) and every view keeps its
        unregistered pose.
    significance : float or None
        Chance that exact turntable poses are called wrong by the significance gate (module
        notes); None applies the pose graph's result whatever its size.
    anchor : int or None
        View index kept as given (default the first view).
    """

    voxel: float = 1.0
    normal_radius: float = 3.0
    distances: tuple[float, ...] = (3.0, 1.5, 1.0, 0.7)
    iterations: int = 30
    min_overlap: float = 0.1
    min_points: int = 100
    pair_information: float = 1e-4
    axis_information: float = 1e-3
    max_angle: float = 5.0
    max_translation: float = 5.0
    max_misclosure: float = 0.3
    significance: float | None = 0.01
    anchor: int | None = None

    def __post_init__(self) -> None:
        if not (self.voxel > 0 and self.distances and all(d > 0 for d in self.distances)):
            raise NurbscanError("registration: voxel and distances must be > 0 mm")
        if self.iterations < 1 or self.min_points < 3:
            raise NurbscanError("registration: iterations >= 1 and min_points >= 3 required")

    def to_dict(self) -> dict:
        """JSON-ready dict."""
        d = asdict(self)
        d["distances"] = list(self.distances)
        return d


@dataclass(frozen=True)
class Correction:
    """One view's rigid correction in the object frame, ``X <- R X + t``.

    ``axis_angle`` is its turn about the turntable's axis (the twist of ``R`` about ``z``,
    degrees; the view's table angle was ``axis_angle`` too large), ``other_angle`` the rest of
    the rotation (degrees), ``translation`` ``t`` (mm).
    """

    view: int
    matrix: np.ndarray = field(repr=False)
    axis_angle: float = 0.0
    other_angle: float = 0.0
    translation: tuple[float, float, float] = (0.0, 0.0, 0.0)

    @classmethod
    def of(cls, view: int, matrix: np.ndarray) -> Correction:
        """Decompose a 4 x 4 correction (swing-twist about ``z``)."""
        alpha, other = twist_swing(matrix[:3, :3])
        return cls(int(view), np.asarray(matrix, float), float(np.degrees(alpha)),
                   float(np.degrees(other)), tuple(float(x) for x in matrix[:3, 3]))

    def to_dict(self) -> dict:
        """JSON-ready dict (degrees, mm)."""
        return {"view": self.view, "axis_angle_deg": round(self.axis_angle, 6),
                "other_rotation_deg": round(self.other_angle, 6),
                "translation_mm": [round(x, 6) for x in self.translation],
                "matrix": np.round(self.matrix, 12).tolist()}


@dataclass(frozen=True)
class Registration:
    """What :func:`register_views` found.

    Attributes
    ----------
    corrections : dict of int -> Correction
        Per view; identity where a view kept its pose.
    applied : bool
        False when the registration diverged (all corrections identity).
    axis_determined : bool
        Whether the data fix the views' turns about the axis.
    axis_information : float
        The information about the turn about the axis per matched point (module notes).
    pairs : list of dict
        The overlapping pairs: ``source``, ``target``, ``overlap``, ``rmse_mm`` (after ICP).
    unregistered : list of int
        Views that overlap none connected to the anchor (kept as given).
    warnings : list of str
    significance : dict or None
        The gate's test (:func:`_significance`) and its ``decision`` (one line).
    """

    corrections: dict
    applied: bool
    axis_determined: bool
    axis_information: float
    pairs: list
    unregistered: list
    warnings: list
    significance: dict | None = None

    def to_dict(self) -> dict:
        """JSON-ready dict."""
        return {"applied": self.applied, "axis_determined": self.axis_determined,
                "axis_information": float(self.axis_information), "pairs": self.pairs,
                "unregistered": self.unregistered, "warnings": self.warnings,
                "significance": self.significance,
                "corrections": [c.to_dict() for c in self.corrections.values()]}


def twist_swing(R: np.ndarray) -> tuple[float, float]:
    """Swing-twist decomposition of a rotation about ``z``: ``R = S Rz(alpha)``.

    Returns ``(alpha, angle of S)`` in radians; ``alpha`` is the turn about ``z``
    (from the quaternion, ``alpha = 2 atan2(q_z, q_w)``, wrapped to [-pi, pi]).
    """
    x, y, z, w = Rotation.from_matrix(np.asarray(R, float)).as_quat()
    alpha = 2.0 * np.arctan2(z, w)
    alpha = (alpha + np.pi) % (2 * np.pi) - np.pi
    S = np.asarray(R, float) @ _rz(-alpha)
    return float(alpha), float(np.linalg.norm(Rotation.from_matrix(S).as_rotvec()))


def register_views(clouds: dict, options: RegistrationOptions = RegistrationOptions(),
                   progress=None) -> Registration:
    """Refine every view's pose jointly: pairwise point-to-plane ICP and a pose graph.

    Parameters
    ----------
    clouds : dict of int -> (points (N, 3), normals (N, 3))
        Each view's samples in the object frame (as the turntable puts them), mm, with unit
        normals.
    options : RegistrationOptions
    progress : callable, optional
        Called with one line per step.

    Returns
    -------
    Registration

    Notes
    -----
    1. thin each view to a voxel grid (:func:`_thinned`);
    2. ICP between every two views, coarse to fine; keep the pairs that overlap
       (:func:`_pairwise`), each with its point-to-plane Hessian (:func:`_hessian`) and its
       correction kept to the motions the Hessian determines (:func:`_determined`);
    3. leave out the views not connected to the anchor (:func:`_connected`);
    4. optimise the pose graph (:func:`_pose_graph`);
    5. if the turn about the axis is undetermined (:func:`_axis_information`), remove it;
    6. check for divergence;
    7. test the corrections against their uncertainty (:func:`_significance`): keep the
       turntable's poses, or turn the views about the axis only (:func:`_turns`), or take
       the registered poses.

    Open3D runs on one thread here (:func:`one_open3d_thread`): its parallel reductions (TBB)
    sum in an order that changes from run to run, and the corrections with it in their last
    digits, which then reach every point of the model.
    """
    with one_open3d_thread():
        return _register_views(clouds, options, progress)


@contextlib.contextmanager
def one_open3d_thread():
    """Open3D limited to one thread (``open3d.utility.set_max_threads``, Open3D >= 0.19) for
    the block, then to its automatic default again: the same inputs give the same bits.
    Measured on four 1024 x 768 4-view teapot scans, serially in one process: with Open3D's 2
    threads, 2 of 4 models changed from run to run (the registration's variance factor in the
    13th digit); with one, none."""
    o3d = _o3d()
    limit = getattr(o3d.utility, "set_max_threads", None)
    if limit is not None:
        limit(1)
    try:
        yield
    finally:
        if limit is not None:
            limit(0)


def _register_views(clouds: dict, options: RegistrationOptions, progress) -> Registration:
    """:func:`register_views`'s steps (its Notes)."""
    say = progress or (lambda _m: None)
    views = sorted(int(v) for v in clouds)
    warnings: list[str] = []
    ident = {v: Correction.of(v, np.eye(4)) for v in views}
    if len(views) < 2:
        return Registration(ident, False, False, 0.0, [], views, warnings)
    anchor = views[0] if options.anchor is None else int(options.anchor)
    if anchor not in clouds:
        raise NurbscanError(f"registration anchor {anchor}: no such view")
    pcd = {v: _thinned(*_split(clouds[v]), options.voxel, options.normal_radius)
           for v in views}
    pairs = _pairwise(pcd, options)
    say(f"merge: registration on {len(pairs)} overlapping view pairs of "
        f"{len(views) * (len(views) - 1) // 2}")
    linked = _connected(views, pairs, anchor)
    lonely = [v for v in views if v not in linked]
    if lonely:
        warnings.append(f"views {lonely} overlap no view connected to view {anchor}: "
                        "their poses are kept unregistered")
    pairs = [p for p in pairs if p["source"] in linked and p["target"] in linked]
    H_all = sum((p["H"] for p in pairs), np.zeros((6, 6)))
    n_all = sum(p["n"] for p in pairs)
    radius = _rms_radius(pcd, linked)
    info = _axis_information(H_all, n_all, radius)
    axis_ok = bool(info >= options.axis_information)
    if not axis_ok and pairs:
        warnings.append(f"the views' turns about the turntable axis are not determined by the "
                        f"surface (a surface of revolution about the axis? information "
                        f"{info:.2g} per point < {options.axis_information:g}): the table "
                        "angles are kept as given")
    corr = dict(ident)
    if len(linked) > 1:
        poses = _pose_graph(sorted(linked), pairs, anchor, options)
        for v, T in poses.items():
            # Open3D's threaded sums differ in the last bits from run to run: rounded to
            # 1e-12 (mm, rad) the corrections, and so the models, are reproducible
            T = np.round(T, 12)
            if not axis_ok:
                alpha, _ = twist_swing(T[:3, :3])
                T = T.copy()
                T[:3, :3] = T[:3, :3] @ _rz(-alpha)
            corr[v] = Correction.of(v, T)
    bad = [c.view for c in corr.values()
           if max(abs(c.axis_angle), c.other_angle) > options.max_angle
           or np.linalg.norm(c.translation) > options.max_translation]
    applied = len(linked) > 1
    test = (_significance(corr, pairs, anchor, options.significance)
            if applied and options.significance is not None else None)
    if test is not None:
        test["decision"] = "turntable poses kept: the registration failed"
    trusted = [p for p in pairs if p.get("neighbours") and p.get("confidence", 0.0) >= 0.5]
    worst_pair = max(trusted, key=lambda p: p["misclosure_deg"], default=None)
    if not bad and worst_pair is not None and \
            worst_pair["misclosure_deg"] > options.max_misclosure:
        warnings.append(f"the views' overlaps disagree: views {worst_pair['source']} and "
                        f"{worst_pair['target']} would be {worst_pair['misclosure_deg']:.2f} "
                        f"degrees from their own ICP result (more than "
                        f"{options.max_misclosure:g}); the surface does not fix the poses "
                        "well enough and every view keeps its unregistered pose")
        corr, applied = dict(ident), False
    elif bad:
        worst = max((corr[v] for v in bad), key=lambda c: abs(c.axis_angle) + c.other_angle)
        warnings.append(f"registration diverged: views {bad} would move by more than "
                        f"{options.max_angle:g} degrees or {options.max_translation:g} mm "
                        f"(view {worst.view}: {worst.axis_angle:.2f} degrees about the axis, "
                        f"{worst.other_angle:.2f} otherwise, "
                        f"{np.linalg.norm(worst.translation):.2f} mm); every view keeps its "
                        "unregistered pose")
        corr, applied = dict(ident), False
    elif test is not None and not test["significant"]:
        # within their uncertainty the corrections are the pairs' noise: the turntable's
        # poses are as good and do not carry it into the model
        corr, applied = dict(ident), False
        test["decision"] = "turntable poses kept: corrections within their uncertainty"
    elif test is not None and axis_ok and not test["rest_significant"]:
        # only the table angles are off (a turntable's error): turns about the axis alone
        turns = _turns(sorted(linked), pairs, anchor)
        corr = {**ident, **{v: Correction.of(v, T) for v, T in turns.items()}}
        test["decision"] = ("turns about the axis only: the other motions are within their "
                            "uncertainty")
    elif test is not None:
        test["decision"] = "registered poses: corrections significant"
    if test is not None:
        turn = max((q["chi2_turn"] for q in test["views"].values()), default=0.0)
        rest = max((q["chi2_rest"] for q in test["views"].values()), default=0.0)
        test["decision"] += (f" (largest chi-square of a turn about the axis {turn:.1f}, "
                             f"threshold {test['threshold_turn']:.1f}; of the other motions "
                             f"{rest:.1f}, threshold {test['threshold_rest']:.1f})")
    out_pairs = [{k: (round(v, 6) if isinstance(v, float) else v) for k, v in p.items()
                  if k not in ("H", "T")} for p in pairs]
    return Registration(corr, applied, axis_ok, float(info), out_pairs, lonely, warnings, test)


# ---------------------------------------------------------------------------- steps
def _split(cloud):
    """``(points, normals or None)`` of a view's cloud (an array or a pair)."""
    if isinstance(cloud, tuple | list):
        return cloud[0], (cloud[1] if len(cloud) > 1 else None)
    return cloud, None


def _o3d():
    return import_open3d("registration")


def _thinned(points: np.ndarray, normals: np.ndarray | None, voxel: float,
             normal_radius: float):
    """An Open3D cloud of one view's points thinned to ``voxel`` mm; normals averaged and
    renormalised, or, without ``normals``, estimated from the neighbours within
    ``normal_radius`` mm (PCA, Open3D ``estimate_normals``)."""
    o3d = _o3d()
    P = np.asarray(points, float).reshape(-1, 3)
    ok = np.isfinite(P).all(1)
    if normals is not None:
        N = np.asarray(normals, float).reshape(-1, 3)
        ok &= np.isfinite(N).all(1)
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(P[ok]))
    if normals is not None:
        pc.normals = o3d.utility.Vector3dVector(N[ok])
    pc = pc.voxel_down_sample(voxel)
    if normals is None:
        pc.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=normal_radius,
                                                                  max_nn=30))
    pc.normalize_normals()
    return pc


def _icp(source, target, options: RegistrationOptions, init: np.ndarray):
    """Coarse-to-fine point-to-plane ICP of ``source`` onto ``target`` (Open3D)."""
    o3d = _o3d()
    reg = o3d.pipelines.registration
    T = init
    for d in options.distances:
        res = reg.registration_icp(
            source, target, d, T, reg.TransformationEstimationPointToPlane(),
            reg.ICPConvergenceCriteria(relative_fitness=1e-7, relative_rmse=1e-7,
                                       max_iteration=options.iterations))
        T = np.asarray(res.transformation)
    return T, res


def _hessian(source, target, T: np.ndarray, distance: float) -> tuple[np.ndarray, int]:
    """The point-to-plane Gauss-Newton Hessian ``sum J^T J`` of ``source`` moved by ``T`` onto
    ``target`` at correspondence distance ``distance``: (6, 6) in the order (rotation,
    translation), and the number of correspondences."""
    S = np.asarray(source.points) @ T[:3, :3].T + T[:3, 3]
    Q, N = np.asarray(target.points), np.asarray(target.normals)
    dist, idx = cKDTree(Q).query(S, distance_upper_bound=distance)
    ok = np.isfinite(dist)
    q, n = Q[idx[ok]], N[idx[ok]]
    J = np.hstack([np.cross(q, n), n])
    return J.T @ J, int(ok.sum())


def _scale(radius: float) -> np.ndarray:
    """Diagonal scaling that expresses rotations in mm at ``radius``."""
    return np.diag([1 / radius] * 3 + [1.0] * 3)


def _determined(T: np.ndarray, H: np.ndarray, n: int, radius: float,
                threshold: float) -> np.ndarray:
    """``T`` kept to the motions that ``H`` determines: its twist (rotation vector, translation)
    projected onto the eigenvectors of the scaled per-point Hessian with eigenvalues at least
    ``threshold`` times the largest."""
    D = _scale(radius)
    Hs = D @ H @ D / max(n, 1)
    w, V = np.linalg.eigh(Hs)
    keep = V[:, w >= threshold * w.max()]
    xi = np.concatenate([Rotation.from_matrix(T[:3, :3]).as_rotvec() * radius, T[:3, 3]])
    xi = keep @ (keep.T @ xi)
    out = np.eye(4)
    out[:3, :3] = Rotation.from_rotvec(xi[:3] / radius).as_matrix()
    out[:3, 3] = xi[3:]
    return out


def _pairwise(pcd: dict, options: RegistrationOptions) -> list[dict]:
    """ICP between every two views that overlap as given; the pairs that still overlap and
    whose ICP did not run away (a correction within 3 ``max_angle`` and 3 ``max_translation``),
    as dicts with ``source``, ``target``, ``overlap`` (share of the source's points matched),
    ``rmse_mm`` (point-to-point, Open3D's), ``n`` (matched points), ``T`` (source onto target)
    and ``H`` (Hessian)."""
    o3d = _o3d()
    views = sorted(pcd)
    radius = _rms_radius(pcd, views)
    fine = options.distances[-1]
    out = []
    for a, i in enumerate(views):
        for j in views[a + 1:]:
            src, tgt = pcd[j], pcd[i]
            need = max(options.min_points, options.min_overlap * len(src.points))
            first = o3d.pipelines.registration.evaluate_registration(src, tgt, fine,
                                                                      np.eye(4))
            if first.fitness * len(src.points) < need:
                continue
            T, res = _icp(src, tgt, options, np.eye(4))
            H, n = _hessian(src, tgt, T, fine)
            if n < need:
                continue
            T = _determined(T, H, n, radius, options.pair_information)
            c = Correction.of(j, T)
            # an ICP that ran far away (a turn to another side of the object) is no overlap
            if (max(abs(c.axis_angle), c.other_angle) > 3 * options.max_angle
                    or np.linalg.norm(c.translation) > 3 * options.max_translation):
                continue
            out.append({"source": j, "target": i, "overlap": n / len(src.points),
                        "rmse_mm": float(res.inlier_rmse), "n": n, "T": T, "H": H})
    return out


def _connected(views: list, pairs: list, anchor: int) -> set:
    """The views linked to ``anchor`` through overlapping pairs."""
    adj = {v: set() for v in views}
    for p in pairs:
        adj[p["source"]].add(p["target"])
        adj[p["target"]].add(p["source"])
    seen, todo = {anchor}, [anchor]
    while todo:
        for w in adj[todo.pop()] - seen:
            seen.add(w)
            todo.append(w)
    return seen


def _rms_radius(pcd: dict, views) -> float:
    """RMS distance of the samples from the axis (mm), at least 1."""
    P = np.concatenate([np.asarray(pcd[v].points) for v in views])
    return float(max(1.0, np.sqrt(np.mean(np.sum(P[:, :2] ** 2, axis=1)))))


def _axis_information(H: np.ndarray, n: int, radius: float) -> float:
    """Information about the turn about ``z`` per matched point that the other five motions do
    not explain: the Schur complement of the scaled Hessian's entry for ``omega_z``."""
    if n == 0:
        return 0.0
    D = _scale(radius)
    Hs = D @ H @ D / n
    k = 2
    o = [0, 1, 3, 4, 5]
    Hoo = Hs[np.ix_(o, o)]
    s = Hs[k, k] - Hs[k, o] @ np.linalg.pinv(Hoo, rcond=1e-8) @ Hs[o, k]
    return float(max(s, 0.0))


def _pose_graph(views: list, pairs: list, anchor: int,
                options: RegistrationOptions) -> dict:
    """Optimise the pose graph (Open3D ``global_optimization``); node ``v``'s pose is view
    ``v``'s correction (4 x 4), the anchor's the identity."""
    o3d = _o3d()
    reg = o3d.pipelines.registration
    node = {v: k for k, v in enumerate(views)}
    g = reg.PoseGraph()
    for _ in views:
        g.nodes.append(reg.PoseGraphNode(np.eye(4)))
    order = {v: k for k, v in enumerate(views)}
    for p in pairs:
        # neighbours in table angle (index order) are trusted, the others may be pruned
        near = abs(order[p["source"]] - order[p["target"]]) in (1, len(views) - 1)
        p["neighbours"] = bool(near)
        g.edges.append(reg.PoseGraphEdge(node[p["source"]], node[p["target"]], p["T"],
                                         p["H"], uncertain=not near))
    opt = reg.GlobalOptimizationOption(max_correspondence_distance=options.distances[-1],
                                       edge_prune_threshold=0.25, preference_loop_closure=1.0,
                                       reference_node=node[anchor])
    reg.global_optimization(g, reg.GlobalOptimizationLevenbergMarquardt(),
                            reg.GlobalOptimizationConvergenceCriteria(), opt)
    A = np.linalg.inv(np.asarray(g.nodes[node[anchor]].pose))
    poses = {v: A @ np.asarray(g.nodes[node[v]].pose) for v in views}
    # the line process removes the edges it prunes from the graph
    kept = {(e.source_node_id, e.target_node_id): float(e.confidence) for e in g.edges}
    for p in pairs:
        # how far the optimised poses are from the pair's own ICP result
        D = np.linalg.inv(p["T"]) @ np.linalg.inv(poses[p["target"]]) @ poses[p["source"]]
        p["misclosure_deg"] = float(np.degrees(np.linalg.norm(
            Rotation.from_matrix(D[:3, :3]).as_rotvec())))
        p["misclosure_mm"] = float(np.linalg.norm(D[:3, 3]))
        p["confidence"] = kept.get((node[p["source"]], node[p["target"]]), 0.0)
    return poses


def _rz(alpha: float) -> np.ndarray:
    c, s = np.cos(alpha), np.sin(alpha)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _twist(T: np.ndarray) -> np.ndarray:
    """The twist ``(rotation vector (rad), translation (mm))`` of a 4 x 4 rigid motion."""
    return np.concatenate([Rotation.from_matrix(T[:3, :3]).as_rotvec(), T[:3, 3]])


def _chi2_quantile(p: float, dof: int) -> float:
    """The chi-square distribution's ``p`` quantile with ``dof`` degrees of freedom,
    ``2 P^-1(dof / 2, p)`` (``P``: the regularised lower incomplete gamma function): what
    ``scipy.stats.chi2.ppf`` computes, without importing ``scipy.stats`` (0.36 s)."""
    from scipy.special import gammaincinv

    return float(2.0 * gammaincinv(dof / 2.0, p))


def _significance(corr: dict, pairs: list, anchor: int, level: float) -> dict:
    """Whether the corrections differ from the turntable's poses by more than their
    uncertainty: a least-squares network adjustment's test (Koch 1999, section 4.2).

    The pose graph, linearised about the corrections, is a Gauss-Markov model: each kept edge
    ``e`` (views ``s`` onto ``t``) observes the relative twist ``x_s - x_t`` with weight its
    point-to-plane Hessian ``H_e`` (6 x 6, rotation about the object frame's origin and
    translation, :func:`_hessian`). The a posteriori variance factor is estimated from the
    misclosures ``m_e`` (the twist of the optimised poses relative to the pair's own ICP
    result), ``s0^2 = sum m_e^T H_e m_e / (6 E - 6 (V - 1))``: this measures the pairs'
    real disagreement, correlated and systematic errors included, not the ICP's nominal
    noise. Without redundancy (``6 E <= 6 (V - 1)``) the pairs' mean squared point-to-plane
    residual is used instead. The covariance of the corrections is ``s0^2 A^+`` with ``A =
    sum B_e^T H_e B_e`` (anchor fixed); each view's correction ``x_v`` gets ``q_v = x_v^T
    Cov_v^+ x_v``, chi-square with (up to) 6 degrees of freedom under the hypothesis that
    the turntable's pose is right. The corrections are significant when some view's
    ``q_v`` exceeds the chi-square quantile at ``1 - level / (V - 1)`` (Bonferroni: ``level``
    is the chance that exact poses are called wrong).

    Returns a dict: ``significant``, ``variance_factor_mm2``, ``dof``, ``threshold`` and per
    view ``chi2`` and ``sd_axis_deg`` (standard deviation of the turn about the axis).
    """
    free = sorted(v for v in corr if v != anchor)
    idx = {v: 6 * k for k, v in enumerate(free)}
    A = np.zeros((6 * len(free), 6 * len(free)))
    num, edges, r2, nr = 0.0, 0, 0.0, 0
    for p in pairs:
        if p.get("confidence", 1.0) <= 0.0:
            continue
        s, t, H = p["source"], p["target"], p["H"]
        m = _twist(np.linalg.inv(p["T"]) @ np.linalg.inv(corr[t].matrix) @ corr[s].matrix)
        num += float(m @ H @ m)
        edges += 1
        r2 += p["rmse_mm"] ** 2 * p["n"]
        nr += p["n"]
        B = np.zeros((6, 6 * len(free)))
        if s in idx:
            B[:, idx[s]:idx[s] + 6] = np.eye(6)
        if t in idx:
            B[:, idx[t]:idx[t] + 6] = -np.eye(6)
        A += B.T @ H @ B
    dof = 6 * edges - 6 * len(free)
    s02 = num / dof if dof > 0 else r2 / max(nr, 1)
    cov = s02 * np.linalg.pinv(A, rcond=1e-10)
    threshold = _chi2_quantile(1.0 - level / max(len(free), 1), 6)
    threshold_rest = _chi2_quantile(1.0 - level / max(len(free), 1), 5)
    rest = [0, 1, 3, 4, 5]
    per = {}
    for v in free:
        S = cov[idx[v]:idx[v] + 6, idx[v]:idx[v] + 6]
        x = _twist(corr[v].matrix)
        Sr = S[np.ix_(rest, rest)]
        per[v] = {"chi2": float(x @ np.linalg.pinv(S, rcond=1e-10) @ x),
                  "chi2_rest": float(x[rest] @ np.linalg.pinv(Sr, rcond=1e-10) @ x[rest]),
                  "chi2_turn": float(x[2] ** 2 / S[2, 2]) if S[2, 2] > 0 else 0.0,
                  "sd_axis_deg": float(np.degrees(np.sqrt(max(S[2, 2], 0.0))))}
    threshold_turn = _chi2_quantile(1.0 - level / max(len(free), 1), 1)
    turns = any(q["chi2_turn"] > threshold_turn for q in per.values())
    others = any(q["chi2_rest"] > threshold_rest for q in per.values())
    return {"significant": turns or others, "turn_significant": turns,
            "rest_significant": others, "variance_factor_mm2": float(s02), "dof": int(dof),
            "threshold": threshold, "threshold_turn": threshold_turn,
            "threshold_rest": threshold_rest, "level": float(level), "views": per}


def _turns(views: list, pairs: list, anchor: int) -> dict:
    """Each view's correction as a turn about the axis only: the weighted least-squares
    turns ``a_v`` (anchor 0) that best explain the pairs' own ICP results, each pair's
    relative turn taken as ``d_e = z^T H_e xi_e / z^T H_e z`` (its twist ``xi_e``'s turn
    about ``z`` given that the other five motions are zero) with weight ``z^T H_e z``: the
    normal equations ``sum w_e g_e g_e^T a = sum w_e d_e g_e``, ``g_e = e_s - e_t``. Linear
    in the turns (turns about one axis commute). Returns ``{view: 4 x 4}``."""
    free = [v for v in views if v != anchor]
    ix = {v: k for k, v in enumerate(free)}
    z = np.array([0.0, 0.0, 1.0, 0.0, 0.0, 0.0])
    A, b = np.zeros((len(free), len(free))), np.zeros(len(free))
    for p in pairs:
        if p.get("confidence", 1.0) <= 0.0:
            continue
        H, xi = p["H"], _twist(p["T"])
        w = float(z @ H @ z)
        if w <= 0:
            continue
        g = np.zeros(len(free))
        if p["source"] in ix:
            g[ix[p["source"]]] += 1.0
        if p["target"] in ix:
            g[ix[p["target"]]] -= 1.0
        A += w * np.outer(g, g)
        b += float(z @ H @ xi) * g
    a = np.linalg.lstsq(A, b, rcond=None)[0]
    out = {anchor: np.eye(4)}
    for v in free:
        T = np.eye(4)
        T[:3, :3] = _rz(float(a[ix[v]]))
        out[v] = np.round(T, 12)
    return out
