"""Synthetic scenes: exact surfaces, ray refinement and closest points against oracles."""

import json

import numpy as np
import pytest

from nurbscan.errors import NurbscanError
from nurbscan.simulate import Cylinder, Plane, Sphere, Teapot, Torus, make_scene, scene_from_dict
from nurbscan.simulate.scenes import bernstein3, load_bpt


@pytest.fixture(scope="module")
def teapot():
    return Teapot()


def _de_casteljau(ctrl, t):
    """Plain de Casteljau on a list of control points (works for complex t)."""
    pts = list(ctrl)
    while len(pts) > 1:
        pts = [(1 - t) * a + t * b for a, b in zip(pts[:-1], pts[1:], strict=True)]
    return pts[0]


def _patch_oracle(ctrl, u, v):
    """S(u, v) of a 4x4 control net by de Casteljau in v on every row, then in u."""
    rows = [_de_casteljau([ctrl[i, j].astype(complex) for j in range(4)], v) for i in range(4)]
    return _de_casteljau(rows, u)


def _random_rays(scene, n, seed, radius=500.0):
    """Rays from a sphere around the scene aimed at random points of its bounding box."""
    rng = np.random.default_rng(seed)
    b = scene.bounds
    c = b.mean(axis=0)
    o = rng.normal(size=(n, 3))
    o = c + radius * o / np.linalg.norm(o, axis=1, keepdims=True)
    tgt = b[0] + rng.random((n, 3)) * (b[1] - b[0])
    d = tgt - o
    return o, d / np.linalg.norm(d, axis=1, keepdims=True)


def _winding_number(vertices, faces, q):
    """Generalised winding number of a triangle soup at points q (Jacobson et al. 2013)."""
    a, b, c = (vertices[faces[:, i]][None] - q[:, None] for i in range(3))
    la, lb, lc = (np.linalg.norm(x, axis=-1) for x in (a, b, c))

    def dot(x, y):
        return np.einsum("...i,...i->...", x, y)

    det = dot(a, np.cross(b, c))
    den = la * lb * lc + dot(a, b) * lc + dot(b, c) * la + dot(c, a) * lb
    return np.arctan2(det, den).sum(axis=1) / (2 * np.pi)


# ---------------------------------------------------------------------------------------------
# teapot data and Bezier evaluation
# ---------------------------------------------------------------------------------------------
def test_teapot_data_and_bounds(teapot):
    p = teapot.patches
    assert p.shape == (32, 4, 4, 3)
    np.testing.assert_allclose(load_bpt() * 37.0, p)
    b = teapot.bounds
    # README: x in [-3.0, 3.43], y in [-2, 2], z in [0, 3.15] model units
    np.testing.assert_allclose(b / 37.0, [[-3.0, -2.0, 0.0], [3.434, 2.0, 3.15]], atol=2e-3)


def test_bezier_evaluation_matches_de_casteljau(teapot):
    rng = np.random.default_rng(3)
    k = rng.integers(0, 32, 300)
    uv = rng.random((300, 2))
    s, su, sv = teapot.evaluate(k, uv, order=1)
    h = 1e-30  # complex-step derivative of the polynomial: exact to round-off
    for i in range(300):
        ctrl = teapot.patches[k[i]]
        u, v = uv[i]
        ref = _patch_oracle(ctrl, u, v)
        np.testing.assert_allclose(s[i], ref.real, rtol=0, atol=1e-12)
        np.testing.assert_allclose(su[i], _patch_oracle(ctrl, u + 1j * h, v).imag / h, atol=1e-12)
        np.testing.assert_allclose(sv[i], _patch_oracle(ctrl, u, v + 1j * h).imag / h, atol=1e-11)


def test_bernstein_second_derivative_and_partition_of_unity():
    t = np.linspace(0, 1, 11)
    np.testing.assert_allclose(bernstein3(t).sum(axis=1), 1.0, atol=1e-15)
    np.testing.assert_allclose(bernstein3(t, 1).sum(axis=1), 0.0, atol=1e-13)
    h = 1e-6
    fd = (bernstein3(t + h, 1) - bernstein3(t - h, 1)) / (2 * h)
    np.testing.assert_allclose(bernstein3(t, 2), fd, atol=1e-6)


def test_teapot_normals_are_outward_by_winding_number(teapot):
    m = teapot.mesh(2.0)
    rng = np.random.default_rng(5)
    k = np.repeat(np.arange(32), 6)
    uv = rng.uniform(0.15, 0.85, (len(k), 2))
    p = teapot.surface_points(k, uv)
    n = teapot.surface_normals(k, uv)
    w_out = _winding_number(m.vertices, m.faces, p + 0.5 * n)
    w_in = _winding_number(m.vertices, m.faces, p - 0.5 * n)
    # outside: winding ~0, inside ~1 (medians per patch: the surface is not watertight)
    assert np.all(np.median((w_in - w_out).reshape(32, 6), axis=1) > 0.8)
    # and the mesh faces are wound the same way as the normals
    fn = m.face_normals
    vn = teapot.surface_normals(m.metadata["face_surface_id"],
                                m.metadata["vertex_uv"][m.faces].mean(axis=1))
    assert np.mean(np.einsum("ij,ij->i", fn, vn) > 0.9) > 0.99


def test_teapot_normals_match_finite_differences(teapot):
    rng = np.random.default_rng(6)
    k = rng.integers(0, 32, 500)
    uv = rng.uniform(0.01, 0.99, (500, 2))
    h = 1e-6
    du = teapot.surface_points(k, uv + [h, 0]) - teapot.surface_points(k, uv - [h, 0])
    dv = teapot.surface_points(k, uv + [0, h]) - teapot.surface_points(k, uv - [0, h])
    ref = -np.cross(du, dv)  # all 32 patches have Su x Sv pointing inwards
    ref /= np.linalg.norm(ref, axis=1, keepdims=True)
    n = teapot.surface_normals(k, uv)
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-12)
    assert np.abs(n - ref).max() < 1e-6


def test_degenerate_patches_have_finite_limit_normals(teapot):
    v = np.linspace(0, 1, 7)
    for k, expect in [(20, [0, 0, 1]), (21, [0, 0, 1]), (28, [0, 0, -1]), (31, [0, 0, -1])]:
        uv = np.column_stack([np.zeros_like(v), v])
        n = teapot.surface_normals(np.full(len(v), k), uv)
        assert np.isfinite(n).all()
        np.testing.assert_allclose(n, np.tile(expect, (len(v), 1)), atol=1e-5)
    # rays straight down on the lid's pole and straight up on the bottom's centre
    top = teapot.intersect([[0.0, 0.0, 500.0]], [[0.0, 0.0, -1.0]])
    np.testing.assert_allclose(top["points"][0], [0, 0, 3.15 * 37], atol=1e-9)
    np.testing.assert_allclose(top["normals"][0], [0, 0, 1], atol=1e-6)
    bot = teapot.intersect([[1e-3, -2e-3, -100.0]], [[0.0, 0.0, 1.0]])
    assert bot["hit"][0] and abs(bot["points"][0, 2]) < 1e-6
    np.testing.assert_allclose(bot["normals"][0], [0, 0, -1], atol=1e-4)
    # closest points at the poles (the Hessian of the distance is singular there)
    d = np.array([0.01, 0.3, 2.0])
    q = np.column_stack([np.zeros(3), np.zeros(3), 3.15 * 37 + d])
    c, dist, sid = teapot.closest_point(np.concatenate([q, q * [1, 1, 0] - d[:, None] * [0, 0, 1]]))
    np.testing.assert_allclose(dist, np.r_[d, d], atol=1e-9)
    assert set(sid[:3]) <= {20, 21, 22, 23} and set(sid[3:]) <= {28, 29, 30, 31}


# ---------------------------------------------------------------------------------------------
# mesh
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("tol", [0.2, 1.0])
def test_teapot_mesh_is_within_tolerance(teapot, tol):
    m = teapot.mesh(tol)
    assert m is teapot.mesh(tol)  # cached
    meta = m.metadata
    assert meta["face_surface_id"].shape == (len(m.faces),)
    assert meta["vertex_uv"].shape == (len(m.vertices), 2)
    # vertices lie on the exact surface
    np.testing.assert_allclose(
        teapot.surface_points(meta["vertex_surface_id"], meta["vertex_uv"]), m.vertices,
        atol=1e-12)
    # chord error: triangle centroids and edge midpoints are within tol of the exact surface
    rng = np.random.default_rng(0)
    f = rng.choice(len(m.faces), 4000, replace=False)
    tri = m.vertices[m.faces[f]]
    q = np.concatenate([tri.mean(axis=1), (tri[:, 0] + tri[:, 1]) / 2])
    d = teapot.distance(q)
    assert d.max() < tol
    assert d.max() > tol / 20  # the grid is not wastefully fine
    # the hit parameters of a vertex are the vertex's parameters
    sid, uv = teapot.mesh_hit_params(f, tri[:, 1], tolerance_mm=tol)
    np.testing.assert_array_equal(sid, meta["face_surface_id"][f])
    np.testing.assert_allclose(uv, meta["vertex_uv"][m.faces[f, 1]], atol=1e-9)


# ---------------------------------------------------------------------------------------------
# rays
# ---------------------------------------------------------------------------------------------
def test_teapot_rays_land_on_the_exact_surface(teapot):
    o, d = _random_rays(teapot, 20000, seed=1)
    r = teapot.intersect(o, d)
    h = r["hit"]
    assert h.sum() > 8000
    p = r["points"][h]
    # on the exact patch at the returned (u, v), and on the ray
    np.testing.assert_allclose(teapot.surface_points(r["surface_id"][h], r["uv"][h]), p,
                               atol=1e-9)
    np.testing.assert_allclose(o[h] + r["t"][h, None] * d[h], p, atol=1e-6)
    assert teapot.distance(p).max() < 1e-6
    # first hits: never behind the mesh hit by more than the mesh tolerance's sliver
    m = teapot.mesh()
    tri, ray, loc = m.ray.intersects_id(o, d, multiple_hits=False, return_locations=True)
    t_mesh = np.full(len(o), np.nan)
    t_mesh[ray] = np.einsum("ij,ij->i", loc - o[ray], d[ray])
    dt = r["t"][h] - t_mesh[h]
    assert np.all(np.isfinite(dt)) and np.abs(dt).max() < 20
    assert np.median(np.abs(dt)) < 0.05
    # normals are unit, finite, and face the ray where the mesh face does
    n = r["normals"][h]
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-12)
    facing = np.sign(np.einsum("ij,ij->i", m.face_normals[tri], d[ray]))
    hit_rays = np.flatnonzero(h)
    f_of = dict(zip(ray.tolist(), facing.tolist(), strict=True))
    sign = np.sign(np.einsum("ij,ij->i", n, d[h]))
    assert np.all(sign == np.array([f_of[i] for i in hit_rays]))
    # almost every mesh hit refines (the rest are grazing rays that miss the exact surface)
    assert h.sum() >= 0.998 * len(ray)


def test_mesh_cast_matches_trimesh_ray_cast(teapot):
    # oracle: trimesh's Embree wrapper (float64 plane / ray locations), first hits
    o, d = _random_rays(teapot, 20000, seed=3)
    ray, face, t, bary = teapot.mesh_cast(o, d)
    m = teapot.mesh()
    tri, ray2, loc = m.ray.intersects_id(o, d, multiple_hits=False, return_locations=True)
    assert len(ray) > 8000 and len(ray2) > 8000
    f1 = np.full(len(o), -1)
    f1[ray] = face
    f2 = np.full(len(o), -1)
    f2[ray2] = tri
    # the same rays hit the same faces (a grazing ray or two may differ in float32)
    assert np.mean(f1[f1 >= 0] == f2[f1 >= 0]) > 0.999 and abs(len(ray) - len(ray2)) <= 2
    same = (f1 == f2) & (f1 >= 0)
    t1 = np.full(len(o), np.nan)
    t1[ray] = t
    t2 = np.full(len(o), np.nan)
    t2[ray2] = np.einsum("ij,ij->i", loc - o[ray2], d[ray2])
    np.testing.assert_allclose(t1[same], t2[same], atol=1e-9)
    # barycentric coordinates: a convex combination reproducing the hit (float32 precision)
    assert np.all(bary >= 0) and np.allclose(bary.sum(axis=1), 1.0)
    p = np.einsum("ni,nij->nj", bary, m.vertices[m.faces[face]])
    assert np.abs(p - (o[ray] + t[:, None] * d[ray])).max() < 5e-3


def test_teapot_refine_from_perturbed_start(teapot):
    """refine() converges from a start displaced along the ray and in (u, v), and across borders."""
    rng = np.random.default_rng(2)
    k = rng.integers(0, 32, 2000)
    uv = rng.uniform(0.02, 0.98, (2000, 2))
    p = teapot.surface_points(k, uv)
    n = teapot.surface_normals(k, uv)
    d = -n + 0.3 * rng.normal(size=n.shape)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    o = p - 50 * d
    start = np.clip(uv + rng.normal(0, 0.01, uv.shape), 0, 1)
    t, pts, nrm, sid, ok = teapot.refine(o, d, np.full(2000, 50.3), k, start)
    assert ok.mean() > 0.99
    np.testing.assert_allclose(pts[ok], p[ok], atol=1e-7)
    np.testing.assert_allclose(t[ok], 50.0, atol=1e-7)
    np.testing.assert_allclose(nrm[ok], n[ok], atol=1e-6)
    # a mesh hit on the neighbouring patch across the border: the neighbours are tried
    ring = np.concatenate([np.arange(12), np.arange(20, 32)])  # rings of 4 patches about z
    k = rng.choice(ring, 1000)
    uv = np.column_stack([rng.uniform(0.02, 0.98, 1000), rng.uniform(0.95, 0.995, 1000)])
    p = teapot.surface_points(k, uv)
    n = teapot.surface_normals(k, uv)
    o = p + 50 * n
    nxt = (k // 4) * 4 + (k + 1) % 4  # v = 1 of patch k is v = 0 of the next one
    t, pts, nrm, sid, ok, uv2 = teapot.refine(o, -n, np.full(1000, 50.0), nxt,
                                              np.column_stack([uv[:, 0], np.zeros(1000)]),
                                              facing=-np.ones(1000), return_uv=True)
    assert ok.all()
    np.testing.assert_array_equal(sid, k)
    np.testing.assert_allclose(pts, p, atol=1e-7)
    np.testing.assert_allclose(uv2, uv, atol=1e-9)


@pytest.mark.parametrize("scene", [Sphere(), Torus(), Cylinder(), Plane(), Sphere(25, (10, -5, 30)),
                                   Torus(50, 10, (5, 5, 10)), Plane((0, 0, 5), (1, 2, 3), None)],
                         ids=lambda s: s.name)
def test_analytic_rays_land_on_the_exact_surface(scene):
    o, d = _random_rays(scene, 6000, seed=4)
    r = scene.intersect(o, d)
    h = r["hit"]
    assert h.sum() > 1500
    p, n = r["points"][h], r["normals"][h]
    np.testing.assert_allclose(o[h] + r["t"][h, None] * d[h], p, atol=1e-6)
    if isinstance(scene, Sphere):
        resid = np.linalg.norm(p - scene.center, axis=1) - scene.radius
        np.testing.assert_allclose(n, (p - scene.center) / scene.radius, atol=1e-9)
    elif isinstance(scene, Torus):
        w = p - scene.center
        rho = np.hypot(w[:, 0], w[:, 1])
        resid = np.hypot(rho - scene.major, w[:, 2]) - scene.minor
        # implicit-function gradient (|w|^2 + R^2 - r^2) w - 2 R^2 (x, y, 0)
        g = (np.sum(w**2, axis=1) + scene.major**2 - scene.minor**2)[:, None] * w
        g[:, :2] -= 2 * scene.major**2 * w[:, :2]
        np.testing.assert_allclose(n, g / np.linalg.norm(g, axis=1, keepdims=True), atol=1e-9)
    elif isinstance(scene, Plane):
        resid = (p - scene.point) @ np.array(scene.normal)
        np.testing.assert_allclose(n, np.tile(scene.normal, (len(n), 1)), atol=1e-12)
    else:
        resid = scene.distance(p)
    assert np.abs(resid).max() < 1e-6
    # first hit: no earlier crossing of the exact surface (sampled along 1000 rays)
    h = np.flatnonzero(h)[:1000]
    s = np.linspace(0.0, 1.0, 300)[None, :-3] * r["t"][h, None]
    q = o[h][:, None, :] + s[..., None] * d[h][:, None, :]
    if isinstance(scene, Plane):
        side = (q - scene.point) @ np.array(scene.normal)
        outside = np.sign(side) == np.sign(side[:, :1])
    elif isinstance(scene, Sphere):
        outside = np.linalg.norm(q - scene.center, axis=2) > scene.radius
    elif isinstance(scene, Torus):
        w = q - scene.center
        outside = np.hypot(np.hypot(w[..., 0], w[..., 1]) - scene.major, w[..., 2]) > scene.minor
    else:  # the cup's material: the wall ring and the bottom slab
        rho, z = np.hypot(q[..., 0], q[..., 1]), q[..., 2]
        wall = (rho > scene.radius - scene.thickness) & (rho < scene.radius) & (z < scene.height)
        slab = (rho < scene.radius) & (z < scene.thickness)
        outside = ~((wall | slab) & (z > 0))
    assert np.all(outside)


def test_torus_refine_picks_the_entry_root_on_grazing_rays():
    tor = Torus()
    o, d = _random_rays(tor, 100000, seed=8)
    r = tor.intersect(o, d)
    h = r["hit"]
    # the entry root of a ray from outside has d . n < 0 (except through the open hole: none)
    assert np.all(np.einsum("ij,ij->i", r["normals"][h], d[h]) < 0)


def test_cylinder_pieces_and_first_hits():
    cup = Cylinder(radius=40, height=100, thickness=3)
    o = np.array([[0, 0, 300.0], [200, 0, 50], [0, 0, -50], [38.5, 0, 300], [39.0, 0.5, 300]])
    d = np.array([[0, 0, -1.0], [-1, 0, 0], [0, 0, 1], [0, 0, -1], [0, 0, -1]])
    r = cup.intersect(o, d)
    assert r["hit"].all()
    np.testing.assert_array_equal(r["surface_id"], [3, 0, 4, 2, 2])
    np.testing.assert_allclose(r["points"][:3], [[0, 0, 3], [40, 0, 50], [0, 0, 0]], atol=1e-12)
    np.testing.assert_allclose(r["normals"], [[0, 0, 1], [1, 0, 0], [0, 0, -1], [0, 0, 1],
                                              [0, 0, 1]], atol=1e-12)
    # from the inside of the cup towards the wall: inner wall, normal towards the axis
    r = cup.intersect([[0, 0, 50.0]], [[1.0, 0, 0]])
    np.testing.assert_array_equal(r["surface_id"], [1])
    np.testing.assert_allclose(r["points"][0], [37, 0, 50], atol=1e-12)
    np.testing.assert_allclose(r["normals"][0], [-1, 0, 0], atol=1e-12)
    # mesh + refine agrees with the closed form
    m = cup.mesh()
    o2, d2 = _random_rays(cup, 5000, seed=9)
    tri, ray, loc = m.ray.intersects_id(o2, d2, multiple_hits=False, return_locations=True)
    sid0, uv0 = cup.mesh_hit_params(tri, loc)
    t0 = np.einsum("ij,ij->i", loc - o2[ray], d2[ray])
    t, p, n, sid, ok = cup.refine(o2[ray], d2[ray], t0, sid0, uv0)
    exact = cup.intersect(o2[ray], d2[ray])
    assert ok.mean() > 0.99
    np.testing.assert_allclose(t[ok], exact["t"][ok], atol=1e-9)


def test_torus_axis_ray_misses_and_side_ray_hits():
    tor = Torus(major=60, minor=20, center=(0, 0, 20))
    r = tor.intersect([[0, 0, 300.0], [-300, 0, 20]], [[0, 0, -1.0], [1, 0, 0]])
    assert not r["hit"][0] and np.isnan(r["points"][0]).all() and r["surface_id"][0] == -1
    np.testing.assert_allclose(r["points"][1], [-80, 0, 20], atol=1e-9)


def test_plane_finite_and_infinite():
    sq = Plane(point=(0, 0, 0), normal=(0, 0, 1), size=100)
    r = sq.intersect([[10, 20, 50.0], [80, 0, 50]], [[0, 0, -1.0], [0, 0, -1]])
    np.testing.assert_array_equal(r["hit"], [True, False])
    inf = Plane(point=(0, 0, 0), normal=(0, 0, 1), size=None)
    r = inf.intersect([[800, 0, 50.0], [0, 0, 50]], [[0, 0, -1.0], [0, 0, 1]])
    np.testing.assert_array_equal(r["hit"], [True, False])  # behind the origin: no hit
    c, dist, _ = sq.closest_point([[70, 0, 5.0]])
    np.testing.assert_allclose(c[0], [50, 0, 0])
    np.testing.assert_allclose(dist, [np.hypot(20, 5)])


# ---------------------------------------------------------------------------------------------
# closest points
# ---------------------------------------------------------------------------------------------
def test_teapot_closest_point_of_offset_points(teapot):
    """Points pushed along the normal of the convex body by d come back with distance |d|."""
    rng = np.random.default_rng(11)
    k = rng.integers(4, 12, 3000)  # body patches
    uv = rng.uniform(0.02, 0.98, (3000, 2))
    p = teapot.surface_points(k, uv)
    # away from the handle and the spout, and from the concave crease with the bottom
    keep = (np.abs(p[:, 1]) > 40) & (p[:, 2] > 20)
    p, k, uv = p[keep], k[keep], uv[keep]
    n = teapot.surface_normals(k, uv)
    off = rng.uniform(0.01, 2.0, len(p)) * rng.choice([-1.0, 1.0], len(p))
    c, dist, sid = teapot.closest_point(p + off[:, None] * n)
    assert np.abs(dist - np.abs(off)).max() < 1e-6
    assert np.abs(c - p).max() < 1e-5


def test_teapot_closest_point_against_dense_sampling(teapot):
    """The exact distance is never more than that of the nearest of 0.8 M surface samples, and
    only slightly less (the samples' spacing): the right patch is found everywhere."""
    from scipy.spatial import cKDTree

    g = np.linspace(0, 1, 161)
    uu, vv = np.meshgrid(g, g)
    uv = np.column_stack([uu.ravel(), vv.ravel()])
    dense = np.concatenate([teapot.surface_points(np.full(len(uv), k), uv) for k in range(32)])
    rng = np.random.default_rng(12)
    p, n, _ = teapot.sample_surface(2000, seed=13)
    q = p + n * rng.uniform(-3, 3, (len(p), 1)) + rng.normal(0, 1, p.shape)
    c, dist, sid = teapot.closest_point(q)
    d_dense = cKDTree(dense).query(q)[0]
    assert np.all(dist <= d_dense + 1e-9)
    assert np.all(dist >= d_dense - 0.5)
    # the closest points are on the surface, and the returned distance is |q - c|
    np.testing.assert_allclose(np.linalg.norm(q - c, axis=1), dist, atol=1e-12)
    # ... and it is a stationary point: q - c is along the normal or c is on a patch border
    _, _, _, cuv = teapot.closest_point_uv(q)
    interior = np.all((cuv > 1e-6) & (cuv < 1 - 1e-6), axis=1) & (dist > 1e-3)
    nrm = teapot.surface_normals(sid[interior], cuv[interior])
    w = (q - c)[interior] / dist[interior, None]
    assert np.all(np.abs(np.einsum("ij,ij->i", w, nrm)) > 1 - 1e-9)


@pytest.mark.parametrize("scene", [Sphere(), Torus(), Cylinder()], ids=lambda s: s.name)
def test_analytic_closest_point_of_offset_points(scene):
    p, n, sid = scene.sample_surface(4000, seed=3)
    off = np.random.default_rng(4).uniform(0.01, 1.0, len(p))
    if isinstance(scene, Cylinder):  # stay off the edges, where another piece may be nearer
        z = p[:, 2]
        rho = np.hypot(p[:, 0], p[:, 1])
        ok = (z > 4) & (z < 96) & ((sid < 2) | (rho < 35))
        ok &= sid != 2
        p, n, off = p[ok], n[ok], off[ok]
    c, dist, _ = scene.closest_point(p + off[:, None] * n)
    assert np.abs(dist - off).max() < 1e-9
    np.testing.assert_allclose(c, p, atol=1e-9)


def test_sample_surface_is_on_the_surface_and_area_uniform():
    sph = Sphere(radius=50, center=(0, 0, 50))
    p, n, _ = sph.sample_surface(40000, seed=1)
    np.testing.assert_allclose(np.linalg.norm(p - sph.center, axis=1), 50, atol=1e-9)
    # the area fraction of a spherical cap of height h is h / (2 r)
    frac = np.mean(p[:, 2] > 80)
    assert abs(frac - 20 / 100) < 0.01
    tp = Teapot()
    p, n, sid = tp.sample_surface(2000, seed=2)
    assert tp.distance(p).max() < 1e-6 and np.isfinite(n).all()


# ---------------------------------------------------------------------------------------------
# factory and serialisation
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("scene", [Teapot(scale=30.0), Sphere(10, (1, 2, 3)), Cylinder(20, 50, 2),
                                   Torus(30, 5, (0, 0, 5)), Plane((0, 0, 1), (0, 1, 0), 50),
                                   Plane(size=None)], ids=lambda s: s.name)
def test_json_round_trip(scene):
    d = json.loads(json.dumps(scene.to_dict()))
    assert d["type"] == "nurbscan.scene" and d["name"] == scene.name
    back = scene_from_dict(d)
    assert back == scene and type(back) is type(scene)


def test_make_scene_and_errors():
    assert make_scene("teapot") == Teapot(37.0)
    assert make_scene("Sphere", radius=5) == Sphere(5.0)
    with pytest.raises(NurbscanError, match="nope.*teapot, sphere, cylinder, torus, plane"):
        make_scene("nope")
    with pytest.raises(NurbscanError, match="radiuss"):
        make_scene("sphere", radiuss=3)
    with pytest.raises(NurbscanError, match="sphere radius"):
        Sphere(radius=-1)
    with pytest.raises(NurbscanError, match="torus"):
        Torus(major=10, minor=20)
    with pytest.raises(NurbscanError, match="thickness"):
        Cylinder(radius=10, thickness=12)
    with pytest.raises(NurbscanError, match="type"):
        scene_from_dict({"name": "sphere"})
    with pytest.raises(NurbscanError, match="directions"):
        Sphere().intersect([0, 0, 0], [[1, 0]])
