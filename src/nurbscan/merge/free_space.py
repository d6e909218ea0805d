"""Free-space consistency of a candidate alignment of two passes (issue 33).

Every view of a pass saw space as empty in front of its surface: along the camera ray of a
pixel, and along the projector ray that lit it, nothing lies between the device's centre and
the first surface point the view measured. A wrong alignment of a second pass puts some of
its surface into space the first pass's devices saw through; the right one does not (up to
the passes' own errors). :class:`FreeSpace` holds what one pass (or several, merged into one
frame) knows of that: its fused surface, its views' devices (camera and projector) with
their poses in the pass's frame and image sizes, and each view's own measured points.

:meth:`FreeSpace.violations` tests points (another pass's samples, moved by a candidate):
for each view and device, the points that project inside its image are joined to its centre
``C`` by a ray, cast against the pass's surface (Open3D ``RaycastingScene``; embree); with
``t`` the first hit and ``r = |X - C|``, a point is in the view's free space when
``r < t - tolerance`` and the hit was measured by that view (one of the view's own points
within ``reach`` mm of it: a hole of the fused surface, or a part of the surface the view's
rays met but the pass did not reconstruct, gives no evidence of free space). Space
carving's test (Kutulakos and Seitz 2000; Curless and Levoy 1996, the "empty" voxels of
volumetric fusion), applied to points instead of voxels.

Two kinds of ray give no evidence either, and are not tested:

* **grazing rays**: a point whose surface (its normal) the ray meets more than ``grazing``
  degrees from the normal. Such a point lies near its own silhouette as the device sees it;
  the pass did not measure that sliver of surface (the detector decodes little beyond 75
  degrees), its fused surface stops short of it, and the ray slips past the end into the
  surface behind, which the view measured along the neighbouring rays. Curless and Levoy
  weight measurements by the same angle for the same reason.
* **rays in front of the view's own points**: one of the view's own points lies within
  about ``reach`` of the ray (in the device's image), no more than ``tolerance`` behind the
  point. The view measured something there, in front of the fused surface's hit: the ray
  passes a depth edge of the view's own data (a silhouette, an occluder the fused surface
  lacks), or meets a surface the view measured at the point itself. The view's points form
  a depth map per device (the nearest per cell of half ``reach`` at the view's median
  depth, the least over the 5 x 5 cells around the point's pixel: within ``reach`` to 1.8
  ``reach`` of the ray).

On the full-resolution teapot's two passes (docs/accuracy.md, "Free space at full
resolution") these two kinds were 93-100 % of the right alignment's violations: samples on
the true surface at the spout, the handle, the lid and the rim, seen edge-on, where the
other pass's fused surface has a gap.

Units: mm; transforms 4 x 4, ``X_rig = M X_frame``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.ndimage import minimum_filter
from scipy.spatial import cKDTree

from ._open3d import import_open3d, raycasting_scene
from .frame import view_object_from_rig

__all__ = ["FreeSpace", "pass_free_space"]


@dataclass
class FreeSpace:
    """What a pass saw as empty, in one frame.

    Attributes
    ----------
    vertices : ndarray (V, 3), faces : ndarray (F, 3) int
        The pass's surface (its fused mesh), mm, in the frame.
    devices : list of tuple
        Per view and device: ``(device, M, view)``: ``device`` a
        :class:`nurbscan.camera.Camera` (or ``Projector``) with its pose in the rig frame and
        its image size, ``M`` (4 x 4) the rig's pose, ``X_rig = M X_frame``, ``view`` the key
        of the view's points in ``seen``.
    seen : dict
        Per view key, the view's own measured points (K, 3) in the frame (mm).
    """

    vertices: np.ndarray
    faces: np.ndarray
    devices: list
    seen: dict
    _scene: object = field(default=None, repr=False, compare=False)
    _trees: dict = field(default_factory=dict, repr=False, compare=False)
    _depths: dict = field(default_factory=dict, repr=False, compare=False)

    def moved(self, T: np.ndarray, key: int = 0) -> FreeSpace:
        """The same free space in another frame, ``X_new = T X_frame``; view keys become
        ``(key, view)`` (so that several passes' free spaces can be joined)."""
        R, t = T[:3, :3], T[:3, 3]
        Ti = np.linalg.inv(T)
        return FreeSpace(np.asarray(self.vertices, float) @ R.T + t, self.faces,
                         [(d, M @ Ti, (key, v)) for d, M, v in self.devices],
                         {(key, v): P @ R.T + t for v, P in self.seen.items()})

    @staticmethod
    def joined(spaces: list) -> FreeSpace:
        """One free space of several in one frame (their surfaces, devices and points)."""
        V, F, off = [], [], 0
        for s in spaces:
            V.append(np.asarray(s.vertices, float))
            F.append(np.asarray(s.faces, np.int64) + off)
            off += len(s.vertices)
        seen: dict = {}
        for s in spaces:
            seen.update(s.seen)
        return FreeSpace(np.concatenate(V), np.concatenate(F),
                         [d for s in spaces for d in s.devices], seen)

    def _raycaster(self):
        if self._scene is None:
            self._scene = raycasting_scene(self.vertices, self.faces, "free space")
        return self._scene

    def _tree(self, view):
        if view not in self._trees:
            self._trees[view] = cKDTree(np.asarray(self.seen[view], float).reshape(-1, 3))
        return self._trees[view]

    def _depth(self, k: int, reach: float):
        """Device ``k``'s depth map of its view's own points (module notes): ``(Z, cell)``,
        ``Z[row, col]`` the least distance (mm) from the device's centre of a point that
        projects into the 5 x 5 cells around, ``cell`` the cell's size (px)."""
        key = (k, reach)
        if key not in self._depths:
            dev, M, view = self.devices[k]
            P = np.asarray(self.seen.get(view, np.zeros((0, 3))), float).reshape(-1, 3)
            Mi = np.linalg.inv(M)
            C = Mi[:3, :3] @ dev.center + Mi[:3, 3]
            px, ok = dev.project(P @ M[:3, :3].T + M[:3, 3], return_valid=True)
            s = np.linalg.norm(P - C, axis=1)
            ok &= np.isfinite(s)
            depth = float(np.median(s[ok])) if ok.any() else 1.0
            cell = max(0.5 * reach * dev.f * dev.sx / dev.dx / depth, 1.0)
            shape = (int(dev.height // cell) + 1, int(dev.width // cell) + 1)
            Z = np.full(shape, np.inf)
            with np.errstate(invalid="ignore"):
                ij = np.floor(np.nan_to_num(px[:, ::-1], nan=-1.0) / cell).astype(np.int64)
            ok &= ((ij >= 0) & (ij < shape)).all(axis=1)
            np.minimum.at(Z, (ij[ok, 0], ij[ok, 1]), s[ok])
            self._depths[key] = (minimum_filter(Z, size=5, mode="constant", cval=np.inf), cell)
        return self._depths[key]

    def violations(self, X: np.ndarray, normals: np.ndarray | None = None,
                   tolerance: float = 1.0, reach: float = 1.5, margin: float = 2.0,
                   grazing: float = 75.0, own_points: bool = True
                   ) -> tuple[np.ndarray, np.ndarray]:
        """Which points lie in space this pass saw as empty.

        Parameters
        ----------
        X : ndarray (N, 3)
            Points in this free space's frame, mm.
        normals : ndarray (N, 3), optional
            The points' surface normals (any length, either sign): rays that meet a point's
            surface more than ``grazing`` degrees from its normal are not tested. None: every
            ray is.
        tolerance : float
            How far in front of the first surface along a ray a point must lie (mm).
        reach : float
            Largest distance (mm) from the ray's first hit to one of the view's own points
            for the hit to count as measured by that view; also about how near the ray one
            of the view's own points no more than ``tolerance`` behind the point must lie for
            the ray to give no evidence (module notes).
        margin : float
            Pixels at the image border left out.
        grazing : float
            Degrees (module notes); 90 or more: no ray is grazing.
        own_points : bool
            Leave out rays in front of the view's own points (module notes).

        Returns
        -------
        violated : ndarray (N,) bool
            In front of a measured surface point by more than ``tolerance`` along some
            view's camera or projector ray that is neither grazing nor in front of the view's
            own points (module notes).
        tested : ndarray (N,) bool
            Inside some device's image, not grazing, with a measured first hit and not found
            in front of the view's own points (the points the test could say something
            about).
        """
        o3d = import_open3d("free space")
        X = np.asarray(X, float).reshape(-1, 3)
        violated = np.zeros(len(X), bool)
        tested = np.zeros(len(X), bool)
        if not len(X) or not len(self.faces):
            return violated, tested
        Nn = None
        if normals is not None and grazing < 90:
            Nn = np.asarray(normals, float).reshape(-1, 3)
            Nn = Nn / np.maximum(np.linalg.norm(Nn, axis=1), 1e-12)[:, None]
        cos_max = np.cos(np.radians(grazing))
        scene = self._raycaster()
        for k, (dev, M, view) in enumerate(self.devices):  # a loop over devices, not points
            if view not in self.seen or not len(self.seen[view]):
                continue
            px, ok = dev.project(X @ M[:3, :3].T + M[:3, 3], return_valid=True)
            ok &= ((px[:, 0] >= margin) & (px[:, 0] <= dev.width - 1 - margin)
                   & (px[:, 1] >= margin) & (px[:, 1] <= dev.height - 1 - margin))
            idx = np.flatnonzero(ok)
            if not len(idx):
                continue
            Mi = np.linalg.inv(M)
            C = Mi[:3, :3] @ dev.center + Mi[:3, 3]
            D = X[idx] - C
            r = np.linalg.norm(D, axis=1)
            D /= r[:, None]
            if Nn is not None:
                keep = np.abs(np.einsum("ij,ij->i", Nn[idx], D)) >= cos_max
                idx, D, r = idx[keep], D[keep], r[keep]
                if not len(idx):
                    continue
            rays = np.hstack([np.broadcast_to(C, D.shape), D]).astype(np.float32)
            t = scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy().astype(float)
            hit = np.flatnonzero(np.isfinite(t))
            if not len(hit):
                continue
            H = C + D[hit] * t[hit, None]
            d, _ = self._tree(view).query(H, distance_upper_bound=reach)
            meas = np.isfinite(d)
            front = meas & (r[hit] < t[hit] - tolerance)
            if own_points and front.any():
                Z, cell = self._depth(k, reach)
                f = np.flatnonzero(front)
                ij = np.floor(px[idx[hit[f]], ::-1] / cell).astype(np.int64)
                ij = np.minimum(ij, np.array(Z.shape) - 1)
                behind = Z[ij[:, 0], ij[:, 1]] <= r[hit[f]] + tolerance
                front[f[behind]] = False
                meas[f[behind]] = False
            tested[idx[hit[meas]]] = True
            violated[idx[hit[front]]] = True
        return violated, tested


def pass_free_space(model, rig, projector: bool = True) -> FreeSpace:
    """The free space of one pass in its own object frame: its fused mesh, its views'
    camera (and projector) poses, ``M = P_v^-1`` with ``P_v`` the view's registered
    ``object_from_rig`` where its reconstruction recorded one (else the calibrated turntable
    at its table angle), and each view's Gordon samples and edge points (``point_view``,
    ``edge_view``).

    Parameters
    ----------
    model : nurbscan.reconstruct.Model
        With its fused mesh.
    rig : nurbscan.camera.Rig
        The pass's calibrated rig.
    projector : bool
        Also the projector's rays.
    """
    fm = model.fused
    devices, seen = [], {}
    P_all = np.asarray(model.points, float).reshape(-1, 3)
    pv = np.asarray(model.point_view, int)
    E_all = np.asarray(model.edge_points, float).reshape(-1, 3)
    ev = np.asarray(model.edge_view, int)
    for e in model.views:
        v = int(e["index"])
        M = np.linalg.inv(view_object_from_rig(e, rig.turntable))
        devices.append((rig.camera, M, v))
        if projector:
            devices.append((rig.projector, M, v))
        seen[v] = np.concatenate([P_all[pv == v], E_all[ev == v]])
    return FreeSpace(np.asarray(fm.vertices, float), np.asarray(fm.faces, np.int64),
                     devices, seen)
