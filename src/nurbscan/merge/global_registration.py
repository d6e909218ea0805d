"""Global registration of two scans of one object without a prior (issue 33).

A second turntable pass sees the object turned over: its object frame is the first pass's
moved by an unknown rigid motion, possibly a half turn. :func:`align_surfaces` finds it from
the two passes' surfaces alone, as desktop scanners do:

1. **Features.** Each surface is thinned to a voxel grid and described by Fast Point Feature
   Histograms (FPFH; Rusu, Blodow and Beetz 2009; Open3D ``compute_fpfh_feature``).
2. **RANSAC** over feature correspondences (Open3D
   ``registration_ransac_based_on_feature_matching``, edge-length and distance checkers),
   run ``trials`` times with different seeds: a candidate motion per run. RANSAC and the
   ICP of step 3 run on one Open3D thread (:func:`~nurbscan.merge.register.one_open3d_thread`):
   on its default threads the same inputs gave other candidates from run to run.
3. **ICP.** Each candidate is refined by point-to-plane ICP (Chen and Medioni 1992; Open3D
   ``registration_icp``), coarse to fine, on denser samples; candidates that converge to the
   same motion are merged.
4. **Score.** Each refined candidate's overlap (the share of the smaller surface within
   ``overlap_distance`` of the other) and the RMS point-to-plane distance over that overlap.
   The best overlap wins. A second, distinct candidate (more than ``distinct_angle`` degrees
   or ``distinct_translation`` mm away) that overlaps nearly as well (``ambiguity`` of the
   best) makes the alignment ambiguous: a symmetric object (a surface of revolution, a
   sphere) admits several alignments and the data cannot choose.
5. **Free space.** When the passes' views are given (:mod:`nurbscan.merge.free_space`), the
   near-equal candidates (within ``ambiguity`` of the best overlap) are told apart by what
   the passes' cameras and projectors saw as empty: a candidate's violation is the share of
   one pass's samples it moves into space in front of the other pass's measured surface,
   along the other pass's camera or projector rays, by more than ``free_space_tolerance``
   (both ways, the mean; rays grazing the sample's surface beyond ``free_space_grazing``
   and rays passing in front of the view's own points give no evidence). The least
   violation wins; the alignment stays ambiguous only when another near-equal candidate
   violates less than ``free_space_margin`` more (a sphere, a surface of revolution: every
   candidate is consistent).

Too small an overlap or too large an RMS means that the two surfaces are not two views of one
object (or overlap too little to be aligned): :class:`~nurbscan.errors.NurbscanError`.

Units: mm, degrees in the report; transforms are 4 x 4, ``X_target = T X_source``.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass

import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from ..errors import NurbscanError
from ._open3d import import_open3d
from .register import one_open3d_thread

__all__ = ["Alignment", "GlobalOptions", "align_surfaces", "motion_difference", "overlap_rms"]


@dataclass(frozen=True)
class GlobalOptions:
    """Settings of :func:`align_surfaces`, by step.

    Attributes
    ----------
    voxel : float
        Voxel (mm) the surfaces are thinned to for the features and RANSAC.
    feature_radius : float
        FPFH neighbourhood radius, in voxels.
    trials : int
        RANSAC runs (seeds 0 .. trials - 1), each a candidate.
    ransac_iterations : int
        RANSAC iterations per run.
    icp_voxel : float
        Voxel (mm) of the ICP's samples.
    icp_distances : tuple of float
        ICP correspondence distance at each level, coarse to fine (mm).
    fine_candidates : int
        Distinct candidates (the best overlapping after the coarse ICP levels, on the
        thinned clouds) refined over the fine levels.
    overlap_distance : float
        Distance (mm) within which a point of one surface counts as overlapping the other:
        its distance to the plane of its nearest sample of the other surface (normal of that
        sample), the nearest sample at most ``overlap_reach`` mm away (the samples' spacing).
    overlap_reach : float
        See ``overlap_distance``.
    min_overlap : float
        Smallest overlap share (of the smaller surface) that is an alignment.
    max_rms : float
        Largest RMS distance over the overlap (mm) that is an alignment.
    ambiguity : float
        A distinct candidate whose overlap is at least this share of the best's makes the
        alignment ambiguous.
    distinct_angle, distinct_translation : float
        Candidates farther apart than this (degrees, mm) are distinct alignments.
    free_space_tolerance : float
        How far (mm) in front of the other pass's measured surface, along one of its camera
        or projector rays, a moved sample must lie to violate its free space
        (:meth:`nurbscan.merge.free_space.FreeSpace.violations`).
    free_space_reach : float
        Distance (mm) from a ray's first hit to the view's own points within which the hit
        counts as measured by that view.
    free_space_voxel : float
        Voxel (mm) the surfaces are thinned to for the free-space test.
    free_space_margin : float
        Among the near-equal candidates (within ``ambiguity`` of the best overlap), the one
        with the least free-space violation is chosen; it resolves the ambiguity when every
        other one violates by at least this share more.
    free_space_warn : float
        A chosen alignment that violates the free space by more than this share is warned
        of (docs/accuracy.md, "Free space at full resolution").
    free_space_grazing : float
        Rays that meet a sample's surface more than this many degrees from its normal are
        not tested (:mod:`nurbscan.merge.free_space`, module notes); 90: all are.
    free_space_own_points : bool
        Leave out rays that pass in front of the view's own points (the same notes).
    """

    voxel: float = 5.0
    feature_radius: float = 4.0
    trials: int = 6
    ransac_iterations: int = 50_000
    icp_voxel: float = 1.0
    icp_distances: tuple[float, ...] = (12.0, 6.0, 3.0, 1.5, 0.8, 0.4)
    fine_candidates: int = 3
    overlap_distance: float = 0.5
    overlap_reach: float = 2.0
    min_overlap: float = 0.15
    max_rms: float = 0.25
    ambiguity: float = 0.9
    distinct_angle: float = 2.0
    distinct_translation: float = 2.0
    free_space_tolerance: float = 1.0
    free_space_reach: float = 1.5
    free_space_voxel: float = 2.0
    free_space_margin: float = 0.01
    free_space_warn: float = 0.01
    free_space_grazing: float = 75.0
    free_space_own_points: bool = True

    def __post_init__(self) -> None:
        if not (self.voxel > 0 and self.icp_voxel > 0 and self.overlap_distance > 0):
            raise NurbscanError("global registration: voxel sizes and distances must be > 0")
        if self.trials < 1 or not self.icp_distances:
            raise NurbscanError("global registration: at least one trial and one ICP level")
        if not 0 < self.min_overlap <= 1:
            raise NurbscanError(f"global registration: min_overlap {self.min_overlap} must be "
                                "in (0, 1]")

    def to_dict(self) -> dict:
        d = asdict(self)
        d["icp_distances"] = list(self.icp_distances)
        return d


@dataclass(frozen=True)
class Alignment:
    """What :func:`align_surfaces` found.

    Attributes
    ----------
    matrix : ndarray (4, 4)
        ``X_target = T X_source``.
    rms_mm : float
        RMS point-to-plane distance over the overlap, mm.
    overlap : float
        Share of the smaller surface within ``overlap_distance`` of the other.
    overlap_source, overlap_target : float
        The same share of each surface.
    candidates : list of dict
        The distinct refined candidates, best first: ``matrix``, ``overlap``, ``rms_mm``,
        ``angle_deg`` and ``translation_mm`` from the best, ``runs`` (RANSAC runs that gave it).
    ambiguous : bool
        A distinct candidate overlaps nearly as well as the best (module notes).
    warnings : list of str
    free_space : float or None
        The chosen candidate's free-space violation (module notes, step 5); None when the
        passes' views were not given.
    chosen_by : str
        ``"overlap"`` (the best overlap) or ``"free space"`` (the least free-space violation
        among the near-equal candidates).
    """

    matrix: np.ndarray
    rms_mm: float
    overlap: float
    overlap_source: float
    overlap_target: float
    candidates: list
    ambiguous: bool
    warnings: list
    free_space: float | None = None
    chosen_by: str = "overlap"

    @property
    def angle_deg(self) -> float:
        """Rotation angle of the transform, degrees."""
        return float(np.degrees(np.linalg.norm(
            Rotation.from_matrix(self.matrix[:3, :3]).as_rotvec())))

    def to_dict(self) -> dict:
        """JSON-ready dict (mm, degrees)."""
        rv = Rotation.from_matrix(self.matrix[:3, :3]).as_rotvec()
        return {"matrix": np.round(self.matrix, 12).tolist(),
                "rotation_deg": round(float(np.degrees(np.linalg.norm(rv))), 6),
                "rotation_axis": (rv / max(np.linalg.norm(rv), 1e-300)).round(9).tolist(),
                "translation_mm": np.round(self.matrix[:3, 3], 6).tolist(),
                "rms_mm": round(self.rms_mm, 6), "overlap": round(self.overlap, 6),
                "overlap_source": round(self.overlap_source, 6),
                "overlap_target": round(self.overlap_target, 6),
                "ambiguous": self.ambiguous, "warnings": list(self.warnings),
                "free_space": self.free_space, "chosen_by": self.chosen_by,
                "candidates": [{**c, "matrix": np.round(c["matrix"], 12).tolist()}
                               for c in self.candidates]}

    @classmethod
    def from_dict(cls, d: dict) -> Alignment:
        """The alignment of a :meth:`to_dict` document (``alignment.json``'s ``global``)."""
        return cls(np.asarray(d["matrix"], float), float(d["rms_mm"]), float(d["overlap"]),
                   float(d["overlap_source"]), float(d["overlap_target"]),
                   [{**c, "matrix": np.asarray(c["matrix"], float)} for c in d["candidates"]],
                   bool(d["ambiguous"]), list(d["warnings"]), d.get("free_space"),
                   d.get("chosen_by", "overlap"))


def motion_difference(A: np.ndarray, B: np.ndarray, radius: float = 0.0) -> tuple[float, float]:
    """Rotation angle (degrees) and translation (mm) of ``A^-1 B`` for 4 x 4 motions; with
    ``radius`` > 0 the translation is the largest displacement of a point within ``radius``
    of the origin, ``|t| + radius * angle``."""
    D = np.linalg.inv(A) @ B
    ang = float(np.linalg.norm(Rotation.from_matrix(D[:3, :3]).as_rotvec()))
    return float(np.degrees(ang)), float(np.linalg.norm(D[:3, 3]) + radius * ang)


def align_surfaces(source: tuple, target: tuple, options: GlobalOptions | None = None,
                   progress=None, names: tuple[str, str] = ("source", "target"),
                   free_space: tuple | None = None) -> Alignment:
    """The rigid motion that puts one surface onto another, without a prior.

    Parameters
    ----------
    source, target : tuple (points (N, 3), normals (N, 3))
        Samples of each surface (mm) with unit normals, each in its own frame, the table and
        anything below the object's base already left out.
    options : GlobalOptions, optional
    progress : callable, optional
        Called with one line per step.
    names : (str, str)
        How the two are named in messages.
    free_space : (FreeSpace, FreeSpace), optional
        What the source's and the target's views saw as empty
        (:func:`nurbscan.merge.free_space.pass_free_space`), each in its own surface's
        frame: chooses among near-equal candidates (module notes, step 5). None: the best
        overlap is chosen.

    Returns
    -------
    Alignment

    Raises
    ------
    NurbscanError
        When no candidate reaches ``min_overlap`` with an RMS under ``max_rms``: the surfaces
        are not of one object, or overlap too little.

    Notes
    -----
    1. thin and describe both surfaces (:func:`_features`);
    2. RANSAC over feature matches, ``trials`` seeds (:func:`_ransac`);
    3. refine every candidate by ICP and merge those that agree (:func:`_refine`);
    4. score the candidates, pick the best, look for an ambiguity (:func:`_score`);
    5. with ``free_space``, every candidate's free-space violation
       (:func:`_free_space_scores`): the least among the near-equal ones wins.
    """
    opt = options or GlobalOptions()
    say = progress or (lambda _m: None)
    o3d = _open3d()
    src, tgt = _cloud(o3d, *source), _cloud(o3d, *target)
    if len(src.points) < 100 or len(tgt.points) < 100:
        raise NurbscanError(f"{names[0]} / {names[1]}: too few surface points to align "
                            f"({len(src.points)} and {len(tgt.points)})")
    s_down, s_feat = _features(o3d, src, opt)
    t_down, t_feat = _features(o3d, tgt, opt)
    say(f"global registration: {len(s_down.points)} and {len(t_down.points)} FPFH points "
        f"({opt.voxel:g} mm voxels), {opt.trials} RANSAC runs")
    t0 = time.perf_counter()
    with one_open3d_thread():  # Open3D's parallel RANSAC differs from run to run
        raw = _ransac(o3d, s_down, t_down, s_feat, t_feat, opt)
        t1 = time.perf_counter()
        s_icp = src.voxel_down_sample(opt.icp_voxel)
        t_icp = tgt.voxel_down_sample(opt.icp_voxel)
        cands = _refine(o3d, s_down, t_down, s_icp, t_icp, raw, opt)
    say(f"global registration: {len(raw)} RANSAC candidates ({t1 - t0:.1f} s), "
        f"{len(cands)} distinct after ICP ({time.perf_counter() - t1:.1f} s)")
    scored = _score(np.asarray(src.points), np.asarray(src.normals), np.asarray(tgt.points),
                    np.asarray(tgt.normals), cands, opt)
    near = [c for c in scored if c["overlap"] >= opt.ambiguity * scored[0]["overlap"]]
    chosen_by = "overlap"
    if free_space is not None and None not in free_space:
        t2 = time.perf_counter()
        _free_space_scores(src, tgt, scored, free_space, opt)
        if len(near) > 1:
            near.sort(key=lambda c: c["free_space"])
            others = [c["free_space"] for c in near[1:]]
            chosen_by = "free space"
            if min(others) >= near[0]["free_space"] + opt.free_space_margin:
                near = near[:1]  # the others put one pass into space the other saw through
            scored = _relative(near + [c for c in scored if not any(c is n for n in near)])
        say(f"global registration: free-space violation of the {len(scored)} candidates "
            + ", ".join(f"{100 * c['free_space']:.2f} %" for c in scored)
            + f" ({time.perf_counter() - t2:.1f} s)")
    best = scored[0]
    warnings = []
    ambiguous = False
    if len(near) > 1:
        ambiguous = True
        fs = ("" if "free_space" not in best else
              f"; their free-space violations {100 * best['free_space']:.2f} % and "
              f"{100 * scored[1]['free_space']:.2f} % do not tell them apart")
        warnings.append(
            f"the alignment of {names[0]} to {names[1]} is ambiguous: a second alignment "
            f"{scored[1]['angle_deg']:.1f} degrees and {scored[1]['translation_mm']:.1f} mm "
            f"away overlaps {100 * scored[1]['overlap']:.1f} % against "
            f"{100 * best['overlap']:.1f} %{fs} (a symmetric object?)")
    if best["overlap"] < opt.min_overlap or not best["rms_mm"] <= opt.max_rms:
        raise NurbscanError(_refusal(best, opt, names))
    if best.get("free_space", 0.0) > opt.free_space_warn:
        warnings.append(f"the alignment of {names[0]} to {names[1]} puts "
                        f"{100 * best['free_space']:.1f} % of one pass's surface into space the "
                        "other pass's views saw as empty: it may be wrong")
    if best["overlap"] < 2 * opt.min_overlap:
        warnings.append(f"the overlap of {names[0]} and {names[1]} is small "
                        f"({100 * best['overlap']:.1f} %): the alignment may be unreliable")
    return Alignment(best["matrix"], best["rms_mm"], best["overlap"], best["overlap_source"],
                     best["overlap_target"], scored[:5], ambiguous, warnings,
                     best.get("free_space"), chosen_by)


def _refusal(best: dict, opt: GlobalOptions, names: tuple[str, str]) -> str:
    """The one-line error of an alignment that is refused: the best candidate's motion
    (degrees, mm), its overlap and RMS against the limits, and which limit failed (too
    little overlap: too few common parts or another object; too large an RMS with enough
    overlap: another object or a surface that does not match)."""
    rv = Rotation.from_matrix(np.asarray(best["matrix"])[:3, :3]).as_rotvec()
    low = best["overlap"] < opt.min_overlap
    rms = best["rms_mm"]
    why = ("too little overlap (scans of different objects, or passes that share too little "
           "of the surface)" if low else
           "the overlap does not match (scans of different objects?)")
    return (f"{names[0]} does not align with {names[1]}: {why}; best alignment found: "
            f"rotation {np.degrees(np.linalg.norm(rv)):.2f} degrees, translation "
            f"{np.linalg.norm(np.asarray(best['matrix'])[:3, 3]):.2f} mm, overlap "
            f"{100 * best['overlap']:.1f} % (at least {100 * opt.min_overlap:.0f} % needed), "
            f"RMS {rms:.3f} mm over it (at most {opt.max_rms:g} mm); nothing merged")


# ---------------------------------------------------------------------------- steps
def _open3d():
    return import_open3d("global registration")


def _cloud(o3d, points, normals):
    P = np.asarray(points, float).reshape(-1, 3)
    N = np.asarray(normals, float).reshape(-1, 3)
    ok = np.isfinite(P).all(1) & np.isfinite(N).all(1)
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(P[ok]))
    pcd.normals = o3d.utility.Vector3dVector(N[ok])
    return pcd


def _features(o3d, pcd, opt: GlobalOptions):
    """Voxel-thinned cloud and its FPFH features (Rusu et al. 2009)."""
    down = pcd.voxel_down_sample(opt.voxel)
    down.normalize_normals()
    feat = o3d.pipelines.registration.compute_fpfh_feature(
        down, o3d.geometry.KDTreeSearchParamHybrid(radius=opt.feature_radius * opt.voxel,
                                                   max_nn=100))
    return down, feat


def _ransac(o3d, s_down, t_down, s_feat, t_feat, opt: GlobalOptions) -> list:
    """One RANSAC motion per seed (4 x 4 arrays)."""
    reg = o3d.pipelines.registration
    dist = 1.5 * opt.voxel
    out = []
    for seed in range(opt.trials):
        o3d.utility.random.seed(seed)
        r = reg.registration_ransac_based_on_feature_matching(
            s_down, t_down, s_feat, t_feat, True, dist,
            reg.TransformationEstimationPointToPoint(False), 3,
            [reg.CorrespondenceCheckerBasedOnEdgeLength(0.9),
             reg.CorrespondenceCheckerBasedOnDistance(dist)],
            reg.RANSACConvergenceCriteria(opt.ransac_iterations, 0.9999))
        if r.fitness > 0:
            out.append(np.asarray(r.transformation, float).copy())
    return out


def _refine(o3d, s_down, t_down, s_icp, t_icp, raw: list, opt: GlobalOptions) -> list:
    """Point-to-plane ICP from each candidate: the levels of ``icp_distances`` above twice the
    feature voxel on the thinned clouds, then candidates that ended within the distinct
    thresholds of an earlier one are merged (its ``runs`` counted), and only the distinct ones
    are refined over the finer levels on the denser samples."""
    reg = o3d.pipelines.registration

    def icp(src, tgt, T, levels):
        for d in levels:
            r = reg.registration_icp(src, tgt, d, T, reg.TransformationEstimationPointToPlane(),
                                     reg.ICPConvergenceCriteria(max_iteration=40))
            T = np.asarray(r.transformation, float).copy()
        return T

    coarse = [d for d in opt.icp_distances if d >= 0.5 * opt.voxel]
    fine = [d for d in opt.icp_distances if d < 0.5 * opt.voxel]
    out: list = []
    for T0 in raw:
        T = icp(s_down, t_down, T0, coarse)
        for c in out:
            ang, tr = motion_difference(c["matrix"], T, 0.0)
            if ang <= opt.distinct_angle and tr <= opt.distinct_translation:
                c["runs"] += 1
                break
        else:
            out.append({"matrix": T, "runs": 1})
    # only the candidates that overlap best on the thinned clouds go on to the fine levels:
    # the best and its runner-up decide the alignment and its ambiguity
    Ps, Pt = np.asarray(s_down.points), np.asarray(t_down.points)
    Nt = np.asarray(t_down.normals)
    tree_t = cKDTree(Pt)
    for c in out:
        c["coarse_overlap"] = overlap_rms(Ps, c["matrix"], Pt, Nt, 0.3 * opt.voxel,
                                          1.5 * opt.voxel, tree_t)[0]
    out.sort(key=lambda c: -c["coarse_overlap"])
    out = out[:opt.fine_candidates]
    for c in out:
        c["matrix"] = icp(s_icp, t_icp, c["matrix"], fine)
    return out


def overlap_rms(P: np.ndarray, T: np.ndarray, Q: np.ndarray, NQ: np.ndarray,
                distance: float, reach: float, tree=None) -> tuple[float, float]:
    """Share of the points ``P`` (N, 3), moved by ``T`` (4 x 4), within ``distance`` (mm) of
    the surface sampled by ``Q`` with normals ``NQ`` (the plane of the nearest sample, at most
    ``reach`` mm away), and the RMS point-to-plane distance over that overlap (mm)."""
    from scipy.spatial import cKDTree

    X = P @ T[:3, :3].T + T[:3, 3]
    d, i = (tree or cKDTree(Q)).query(X, distance_upper_bound=reach)
    near = np.flatnonzero(np.isfinite(d))
    plane = np.abs(np.einsum("ij,ij->i", X[near] - Q[i[near]], NQ[i[near]]))
    ok = plane <= distance
    if not ok.any():
        return 0.0, float("inf")
    return float(ok.sum() / max(len(P), 1)), float(np.sqrt(np.mean(plane[ok] ** 2)))


def _score(Ps, Ns, Pt, Nt, cands: list, opt: GlobalOptions) -> list:
    """Overlap shares and RMS over the overlap of each candidate (:func:`overlap_rms`, both
    ways), best (overlap of the smaller surface) first, with each candidate's angle and
    translation from the best."""
    if not cands:
        return [{"matrix": np.eye(4), "overlap": 0.0, "overlap_source": 0.0,
                 "overlap_target": 0.0, "rms_mm": float("inf"), "runs": 0,
                 "angle_deg": 0.0, "translation_mm": 0.0}]
    tree_t, tree_s = cKDTree(Pt), cKDTree(Ps)
    scored = []
    for c in cands:
        T = c["matrix"]
        share_s, rms = overlap_rms(Ps, T, Pt, Nt, opt.overlap_distance, opt.overlap_reach,
                                   tree_t)
        ov_t, _ = overlap_rms(Pt, np.linalg.inv(T), Ps, Ns, opt.overlap_distance,
                              opt.overlap_reach, tree_s)
        smaller = share_s if len(Ps) <= len(Pt) else ov_t
        scored.append({"matrix": T, "overlap": smaller, "overlap_source": share_s,
                       "overlap_target": ov_t, "rms_mm": rms, "runs": c["runs"]})
    scored.sort(key=lambda c: (-c["overlap"], c["rms_mm"]))
    for c in scored:
        c["overlap"], c["overlap_source"] = round(c["overlap"], 6), round(c["overlap_source"], 6)
        c["overlap_target"], c["rms_mm"] = round(c["overlap_target"], 6), round(c["rms_mm"], 6)
    return _relative(scored)


def _relative(scored: list) -> list:
    """Each candidate's angle (degrees) and translation (mm) from the first."""
    for c in scored:
        ang, tr = motion_difference(scored[0]["matrix"], c["matrix"], 0.0)
        c["angle_deg"], c["translation_mm"] = round(ang, 6), round(tr, 6)
    return scored


def _free_space_scores(src, tgt, cands: list, free_space: tuple, opt: GlobalOptions) -> None:
    """Each candidate's free-space violation (module notes, step 5), in place: the share
    of the source's samples (thinned to ``free_space_voxel``) that the candidate puts into
    space the target's views saw as empty (``free_space_source``), the share of the
    target's samples that its inverse puts into the source's (``free_space_target``), and
    their mean (``free_space``)."""
    fs_src, fs_tgt = free_space
    s_fs = src.voxel_down_sample(opt.free_space_voxel)
    t_fs = tgt.voxel_down_sample(opt.free_space_voxel)
    Ps, Ns = np.asarray(s_fs.points), np.asarray(s_fs.normals)
    Pt, Nt = np.asarray(t_fs.points), np.asarray(t_fs.normals)
    kw = {"tolerance": opt.free_space_tolerance, "reach": opt.free_space_reach,
          "grazing": opt.free_space_grazing, "own_points": opt.free_space_own_points}
    for c in cands:
        T = np.asarray(c["matrix"], float)
        Ti = np.linalg.inv(T)
        vs = fs_tgt.violations(Ps @ T[:3, :3].T + T[:3, 3], Ns @ T[:3, :3].T, **kw)[0].mean()
        vt = fs_src.violations(Pt @ Ti[:3, :3].T + Ti[:3, 3], Nt @ Ti[:3, :3].T, **kw)[0].mean()
        c["free_space_source"], c["free_space_target"] = round(float(vs), 6), round(float(vt), 6)
        c["free_space"] = round(0.5 * float(vs + vt), 6)
