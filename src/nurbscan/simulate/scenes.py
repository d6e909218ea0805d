"""Synthetic scenes with exact ground truth for the simulated scanner.

Every scene is a union of parametric surfaces ``S_k(u, v)`` (``k`` = surface id), in
millimetres, in the object (table) frame of ``docs/conventions.md`` (z up, the table top is
z = 0). A scene offers

* :meth:`Scene.mesh` - a fine triangle mesh of the exact surfaces (vertices lie on the exact
  surface, per face the surface id, per vertex the surface parameters), for a fast ray cast;
* :meth:`Scene.refine` - ray / exact-surface intersection by Newton's method started from the
  mesh hit, to a residual far below 1 um;
* :meth:`Scene.intersect` - mesh ray cast (Embree, :meth:`Scene.mesh_cast`) followed by
  :meth:`refine`;
* :meth:`Scene.closest_point` - the exact closest point on the true surface (the ground truth of
  the paper's Table I);
* :meth:`Scene.sample_surface`, :meth:`Scene.to_dict` / :func:`scene_from_dict`.

Scenes:

* :class:`Teapot` - the Utah teapot (Newell 1975), 32 bicubic Bezier patches read from the
  package's ``data/teapot.bpt``, 37 mm per model unit by default;
* :class:`Sphere`, :class:`Cylinder` (an open cup), :class:`Torus` and :class:`Plane`, with
  closed-form intersection and projection (the torus intersection by Newton on its exact
  signed distance).

Normals returned by every method are unit and point out of the object's material, whatever
side a ray comes from.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from importlib import resources

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from nurbscan.errors import NurbscanError

__all__ = [
    "SCENE_TYPE",
    "Cylinder",
    "Plane",
    "Scene",
    "Sphere",
    "Teapot",
    "Torus",
    "load_bpt",
    "make_scene",
    "scene_from_dict",
]

SCENE_TYPE = "nurbscan.scene"
SCENE_VERSION = 1

#: Convergence of the Newton iterations (mm); well below the 1e-6 mm the API promises.
_NEWTON_TOL_MM = 1e-10
#: A parameter may exceed its domain by this much after Newton and still count as inside.
_DOMAIN_SLACK = 1e-9


# --------------------------------------------------------------------------------------------
# small vector helpers
# --------------------------------------------------------------------------------------------
def _dot(a, b):
    return np.einsum("...i,...i->...", a, b)


def _cross(a, b):
    """``np.cross`` of (..., 3) arrays, the same arithmetic without its axis handling (twice
    as fast on the Newton iterations' small arrays)."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    out[..., 0] = a1 * b2 - a2 * b1
    out[..., 1] = a2 * b0 - a0 * b2
    out[..., 2] = a0 * b1 - a1 * b0
    return out


def _unit(a):
    n = np.linalg.norm(a, axis=-1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        return a / n


def _as_rays(origins, directions):
    d = np.atleast_2d(np.asarray(directions, dtype=float))
    if d.ndim != 2 or d.shape[1] != 3:
        raise NurbscanError(f"ray directions: expected shape (N, 3), got {np.shape(directions)}")
    o = np.asarray(origins, dtype=float)
    if o.shape == (3,):
        o = np.broadcast_to(o, d.shape)
    if o.shape != d.shape:
        raise NurbscanError(
            f"ray origins: expected shape (3,) or {d.shape}, got {np.shape(origins)}"
        )
    return np.ascontiguousarray(o), np.ascontiguousarray(d)


def _as_points(points):
    p = np.atleast_2d(np.asarray(points, dtype=float))
    if p.ndim != 2 or p.shape[1] != 3:
        raise NurbscanError(f"points: expected shape (N, 3), got {np.shape(points)}")
    return p


def _vec3(value, what):
    a = np.asarray(value, dtype=float)
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise NurbscanError(f"{what}: expected 3 finite numbers, got {value!r}")
    return tuple(float(x) for x in a)


def _positive(value, what):
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise NurbscanError(f"{what}: expected a positive number, got {value!r}") from None
    if not (math.isfinite(x) and x > 0):
        raise NurbscanError(f"{what}: expected a positive number, got {value!r}")
    return x


# --------------------------------------------------------------------------------------------
# Bernstein basis of degree 3
# --------------------------------------------------------------------------------------------
def bernstein3(t, order=0):
    """Cubic Bernstein polynomials and their derivatives.

    Parameters
    ----------
    t : array_like, shape (N,)
        Parameters (normally in [0, 1]).
    order : {0, 1, 2}
        Derivative order.

    Returns
    -------
    B : ndarray, shape (N, 4)
        ``d^order/dt^order B_{i,3}(t)``, ``B_{i,3}(t) = C(3, i) t^i (1 - t)^(3 - i)``
        (Piegl and Tiller, The NURBS Book, eq. 1.8 and A1.3).
    """
    if order not in (0, 1, 2):
        raise ValueError(f"order must be 0, 1 or 2, got {order}")
    t = np.asarray(t, dtype=float)
    s = 1.0 - t
    out = np.empty(t.shape + (4,))  # filled column by column: faster than np.stack
    if order == 0:
        out[..., 0], out[..., 1] = s * s * s, 3 * t * s * s
        out[..., 2], out[..., 3] = 3 * t * t * s, t * t * t
    elif order == 1:
        out[..., 0], out[..., 1] = -3 * s * s, 3 * s * (1 - 3 * t)
        out[..., 2], out[..., 3] = 3 * t * (2 - 3 * t), 3 * t * t
    else:
        out[..., 0], out[..., 1] = 6 * s, 18 * t - 12
        out[..., 2], out[..., 3] = 6 - 18 * t, 6 * t
    return out


def load_bpt(path=None, scale=1.0):
    """Read Bezier patches in the BPT text format.

    Parameters
    ----------
    path : path-like or None
        A BPT file (``count``; per patch ``"du dv"`` then ``(du+1)(dv+1)`` points row by row);
        None reads the package's Utah teapot ``nurbscan/data/teapot.bpt``.
    scale : float
        Factor applied to the coordinates (37.0 gives millimetres for the teapot).

    Returns
    -------
    ndarray, shape (P, 4, 4, 3)
        Control points ``P[k, i, j]``; ``i`` indexes u (rows), ``j`` indexes v.
    """
    if path is None:
        text = resources.files("nurbscan").joinpath("data/teapot.bpt").read_text()
        name = "nurbscan/data/teapot.bpt"
    else:
        name = str(path)
        try:
            with open(path, encoding="utf-8") as fh:
                text = fh.read()
        except OSError as exc:
            raise NurbscanError(f"{name}: cannot read ({exc.strerror})") from None
    tok = text.split()
    try:
        count = int(tok[0])
        pos, patches = 1, []
        for k in range(count):
            du, dv = int(tok[pos]), int(tok[pos + 1])
            if (du, dv) != (3, 3):
                raise NurbscanError(f"{name}: patch {k} has degree ({du}, {dv}), only bicubic")
            pos += 2
            patches.append(np.array(tok[pos : pos + 48], dtype=float).reshape(4, 4, 3))
            pos += 48
    except (IndexError, ValueError):
        raise NurbscanError(f"{name}: not a valid BPT file (truncated or non-numeric)") from None
    return np.array(patches) * float(scale)


# --------------------------------------------------------------------------------------------
# base class
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Scene:
    """Base class of the synthetic scenes: a union of parametric surfaces, in mm.

    Subclasses define the surfaces through :meth:`_eval` (point and derivatives of surface
    ``k`` at parameters ``(u, v)``), :meth:`_domain`, :meth:`_grid_size` and
    :meth:`_orientation`; the generic ray refinement and closest-point search below then work
    for any smooth parametric surface (Bezier patches of the teapot). Analytic scenes override
    them with closed forms.
    """

    name = "scene"
    #: Whether the surface can cast shadows on itself (the renderer skips the shadow rays of
    #: its points when not: a plane, or a convex body lit on the side facing the light).
    self_shadowing = True

    # ---- surface description (subclasses) -------------------------------------------------
    @property
    def n_surfaces(self) -> int:
        """Number of surfaces (surface ids are ``0 .. n_surfaces - 1``)."""
        raise NotImplementedError

    def _eval(self, k, u, v, order=1):
        """Point and derivatives of surface ``k``.

        Returns ``[S, Su, Sv]`` (order 1) or ``[S, Su, Sv, Suu, Suv, Svv]`` (order 2),
        each (n, 3) mm (per unit parameter); with order 0 ``[S]`` (or more: callers take
        what they need).
        """
        raise NotImplementedError

    def _domain(self, k):
        """Parameter domain ``(u0, u1, v0, v1)`` of surface ``k``."""
        return (0.0, 1.0, 0.0, 1.0)

    def _periodic(self, k):
        """Whether u and v of surface ``k`` are periodic over their domain."""
        return (False, False)

    def _orientation(self, k):
        """+1 if ``Su x Sv`` of surface ``k`` points out of the material, else -1."""
        return 1.0

    def _grid_size(self, k, tolerance_mm):
        """Grid intervals ``(nu, nv)`` meshing surface ``k`` within ``tolerance_mm``."""
        raise NotImplementedError

    # ---- parametric evaluation --------------------------------------------------------------
    def evaluate(self, surface_id, uv, order=1):
        """Exact surface points (and derivatives) at surface parameters.

        Parameters
        ----------
        surface_id : array_like of int, shape (N,)
        uv : array_like, shape (N, 2)
        order : {0, 1, 2}

        Returns
        -------
        list of ndarray, each (N, 3), mm
            ``[S]``, ``[S, Su, Sv]`` or ``[S, Su, Sv, Suu, Suv, Svv]``.
        """
        sid = np.asarray(surface_id, dtype=np.int64).reshape(-1)
        uv = np.asarray(uv, dtype=float).reshape(-1, 2)
        nout = {0: 1, 1: 3, 2: 6}[order]
        out = [np.full((sid.size, 3), np.nan) for _ in range(nout)]
        for k, idx in _groups(sid, self.n_surfaces):
            vals = self._eval(k, uv[idx, 0], uv[idx, 1], order)  # may give more
            for o, val in zip(out, vals[:nout], strict=False):
                o[idx] = val
        return out

    def surface_points(self, surface_id, uv):
        """Exact points ``S_k(u, v)``, shape (N, 3) mm."""
        return self.evaluate(surface_id, uv, order=0)[0]

    def surface_normals(self, surface_id, uv):
        """Unit outward normals at surface parameters, shape (N, 3).

        ``n = s_k (Su x Sv) / |Su x Sv|``; where the surface is degenerate (a collapsed row of
        control points: the lid's top, the bottom's centre, a sphere's pole) ``Su x Sv`` vanishes
        and the limit normal is taken at a parameter moved 1e-7 of the domain towards the
        domain's centre (the normal is continuous there).
        """
        sid = np.asarray(surface_id, dtype=np.int64).reshape(-1)
        uv = np.asarray(uv, dtype=float).reshape(-1, 2)
        n = np.full((sid.size, 3), np.nan)
        for k, idx in _groups(sid, self.n_surfaces):
            n[idx] = self._normals_k(k, uv[idx])
        return n

    def _points_normals(self, surface_id, uv):
        """:meth:`surface_points` and :meth:`surface_normals` together, from one evaluation of
        ``S, Su, Sv`` per surface (the same values), shapes (N, 3) and (N, 3)."""
        if type(self)._normals_k is not Scene._normals_k:  # a scene with its own normals
            return self.surface_points(surface_id, uv), self.surface_normals(surface_id, uv)
        sid = np.asarray(surface_id, dtype=np.int64).reshape(-1)
        uv = np.asarray(uv, dtype=float).reshape(-1, 2)
        pts = np.full((sid.size, 3), np.nan)
        nrm = np.full((sid.size, 3), np.nan)
        for k, idx in _groups(sid, self.n_surfaces):
            uvk = uv[idx]
            sk, su, sv = self._eval(k, uvk[:, 0], uvk[:, 1], 1)[:3]
            pts[idx] = sk
            nrm[idx] = self._normals_from(k, uvk, su, sv)
        return pts, nrm

    def _normals_k(self, k, uv):
        _, su, sv = self._eval(k, uv[:, 0], uv[:, 1], 1)[:3]
        return self._normals_from(k, uv, su, sv)

    def _normals_from(self, k, uv, su, sv):
        """Unit outward normals of surface ``k`` from its derivatives at ``uv`` (see
        :meth:`surface_normals` for the degenerate points)."""
        u0, u1, v0, v1 = self._domain(k)
        c = _cross(su, sv)
        size = _dot(su, su) + _dot(sv, sv)
        bad = ~(np.linalg.norm(c, axis=1) > 1e-10 * np.maximum(size, 1e-300))
        bad |= ~np.isfinite(c).all(axis=1)
        for _ in range(4):
            if not bad.any():
                break
            centre = np.array([(u0 + u1) / 2, (v0 + v1) / 2])
            span = np.array([u1 - u0, v1 - v0])
            step = 1e-7 if _ == 0 else 1e-7 * 100.0**_
            w = uv[bad] + step * span * np.sign(centre - uv[bad])
            _, su2, sv2 = self._eval(k, w[:, 0], w[:, 1], 1)
            c2 = _cross(su2, sv2)
            c[bad] = c2
            size2 = _dot(su2, su2) + _dot(sv2, sv2)
            still = ~(np.linalg.norm(c2, axis=1) > 1e-10 * np.maximum(size2, 1e-300))
            bad[bad] = still
        return self._orientation(k) * _unit(c)

    # ---- mesh ---------------------------------------------------------------------------------
    def mesh(self, tolerance_mm=0.2):
        """A triangle mesh of the exact surfaces (cached per tolerance).

        Each surface is sampled on a regular ``(nu + 1) x (nv + 1)`` parameter grid chosen so that
        the chord error (distance from a triangle to the surface) is below ``tolerance_mm``; the
        vertices lie on the exact surface. Vertices are not merged across surfaces, so each carries
        its own parameters; zero-area triangles (at degenerate rows) are dropped; faces are wound
        so that their normals point outwards.

        Returns
        -------
        trimesh.Trimesh
            With ``mesh.metadata["face_surface_id"]`` (F,) int, ``["vertex_surface_id"]`` (V,) int
            and ``["vertex_uv"]`` (V, 2) float; use :meth:`mesh_hit_params` to turn a hit on face
            ``f`` at a location into ``(surface_id, uv)``.
        """
        tol = _positive(tolerance_mm, "mesh tolerance_mm")
        cache = self.__dict__.setdefault("_mesh_cache", {})
        if tol not in cache:
            cache[tol] = self._build_mesh(tol)
        return cache[tol]

    def _build_mesh(self, tol):
        verts, faces, vsid, vuv, fsid = [], [], [], [], []
        base = 0
        for k in range(self.n_surfaces):
            nu, nv = self._grid_size(k, tol)
            u0, u1, v0, v1 = self._domain(k)
            uu, vv = np.meshgrid(np.linspace(u0, u1, nu + 1), np.linspace(v0, v1, nv + 1),
                                 indexing="ij")
            uv = np.column_stack([uu.ravel(), vv.ravel()])
            p = self._eval(k, uv[:, 0], uv[:, 1], 1)[0]
            idx = np.arange((nu + 1) * (nv + 1)).reshape(nu + 1, nv + 1)
            a, b = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel()
            c, d = idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
            f = np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d])])
            if self._orientation(k) < 0:
                f = f[:, ::-1]
            tri = p[f]
            area = np.linalg.norm(_cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
            f = f[area > 1e-12 * max(np.ptp(p, axis=0).max(), 1.0) ** 2]
            verts.append(p)
            faces.append(f + base)
            vsid.append(np.full(len(p), k))
            vuv.append(uv)
            fsid.append(np.full(len(f), k))
            base += len(p)
        m = trimesh.Trimesh(np.concatenate(verts), np.concatenate(faces), process=False,
                            validate=False)
        m.metadata["face_surface_id"] = np.concatenate(fsid)
        m.metadata["vertex_surface_id"] = np.concatenate(vsid)
        m.metadata["vertex_uv"] = np.concatenate(vuv)
        m.metadata["tolerance_mm"] = tol
        m.metadata["scene"] = self.name
        return m

    def mesh_hit_params(self, face_index, locations, tolerance_mm=0.2):
        """Surface id and interpolated ``(u, v)`` of hits on :meth:`mesh` faces.

        Parameters
        ----------
        face_index : array_like of int, shape (N,)
            Hit faces of ``mesh(tolerance_mm)``.
        locations : array_like, shape (N, 3)
            Hit points (mm).

        Returns
        -------
        surface_id : ndarray, shape (N,) int
        uv : ndarray, shape (N, 2)
            Barycentric interpolation of the face's vertex parameters: a Newton start.
        """
        m = self.mesh(tolerance_mm)
        fi = np.asarray(face_index, dtype=np.int64).reshape(-1)
        loc = np.asarray(locations, dtype=float).reshape(-1, 3)
        fv = m.faces[fi]
        tri = m.vertices[fv]
        bary = trimesh.triangles.points_to_barycentric(tri, loc)
        bary = np.clip(np.nan_to_num(bary, nan=1.0 / 3.0), 0.0, 1.0)
        bary /= bary.sum(axis=1, keepdims=True)
        uv = np.einsum("ni,nij->nj", bary, m.metadata["vertex_uv"][fv])
        return m.metadata["face_surface_id"][fi], uv

    def _ray_engine(self, tol):
        """The Embree scene of ``mesh(tol)`` (cached): ``(scene, origin)`` with the vertices
        shifted by ``origin`` (the mesh's centre, for float32 precision), or None without
        ``embreex`` (then trimesh's ray module is used)."""
        cache = self.__dict__.setdefault("_embree_cache", {})
        if tol not in cache:
            try:
                from embreex import rtcore_scene
                from embreex.mesh_construction import TriangleMesh
            except ImportError:  # pragma: no cover - embreex is a dependency
                cache[tol] = None
            else:
                m = self.mesh(tol)
                origin = 0.5 * (m.vertices.min(axis=0) + m.vertices.max(axis=0))
                sc = rtcore_scene.EmbreeScene()
                TriangleMesh(scene=sc, vertices=(m.vertices - origin).astype(np.float32),
                             indices=np.ascontiguousarray(m.faces, dtype=np.int32))
                cache[tol] = (sc, origin)
        return cache[tol]

    def mesh_cast(self, origins, directions, tolerance_mm=0.2):
        """First hits of rays on :meth:`mesh` (Embree, one call for all rays).

        Parameters
        ----------
        origins : ndarray, shape (N, 3)
            Ray origins (mm).
        directions : ndarray, shape (N, 3)
            Unit ray directions.

        Returns
        -------
        ray : ndarray of int, shape (M,)
            Indices of the rays that hit the mesh.
        face : ndarray of int, shape (M,)
            Hit faces.
        t : ndarray, shape (M,)
            Distance along the ray (mm): the ray / face-plane intersection in float64 (Embree
            works in float32; its distance is used for faces edge-on to the ray).
        bary : ndarray, shape (M, 3)
            Barycentric coordinates of the hit in the face (from Embree, float32 precision).
        """
        o, d = _as_rays(origins, directions)
        tol = _positive(tolerance_mm, "mesh tolerance_mm")
        m = self.mesh(tol)
        eng = self._ray_engine(tol)
        if eng is None:  # pragma: no cover - embreex is a dependency
            tri, ray, loc = m.ray.intersects_id(o, d, multiple_hits=False,
                                                return_locations=True)
            tri, ray = np.asarray(tri, np.int64), np.asarray(ray, np.int64)
            loc = np.asarray(loc, float).reshape(-1, 3)
            bary = trimesh.triangles.points_to_barycentric(m.vertices[m.faces[tri]], loc)
            bary = np.clip(np.nan_to_num(bary, nan=1.0 / 3.0), 0.0, 1.0)
            bary /= bary.sum(axis=1, keepdims=True)
            return ray, tri, _dot(loc - o[ray], d[ray]), bary
        sc, origin = eng
        r = sc.run((o - origin).astype(np.float32), d.astype(np.float32), output=1)
        prim = np.asarray(r["primID"])
        ray = np.flatnonzero(prim >= 0)
        tri = prim[ray].astype(np.int64)
        fu = np.asarray(r["u"], float)[ray]
        fv = np.asarray(r["v"], float)[ray]
        bary = np.clip(np.column_stack([1.0 - fu - fv, fu, fv]), 0.0, 1.0)
        bary /= bary.sum(axis=1, keepdims=True)
        # distance to the face's plane in float64 (as trimesh's planes_lines)
        nrm = np.take(m.face_normals, tri, axis=0)
        dn = _dot(np.take(d, ray, axis=0), nrm)
        v0 = np.take(m.vertices, m.faces[tri, 0], axis=0)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = _dot(v0 - np.take(o, ray, axis=0), nrm) / dn
        flat = ~(np.abs(dn) > 1e-12) | ~np.isfinite(t)
        t[flat] = np.asarray(r["tfar"], float)[ray[flat]]
        return ray, tri, t, bary

    def _candidates_near(self, points, k):
        """Surface ids (N, k) and parameters (N, k, 2) of the k nearest mesh vertices.

        Coincident vertices of one surface (a degenerate row: a pole) count once, so that a
        pole does not hide the other surfaces meeting there.
        """
        cache = self.__dict__.setdefault("_kdtree_cache", [])
        if not cache:
            m = self.mesh()
            key = np.column_stack([m.metadata["vertex_surface_id"],
                                   np.round(m.vertices, 9)])
            _, keep = np.unique(key, axis=0, return_index=True)
            cache.append((cKDTree(m.vertices[keep]), m.metadata["vertex_surface_id"][keep],
                          m.metadata["vertex_uv"][keep]))
        tree, vsid, vuv = cache[0]
        k = int(min(k, len(vsid)))
        dist, nn = tree.query(points, k=k)
        nn = nn.reshape(len(points), k)
        return dist.reshape(len(points), k), vsid[nn], vuv[nn]

    # ---- rays ---------------------------------------------------------------------------------
    def refine(self, origins, directions, t0, surface_id, uv0, max_dt=None, facing=None,
               return_uv=False):
        """Intersect rays with the exact surface by Newton's method from a mesh hit.

        Solves ``S_k(u, v) = o + t d`` for ``(u, v, t)`` (3 x 3 Newton, Cramer's rule,
        vectorised per surface) from ``(uv0, t0)``. A ray whose iteration leaves the surface's
        domain (the hit is on a neighbouring patch) is retried from the nearest mesh vertices of
        the other surfaces around ``o + t0 d``, keeping the root nearest ``t0``.

        Parameters
        ----------
        origins : array_like, shape (N, 3) or (3,)
            Ray origins (mm).
        directions : array_like, shape (N, 3)
            Unit ray directions.
        t0 : array_like, shape (N,)
            Mesh hit distances (mm).
        surface_id : array_like of int, shape (N,)
        uv0 : array_like, shape (N, 2)
            Start parameters (from :meth:`mesh_hit_params`).
        max_dt : float or None
            Reject roots farther than this from ``t0`` (mm); default 20 mm (a silhouette
            sliver of a 0.2 mm mesh on a 100 mm radius is about 13 mm long).
        facing : array_like, shape (N,), optional
            Sign of ``d . n`` of the hit mesh face (-1: the ray meets the outside of the
            surface, +1: the inside). Near a silhouette a ray crosses the exact surface twice
            around the mesh hit; the root whose ``d . n`` has this sign is kept (the other one is
            found again by restarting Newton from the start reflected through the mesh hit), and
            the ray is not ok if there is none. Default: the sign at ``uv0`` on the exact surface.

        Returns
        -------
        t : ndarray, shape (N,)
            Distances along the rays (mm).
        points : ndarray, shape (N, 3)
            Exact surface points ``S_k(u, v)`` (mm).
        normals : ndarray, shape (N, 3)
            Unit outward normals.
        surface_id : ndarray, shape (N,) int
            Surface of the hit (may differ from the input near a patch border).
        ok : ndarray, shape (N,) bool
            False where Newton failed; those rows hold NaN.
        uv : ndarray, shape (N, 2)
            Surface parameters of the hit; a sixth output, only with ``return_uv=True``.
        """
        o, d = _as_rays(origins, directions)
        n = len(d)
        t0 = np.broadcast_to(np.asarray(t0, dtype=float), (n,)).copy()
        sid = np.broadcast_to(np.asarray(surface_id, dtype=np.int64), (n,)).copy()
        uv = np.broadcast_to(np.asarray(uv0, dtype=float), (n, 2)).copy()
        if max_dt is None:
            max_dt = 20.0
        if facing is None:
            facing = np.zeros(n)
            good = (sid >= 0) & (sid < self.n_surfaces) & np.isfinite(uv).all(axis=1)
            if good.any():
                facing[good] = np.sign(_dot(d[good], self.surface_normals(sid[good], uv[good])))
        facing = np.nan_to_num(np.broadcast_to(np.asarray(facing, dtype=float), (n,)))
        t, uv, sid, ok = self._refine_impl(o, d, t0, sid, uv, float(max_dt), np.sign(facing))
        pts = np.full((n, 3), np.nan)
        nrm = np.full((n, 3), np.nan)
        if ok.any():
            pts[ok], nrm[ok] = self._points_normals(sid[ok], uv[ok])
        bad = ~ok | ~np.isfinite(nrm).all(axis=1)
        ok = ok & ~bad
        t = np.where(ok, t, np.nan)
        pts[~ok] = np.nan
        nrm[~ok] = np.nan
        uv[~ok] = np.nan
        return (t, pts, nrm, sid, ok, uv) if return_uv else (t, pts, nrm, sid, ok)

    def _refine_impl(self, o, d, t0, sid, uv, max_dt, facing):
        uv_start = uv.copy()
        t, uv1, ok = self._ray_newton(o, d, t0, sid, uv)
        ok &= np.abs(t - t0) <= max_dt
        bad = np.flatnonzero(~ok & np.isfinite(t0))
        if bad.size:
            # retry on the surfaces of the nearest mesh vertices (patch borders)
            _, vs, vuv = self._candidates_near(o[bad] + t0[bad, None] * d[bad], 12)
            self._retry_candidates(o, d, t0, bad, vs, vuv, max_dt, t, uv1, sid, ok)
        # the other root of a silhouette sliver: restart reflected through the mesh hit
        wrong = self._wrong_side(d, sid, uv1, ok, facing)
        if wrong.any():
            w = np.flatnonzero(wrong)
            ok[w] = False
            t_bad, uv_bad, s_bad = t[w], uv1[w], sid[w]
            start_uv = np.where(s_bad[:, None] == sid[w][:, None], uv_start[w], uv_bad)
            facs = (1.0, 2.0, 4.0, 8.0)
            (ulo, uhi), (vlo, vhi) = self._domain_arrays(s_bad)
            tt = np.concatenate([t0[w] - fac * (t_bad - t0[w]) for fac in facs])
            uu = np.concatenate([start_uv - fac * (uv_bad - start_uv) for fac in facs])
            m = len(facs)
            uu = np.column_stack([np.clip(uu[:, 0], np.tile(ulo, m), np.tile(uhi, m)),
                                  np.clip(uu[:, 1], np.tile(vlo, m), np.tile(vhi, m))])
            # every restart at once (each ray's Newton is its own), accepted in their order
            ww = np.tile(w, m)
            tall, uvall, okall = self._ray_newton(o[ww], d[ww], tt, np.tile(s_bad, m), uu)
            for i in range(m):
                part = slice(i * w.size, (i + 1) * w.size)
                tj, uvj, okj = tall[part], uvall[part], okall[part]
                okj &= (np.abs(tj - t0[w]) <= max_dt) & (np.abs(tj - t_bad) > 1e-7) & ~ok[w]
                okj &= ~self._wrong_side(d[w], s_bad, uvj, okj, facing[w])
                acc = w[okj]
                t[acc], uv1[acc], ok[acc] = tj[okj], uvj[okj], True
        return t, uv1, sid, ok

    def _retry_candidates(self, o, d, t0, bad, vs, vuv, max_dt, t, uv1, sid, ok):
        """Newton from the nearest mesh vertices of other surfaces for the rays ``bad``
        (``vs`` (B, k) their surfaces, ``vuv`` (B, k, 2) their parameters, nearest first):
        candidate j of a ray is tried where its surface is not that of a nearer candidate nor
        the ray's current one, and the root nearest ``t0`` within ``max_dt`` is kept; ``t``,
        ``uv1``, ``sid`` and ``ok`` are updated in place.

        Every candidate that may be tried is solved in one Newton call (each ray's iteration
        is its own, so the roots are those of one call per candidate); the choice then runs
        over the candidates in order, the ray's current surface as it was at that candidate.
        """
        k = vs.shape[1]
        first = np.ones(vs.shape, bool)  # the surface not among the nearer candidates
        for j in range(1, k):
            first[:, j] = (vs[:, :j] != vs[:, j:j + 1]).all(axis=1)
        # the current surface is checked in the choice below: a ray that took a candidate
        # tries the surface it came with again at that surface's own candidate
        jr, jc = np.nonzero(first.T)  # candidate-major order
        if jr.size == 0:
            return
        sel = bad[jc]
        tj, uvj, okj = self._ray_newton(o[sel], d[sel], t0[sel], vs[jc, jr], vuv[jc, jr])
        dt = np.abs(tj - t0[sel])
        okj &= dt <= max_dt
        best = np.full(bad.size, np.inf)
        starts = np.searchsorted(jr, np.arange(k + 1))
        for j in range(k):
            a, b = starts[j], starts[j + 1]
            if a == b:
                continue
            rows, w = jc[a:b], sel[a:b]
            acc = okj[a:b] & (vs[rows, j] != sid[w]) & (dt[a:b] < best[rows])
            w = w[acc]
            t[w], uv1[w], sid[w], ok[w] = tj[a:b][acc], uvj[a:b][acc], vs[rows, j][acc], True
            best[rows[acc]] = dt[a:b][acc]

    def _domain_arrays(self, sid):
        dom = np.array([self._domain(int(k)) for k in range(self.n_surfaces)])[sid]
        return (dom[:, 0], dom[:, 1]), (dom[:, 2], dom[:, 3])

    def _wrong_side(self, d, sid, uv, ok, facing):
        """Rays whose root has ``sign(d . n)`` opposite to ``facing`` (0 = no constraint)."""
        wrong = np.zeros(len(d), bool)
        chk = ok & (facing != 0)
        if chk.any():
            s = np.sign(_dot(d[chk], self.surface_normals(sid[chk], uv[chk])))
            wrong[chk] = s == -facing[chk]
        return wrong

    def _ray_newton(self, o, d, t0, sid, uv, iters=30):
        """Newton on ``F(u, v, t) = S_k(u, v) - o - t d`` for each ray (grouped by surface)."""
        n = len(d)
        t = np.full(n, np.nan)
        uv_out = np.full((n, 2), np.nan)
        ok = np.zeros(n, bool)
        for k, idx in _groups(sid, self.n_surfaces):
            tk, uvk, okk = self._ray_newton_k(k, np.take(o, idx, axis=0), np.take(d, idx, axis=0),
                                              t0[idx], np.take(uv, idx, axis=0), iters)
            t[idx], uv_out[idx], ok[idx] = tk, uvk, okk
        return t, uv_out, ok

    def _ray_newton_k(self, k, o, d, t, uv, iters):
        """Newton on surface ``k``: solve ``[Su Sv -d] (du, dv, dt) = -(S - o - t d)`` by
        Cramer's rule, steps limited to a quarter of the domain; ok where the root is inside
        the domain (periodic parameters wrap) and ``S(u, v)`` is within 1e-7 mm of the ray."""
        u0, u1, v0, v1 = self._domain(k)
        pu, pv = self._periodic(k)
        lo, hi = np.array([u0, v0]), np.array([u1, v1])
        span = hi - lo
        uv = np.clip(uv.copy(), lo, hi)
        t = t.copy()
        act = np.arange(len(t))
        # the active rays' data are kept compact (no gathers per iteration); converged rays are
        # written back as they leave
        oa, da, ua, ta = o, d, uv, t
        for _ in range(iters):
            if act.size == 0:
                break
            s, su, sv = self._eval(k, ua[:, 0], ua[:, 1], 1)
            f = s - oa - ta[:, None] * da
            c = -da
            sxc = _cross(sv, c)
            det = _dot(su, sxc)
            with np.errstate(divide="ignore", invalid="ignore"):
                du = -_dot(f, sxc) / det
                dv = -_dot(su, _cross(f, c)) / det
                dt = -_dot(su, _cross(sv, f)) / det
            sing = ~np.isfinite(du) | ~np.isfinite(dv) | ~np.isfinite(dt)
            du[sing], dv[sing], dt[sing] = 0.0, 0.0, 0.0
            step = np.column_stack([du, dv])
            # limit the parameter step to a quarter of the domain (damping far from the root)
            big = np.abs(step / span).max(axis=1)
            scale = np.where(big > 0.25, 0.25 / np.maximum(big, 1e-300), 1.0)
            step *= scale[:, None]
            dt *= scale
            new = ua + step
            # nudge singular (degenerate-point) iterates towards the domain centre
            new[sing] += 1e-6 * span * np.sign((lo + hi) / 2 - new[sing])
            for ax, per in enumerate((pu, pv)):
                if per:
                    new[:, ax] = lo[ax] + np.mod(new[:, ax] - lo[ax], span[ax])
                else:  # allow a small excursion so that Newton can cross an edge and be caught
                    new[:, ax] = np.clip(new[:, ax], lo[ax] - 0.5 * span[ax],
                                         hi[ax] + 0.5 * span[ax])
            ua = new
            ta = ta + dt
            conv = (np.linalg.norm(f, axis=1) < _NEWTON_TOL_MM) & ~sing
            conv &= np.abs(dt) < 1e-9
            if conv.any():
                uv[act[conv]] = ua[conv]
                t[act[conv]] = ta[conv]
                keep = np.flatnonzero(~conv)  # np.take: faster than a boolean mask
                act, oa, da = act[keep], np.take(oa, keep, axis=0), np.take(da, keep, axis=0)
                ua, ta = np.take(ua, keep, axis=0), ta[keep]
        uv[act] = ua
        t[act] = ta
        inside = np.all((uv >= lo - _DOMAIN_SLACK * span) & (uv <= hi + _DOMAIN_SLACK * span),
                        axis=1)
        uv = np.clip(uv, lo, hi)
        # final check on the clamped parameters: the point must lie on the ray
        s = self._eval(k, uv[:, 0], uv[:, 1], 0)[0]
        off = s - o
        tt = _dot(off, d) / _dot(d, d)
        resid = np.linalg.norm(off - tt[:, None] * d, axis=1)
        ok = inside & np.isfinite(resid) & (resid < 1e-7)
        return np.where(ok, tt, np.nan), uv, ok

    def intersect(self, origins, directions, tolerance_mm=0.2):
        """First intersection of rays with the exact surface.

        Embree ray cast (:meth:`mesh_cast`, first hit) on :meth:`mesh`, then :meth:`refine`
        from the hit's barycentric interpolation of the face's vertex parameters. Rays that
        miss the mesh, or whose refinement fails, have ``hit`` False and NaN values. A ray
        grazing the surface within about the mesh tolerance of a silhouette may miss the
        (inscribed) mesh although it touches the exact surface.

        Parameters
        ----------
        origins : array_like, shape (N, 3) or (3,)
        directions : array_like, shape (N, 3)
            Ray directions (normalised here).

        Returns
        -------
        dict
            ``t`` (N,) mm along the unit direction, ``points`` (N, 3) mm, ``normals`` (N, 3) unit
            outward, ``surface_id`` (N,) int (-1 for no hit), ``uv`` (N, 2), ``hit`` (N,) bool.
        """
        o, d = _as_rays(origins, directions)
        d = _unit(d)
        n = len(d)
        out = {
            "t": np.full(n, np.nan),
            "points": np.full((n, 3), np.nan),
            "normals": np.full((n, 3), np.nan),
            "surface_id": np.full(n, -1, dtype=np.int64),
            "uv": np.full((n, 2), np.nan),
            "hit": np.zeros(n, bool),
        }
        if n == 0:
            return out
        m = self.mesh(tolerance_mm)
        ray, tri, t0, bary = self.mesh_cast(o, d, tolerance_mm)
        if ray.size == 0:
            return out
        fv = m.faces[tri]
        sid0 = m.metadata["face_surface_id"][tri]
        uv0 = np.einsum("ni,nij->nj", bary, m.metadata["vertex_uv"][fv])
        o_r, d_r = np.take(o, ray, axis=0), np.take(d, ray, axis=0)
        facing = np.sign(_dot(np.take(m.face_normals, tri, axis=0), d_r))
        t, p, nrm, sid, ok, uv = self.refine(o_r, d_r, t0, sid0, uv0,
                                             max_dt=max(20.0, 100 * tolerance_mm), facing=facing,
                                             return_uv=True)
        r = ray[ok]
        out["t"][r], out["points"][r], out["normals"][r] = t[ok], p[ok], nrm[ok]
        out["surface_id"][r], out["uv"][r], out["hit"][r] = sid[ok], uv[ok], True
        return out

    # ---- closest point ------------------------------------------------------------------------
    def closest_point(self, points, k_candidates=32):
        """Exact closest points on the true surface.

        Candidates: the surfaces of the ``k_candidates`` nearest mesh vertices (a KD-tree), each
        started from its nearest vertex's ``(u, v)``, then further starts in other parts of a
        surface (1/8 x 1/8 cells of its domain) whose vertex is near enough to beat the best
        distance so far; from each start, projected Newton's method on
        ``|S_k(u, v) - q|^2`` with the parameters clamped to the domain (an active set on the
        domain edges, Gauss-Newton with Levenberg damping where the Hessian is not positive,
        step halving if the distance grows). The minimum over the candidates is returned.

        Parameters
        ----------
        points : array_like, shape (N, 3)
            Query points (mm, object frame).

        Returns
        -------
        closest : ndarray, shape (N, 3)
        distance : ndarray, shape (N,) mm
        surface_id : ndarray, shape (N,) int
        """
        q = _as_points(points)
        closest, dist, sid, _ = self._closest_generic(q, k_candidates)
        return closest, dist, sid

    def distance(self, points):
        """Distance (mm) from each point (N, 3) to the exact surface, shape (N,)."""
        return self.closest_point(points)[1]

    def closest_point_uv(self, points, k_candidates=32):
        """Like :meth:`closest_point` but also returns the surface parameters (N, 2)."""
        return self._closest_generic(_as_points(points), k_candidates)

    def _closest_generic(self, q, k_candidates):
        n = len(q)
        vd, vs, vuv = self._candidates_near(q, k_candidates)
        k = vs.shape[1]
        # stage 1: one start per surface, its nearest vertex
        first = np.ones((n, k), bool)
        for j in range(1, k):
            first[:, j] = np.all(vs[:, :j] != vs[:, j : j + 1], axis=1)
        best = self._run_starts(q, *np.nonzero(first), vs, vuv, None)
        # stage 2: further local minima on one surface (the two sides of the handle, of the rim):
        # one start per 1/8 x 1/8 cell of a surface's domain, only where the start vertex is
        # near enough to beat the best so far (every surface point is within the longest mesh
        # edge / sqrt(3) of a vertex of its triangle, plus the chord error)
        dom = np.array([self._domain(s) for s in range(self.n_surfaces)])[vs]
        cell = np.floor(8 * (vuv - dom[..., [0, 2]]) / (dom[..., [1, 3]] - dom[..., [0, 2]]))
        key = (vs * 9 + np.clip(cell[..., 0], 0, 8)) * 9 + np.clip(cell[..., 1], 0, 8)
        again = ~first & (vd < best[1][:, None] + self._reach()[vs])
        for j in range(1, k):
            again[:, j] &= np.all(key[:, :j] != key[:, j : j + 1], axis=1)
        if again.any():
            best = self._run_starts(q, *np.nonzero(again), vs, vuv, best)
        return best[0], best[1], best[2], best[3]

    def _run_starts(self, q, pi, cj, vs, vuv, best):
        """Projected Newton from start (pi, cj) pairs; keep the per-point minimum in ``best``."""
        n = len(q)
        if best is None:
            best = (np.full((n, 3), np.nan), np.full(n, np.inf), np.full(n, -1, dtype=np.int64),
                    np.full((n, 2), np.nan))
        bp, bd, bs, buv = (b.copy() for b in best)
        cs, cuv = vs[pi, cj], vuv[pi, cj]
        m = len(pi)
        all_p, all_d, all_uv = np.empty((m, 3)), np.empty(m), np.empty((m, 2))
        for s, idx in _groups(cs, self.n_surfaces):
            uv, p = self._project_k(s, q[pi[idx]], cuv[idx])
            all_p[idx], all_uv[idx] = p, uv
            all_d[idx] = np.linalg.norm(p - q[pi[idx]], axis=1)
        all_d = np.where(np.isfinite(all_d), all_d, np.inf)
        order = np.lexsort((all_d, pi))
        head = order[np.r_[True, pi[order][1:] != pi[order][:-1]]]
        w = pi[head]
        better = all_d[head] < bd[w]
        w, head = w[better], head[better]
        bp[w], bd[w], bs[w], buv[w] = all_p[head], all_d[head], cs[head], all_uv[head]
        return bp, bd, bs, buv

    def _reach(self):
        """Per surface, a bound (mm) on the distance from a surface point to the nearest vertex:
        longest edge / sqrt(3) (a triangle's circumradius bound) + the mesh tolerance."""
        cache = self.__dict__.setdefault("_reach_cache", [])
        if not cache:
            m = self.mesh()
            tri = m.vertices[m.faces]
            edge = np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=2).max(axis=1)
            reach = np.zeros(self.n_surfaces)
            np.maximum.at(reach, m.metadata["face_surface_id"], edge)
            cache.append(reach / math.sqrt(3.0) + m.metadata["tolerance_mm"])
        return cache[0]

    def _project_k(self, k, q, uv, iters=40):
        """Projected Newton for ``min |S_k(u, v) - q|^2`` over the domain box."""
        u0, u1, v0, v1 = self._domain(k)
        pu, pv = self._periodic(k)
        lo, hi = np.array([u0, v0]), np.array([u1, v1])
        span = hi - lo
        periodic = np.array([pu, pv])
        uv = np.clip(np.asarray(uv, dtype=float).copy(), lo, hi)
        act = np.arange(len(q))
        for _ in range(iters):
            if act.size == 0:
                break
            s, su, sv, suu, suv, svv = self._eval(k, uv[act, 0], uv[act, 1], 2)
            r = s - q[act]
            f0 = _dot(r, r)
            gu, gv = _dot(su, r), _dot(sv, r)
            a, b, c = _dot(su, su), _dot(su, sv), _dot(sv, sv)
            ha, hb, hc = a + _dot(suu, r), b + _dot(suv, r), c + _dot(svv, r)
            det = ha * hc - hb * hb
            npd = ~((ha > 0) & (det > 1e-12 * np.maximum(ha * hc, 1e-300)))
            lam = 1e-9 * (a + c) + 1e-300
            ha = np.where(npd, a + lam, ha)
            hc = np.where(npd, c + lam, hc)
            hb = np.where(npd, b, hb)
            # active set: a coordinate at a bound whose gradient points outwards stays fixed
            cur = uv[act]
            at_lo = (cur <= lo) & ~periodic
            at_hi = (cur >= hi) & ~periodic
            g = np.column_stack([gu, gv])
            fixed = (at_lo & (g > 0)) | (at_hi & (g < 0))
            fu, fv = ~fixed[:, 0], ~fixed[:, 1]
            both = fu & fv
            det2 = ha * hc - hb * hb
            with np.errstate(divide="ignore", invalid="ignore"):
                du = np.where(both, -(hc * gu - hb * gv) / det2, np.where(fu, -gu / ha, 0.0))
                dv = np.where(both, -(ha * gv - hb * gu) / det2, np.where(fv, -gv / hc, 0.0))
            step = np.nan_to_num(np.column_stack([du, dv]))
            big = np.abs(step / span).max(axis=1)
            step *= np.where(big > 0.25, 0.25 / np.maximum(big, 1e-300), 1.0)[:, None]
            # backtracking: halve the step while the distance grows (beyond round-off)
            trial = self._wrap_clip(cur + step, lo, hi, periodic)
            stuck = np.zeros(len(act), bool)
            chk = np.arange(len(act))
            for h in range(12):
                st = self._eval(k, trial[chk, 0], trial[chk, 1], 0)[0] - q[act[chk]]
                worse = _dot(st, st) > f0[chk] * (1 + 1e-12) + 1e-24
                chk = chk[worse]
                if chk.size == 0:
                    break
                if h == 11:
                    stuck[chk] = True
                    trial[chk] = cur[chk]
                    break
                step[chk] *= 0.5
                trial[chk] = self._wrap_clip(cur[chk] + step[chk], lo, hi, periodic)
            moved = np.abs(trial - cur).max(axis=1)
            uv[act] = trial
            conv = (moved <= 1e-12 * span.max()) | stuck
            act = act[~conv]
        p = self._eval(k, uv[:, 0], uv[:, 1], 1)[0]
        return uv, p

    @staticmethod
    def _wrap_clip(uv, lo, hi, periodic):
        out = np.clip(uv, lo, hi)
        for ax in range(2):
            if periodic[ax]:
                out[:, ax] = lo[ax] + np.mod(uv[:, ax] - lo[ax], hi[ax] - lo[ax])
        return out

    # ---- sampling, bounds, serialisation ------------------------------------------------------
    def sample_surface(self, n, seed=0):
        """Roughly area-uniform random points on the exact surface.

        Triangles of :meth:`mesh` are drawn with probability proportional to their area, a
        uniform barycentric point is drawn in each, and its interpolated ``(u, v)`` is evaluated
        on the exact surface.

        Returns
        -------
        points : ndarray, shape (n, 3) mm
        normals : ndarray, shape (n, 3) unit outward
        surface_id : ndarray, shape (n,) int
        """
        n = int(n)
        rng = np.random.default_rng(seed)
        m = self.mesh()
        area = m.area_faces
        f = rng.choice(len(area), size=n, p=area / area.sum())
        r1, r2 = rng.random(n), rng.random(n)
        s1 = np.sqrt(r1)
        bary = np.column_stack([1 - s1, s1 * (1 - r2), s1 * r2])
        fv = m.faces[f]
        uv = np.einsum("ni,nij->nj", bary, m.metadata["vertex_uv"][fv])
        sid = m.metadata["face_surface_id"][f]
        return self.surface_points(sid, uv), self.surface_normals(sid, uv), sid

    @property
    def bounds(self):
        """Axis-aligned bounds of the exact surface, shape (2, 3) mm (min row, max row)."""
        cache = self.__dict__.setdefault("_bounds_cache", [])
        if not cache:
            cache.append(self._bounds())
        return cache[0].copy()

    def _bounds(self):
        pts = []
        for k in range(self.n_surfaces):
            u0, u1, v0, v1 = self._domain(k)
            uu, vv = np.meshgrid(np.linspace(u0, u1, 201), np.linspace(v0, v1, 201))
            pts.append(self._eval(k, uu.ravel(), vv.ravel(), 1)[0])
        pts = np.concatenate(pts)
        return np.array([pts.min(axis=0), pts.max(axis=0)])

    def params(self) -> dict:
        """The constructor parameters, JSON-ready."""
        out = {}
        for f in dataclasses.fields(self):
            val = getattr(self, f.name)
            out[f.name] = list(val) if isinstance(val, tuple) else val
        return out

    def to_dict(self) -> dict:
        """``{"type": "nurbscan.scene", "version": 1, "name": ..., <parameters>}``."""
        return {"type": SCENE_TYPE, "version": SCENE_VERSION, "name": self.name, **self.params()}

    @classmethod
    def from_dict(cls, d):
        """Inverse of :meth:`to_dict` (any scene type)."""
        return scene_from_dict(d)


def _groups(sid, n_surfaces):
    """Yield ``(k, indices)`` for each surface id present in ``sid`` (sorted once)."""
    sid = np.asarray(sid, dtype=np.int64)
    if sid.size == 0:
        return
    order = np.argsort(sid, kind="stable")
    s = sid[order]
    cuts = np.flatnonzero(np.diff(s)) + 1
    for chunk in np.split(order, cuts):
        k = int(sid[chunk[0]])
        if 0 <= k < n_surfaces:
            yield k, chunk


# --------------------------------------------------------------------------------------------
# Utah teapot
# --------------------------------------------------------------------------------------------
#: Orientation of ``Su x Sv`` of the 32 teapot patches (+1 outward): all inward. Found by the
#: generalised winding number of the mesh at points pushed off each patch (tested).
_TEAPOT_ORIENTATION = np.array([-1.0] * 32)


@dataclass(frozen=True)
class Teapot(Scene):
    """The Utah teapot: 32 bicubic Bezier patches (Newell 1975), ``scale`` mm per model unit.

    Patches 0-3 rim, 4-11 body, 12-15 handle, 16-19 spout, 20-27 lid (20-23 the knob, whose
    row u = 0 collapses to the top point), 28-31 bottom (row u = 0 collapses to the centre,
    at z = 0). The surface is the union of the patches as they are: the handle and spout pass
    through the body, the spout is open, and a 0.1-unit annular gap separates the lid from the
    rim.

    ``S_k(u, v) = sum_ij B_i(u) B_j(v) P_kij`` (Piegl and Tiller eq. 1.9), ``P`` =
    :attr:`patches`. In the data ``Su x Sv`` points into the pot on all 32 patches (checked
    by the generalised winding number in the tests), so the outward normal is
    ``-(Su x Sv) / |Su x Sv|``.
    """

    scale: float = 37.0
    name = "teapot"

    def __post_init__(self):
        object.__setattr__(self, "scale", _positive(self.scale, "teapot scale"))

    @property
    def patches(self):
        """Control points, shape (32, 4, 4, 3) mm."""
        cache = self.__dict__.setdefault("_patches", [])
        if not cache:
            cache.append(load_bpt(None, self.scale))
        return cache[0]

    @property
    def n_surfaces(self):
        return len(self.patches)

    def _orientation(self, k):
        return float(_TEAPOT_ORIENTATION[k])

    def _eval(self, k, u, v, order=1):
        # sum_ij a_i b_j P_ij, contracted one index at a time; the partial sums over i are
        # shared by S, Sv (and Svv), those of the u-derivative by Su (and Suv)
        p = self.patches[k]
        bu, bv = bernstein3(u), bernstein3(v)
        a0 = np.einsum("ni,ijc->njc", bu, p)
        out = [np.einsum("njc,nj->nc", a0, bv)]
        if order < 1:
            return out
        du, dv = bernstein3(u, 1), bernstein3(v, 1)
        a1 = np.einsum("ni,ijc->njc", du, p)
        out += [np.einsum("njc,nj->nc", a1, bv), np.einsum("njc,nj->nc", a0, dv)]
        if order >= 2:
            a2 = np.einsum("ni,ijc->njc", bernstein3(u, 2), p)
            out += [np.einsum("njc,nj->nc", a2, bv), np.einsum("njc,nj->nc", a1, dv),
                    np.einsum("njc,nj->nc", a0, bernstein3(v, 2))]
        return out

    def _grid_size(self, k, tol):
        # second derivatives are Bezier with control points 6 D2 P, 9 Du Dv P (convex hull bound)
        p = self.patches[k]
        muu = np.linalg.norm(6 * np.diff(p, 2, axis=0), axis=-1).max()
        mvv = np.linalg.norm(6 * np.diff(p, 2, axis=1), axis=-1).max()
        muv = np.linalg.norm(9 * np.diff(np.diff(p, axis=0), axis=1), axis=-1).max()
        # linear interpolation error on a triangle <= (muu hu^2 + 2 muv hu hv + mvv hv^2) / 8
        nu = max(4, math.ceil(math.sqrt(muu / (2.0 * tol))))
        nv = max(4, math.ceil(math.sqrt(mvv / (2.0 * tol))))
        while (muu / nu**2 + 2 * muv / (nu * nv) + mvv / nv**2) / 8 > tol:
            nu, nv = nu + 1, nv + 1
        return nu, nv


# --------------------------------------------------------------------------------------------
# analytic scenes
# --------------------------------------------------------------------------------------------
def _arc_steps(radius, angle, tol):
    """Intervals so that chords of an arc (radius, angle) deviate < tol/2 (sagitta)."""
    c = max(-1.0, 1.0 - 0.5 * tol / radius)
    dmax = 2.0 * math.acos(c) if c > -1 else math.pi
    return max(4, math.ceil(angle / max(dmax, 1e-9)))


def _pick_root(t_a, t_b, t0, facing=None, sign_a=None):
    """Of two roots per ray (NaN if absent), the one nearest ``t0``; where ``facing`` is not 0,
    the one whose ``sign(d . n)`` (``sign_a`` for ``t_a``, the opposite for ``t_b``: a ray enters
    and leaves a quadric) equals ``facing``."""
    da = np.abs(t_a - t0)
    db = np.abs(t_b - t0)
    da = np.where(np.isfinite(da), da, np.inf)
    db = np.where(np.isfinite(db), db, np.inf)
    pick_a = da <= db
    if facing is not None:
        pick_a = np.where(facing == 0, pick_a, sign_a == facing)
    return np.where(pick_a, t_a, t_b)


def _first_hit_dict(scene, o, d, t, ks, uvs):
    """Intersection dict from candidate crossings ``t`` (N, C) (inf / NaN = none) of surfaces
    ``ks`` (C,) with parameters ``uvs`` (N, C, 2): the smallest ``t`` wins."""
    n = len(d)
    t = np.where(np.isfinite(t), t, np.inf)
    j = np.argmin(t, axis=1) if n else np.zeros(0, np.int64)
    tt = t[np.arange(n), j]
    hit = np.isfinite(tt)
    sid = np.where(hit, ks[j], -1)
    uv = np.where(hit[:, None], uvs[np.arange(n), j], np.nan)
    pts = np.full((n, 3), np.nan)
    nrm = np.full((n, 3), np.nan)
    if hit.any():
        pts[hit] = scene.surface_points(sid[hit], uv[hit])
        nrm[hit] = scene.surface_normals(sid[hit], uv[hit])
    return {"t": np.where(hit, tt, np.nan), "points": pts, "normals": nrm, "surface_id": sid,
            "uv": uv, "hit": hit}


def _sorted_roots(a, b, c):
    """Roots ``t_lo <= t_hi`` of ``a t^2 + 2 b t + c = 0`` (NaN where none), stable formula."""
    disc = b * b - a * c
    sq = np.sqrt(np.where(disc >= 0, disc, np.nan))
    qq = -(b + np.copysign(sq, b))
    with np.errstate(divide="ignore", invalid="ignore"):
        r1, r2 = qq / a, c / qq
    return np.fmin(r1, r2), np.fmax(r1, r2)


@dataclass(frozen=True)
class Sphere(Scene):
    """Sphere of ``radius`` mm about ``center`` (mm); one surface, ``u`` = polar angle from +z in
    [0, pi], ``v`` = azimuth in [0, 2 pi). Closed-form ray intersection and projection."""

    radius: float = 60.0
    center: tuple = (0.0, 0.0, 60.0)
    name = "sphere"
    self_shadowing = False

    def __post_init__(self):
        object.__setattr__(self, "radius", _positive(self.radius, "sphere radius"))
        object.__setattr__(self, "center", _vec3(self.center, "sphere center"))

    @property
    def n_surfaces(self):
        return 1

    def _domain(self, k):
        return (0.0, math.pi, 0.0, 2 * math.pi)

    def _periodic(self, k):
        return (False, True)

    def _eval(self, k, u, v, order=1):
        r, c = self.radius, np.array(self.center)
        su, cu, sv, cv = np.sin(u), np.cos(u), np.sin(v), np.cos(v)
        s = c + r * np.column_stack([su * cv, su * sv, cu])
        d_u = r * np.column_stack([cu * cv, cu * sv, -su])
        d_v = r * np.column_stack([-su * sv, su * cv, 0 * u])
        out = [s, d_u, d_v]
        if order >= 2:
            out += [
                r * np.column_stack([-su * cv, -su * sv, -cu]),
                r * np.column_stack([-cu * sv, cu * cv, 0 * u]),
                r * np.column_stack([-su * cv, -su * sv, 0 * u]),
            ]
        return out

    def _normals_k(self, k, uv):
        u, v = uv[:, 0], uv[:, 1]
        return np.column_stack([np.sin(u) * np.cos(v), np.sin(u) * np.sin(v), np.cos(u)])

    def _grid_size(self, k, tol):
        n = _arc_steps(self.radius, math.pi, tol)
        return n, 2 * n

    def _uv_of(self, p):
        w = p - np.array(self.center)
        u = np.arccos(np.clip(w[:, 2] / np.linalg.norm(w, axis=1), -1, 1))
        v = np.mod(np.arctan2(w[:, 1], w[:, 0]), 2 * math.pi)
        return np.column_stack([u, v])

    def _refine_impl(self, o, d, t0, sid, uv, max_dt, facing):
        # |o + t d - c|^2 = r^2:  a t^2 + 2 b t + cc = 0
        w = o - np.array(self.center)
        lo, hi = _sorted_roots(_dot(d, d), _dot(w, d), _dot(w, w) - self.radius**2)
        t = _pick_root(lo, hi, t0, facing, -1.0)  # the ray enters at the lower root
        ok = np.isfinite(t) & (np.abs(t - t0) <= max_dt)
        p = o + t[:, None] * d
        uvn = np.where(ok[:, None], self._uv_of(np.where(ok[:, None], p, 1.0)), np.nan)
        return np.where(ok, t, np.nan), uvn, np.zeros(len(t), np.int64), ok

    def intersect(self, origins, directions, tolerance_mm=0.2):
        """First intersection in closed form (no mesh): the smallest root with ``t > 0``."""
        o, d = _as_rays(origins, directions)
        d = _unit(d)
        w = o - np.array(self.center)
        lo, hi = _sorted_roots(_dot(d, d), _dot(w, d), _dot(w, w) - self.radius**2)
        t = np.column_stack([lo, hi])
        t = np.where(t > 0, t, np.inf)
        p = o[:, None, :] + np.nan_to_num(t, posinf=0.0)[:, :, None] * d[:, None, :]
        uvs = np.stack([self._uv_of(p[:, 0]), self._uv_of(p[:, 1])], axis=1)
        return _first_hit_dict(self, o, d, t, np.array([0, 0]), uvs)

    def closest_point(self, points, k_candidates=16):
        q = _as_points(points)
        c = np.array(self.center)
        w = q - c
        nw = np.linalg.norm(w, axis=1)
        dirn = np.where(nw[:, None] > 0, w / np.where(nw > 0, nw, 1)[:, None], [0, 0, 1])
        return c + self.radius * dirn, np.abs(nw - self.radius), np.zeros(len(q), np.int64)

    def _bounds(self):
        c = np.array(self.center)
        return np.array([c - self.radius, c + self.radius])


@dataclass(frozen=True)
class Torus(Scene):
    """Torus about the z axis through ``center``: tube of radius ``minor`` around a circle of
    radius ``major`` (mm). ``u`` = azimuth, ``v`` = angle around the tube (both [0, 2 pi)),
    ``S = c + ((R + r cos v) cos u, (R + r cos v) sin u, r sin v)``. Rays: Newton on the exact
    signed distance ``sqrt((rho - R)^2 + z^2) - r`` along the ray from the mesh hit (the root
    of the quartic nearest the hit); closest points in closed form."""

    major: float = 60.0
    minor: float = 20.0
    center: tuple = (0.0, 0.0, 20.0)
    name = "torus"

    def __post_init__(self):
        object.__setattr__(self, "major", _positive(self.major, "torus major radius"))
        object.__setattr__(self, "minor", _positive(self.minor, "torus minor radius"))
        object.__setattr__(self, "center", _vec3(self.center, "torus center"))
        if self.minor >= self.major:
            raise NurbscanError(
                f"torus: minor radius {self.minor} must be below the major radius {self.major}"
            )

    @property
    def n_surfaces(self):
        return 1

    def _domain(self, k):
        return (0.0, 2 * math.pi, 0.0, 2 * math.pi)

    def _periodic(self, k):
        return (True, True)

    def _eval(self, k, u, v, order=1):
        big, r, c = self.major, self.minor, np.array(self.center)
        cu, su, cv, sv = np.cos(u), np.sin(u), np.cos(v), np.sin(v)
        rho = big + r * cv
        s = c + np.column_stack([rho * cu, rho * su, r * sv])
        d_u = np.column_stack([-rho * su, rho * cu, 0 * u])
        d_v = np.column_stack([-r * sv * cu, -r * sv * su, r * cv])
        out = [s, d_u, d_v]
        if order >= 2:
            out += [
                np.column_stack([-rho * cu, -rho * su, 0 * u]),
                np.column_stack([r * sv * su, -r * sv * cu, 0 * u]),
                np.column_stack([-r * cv * cu, -r * cv * su, -r * sv]),
            ]
        return out

    def _normals_k(self, k, uv):
        u, v = uv[:, 0], uv[:, 1]
        return np.column_stack([np.cos(v) * np.cos(u), np.cos(v) * np.sin(u), np.sin(v)])

    def _grid_size(self, k, tol):
        return (_arc_steps(self.major + self.minor, 2 * math.pi, tol),
                _arc_steps(self.minor, 2 * math.pi, tol))

    def _sdf(self, p):
        w = p - np.array(self.center)
        rho = np.hypot(w[:, 0], w[:, 1])
        q = np.column_stack([rho - self.major, w[:, 2]])
        nq = np.linalg.norm(q, axis=1)
        # gradient of the distance: (q0 * rho_hat, q1) / |q|
        with np.errstate(invalid="ignore", divide="ignore"):
            rh = np.column_stack([w[:, 0], w[:, 1]]) / rho[:, None]
            g = np.column_stack([q[:, 0:1] * rh, q[:, 1:2]]) / nq[:, None]
        return nq - self.minor, g

    def _uv_of(self, p):
        w = p - np.array(self.center)
        u = np.mod(np.arctan2(w[:, 1], w[:, 0]), 2 * math.pi)
        rho = np.hypot(w[:, 0], w[:, 1])
        v = np.mod(np.arctan2(w[:, 2], rho - self.major), 2 * math.pi)
        return np.column_stack([u, v])

    def _sdf_newton(self, o, d, t, t0, max_dt, facing):
        """Newton on ``sdf(o + t d) = 0`` in ``t``; ok where converged on the ``facing`` side."""
        t = t.copy()
        act = np.flatnonzero(np.isfinite(t))
        for _ in range(60):
            if act.size == 0:
                break
            f, g = self._sdf(o[act] + t[act, None] * d[act])
            slope = _dot(g, d[act])
            with np.errstate(divide="ignore", invalid="ignore"):
                dt = -f / slope
            dt = np.clip(np.nan_to_num(dt, nan=0.0), -self.minor / 2, self.minor / 2)
            t[act] += dt
            act = act[np.abs(f) >= _NEWTON_TOL_MM]
        f, g = self._sdf(o + t[:, None] * d)
        ok = np.isfinite(f) & (np.abs(f) < 1e-7) & (np.abs(t - t0) <= max_dt)
        side = np.sign(_dot(g, d))
        return t, ok, ok & (facing != 0) & (side == -facing)

    def _refine_impl(self, o, d, t0, sid, uv, max_dt, facing):
        t, ok, wrong = self._sdf_newton(o, d, t0, t0, max_dt, facing)
        ok &= ~wrong
        w = np.flatnonzero(wrong)
        for fac in (1.0, 2.0, 4.0, 8.0):  # the other root of a silhouette sliver
            if w.size == 0:
                break
            tj, okj, wrj = self._sdf_newton(o[w], d[w], t0[w] - fac * (t[w] - t0[w]), t0[w],
                                            max_dt, facing[w])
            okj &= ~wrj
            t[w[okj]], ok[w[okj]] = tj[okj], True
            w = w[~okj]
        p = o + np.where(ok, t, 0.0)[:, None] * d
        uvn = np.where(ok[:, None], self._uv_of(p), np.nan)
        return np.where(ok, t, np.nan), uvn, np.zeros(len(t), np.int64), ok

    def closest_point(self, points, k_candidates=16):
        q = _as_points(points)
        c = np.array(self.center)
        w = q - c
        rho = np.hypot(w[:, 0], w[:, 1])
        rh = np.where(rho[:, None] > 0, w[:, :2] / np.where(rho > 0, rho, 1)[:, None], [1, 0])
        ring = np.column_stack([self.major * rh, np.zeros(len(q))])
        e = w - ring
        ne = np.linalg.norm(e, axis=1)
        dirn = np.where(ne[:, None] > 0, e / np.where(ne > 0, ne, 1)[:, None],
                        np.column_stack([rh, np.zeros(len(q))]))
        return c + ring + self.minor * dirn, np.abs(ne - self.minor), np.zeros(len(q), np.int64)

    def _bounds(self):
        c = np.array(self.center)
        e = np.array([self.major + self.minor] * 2 + [self.minor])
        return np.array([c - e, c + e])


@dataclass(frozen=True)
class Cylinder(Scene):
    """An open cup standing on the table: a cylinder of outer ``radius``, ``height`` and wall and
    bottom ``thickness`` (mm), axis z, bottom at z = 0.

    Surfaces (``u`` = azimuth in [0, 2 pi) throughout):

    0. outer wall, r = R, ``v`` = z in [0, H];
    1. inner wall, r = R - th, ``v`` = z in [th, H] (normal towards the axis);
    2. rim annulus, z = H, ``v`` = r in [R - th, R] (normal +z);
    3. inner bottom disk, z = th, ``v`` = r in [0, R - th] (normal +z);
    4. outer bottom disk, z = 0, ``v`` = r in [0, R] (normal -z).

    Ray intersection and closest points are closed form.
    """

    radius: float = 40.0
    height: float = 100.0
    thickness: float = 3.0
    name = "cylinder"

    def __post_init__(self):
        for f in ("radius", "height", "thickness"):
            object.__setattr__(self, f, _positive(getattr(self, f), f"cylinder {f}"))
        if self.thickness >= min(self.radius, self.height):
            raise NurbscanError(
                f"cylinder thickness {self.thickness}: must be below the radius and the height"
            )

    @property
    def n_surfaces(self):
        return 5

    def _pieces(self):
        big, h, th = self.radius, self.height, self.thickness
        # kind, radius / z, v-range, orientation
        return [
            ("wall", big, (0.0, h), 1.0),
            ("wall", big - th, (th, h), -1.0),
            ("disk", h, (big - th, big), 1.0),
            ("disk", th, (0.0, big - th), 1.0),
            ("disk", 0.0, (0.0, big), -1.0),
        ]

    def _domain(self, k):
        v0, v1 = self._pieces()[k][2]
        return (0.0, 2 * math.pi, v0, v1)

    def _periodic(self, k):
        return (True, False)

    def _eval(self, k, u, v, order=1):
        kind, val, _, _ = self._pieces()[k]
        cu, su, z0 = np.cos(u), np.sin(u), 0 * u
        if kind == "wall":
            s = np.column_stack([val * cu, val * su, v])
            d_u = np.column_stack([-val * su, val * cu, z0])
            d_v = np.column_stack([z0, z0, 1 + z0])
            dd = [np.column_stack([-val * cu, -val * su, z0]), np.zeros_like(s), np.zeros_like(s)]
        else:
            s = np.column_stack([v * cu, v * su, val + z0])
            d_u = np.column_stack([-v * su, v * cu, z0])
            d_v = np.column_stack([cu, su, z0])
            dd = [np.column_stack([-v * cu, -v * su, z0]), np.column_stack([-su, cu, z0]),
                  np.zeros_like(s)]
        return [s, d_u, d_v] + (dd if order >= 2 else [])

    def _normals_k(self, k, uv):
        kind, _, _, sign = self._pieces()[k]
        u = uv[:, 0]
        if kind == "wall":
            return sign * np.column_stack([np.cos(u), np.sin(u), 0 * u])
        return sign * np.column_stack([0 * u, 0 * u, 1 + 0 * u])

    def _orientation(self, k):
        kind, _, _, sign = self._pieces()[k]
        # wall: Su x Sv = (r cos u, r sin u, 0) outward; disk: Su x Sv = (0, 0, -r) downward
        return sign if kind == "wall" else -sign

    def _grid_size(self, k, tol):
        kind, val, (v0, v1), _ = self._pieces()[k]
        nu = _arc_steps(self.radius, 2 * math.pi, tol)
        return nu, (1 if kind == "wall" else max(1, math.ceil((v1 - v0) / 10.0)))

    def _candidates(self, o, d):
        """All ray crossings with the 5 pieces: ``t`` (N, 7), surface id (7,), ``uv`` (N, 7, 2);
        NaN where a crossing is absent or off the piece."""
        ts, ks, uvs = [], [], []
        slack = 1e-9
        for k, (kind, val, (v0, v1), _) in enumerate(self._pieces()):
            if kind == "wall":
                a = d[:, 0] ** 2 + d[:, 1] ** 2
                b = o[:, 0] * d[:, 0] + o[:, 1] * d[:, 1]
                c = o[:, 0] ** 2 + o[:, 1] ** 2 - val**2
                roots = _sorted_roots(a, b, c)
            else:
                with np.errstate(divide="ignore", invalid="ignore"):
                    roots = ((val - o[:, 2]) / d[:, 2],)
            for t in roots:
                p = o + np.where(np.isfinite(t), t, 0.0)[:, None] * d
                v = p[:, 2] if kind == "wall" else np.hypot(p[:, 0], p[:, 1])
                good = np.isfinite(t) & (v >= v0 - slack) & (v <= v1 + slack)
                u = np.mod(np.arctan2(p[:, 1], p[:, 0]), 2 * math.pi)
                ts.append(np.where(good, t, np.nan))
                ks.append(k)
                uvs.append(np.column_stack([u, np.clip(v, v0, v1)]))
        return np.column_stack(ts), np.array(ks), np.stack(uvs, axis=1)

    def _refine_impl(self, o, d, t0, sid, uv, max_dt, facing):
        # every crossing of every piece; keep the one nearest t0 on the facing side
        t, ks, uvs = self._candidates(o, d)
        n = len(d)
        cost = np.abs(t - t0[:, None])
        for j, k in enumerate(ks):
            side = np.sign(_dot(d, self._normals_k(k, uvs[:, j])))
            cost[(facing != 0) & (side == -facing), j] = np.nan
        cost = np.where(np.isfinite(cost) & (cost <= max_dt), cost, np.inf)
        j = np.argmin(cost, axis=1)
        ok = np.isfinite(cost[np.arange(n), j])
        return (np.where(ok, t[np.arange(n), j], np.nan), uvs[np.arange(n), j],
                np.where(ok, ks[j], -1), ok)

    def intersect(self, origins, directions, tolerance_mm=0.2):
        """First intersection in closed form (no mesh): the nearest crossing with ``t > 0``."""
        o, d = _as_rays(origins, directions)
        d = _unit(d)
        t, ks, uvs = self._candidates(o, d)
        t = np.where(t > 0, t, np.inf)
        return _first_hit_dict(self, o, d, t, ks, uvs)

    def closest_point(self, points, k_candidates=16):
        q = _as_points(points)
        n = len(q)
        rho = np.hypot(q[:, 0], q[:, 1])
        rh = np.where(rho[:, None] > 0, q[:, :2] / np.where(rho > 0, rho, 1)[:, None], [1, 0])
        best_d = np.full(n, np.inf)
        best_p = np.full((n, 3), np.nan)
        best_s = np.full(n, -1, dtype=np.int64)
        for k, (kind, val, (v0, v1), _) in enumerate(self._pieces()):
            if kind == "wall":  # ruled surface: same azimuth, z clamped
                p = np.column_stack([val * rh, np.clip(q[:, 2], v0, v1)])
            else:  # same azimuth, radius clamped, on the plane
                p = np.column_stack([np.clip(rho, v0, v1)[:, None] * rh, np.full(n, val)])
            dd = np.linalg.norm(p - q, axis=1)
            better = dd < best_d
            best_d[better], best_p[better], best_s[better] = dd[better], p[better], k
        return best_p, best_d, best_s

    def _bounds(self):
        r = self.radius
        return np.array([[-r, -r, 0.0], [r, r, self.height]])


@dataclass(frozen=True)
class Plane(Scene):
    """A plane through ``point`` with unit ``normal`` (mm): a ``size`` x ``size`` square centred
    on ``point``, or unbounded when ``size`` is None (its mesh is then a 1e5 mm square; ray
    intersection is closed form and needs no mesh). ``u``, ``v`` are mm along two orthonormal
    in-plane axes ``e1``, ``e2`` with ``e1 x e2 = normal``."""

    point: tuple = (0.0, 0.0, 0.0)
    normal: tuple = (0.0, 0.0, 1.0)
    size: float | None = 200.0
    name = "plane"
    self_shadowing = False

    def __post_init__(self):
        object.__setattr__(self, "point", _vec3(self.point, "plane point"))
        nrm = np.array(_vec3(self.normal, "plane normal"))
        if np.linalg.norm(nrm) == 0:
            raise NurbscanError("plane normal: must not be zero")
        object.__setattr__(self, "normal", tuple(float(x) for x in nrm / np.linalg.norm(nrm)))
        if self.size is not None:
            object.__setattr__(self, "size", _positive(self.size, "plane size"))

    @property
    def n_surfaces(self):
        return 1

    @property
    def axes(self):
        """In-plane unit axes ``(e1, e2)`` with ``e1 x e2 = normal``."""
        nrm = np.array(self.normal)
        ref = np.array([1.0, 0, 0]) if abs(nrm[0]) < 0.9 else np.array([0, 1.0, 0])
        e1 = _unit(ref - _dot(ref, nrm) * nrm)
        return e1, _cross(nrm, e1)

    @property
    def _half(self):
        return 0.5 * (self.size if self.size is not None else 1e5)

    def _domain(self, k):
        h = self._half
        return (-h, h, -h, h)

    def _eval(self, k, u, v, order=1):
        e1, e2 = self.axes
        s = np.array(self.point) + u[:, None] * e1 + v[:, None] * e2
        out = [s, np.broadcast_to(e1, s.shape).copy(), np.broadcast_to(e2, s.shape).copy()]
        if order >= 2:
            out += [np.zeros_like(s)] * 3
        return out

    def _grid_size(self, k, tol):
        return 1, 1

    def _refine_impl(self, o, d, t0, sid, uv, max_dt, facing):
        nrm = np.array(self.normal)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = _dot(np.array(self.point) - o, nrm) / _dot(d, nrm)
        e1, e2 = self.axes
        w = o + t[:, None] * d - np.array(self.point)
        uvn = np.column_stack([_dot(w, e1), _dot(w, e2)])
        ok = np.isfinite(t)
        if self.size is not None:
            ok &= np.all(np.abs(uvn) <= self._half * (1 + 1e-12), axis=1)
        return np.where(ok, t, np.nan), uvn, np.zeros(len(t), np.int64), ok

    def intersect(self, origins, directions, tolerance_mm=0.2):
        o, d = _as_rays(origins, directions)
        d = _unit(d)
        n = len(d)
        t, p, nrm, sid, ok, uv = self.refine(o, d, np.zeros(n), np.zeros(n, np.int64),
                                             np.zeros((n, 2)), max_dt=np.inf, return_uv=True)
        ok &= t > 0
        nan = ~ok
        t[nan], p[nan], nrm[nan], uv[nan] = np.nan, np.nan, np.nan, np.nan
        return {"t": t, "points": p, "normals": nrm, "surface_id": np.where(ok, 0, -1),
                "uv": uv, "hit": ok}

    def closest_point(self, points, k_candidates=16):
        q = _as_points(points)
        e1, e2 = self.axes
        w = q - np.array(self.point)
        uv = np.column_stack([_dot(w, e1), _dot(w, e2)])
        if self.size is not None:
            uv = np.clip(uv, -self._half, self._half)
        p = np.array(self.point) + uv[:, :1] * e1 + uv[:, 1:] * e2
        return p, np.linalg.norm(q - p, axis=1), np.zeros(len(q), np.int64)

    def _bounds(self):
        corners = self._eval(0, np.array([-1, 1, 1, -1.0]) * self._half,
                             np.array([-1, -1, 1, 1.0]) * self._half)[0]
        return np.array([corners.min(axis=0), corners.max(axis=0)])


# --------------------------------------------------------------------------------------------
# factory
# --------------------------------------------------------------------------------------------
SCENES = {"teapot": Teapot, "sphere": Sphere, "cylinder": Cylinder, "torus": Torus,
          "plane": Plane}

from .blob import Blob  # noqa: E402  (a Scene subclass in its own module, issue 33)

SCENES["blob"] = Blob


def make_scene(name: str, **params) -> Scene:
    """Build a scene by name (``teapot``, ``sphere``, ``cylinder``, ``torus``, ``plane``,
    ``blob``).

    Raises
    ------
    NurbscanError
        For an unknown name (listing the valid ones) or unknown / invalid parameters.
    """
    cls = SCENES.get(str(name).lower())
    if cls is None:
        raise NurbscanError(f"scene {name!r}: unknown, expected one of {', '.join(SCENES)}")
    valid = [f.name for f in dataclasses.fields(cls)]
    extra = sorted(set(params) - set(valid))
    if extra:
        raise NurbscanError(
            f"scene {name!r}: unknown parameter(s) {', '.join(extra)}; valid: {', '.join(valid)}"
        )
    return cls(**params)


def scene_from_dict(d: dict) -> Scene:
    """Rebuild a scene from :meth:`Scene.to_dict` output."""
    if not isinstance(d, dict) or d.get("type") != SCENE_TYPE:
        got = d.get("type") if isinstance(d, dict) else type(d).__name__
        raise NurbscanError(f"scene: expected a dict with type {SCENE_TYPE!r}, got {got!r}")
    params = {k: v for k, v in d.items() if k not in ("type", "version", "name", "pose")}
    for key in ("center", "point", "normal"):
        if key in params and isinstance(params[key], list):
            params[key] = tuple(params[key])
    scene = make_scene(d.get("name", ""), **params)
    if d.get("pose") is not None:  # a resting pose on the table (nurbscan.simulate.pose)
        from .pose import pose_from_dict

        return pose_from_dict(scene, d["pose"])
    return scene
