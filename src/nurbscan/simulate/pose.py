"""An object in a resting pose on the turntable: a scene rotated, then set down on the table top.

A turntable scanner sees an object from one band of elevations; to see the rest the user turns
it over and scans again (issue 33). :func:`posed` places a scene in any resting pose: the
object is rotated about the object frame's origin by ``R``, then translated so that its lowest
point lies on the table plane (``z = 0``) and the centre of its bounding box in ``x``, ``y`` is
on the turntable's axis (``x = y = 0``, docs/conventions.md). :class:`PosedScene` is the moved
scene with the exact ground truth of the moved surface: every query is the base scene's in its
own frame, ``X_base = R^T (X - t)``, moved back (rays, closest points, samples, the mesh).

Its ``to_dict`` is the base scene's with a ``pose`` entry (``R`` row-major, ``t`` mm), so that
``truth/scene.json`` of a posed scan describes the posed object and
:func:`nurbscan.simulate.scenes.scene_from_dict` rebuilds it.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field

import numpy as np
import trimesh
from scipy.spatial.transform import Rotation

from ..errors import NurbscanError

__all__ = ["POSES", "PosedScene", "parse_pose", "pose_from_dict", "posed", "rest_translation"]

#: Named resting poses: rotations about the object frame's axes, degrees (x, y, z, applied in
#: that order, extrinsic). ``side``: turned a quarter about x (the teapot lies on its side, the
#: spout up or down depending on its azimuth); ``upside-down``: a half turn about x.
POSES = {"upright": (0.0, 0.0, 0.0), "side": (90.0, 0.0, 0.0),
         "upside-down": (180.0, 0.0, 0.0)}


def parse_pose(text: str) -> np.ndarray:
    """A pose name (:data:`POSES`) or ``RX,RY,RZ`` (degrees, extrinsic x then y then z) as a
    3 x 3 rotation matrix.

    Raises
    ------
    NurbscanError
        For anything else (one line naming the value and what is expected).
    """
    key = str(text).strip().lower()
    if key in POSES:
        angles = POSES[key]
    else:
        parts = [p for p in re.split(r"[,\s]+", key) if p]
        try:
            angles = tuple(float(p) for p in parts)
        except ValueError:
            angles = ()
        if len(angles) != 3 or not all(math.isfinite(a) for a in angles):
            raise NurbscanError(f"--pose {text!r}: expected {', '.join(POSES)} or three angles "
                                "in degrees RX,RY,RZ (e.g. 90,0,30)")
    return Rotation.from_euler("xyz", angles, degrees=True).as_matrix()


def rest_translation(scene, R: np.ndarray) -> np.ndarray:
    """The translation ``t`` (3,) mm that sets ``scene`` rotated by ``R`` down on the table:
    its lowest point at ``z = 0``, its bounding box centred on the axis in ``x`` and ``y``.

    The lowest point is the lowest vertex of the scene's fine mesh (tolerance 0.05 mm; the
    vertices lie on the exact surface), refined on the exact surface: the closest point to a
    point 1e4 mm below it minimises ``z + |p - c|^2 / 2e4`` (support point in ``-z`` to about
    1e-5 mm), taken twice.
    """
    R = np.asarray(R, float)
    V = scene.mesh(0.05).vertices @ R.T
    lo, hi = V.min(0), V.max(0)
    low = V[np.argmin(V[:, 2])]
    for _ in range(2):
        q = (low - np.array([0.0, 0.0, 1e4])) @ R  # in the base frame (R^T x = x @ R)
        p = scene.closest_point(q[None])[0][0] @ R.T
        if p[2] < low[2]:
            low = p
        else:
            break
    return np.array([-0.5 * (lo[0] + hi[0]), -0.5 * (lo[1] + hi[1]), -min(low[2], lo[2])])


def posed(scene, rotation) -> PosedScene:
    """``scene`` rotated by ``rotation`` (3 x 3, or a pose string for :func:`parse_pose`)
    about the origin and set down on the table (:func:`rest_translation`)."""
    R = parse_pose(rotation) if isinstance(rotation, str) else np.asarray(rotation, float)
    if R.shape != (3, 3) or not np.allclose(R @ R.T, np.eye(3), atol=1e-9) \
            or np.linalg.det(R) < 0:
        raise NurbscanError("pose: the rotation must be a proper 3 x 3 rotation matrix")
    base = scene.base if isinstance(scene, PosedScene) else scene
    if isinstance(scene, PosedScene):
        R = R @ np.asarray(scene.rotation)
    t = rest_translation(base, R)
    return PosedScene(base, tuple(map(tuple, R.tolist())), tuple(float(x) for x in t))


@dataclass(frozen=True, eq=False)
class PosedScene:
    """A scene moved rigidly: ``X = R X_base + t`` (mm).

    Offers the interface of :class:`nurbscan.simulate.scenes.Scene` that the renderer and the
    evaluation use (``intersect``, ``mesh``, ``mesh_cast``, ``refine``, ``closest_point``,
    ``sample_surface``, ``evaluate``, ``bounds``, ``to_dict``), each computed by the base scene
    in its own frame. Surface ids and parameters are the base scene's.

    Attributes
    ----------
    base : Scene
    rotation : tuple of 3 tuples
        ``R``, rows.
    translation : tuple of 3 float
        ``t``, mm.
    """

    base: object
    rotation: tuple
    translation: tuple
    _cache: dict = field(default_factory=dict, repr=False, compare=False)

    # ---- frame --------------------------------------------------------------------------------
    @property
    def R(self) -> np.ndarray:
        return np.asarray(self.rotation, float)

    @property
    def t(self) -> np.ndarray:
        return np.asarray(self.translation, float)

    def _to_base(self, points):
        return (np.asarray(points, float) - self.t) @ self.R  # R^T (X - t), row vectors

    def _dir_to_base(self, d):
        return np.asarray(d, float) @ self.R

    def _from_base(self, points):
        return np.asarray(points, float) @ self.R.T + self.t

    def _dir_from_base(self, d):
        return np.asarray(d, float) @ self.R.T

    # ---- scene interface ----------------------------------------------------------------------
    @property
    def name(self) -> str:
        return self.base.name

    @property
    def self_shadowing(self) -> bool:
        return getattr(self.base, "self_shadowing", True)

    @property
    def n_surfaces(self) -> int:
        return self.base.n_surfaces

    def evaluate(self, surface_id, uv, order=1):
        """:meth:`Scene.evaluate` moved: the point by ``R, t``, the derivatives by ``R``."""
        out = self.base.evaluate(surface_id, uv, order)
        return [self._from_base(out[0])] + [self._dir_from_base(a) for a in out[1:]]

    def surface_points(self, surface_id, uv):
        return self._from_base(self.base.surface_points(surface_id, uv))

    def surface_normals(self, surface_id, uv):
        return self._dir_from_base(self.base.surface_normals(surface_id, uv))

    def mesh(self, tolerance_mm=0.2):
        """The base scene's mesh moved (cached per tolerance; same metadata)."""
        key = ("mesh", float(tolerance_mm))
        if key not in self._cache:
            m = self.base.mesh(tolerance_mm)
            moved = trimesh.Trimesh(self._from_base(m.vertices), m.faces, process=False,
                                    validate=False)
            moved.metadata.update(m.metadata)
            self._cache[key] = moved
        return self._cache[key]

    def mesh_hit_params(self, face_index, locations, tolerance_mm=0.2):
        return self.base.mesh_hit_params(face_index, self._to_base(locations), tolerance_mm)

    def mesh_cast(self, origins, directions, tolerance_mm=0.2):
        """The base scene's :meth:`Scene.mesh_cast` on the rays moved into its frame (a rigid
        motion keeps distances along the rays and barycentric coordinates)."""
        return self.base.mesh_cast(self._to_base(origins), self._dir_to_base(directions),
                                   tolerance_mm)

    def refine(self, origins, directions, t0, surface_id, uv0, max_dt=None, facing=None,
               return_uv=False):
        out = self.base.refine(self._to_base(origins), self._dir_to_base(directions), t0,
                               surface_id, uv0, max_dt=max_dt, facing=facing,
                               return_uv=return_uv)
        t, p, n = out[:3]
        return (t, self._from_base(p), self._dir_from_base(n)) + tuple(out[3:])

    def intersect(self, origins, directions, tolerance_mm=0.2):
        o = np.asarray(origins, float)
        r = self.base.intersect(self._to_base(o), self._dir_to_base(directions), tolerance_mm)
        r = dict(r)
        r["points"] = self._from_base(r["points"])
        r["normals"] = self._dir_from_base(r["normals"])
        return r

    def closest_point(self, points, k_candidates=32):
        p, d, s = self.base.closest_point(self._to_base(points), k_candidates)
        return self._from_base(p), d, s

    def closest_point_uv(self, points, k_candidates=32):
        p, d, s, uv = self.base.closest_point_uv(self._to_base(points), k_candidates)
        return self._from_base(p), d, s, uv

    def distance(self, points):
        return self.closest_point(points)[1]

    def sample_surface(self, n, seed=0):
        p, nrm, s = self.base.sample_surface(n, seed=seed)
        return self._from_base(p), self._dir_from_base(nrm), s

    @property
    def bounds(self) -> np.ndarray:
        """Axis-aligned bounds (2, 3) mm: the moved fine mesh's, padded by its tolerance."""
        key = ("bounds",)
        if key not in self._cache:
            V = self.mesh(0.05).vertices
            self._cache[key] = np.array([V.min(0) - 0.05, V.max(0) + 0.05])
        return self._cache[key].copy()

    def params(self) -> dict:
        return self.base.params()

    def to_dict(self) -> dict:
        """The base scene's dict with ``pose``: ``{"R": 3 x 3 rows, "t": [3] mm}``."""
        return {**self.base.to_dict(),
                "pose": {"R": [list(r) for r in self.rotation], "t": list(self.translation)}}

    def __reduce__(self):
        # rebuilt from its dict in a worker process: the caches (meshes) are not sent
        return (_rebuild, (self.to_dict(),))


def _rebuild(d: dict) -> PosedScene:
    from .scenes import scene_from_dict

    return scene_from_dict(d)


def pose_from_dict(base, pose) -> PosedScene:
    """:class:`PosedScene` of ``base`` from a ``{"R": 3 x 3, "t": [3]}`` dict (scene.json)."""
    try:
        R = np.asarray(pose["R"], float).reshape(3, 3)
        t = np.asarray(pose["t"], float).reshape(3)
    except (KeyError, TypeError, ValueError):
        raise NurbscanError(f"scene pose: expected {{'R': 3 x 3, 't': 3}}, got {pose!r}") \
            from None
    if not (np.isfinite(R).all() and np.isfinite(t).all()
            and np.allclose(R @ R.T, np.eye(3), atol=1e-9) and np.linalg.det(R) > 0):
        raise NurbscanError("scene pose: R must be a proper rotation matrix, t finite")
    return PosedScene(base, tuple(map(tuple, R.tolist())), tuple(float(x) for x in t))
