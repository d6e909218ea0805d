"""Image formation of the synthetic scanner: camera images of a scene under the projected grid.

Every camera pixel's value is computed from exact geometry (docs/scan-format.md lists what is
stored as truth). For one view at table angle theta:

1. **Camera rays.** Each pixel centre (i, j) is back-projected through the camera's Tsai model
   (method.md section 4, closed form) and taken into the object frame (the turntable's frame at
   angle theta). The scene's ``intersect`` returns the first hit refined to the exact surface
   (Newton on the Bezier patch or the analytic shape, within 1e-6 mm).
2. **Table.** With ``RenderSettings.table`` the table top is a dark matte disc of radius
   ``table_radius`` at z = 0 of the object frame (surface id -2), intersected analytically;
   beyond the scene and the table the background is black (surface id -1).
3. **Projector visibility (shadows).** A surface point X is lit when it faces the projector,
   its projection ``projector.project(X)`` falls inside the projector image
   ([-0.5, width - 0.5] x [-0.5, height - 0.5]), and the ray cast
   from the projector's centre towards X first meets the scene at X (within
   ``shadow_epsilon`` mm): the projector sees the same surface point. Scenes that cannot
   shadow themselves (``self_shadowing = False``: a plane, the sphere) need that ray only for
   points on the table.
4. **Pattern.** The projector coordinate (u, v) of X is ``projector.project(X)`` (Tsai,
   inverted distortion). The projected light there is the pattern blurred by the projector's
   defocus, a Gaussian of ``projector_blur`` projector px. It is evaluated analytically: each
   direction's band profile blurred by a Gaussian is a sum over bands of differences of two
   erf's, V_c(u) = sum_i col_ic [Phi((u - r_i)/s) - Phi((u - f_i)/s)] (r_i, f_i the exact band
   edges of :class:`~nurbscan.pattern.Pattern`), tabulated at 1/64 projector px (linear
   interpolation, error < 1e-5 for s >= 0.3 px) with its first and second antiderivatives
   (integrated exactly for the interpolant), and the two directions combine by the crossing
   rule (OR): P_c = 1 - (1 - V_c(u)) (1 - H_c(v)), which for 0/1 colour channels is *exactly*
   the Gaussian blur of the OR-ed pattern image (the Gaussian is separable and V, H depend on
   one coordinate each).
5. **Pixel area (anti-aliasing).** A pixel integrates the light over its area. Two cases:

   * *Continuous surface* (the pixel and its four neighbours hit the same kind of surface,
     with equal albedo, all lit or all unlit, and lit neighbours' projector coordinates differ
     by less than a jump threshold): no further rays. Over the pixel the projector
     coordinates are the linear map (u, v) + J (x, y), J the Jacobian of the exact
     pixel-centre field by central differences; the pixel's footprint along u is then the
     convolution of two boxes of widths |du/dx| and |du/dy| (a trapezoid), and the mean of
     V over it is a second difference of V's second antiderivative -- *exact* for the linear
     map, so an edge's image moves continuously with the edge (no snapping, blur on or off).
     The same along v; the crossing rule combines the two means (exact when the grid's lines
     run along the pixel axes; otherwise the covariance of V and H inside one pixel is
     neglected). With ``smooth_samples`` = n > 1 the pixel is split into n x n cells, each
     integrated so. Shading factors (distance, angles, albedo) are the pixel centre's.
   * *Discontinuity* (silhouette, shadow edge, table / object, self-occlusion, texture edge,
     the projector image's border, the camera image's border): ``samples`` x ``samples``
     rays on a regular sub-pixel grid are traced exactly, each with its own hit, shadow test,
     shading and pattern (its cell's trapezoid mean, J from the neighbouring sub-samples, or a
     point sample next to a jump); misses count as black; the pixel is their mean. A texture
     given with its cell mean (``albedo_cell``, the chessboard target's) is averaged over
     each sub-sample's cell the same way, so printed edges do not snap to the sub-samples.

6. **Shading.** Irradiance from the projector E = power (d_ref / d)^2 max(n.l, 0) (inverse
   square fall-off from the projector's centre, Lambert's cosine); radiance
   L_j = albedo_j (E P_j + ambient) + gloss (n.h)^shininess E P_j for each projector primary
   j (Blinn-Phong lobe, h the half vector between the directions to the projector and to the
   camera; white highlight). Normals are turned towards the camera. Albedo is constant
   (``RenderSettings.albedo``) or a function of the object-frame point.
7. **Camera.** Camera RGB = M L with the 3 x 3 ``mixing`` matrix (crosstalk between the
   projector primaries and the camera's colour filters); lens blur, a Gaussian of
   ``camera_blur`` camera px; the signal in electrons ``exposure * full_well * L``, shot noise
   (Gaussian approximation of Poisson, variance = signal), read noise (``read_noise``
   electrons), both scaled by ``noise``; clipping at the full well; gamma encoding
   v^(1 / gamma); quantisation to 8 or 16 bits.

The white-light image is the same with the projector showing white (P = 1 inside its image).
Random numbers come from ``numpy.random.default_rng(SeedSequence([seed, stream, kind]))``, so
the same seed gives the same images bit for bit.
"""

from __future__ import annotations

import functools
import math
import os
import time
from collections.abc import Callable, Mapping
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass, field, fields
from typing import Any

import cv2
import numpy as np
from scipy.special import ndtr

from ..errors import NurbscanError

TYPE = "nurbscan.render_settings"
VERSION = 1

#: Surface id of the table top and of the background in the truth arrays.
TABLE_ID = -2
BACKGROUND_ID = -1

_CHUNK = 1 << 19  # rays / pixels per vectorised block (bounds the memory)


@dataclass(frozen=True)
class RenderSettings:
    """Every parameter of the image formation, with realistic defaults.

    Attributes
    ----------
    samples : int
        Traced sub-samples per pixel along each axis (``samples**2`` rays per pixel) at
        discontinuities. Default 4.
    smooth_samples : int
        Sub-cells per axis of a pixel on a continuous surface, each integrating its cell
        along u and v with a box (module notes, step 5). Default 1: the box integral of the
        whole pixel, exact for each band direction (the crossing rule then acts on the two
        directions' pixel means).
    projector_blur : float
        Projector defocus, Gaussian sigma in projector px. Default 0.6 (0 = sharp).
    camera_blur : float
        Camera lens blur, Gaussian sigma in camera px. Default 0.5 (0 = off).
    projector_power : float
        Relative irradiance of full projector light on a surface facing it at
        ``ref_distance``. Default 1.
    ref_distance : float
        Distance (mm) at which ``projector_power`` applies; irradiance falls as 1/d^2.
    ambient : float
        Ambient (room) irradiance, relative to ``projector_power``. Default 0.02.
    albedo : (float, float, float)
        Diffuse albedo of the scene's surface per projector primary (white glazed ceramic).
    gloss, shininess : float
        Weight and exponent of the Blinn-Phong glossy lobe (0 = matte). Default 0.2, 60.
    table : bool
        Render the table top (a matte disc at z = 0 of the object frame). Default true.
    table_radius : float
        Radius of the table top, mm. Default 150.
    table_albedo : (float, float, float)
        Albedo of the table top (dark matte). Default 0.03.
    mixing : 3 x 3 tuple
        Camera RGB from projector primaries: row k = response of camera channel k to the
        red, green and blue primaries (crosstalk off the diagonal).
    exposure : float
        Signal as a fraction of the full well for radiance 1. Default 0.6.
    full_well : float
        Full-well capacity, electrons. Default 7000 (2.3 um pixels).
    read_noise : float
        Read noise, electrons rms. Default 4.
    noise : float
        Scale of shot and read noise (0 = noise free, 1 = the defaults above).
    gamma : float
        Encoding gamma (output = signal^(1/gamma)); 1 = linear. Default 2.2.
    bit_depth : int
        8 or 16.
    shadow_epsilon : float
        Tolerance (mm) of the projector visibility test. Default 1e-3.
    """

    samples: int = 4
    smooth_samples: int = 1
    projector_blur: float = 0.6
    camera_blur: float = 0.5
    projector_power: float = 1.0
    ref_distance: float = 600.0
    ambient: float = 0.02
    albedo: tuple[float, float, float] = (0.82, 0.82, 0.80)
    gloss: float = 0.2
    shininess: float = 60.0
    table: bool = True
    table_radius: float = 150.0
    table_albedo: tuple[float, float, float] = (0.03, 0.03, 0.03)
    mixing: tuple[tuple[float, float, float], ...] = (
        (0.92, 0.10, 0.02),
        (0.07, 0.86, 0.12),
        (0.01, 0.09, 0.90),
    )
    exposure: float = 0.6
    full_well: float = 7000.0
    read_noise: float = 4.0
    noise: float = 1.0
    gamma: float = 2.2
    bit_depth: int = 8
    shadow_epsilon: float = 1e-3
    type: str = field(default=TYPE, repr=False)

    def __post_init__(self) -> None:
        def bad(name: str, why: str):
            raise NurbscanError(f"render setting {name}={getattr(self, name)!r}: {why}")

        for name in ("samples", "smooth_samples"):
            v = getattr(self, name)
            if not isinstance(v, int | np.integer) or not 1 <= v <= 16:
                bad(name, "must be an integer 1..16")
        for name in ("projector_blur", "camera_blur", "ambient", "gloss", "noise",
                     "read_noise", "shadow_epsilon"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and math.isfinite(v) and v >= 0):
                bad(name, "must be a finite number >= 0")
        for name in ("projector_power", "ref_distance", "exposure", "full_well", "gamma",
                     "shininess", "table_radius"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and math.isfinite(v) and v > 0):
                bad(name, "must be a finite number > 0")
        if self.bit_depth not in (8, 16):
            bad("bit_depth", "must be 8 or 16")
        for name in ("albedo", "table_albedo"):
            v = tuple(float(x) for x in getattr(self, name))
            if len(v) != 3 or not all(0 <= x <= 1 for x in v):
                bad(name, "must be three values in [0, 1]")
            object.__setattr__(self, name, v)
        m = np.asarray(self.mixing, dtype=float)
        if m.shape != (3, 3) or not np.all(np.isfinite(m)) or np.any(m < 0):
            bad("mixing", "must be a 3 x 3 matrix of values >= 0")
        object.__setattr__(self, "mixing", tuple(tuple(float(x) for x in r) for r in m))

    def replace(self, **changes: Any) -> RenderSettings:
        """A copy with some fields changed."""
        d = {f.name: getattr(self, f.name) for f in fields(self)}
        d.update(changes)
        return RenderSettings(**d)

    def with_noise_scale(self, scale: float) -> RenderSettings:
        """A copy with the noise scaled (the command line's ``--noise``)."""
        return self.replace(noise=float(scale) * self.noise)

    def ideal(self) -> RenderSettings:
        """A copy without noise and without any blur (for checks against the truth)."""
        return self.replace(noise=0.0, camera_blur=0.0, projector_blur=0.0)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict with ``type`` and ``version``."""
        d = asdict(self)
        d["mixing"] = [list(r) for r in self.mixing]
        d["albedo"] = list(self.albedo)
        d["table_albedo"] = list(self.table_albedo)
        d["version"] = VERSION
        return d

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], source: str = "render settings") -> RenderSettings:
        """Rebuild from :meth:`to_dict` output; unknown keys raise a NurbscanError."""
        if not isinstance(d, Mapping) or d.get("type", TYPE) != TYPE:
            raise NurbscanError(f"{source}: not a {TYPE!r} object")
        names = {f.name for f in fields(cls)}
        extra = set(d) - names - {"version"}
        if extra:
            raise NurbscanError(f"{source}: unknown keys {sorted(extra)}")
        kw = {k: v for k, v in d.items() if k in names and k != "type"}
        for k in ("albedo", "table_albedo"):
            if k in kw:
                kw[k] = tuple(kw[k])
        if "mixing" in kw:
            kw["mixing"] = tuple(tuple(r) for r in kw["mixing"])
        try:
            return cls(**kw)
        except TypeError as exc:
            raise NurbscanError(f"{source}: {exc}") from None


# ---------------------------------------------------------------------------- pattern profile
def step_coverage(t: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Share of the footprint t + A + B above 0, A ~ U[-a/2, a/2], B ~ U[-b/2, b/2].

    This is the mean of the unit step over a cell whose coordinate is the linear map
    t + a' x + b' y (|a'| = a, |b'| = b, x and y uniform over the cell): the cumulative
    distribution of the trapezoid (the convolution of two boxes, as in
    :meth:`BandProfile.trapezoid`) at t, F(t) = [R(t + p) - R(t + q) - R(t - q) + R(t - p)]
    / (a b) with R(t) = max(t, 0)^2 / 2, p = (a + b) / 2, q = (a - b) / 2; a box
    (b -> 0) or a point sample (a, b -> 0) in the limits. All arrays broadcast; same units.
    """
    t, a, b = np.broadcast_arrays(*(np.asarray(x, float) for x in (t, a, b)))
    big, small = np.maximum(a, b), np.minimum(a, b)
    p, q = 0.5 * (big + small), 0.5 * (big - small)
    with np.errstate(divide="ignore", invalid="ignore"):
        r = [np.square(np.maximum(t + c, 0.0)) for c in (p, q, -q, -p)]
        trap = 0.5 * (r[0] - r[1] - r[2] + r[3]) / (big * small)
        box = np.clip(t / big + 0.5, 0.0, 1.0)
    point = (t > 0) + 0.5 * (t == 0)
    out = np.clip(np.where(t >= p, 1.0, np.where(t <= -p, 0.0,
                                                 np.where(small > 1e-9 * big, trap, box))),
                  0.0, 1.0)
    return np.where(big > 0, out, point)


class BandProfile:
    """The blurred 1-D light profile of one band direction and its exact pixel averages.

    V_c(u) = sum_i col_ic [Phi((u - r_i) / s) - Phi((u - f_i) / s)] for the bands i with edges
    (r_i, f_i) (projector px) and colour channel c in [0, 1]; s the defocus sigma (s = 0: the
    exact box). V is tabulated at ``res`` points per px over the projector image plus a
    margin (zero outside) and linearly interpolated (error < 1e-5 for s >= 0.3 px); its first
    and second antiderivatives C1, C2 are integrated *exactly* for that piecewise-linear V,
    so that averages of V over a box or a trapezoid are exact differences of them.

    Parameters
    ----------
    edges : ndarray, shape (nb, 2)
        Rising and falling edge of each band, projector px.
    colours : ndarray, shape (nb, 3)
        Colour of each band, channels in [0, 1].
    size : int
        Projector image size along the coordinate, px.
    sigma : float
        Gaussian defocus sigma, projector px.
    """

    def __init__(self, edges: np.ndarray, colours: np.ndarray, size: int, sigma: float,
                 res: int = 64):
        pad = int(math.ceil(8 * sigma)) + 16
        self.lo = -0.5 - pad
        self.res = res
        self.h = 1.0 / res
        n = (size + 2 * pad) * res + 1
        self.n = n
        x = self.lo + np.arange(n) / res
        val = np.zeros((n, 3))
        reach = 8 * sigma + 2.0 / res
        for (r, f), col in zip(np.asarray(edges, float), np.asarray(colours, float), strict=True):
            i0 = max(int((r - reach - self.lo) * res), 0)
            i1 = min(int((f + reach - self.lo) * res) + 2, n)
            xs = x[i0:i1]
            if sigma > 0:
                prof = ndtr((xs - r) / sigma) - ndtr((xs - f) / sigma)
            else:
                prof = ((xs > r) & (xs < f)) + 0.5 * ((xs == r) | (xs == f))
            val[i0:i1] += prof[:, None] * col[None, :]
        h = self.h
        dv = np.diff(val, axis=0)
        c1 = np.concatenate([np.zeros((1, 3)), np.cumsum(h * (val[:-1] + 0.5 * dv), axis=0)])
        c2 = np.concatenate([np.zeros((1, 3)), np.cumsum(
            h * c1[:-1] + h * h * (val[:-1] / 2 + dv / 6), axis=0)])
        slope = np.concatenate([dv, np.zeros((1, 3))]) / h  # dV/du on each interval
        # one row per node: C2, C1, V / 2, (dV/du) / 6 (a single gather per evaluation; the
        # Taylor coefficients of C2, so that it is a plain Horner scheme)
        self.table = np.ascontiguousarray(np.concatenate([c2, c1, val / 2, slope / 6], axis=1))

    def _locate(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        u = np.asarray(u, float)
        t = (np.where(np.isnan(u), self.lo, u) - self.lo) * self.res  # +-inf: clipped below
        np.clip(t, 0.0, self.n - 1.0, out=t)
        i = np.minimum(t.astype(np.int64), self.n - 2)
        # np.take: a row gather about twice as fast as fancy indexing
        return np.take(self.table, i, axis=0), ((t - i) * self.h)[..., None]

    def sample(self, u: np.ndarray) -> np.ndarray:
        """V(u), shape u.shape + (3,)."""
        r, x = self._locate(u)
        return 2.0 * (r[..., 6:9] + 3.0 * x * r[..., 9:12])

    def _c1(self, u):
        r, x = self._locate(u)
        return r[..., 3:6] + x * (2.0 * r[..., 6:9] + 3.0 * x * r[..., 9:12])

    def _c2(self, u):
        r, x = self._locate(u)
        out = r[..., 9:12] * x  # Horner, in place (no temporaries of the result's size)
        out += r[..., 6:9]
        out *= x
        out += r[..., 3:6]
        out *= x
        out += r[..., 0:3]
        return out

    def box(self, u: np.ndarray, width: np.ndarray) -> np.ndarray:
        """Mean of V over [u - width/2, u + width/2] (width >= 0 px; V(u) below 1e-3 px)."""
        w = np.maximum(np.asarray(width, float), 1e-3)
        out = (self._c1(u + 0.5 * w) - self._c1(u - 0.5 * w)) / w[..., None]
        return np.clip(out, 0.0, None)

    def trapezoid(self, u: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """Mean of V over u + A + B with A, B uniform on [-a/2, a/2], [-b/2, b/2].

        This is the exact average over a pixel (or a sub-cell) whose coordinate is the linear
        map u + a' x + b' y, |a'| = a, |b'| = b, x and y uniform over the cell: the
        distribution of a' x + b' y is the convolution of two boxes (a trapezoid), and
        mean = [C2(u + p) - C2(u + q) - C2(u - q) + C2(u - p)] / (a b), p = (a + b) / 2,
        q = (a - b) / 2. Where the smaller width is below 0.02 px the box of the larger is
        used (error < 1e-4).
        """
        shape = np.shape(u)
        u = np.asarray(u, float).reshape(-1)
        a = np.asarray(a, float).reshape(-1)
        b = np.asarray(b, float).reshape(-1)
        big, small = np.maximum(a, b), np.minimum(a, b)
        thin = small < 0.02
        # index lists and np.take instead of boolean masks (row gathers twice as fast); the
        # common all-thick / all-thin cases need no gather at all
        ti = np.flatnonzero(thin)
        if ti.size == u.size:
            return np.clip(self.box(u, big), 0.0, None).reshape(shape + (3,))
        out = np.empty((u.size, 3))
        if ti.size:
            out[ti] = self.box(u[ti], big[ti])
        if ti.size == 0:
            uk, bk, sk = u, big, small
        else:
            ki = np.flatnonzero(~thin)
            uk, bk, sk = u[ki], big[ki], small[ki]
        p, q = 0.5 * (bk + sk), 0.5 * (bk - sk)
        num = self._c2(uk + p)
        num -= self._c2(uk + q)
        num -= self._c2(uk - q)
        num += self._c2(uk - p)
        num /= (bk * sk)[:, None]
        if ti.size == 0:
            out = num
        else:
            out[ki] = num
        return np.clip(out, 0.0, None, out=out).reshape(shape + (3,))


class PatternLight:
    """The projector's light on the projector image plane: the blurred pattern.

    ``light(u, v)`` -> (..., 3) in [0, 1] at points; ``light_cell(u, v, ju, jv)`` the exact
    average over a cell whose projector coordinates are the linear map (u, v) + J (x, y),
    x, y uniform over the cell, ``ju`` = (|du/dx|, |du/dy|), ``jv`` likewise (cell units):
    each direction's mean by :meth:`BandProfile.trapezoid`, combined by the crossing rule
    (for the product term this takes the mean of V H as the product of the means, exact when
    the grid's lines run along the pixel axes).
    """

    def __init__(self, pattern, sigma: float):
        rgb = np.asarray(pattern.rgb, float) / 255.0
        seq = np.asarray(pattern.sequence)
        self.vertical = BandProfile(pattern.vertical_edges,
                                    rgb[seq[: len(pattern.vertical_edges)]],
                                    pattern.width, sigma)
        self.horizontal = BandProfile(pattern.horizontal_edges,
                                      rgb[seq[: len(pattern.horizontal_edges)]],
                                      pattern.height, sigma)

    def light(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        a = self.vertical.sample(u)
        b = self.horizontal.sample(v)
        return 1.0 - (1.0 - a) * (1.0 - b)

    def light_cell(self, u, v, ju, jv) -> np.ndarray:
        a = self.vertical.trapezoid(u, ju[..., 0], ju[..., 1])
        b = self.horizontal.trapezoid(v, jv[..., 0], jv[..., 1])
        return 1.0 - (1.0 - a) * (1.0 - b)


@functools.lru_cache(maxsize=8)
def pattern_light(pattern, sigma: float) -> PatternLight:
    """The (cached) :class:`PatternLight` of a pattern at a defocus sigma (projector px)."""
    return PatternLight(pattern, sigma)


# ---------------------------------------------------------------------------- geometry
def _object_transform(turntable, angle: float) -> tuple[np.ndarray, np.ndarray]:
    """(M, t) with X_rig = M X_obj + t at table angle ``angle`` (from ``to_rig``)."""
    pts = np.vstack([np.zeros(3), np.eye(3)])
    rig = np.asarray(turntable.to_rig(pts, angle), float)
    t = rig[0]
    m = (rig[1:] - t).T
    return m, t


@dataclass
class _Context:
    scene: Any
    rig: Any
    settings: RenderSettings
    light: PatternLight | None
    m: np.ndarray
    t: np.ndarray
    cam_centre: np.ndarray
    proj_centre: np.ndarray
    albedo_fn: Callable[[np.ndarray], np.ndarray] | None
    albedo_cell: Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray] | None = None


def _mm(a: np.ndarray, m: np.ndarray) -> np.ndarray:
    """Rows of ``a`` (N, 3) times ``m.T``: m applied to each row (einsum: a tall-skinny matmul
    through BLAS is an order of magnitude slower)."""
    return np.einsum("ij,kj->ik", a, m)


def _mv(m: np.ndarray, v: np.ndarray) -> np.ndarray:
    return np.asarray(m, float) @ np.asarray(v, float)


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise dot products of (N, 3) arrays."""
    return np.einsum("ij,ij->i", a, b)


def _norm(a: np.ndarray) -> np.ndarray:
    """Row-wise Euclidean norms of an (N, 3) array."""
    return np.sqrt(np.einsum("ij,ij->i", a, a))


def _trace(ctx: _Context, pix: np.ndarray,
           out: dict[str, np.ndarray] | None = None) -> dict[str, np.ndarray]:
    """Trace camera rays through the pixel positions ``pix`` (N, 2): geometry and shading.

    Returns per ray: ``valid`` (hit anything), ``sid``, ``x_obj``, ``x_rig``, ``proj`` (N, 2),
    ``lit``, ``depth``, and the shading factors ``gain`` and ``amb`` (N, 3) of the radiance
    L_j = gain_j P_j + amb_j (module notes, step 6), ``albedo`` (N, 3) and, without ``out``,
    the irradiance ``irr`` (N,), so that gain = (albedo + gloss term) irr. With ``out``
    (arrays of those names and shapes, filled with the no-hit defaults: NaN, 0, False,
    ``BACKGROUND_ID``) the results are written there instead (no temporary arrays).
    """
    s = ctx.settings
    n = pix.shape[0]
    origin, dirs = ctx.rig.camera.back_project(pix)
    origin = np.asarray(origin, float).reshape(-1, 3)
    dirs = np.asarray(dirs, float).reshape(n, 3)
    m, t = ctx.m, ctx.t
    o_obj = np.broadcast_to(_mv(m.T, (origin - t)[0]), (n, 3))
    d_obj = _mm(dirs, m.T)
    hit = _cast(ctx.scene, o_obj, d_obj)
    valid = np.asarray(hit["hit"], bool).copy()
    dist = np.where(valid, np.asarray(hit["t"], float), np.inf)
    if out is None:
        out = {"valid": valid, "sid": np.full(n, BACKGROUND_ID, np.int32),
               "x_obj": np.full((n, 3), np.nan), "x_rig": np.full((n, 3), np.nan),
               "proj": np.full((n, 2), np.nan), "lit": np.zeros(n, bool),
               "depth": np.full(n, np.nan), "gain": np.zeros((n, 3), np.float32),
               "amb": np.zeros((n, 3), np.float32), "albedo": np.zeros((n, 3), np.float32),
               "irr": np.zeros(n, np.float32)}
    else:  # the caller's arrays, holding the defaults above; ``valid`` is copied at the end
        out = dict(out)
        out["valid_view"], out["valid"] = out["valid"], valid
    on = np.zeros(n, bool)
    if s.table:
        with np.errstate(divide="ignore", invalid="ignore"):
            tt = -o_obj[:, 2] / d_obj[:, 2]
        cand = np.flatnonzero((d_obj[:, 2] < 0) & (tt > 0) & (tt < dist))
        xt = o_obj[cand] + tt[cand, None] * d_obj[cand]
        cand = cand[np.hypot(xt[:, 0], xt[:, 1]) <= s.table_radius]
        on[cand] = True
        valid |= on
    idx = np.flatnonzero(valid)
    if idx.size == 0:
        return _done(out, valid)
    on_v = on[idx]
    sid = np.where(on_v, TABLE_ID, np.asarray(hit["surface_id"])[idx]).astype(np.int32)
    x_obj = np.take(np.asarray(hit["points"], float), idx, axis=0)  # np.take: fast row gather
    nrm = np.take(np.asarray(hit["normals"], float), idx, axis=0)
    if on_v.any():
        ti = idx[on_v]
        x_obj[on_v] = o_obj[ti] + tt[ti, None] * d_obj[ti]
        x_obj[on_v, 2] = 0.0
        nrm[on_v] = (0.0, 0.0, 1.0)
    x_rig = _mm(x_obj, m) + t
    n_rig = _mm(nrm, m)
    to_cam = ctx.cam_centre - x_rig
    n_rig *= np.sign(_dot(n_rig, to_cam))[:, None]
    n_rig /= _norm(n_rig)[:, None]
    proj = np.asarray(ctx.rig.projector.project(x_rig), float).reshape(-1, 2)
    to_proj = ctx.proj_centre - x_rig
    dp = _norm(to_proj)
    lvec = to_proj / dp[:, None]
    cos_p = _dot(n_rig, lvec)
    pw, ph = ctx.rig.projector.width, ctx.rig.projector.height
    with np.errstate(invalid="ignore"):
        lit = ((proj[:, 0] >= -0.5) & (proj[:, 0] <= pw - 0.5) & (proj[:, 1] >= -0.5)
               & (proj[:, 1] <= ph - 0.5) & (cos_p > 0))
    # shadow rays from the projector's centre (object frame)
    li = np.flatnonzero(lit)
    if not getattr(ctx.scene, "self_shadowing", True):
        li = li[on_v[li]]  # the scene's own points cannot be shadowed: the table's only
    if li.size:
        po = _mv(m.T, ctx.proj_centre - t)
        lit[li[_shadowed(ctx.scene, po, x_obj[li], cos_p[li], s.shadow_epsilon)]] = False
    cam = ctx.rig.camera
    depth = np.einsum("ij,j->i", x_rig, np.asarray(cam.R, float)[2]) + float(
        np.asarray(cam.T, float)[2])
    # shading factors: L_j = G_j P_j + A_j
    irr = s.projector_power * (s.ref_distance / dp) ** 2 * np.clip(cos_p, 0, None)
    irr = np.where(lit, irr, 0.0)
    vvec = to_cam / _norm(to_cam)[:, None]
    h = lvec + vvec
    h /= _norm(h)[:, None]
    spec = s.gloss * np.clip(_dot(n_rig, h), 0, None) ** s.shininess
    spec = np.where(on_v | ~lit, 0.0, spec)
    alb = np.empty((idx.size, 3))
    obj = ~on_v
    if ctx.albedo_fn is not None and obj.any():
        alb[obj] = np.asarray(ctx.albedo_fn(x_obj[obj]), float).reshape(-1, 3)
    else:
        alb[obj] = s.albedo
    alb[on_v] = s.table_albedo
    out["sid"][idx] = sid
    out["x_obj"][idx] = x_obj
    out["x_rig"][idx] = x_rig
    out["proj"][idx] = proj
    out["lit"][idx] = lit
    out["depth"][idx] = depth
    out["gain"][idx] = (alb + spec[:, None]) * irr[:, None]
    out["amb"][idx] = alb * s.ambient
    out["albedo"][idx] = alb
    if "irr" in out:
        out["irr"][idx] = irr
    return _done(out, valid)


def _done(out: dict[str, np.ndarray], valid: np.ndarray) -> dict[str, np.ndarray]:
    """Copy ``valid`` into the caller's array of :func:`_trace` (if any)."""
    view = out.pop("valid_view", None)
    if view is not None:
        view[:] = valid
    return out


def _cast(scene, origins: np.ndarray, directions: np.ndarray) -> dict[str, np.ndarray]:
    """``scene.intersect`` for the rays that meet the scene's bounding box (padded by 1 mm).

    Rays that miss the box (slab test) are not cast; they come back as misses.
    """
    n = len(directions)
    box = getattr(scene, "bounds", None)
    if box is None or callable(box):
        sel = np.arange(n)
    else:
        lo, hi = np.asarray(box, float)[0] - 1.0, np.asarray(box, float)[1] + 1.0
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / directions
            ta = (lo - origins) * inv
            tb = (hi - origins) * inv
        tmin = np.fmax.reduce(np.minimum(ta, tb), axis=1)  # nanmax without its copies
        tmax = np.fmin.reduce(np.maximum(ta, tb), axis=1)
        sel = np.flatnonzero(tmax >= np.maximum(tmin, 0.0))
    out = {"t": np.full(n, np.nan), "points": np.full((n, 3), np.nan),
           "normals": np.full((n, 3), np.nan), "surface_id": np.full(n, -1, np.int64),
           "hit": np.zeros(n, bool)}
    if sel.size:
        r = scene.intersect(np.take(origins, sel, axis=0), np.take(directions, sel, axis=0))
        for key in out:
            out[key][sel] = r[key]
    return out


def _shadowed(scene, origin: np.ndarray, points: np.ndarray, cos_p: np.ndarray,
              eps: float) -> np.ndarray:
    """Which surface points (N, 3) are hidden from a light at ``origin`` (object frame).

    A point X is shadowed when the ray from ``origin`` towards X meets the exact surface more
    than ``eps`` mm before X. With a meshed scene (``scene.mesh()``, the inscribed mesh that
    ``intersect`` casts on, tolerance 0.2 mm) the first mesh hit (``scene.mesh_cast``: one
    Embree call for all rays) settles most rays: a hit more
    than 0.5 + 0.5 / cos mm before X is an occluder; a miss, or a hit beyond that margin, is
    resolved exactly by ``scene.intersect`` (Newton on the true surface) only when the hit is
    more than ``eps`` before X. Without a mesh every ray is cast exactly.
    """
    d = points - origin
    dist = _norm(d)
    d = d / dist[:, None]
    o = np.broadcast_to(origin, d.shape)
    mesh_fn = getattr(scene, "mesh", None)
    if callable(mesh_fn):
        tm = np.full(len(d), np.inf)
        cast = getattr(scene, "mesh_cast", None)
        if callable(cast):  # Embree directly: one call, no per-hit Python work
            ray, _, tr, _ = cast(np.ascontiguousarray(o), d)
            tm[ray] = tr
        else:
            tri, ray, loc = mesh_fn().ray.intersects_id(np.ascontiguousarray(o), d,
                                                        multiple_hits=False,
                                                        return_locations=True)
            ray = np.asarray(ray, int)
            if ray.size:
                tm[ray] = _dot(np.asarray(loc, float) - o[ray], d[ray])
        margin = 0.5 + 0.5 / np.maximum(cos_p, 0.02)
        sure = tm < dist - margin
        unsure = np.flatnonzero(~sure & (tm < dist - eps))
    else:
        sure = np.zeros(len(d), bool)
        unsure = np.arange(len(d))
    if unsure.size:
        r = scene.intersect(np.ascontiguousarray(o[unsure]), np.ascontiguousarray(d[unsure]))
        sure[unsure] = np.asarray(r["hit"], bool) & (np.asarray(r["t"], float)
                                                     < dist[unsure] - eps)
    return sure


def subsample_offsets(samples: int) -> np.ndarray:
    """Regular ``samples`` x ``samples`` sub-sample offsets in a pixel, shape (samples^2, 2)."""
    g = (np.arange(samples) + 0.5) / samples - 0.5
    ox, oy = np.meshgrid(g, g)
    return np.stack([ox.ravel(), oy.ravel()], axis=1)


# ---------------------------------------------------------------------------- sensor
def encode(linear: np.ndarray, settings: RenderSettings,
           rng: np.random.Generator | None) -> np.ndarray:
    """Camera blur, noise, clipping, gamma and quantisation of a linear RGB image.

    Parameters
    ----------
    linear : ndarray, shape (H, W, 3)
        Camera-channel radiance in relative units (1 = ``exposure`` of the full well).
    settings : RenderSettings
    rng : numpy Generator or None
        Random numbers for the noise (None, or ``settings.noise == 0``: no noise).

    Returns
    -------
    image : ndarray of uint8 or uint16, shape (H, W, 3)
    """
    s = settings
    img = np.ascontiguousarray(linear, dtype=np.float32)
    # in place, float32 throughout (the same operations, hence bits, as the plain expressions
    # e + noise * sqrt(max(e, 0) + read_noise^2) * N, clip(e / full_well, 0, 1)^(1/g): shot and
    # read noise are independent Gaussians, so one draw of their summed variance is the same
    # distribution); few fresh arrays: each new 85 MB buffer costs its page faults
    if s.camera_blur > 0:
        e = cv2.GaussianBlur(img, (0, 0), sigmaX=s.camera_blur, sigmaY=s.camera_blur,
                             borderType=cv2.BORDER_REFLECT)
        e *= np.float32(s.exposure * s.full_well)
    else:
        e = img * np.float32(s.exposure * s.full_well)
    if s.noise > 0 and rng is not None:
        sd = np.clip(e, 0, None)
        sd += np.float32(s.read_noise ** 2)
        np.sqrt(sd, out=sd)
        np.multiply(np.float32(s.noise), sd, out=sd)
        buf = np.empty_like(e)
        sd *= rng.standard_normal(dtype=np.float32, out=buf)
        e += sd
        del sd, buf
    np.divide(e, np.float32(s.full_well), out=e)
    np.clip(e, 0.0, 1.0, out=e)
    if s.gamma != 1:
        np.power(e, np.float32(1.0 / s.gamma), out=e)
    top = 255 if s.bit_depth == 8 else 65535
    e *= np.float32(top)
    np.rint(e, out=e)
    return e.astype(np.uint8 if s.bit_depth == 8 else np.uint16)


def noise_rng(seed: int, stream: int, kind: int) -> np.random.Generator:
    """The generator of one image: ``kind`` 0 = grid, 1 = white; ``stream`` the image's number."""
    return np.random.default_rng(np.random.SeedSequence([int(seed), int(stream), int(kind)]))


# ---------------------------------------------------------------------------- rendering
@dataclass(frozen=True)
class RenderedView:
    """One rendered view.

    Attributes
    ----------
    grid, white : ndarray, shape (H, W, 3), uint8 or uint16
        The camera images under the grid and under white light.
    linear_grid, linear_white : ndarray, shape (H, W, 3), float32
        The noise-free camera radiance before blur and encoding.
    truth : dict of ndarray
        At each pixel centre: ``depth`` (camera z, mm), ``point_rig`` and ``point_obj``
        (H, W, 3, mm), ``surface_id`` (int32; -1 background, -2 table), ``proj_x``,
        ``proj_y`` (exact projector coordinate, px), ``lit`` (bool). Geometric arrays are
        float64 (NaN where nothing is hit), so that the truth keeps 1e-6 px / 1e-6 mm.
    stats : dict
        Wall-clock seconds of each phase and pixel counts (for benchmarks).
    """

    grid: np.ndarray
    white: np.ndarray
    linear_grid: np.ndarray
    linear_white: np.ndarray
    truth: dict[str, np.ndarray]
    stats: dict[str, float] = field(default_factory=dict)


def _neighbour_ok(valid, sid, lit, u, v, alb, jump) -> tuple[np.ndarray, np.ndarray]:
    """Continuity of each pixel with its right and lower neighbour, shapes (H, W-1), (H-1, W).

    Neighbours are continuous when both hit the same kind of surface (object, table or
    nothing), both are lit or both are not, their albedos agree (texture edges are traced
    exactly) and, when lit, their projector coordinates differ by less than ``jump`` px.
    """
    cls = np.where(sid >= 0, 0, sid)

    def ok(sl_a, sl_b):
        same = (valid[sl_a] == valid[sl_b]) & (cls[sl_a] == cls[sl_b]) & (lit[sl_a] == lit[sl_b])
        aa, ab = alb[sl_a], alb[sl_b]
        for c in range(alb.shape[-1]):  # per channel: np.all over a length-3 axis is slow
            same &= np.abs(aa[..., c] - ab[..., c]) < 1e-6
        with np.errstate(invalid="ignore"):
            smooth = (np.abs(u[sl_a] - u[sl_b]) < jump) & (np.abs(v[sl_a] - v[sl_b]) < jump)
        return same & (smooth | ~lit[sl_a])

    with ThreadPoolExecutor(max_workers=2) as pool:  # numpy releases the GIL: 2 threads
        jx = pool.submit(ok, (slice(None), slice(None, -1)), (slice(None), slice(1, None)))
        oky = ok((slice(None, -1), slice(None)), (slice(1, None), slice(None)))
        okx = jx.result()
    return okx, oky


def render_view(scene, rig, pattern, angle: float = 0.0, settings: RenderSettings | None = None,
                seed: int = 0, stream: int = 0,
                albedo: Callable[[np.ndarray], np.ndarray] | None = None,
                workers: int | None = None,
                albedo_cell: Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]
                | None = None, truth: bool = True) -> RenderedView:
    """Render the grid image, the white image and the truth of one view (module notes).

    Parameters
    ----------
    scene : object with ``intersect(origins, directions)``
        In the object (table) frame, mm (see :mod:`nurbscan.simulate.scenes`).
    rig : nurbscan.camera.Rig
    pattern : nurbscan.pattern.Pattern
        Its size must be the projector's.
    angle : float
        Table angle, radians.
    settings : RenderSettings, optional
    seed, stream : int
        Noise seed and the image's stream number (a view or calibration pose index).
    albedo : callable, optional
        ``albedo(points_obj (N, 3)) -> (N, 3)`` texture of the scene's surface; default the
        constant ``settings.albedo``.
    workers : int, optional
        Threads (default: the number of CPUs). The result does not depend on it.
    albedo_cell : callable, optional
        ``albedo_cell(points_obj, dx, dy) -> (N, 3)``, the texture's mean over the
        parallelogram cells ``points + dx s + dy t`` (s, t in [-1/2, 1/2]; object frame, mm).
        With it the traced sub-samples of texture edges integrate the texture over their
        cells (sides from the neighbouring sub-samples on the same surface) instead of
        point-sampling it, so that a printed edge moves continuously with the surface
        (module notes, step 5).
    truth : bool
        Keep the 3-D truth (``depth``, ``point_rig``, ``point_obj``: 0.4 GB at 7 MP). Without
        it ``RenderedView.truth`` holds only the 2-D arrays (calibration images need none).
    """
    s = settings or RenderSettings()
    cam = rig.camera
    if (pattern.width, pattern.height) != (rig.projector.width, rig.projector.height):
        raise NurbscanError(
            f"pattern {pattern.width} x {pattern.height}: not the projector's size "
            f"{rig.projector.width} x {rig.projector.height}")
    m, t = _object_transform(rig.turntable, float(angle))
    light = pattern_light(pattern, float(s.projector_blur))
    ctx = _Context(scene=scene, rig=rig, settings=s, light=light, m=m, t=t,
                   cam_centre=np.asarray(cam.center, float),
                   proj_centre=np.asarray(rig.projector.center, float), albedo_fn=albedo,
                   albedo_cell=albedo_cell)
    W, H = int(cam.width), int(cam.height)
    npx = W * H
    n_workers = max(1, int(workers or os.cpu_count() or 1))
    # ---- pass 1: exact rays through the pixel centres
    valid = np.zeros(npx, bool)
    lit = np.zeros(npx, bool)
    sid = np.full(npx, BACKGROUND_ID, np.int32)
    # the 3-D truth is written per chunk into scratch arrays when it is not kept
    n_geo = npx if truth else 0
    x_obj = np.full((n_geo, 3), np.nan)
    x_rig = np.full((n_geo, 3), np.nan)
    proj = np.full((npx, 2), np.nan)
    depth = np.full(n_geo, np.nan)
    gain = np.zeros((npx, 3), np.float32)
    amb = np.zeros((npx, 3), np.float32)
    albedo_px = np.zeros((npx, 3), np.float32)
    clock = time.perf_counter()
    stats: dict[str, float] = {}

    def lap(name: str) -> None:
        nonlocal clock
        now = time.perf_counter()
        stats[f"{name}_s"] = now - clock
        clock = now

    _warm_up(scene)
    lap("warm_up")

    def centres(a: int) -> None:
        b = min(a + _CHUNK, npx)
        k = np.arange(a, b)
        # written straight into the image's arrays (they hold the no-hit defaults)
        geo = ((x_obj[a:b], x_rig[a:b], depth[a:b]) if truth else
               (np.full((b - a, 3), np.nan), np.full((b - a, 3), np.nan),
                np.full(b - a, np.nan)))
        _trace(ctx, np.stack([k % W, k // W], axis=1).astype(float), out={
            "valid": valid[a:b], "lit": lit[a:b], "sid": sid[a:b], "x_obj": geo[0],
            "x_rig": geo[1], "proj": proj[a:b], "depth": geo[2], "gain": gain[a:b],
            "amb": amb[a:b], "albedo": albedo_px[a:b]})

    pool = ThreadPoolExecutor(max_workers=n_workers)
    with pool:
        list(pool.map(centres, range(0, npx, _CHUNK)))
    lap("centre_rays")
    shape = (H, W)
    valid2, lit2, sid2 = valid.reshape(shape), lit.reshape(shape), sid.reshape(shape)
    u2, v2 = proj[:, 0].reshape(shape), proj[:, 1].reshape(shape)
    # ---- continuity and Jacobian of the projector coordinate field
    both = lit2[:, 1:] & lit2[:, :-1]
    du = np.abs(np.diff(u2, axis=1))[both]
    dv = np.abs(np.diff(v2, axis=0))[lit2[1:] & lit2[:-1]]
    typical = max(float(np.median(du)) if du.size else 0.0,
                  float(np.median(dv)) if dv.size else 0.0)
    jump = max(3.0, 6.0 * typical)
    okx, oky = _neighbour_ok(valid2, sid2, lit2, u2, v2, albedo_px.reshape(H, W, 3), jump)
    smooth = np.zeros(shape, bool)
    smooth[1:-1, 1:-1] = (okx[1:-1, 1:] & okx[1:-1, :-1] & oky[1:, 1:-1] & oky[:-1, 1:-1])
    exact = ~smooth  # pixels traced with one ray per sub-sample
    exact &= ~(~valid2 & _all_neighbours(~valid2))  # plain background needs nothing
    offs = subsample_offsets(s.samples)
    ns = offs.shape[0]
    soffs = subsample_offsets(s.smooth_samples)
    nss = soffs.shape[0]
    lin_grid = np.zeros((npx, 3), np.float32)
    lin_white = np.zeros((npx, 3), np.float32)
    # smooth pixels: shading of the centre, pattern averaged over the sub-cells
    flat_smooth = smooth.ravel()
    sm_lit = np.flatnonzero(flat_smooth & lit)
    sm_dark = flat_smooth & ~lit
    np.add(gain, amb, out=lin_white, where=flat_smooth[:, None])  # masked, without gathers
    np.copyto(lin_grid, amb, where=sm_dark[:, None])

    def smooth_block(a: int) -> None:
        k = sm_lit[a:a + step_s]
        # central differences: (du/dx, dv/dx), (du/dy, dv/dy); the four neighbours are lit
        # (the image's border is traced exactly)
        ux = 0.5 * (np.take(proj, k + 1, axis=0) - np.take(proj, k - 1, axis=0))
        uy = 0.5 * (np.take(proj, k + W, axis=0) - np.take(proj, k - W, axis=0))
        us = proj[k, 0:1] + ux[:, 0:1] * soffs[:, 0] + uy[:, 0:1] * soffs[:, 1]
        vs = proj[k, 1:2] + ux[:, 1:2] * soffs[:, 0] + uy[:, 1:2] * soffs[:, 1]
        ju = np.stack([np.abs(ux[:, 0]), np.abs(uy[:, 0])], axis=1) / s.smooth_samples
        jv = np.stack([np.abs(ux[:, 1]), np.abs(uy[:, 1])], axis=1) / s.smooth_samples
        shp = us.shape + (2,)
        p = ctx.light.light_cell(us, vs, np.broadcast_to(ju[:, None], shp),
                                 np.broadcast_to(jv[:, None], shp))
        p = p[:, 0] if nss == 1 else p.mean(axis=1)  # the mean of one value is that value
        lin_grid[k] = np.take(gain, k, axis=0) * p + np.take(amb, k, axis=0)

    # exact pixels: one traced ray per sub-sample
    ex = np.flatnonzero(exact.ravel())

    def exact_block(a: int) -> None:
        k = ex[a:a + step_x]
        base = np.stack([k % W, k // W], axis=1).astype(float)
        pix = (base[:, None, :] + offs[None, :, :]).reshape(-1, 2)
        r = _trace(ctx, pix)
        if ctx.albedo_cell is not None:
            _integrate_texture(ctx, r, s.samples)
        p = np.zeros((pix.shape[0], 3), np.float32)
        lt = r["lit"]
        if lt.any():
            ju, jv = _subcell_jacobian(r["proj"], s.samples)
            p[lt] = ctx.light.light_cell(r["proj"][lt, 0], r["proj"][lt, 1], ju[lt], jv[lt])
        g = r["gain"]
        lin_grid[k] = (g * p + r["amb"]).reshape(-1, ns, 3).mean(axis=1)
        lin_white[k] = (g + r["amb"]).reshape(-1, ns, 3).mean(axis=1)

    step_s = max(_CHUNK // nss, 1)
    step_x = max(_CHUNK // (4 * ns), 1)
    pool = ThreadPoolExecutor(max_workers=n_workers)
    with pool:
        jobs = [pool.submit(smooth_block, a) for a in range(0, sm_lit.size, step_s)]
        n_smooth = len(jobs)
        jobs += [pool.submit(exact_block, a) for a in range(0, ex.size, step_x)]
        for j in jobs[:n_smooth]:
            j.result()
        lap("smooth_pixels")
        for j in jobs[n_smooth:]:
            j.result()
        lap("exact_pixels")
    stats.update(smooth_lit_pixels=int(sm_lit.size), exact_pixels=int(ex.size),
                 exact_rays=int(ex.size * ns))
    mix = np.asarray(s.mixing, np.float32)
    lin_grid = cv2.transform(lin_grid.reshape(H, W, 3), mix)  # per pixel: M @ rgb
    lin_white = cv2.transform(lin_white.reshape(H, W, 3), mix)
    # the two images' sensors are independent (own generators): one thread each
    pool = ThreadPoolExecutor(max_workers=min(2, n_workers))
    with pool:
        job = pool.submit(encode, lin_white, s, noise_rng(seed, stream, 1))
        grid = encode(lin_grid, s, noise_rng(seed, stream, 0))
        white = job.result()
    lap("sensor")
    geometry = {"depth": depth.reshape(shape), "point_rig": x_rig.reshape(H, W, 3),
                "point_obj": x_obj.reshape(H, W, 3)} if truth else {}
    truth = {
        **geometry,
        "surface_id": sid2,
        "proj_x": u2,
        "proj_y": v2,
        "lit": lit2,
    }
    return RenderedView(grid=grid, white=white, linear_grid=lin_grid, linear_white=lin_white,
                        truth=truth, stats=stats)


def _subcell_jacobian(proj: np.ndarray, samples: int) -> tuple[np.ndarray, np.ndarray]:
    """|Jacobian| of the projector coordinates over each traced sub-sample's cell.

    ``proj`` (N * samples^2, 2) holds the sub-samples pixel by pixel, x fastest. Returns
    ``ju``, ``jv`` (N * samples^2, 2): (|du/dx|, |du/dy|) and (|dv/dx|, |dv/dy|) in
    projector px per cell, by differences between neighbouring sub-samples (central inside,
    one-sided at the pixel's border); 0 (a point sample) where a neighbour hits nothing or
    the difference is a jump (over 4 px: another surface).
    """
    if samples < 2:
        z = np.zeros((len(proj), 2))
        return z, z
    q = proj.reshape(-1, samples, samples, 2)
    gy = np.abs(np.gradient(q, axis=1)).reshape(-1, 2)
    gx = np.abs(np.gradient(q, axis=2)).reshape(-1, 2)
    gx = np.where(np.isfinite(gx) & (gx < 4.0), gx, 0.0)
    gy = np.where(np.isfinite(gy) & (gy < 4.0), gy, 0.0)
    return np.stack([gx[:, 0], gy[:, 0]], axis=1), np.stack([gx[:, 1], gy[:, 1]], axis=1)


def _subcell_steps(q: np.ndarray, ok: np.ndarray, sid: np.ndarray, axis: int) -> np.ndarray:
    """Step of ``q`` (N, S, S, 3) between neighbouring sub-samples along ``axis`` (1 or 2).

    Per sub-sample, the mean of its differences to the neighbours on the same surface (same
    ``sid``, both ``ok``): central inside a surface, one-sided at its border, 0 where it has
    none. Shape (N * S * S, 3).
    """
    d = np.diff(q, axis=axis)
    a = [slice(None)] * 3
    b = [slice(None)] * 3
    a[axis], b[axis] = slice(None, -1), slice(1, None)
    same = ok[tuple(a)] & ok[tuple(b)] & (sid[tuple(a)] == sid[tuple(b)])
    d = np.where(same[..., None], d, 0.0)
    pad_lo, pad_hi = [(0, 0)] * 4, [(0, 0)] * 4
    pad_lo[axis], pad_hi[axis] = (1, 0), (0, 1)
    total = np.pad(d, pad_lo) + np.pad(d, pad_hi)
    count = np.pad(same, pad_lo[:3]).astype(float) + np.pad(same, pad_hi[:3])
    return (total / np.maximum(count, 1.0)[..., None]).reshape(-1, 3)


def _integrate_texture(ctx: _Context, r: dict[str, np.ndarray], samples: int) -> None:
    """Replace the point-sampled albedo of traced sub-samples by its mean over their cells.

    Each sub-sample's cell sides are the steps to its neighbouring sub-samples on the same
    surface (:func:`_subcell_steps`); ``ctx.albedo_cell`` averages the texture over the cell,
    and ``gain`` and ``amb`` of ``r`` (from :func:`_trace`) are rescaled to it in place.
    """
    obj = np.flatnonzero(r["sid"] >= 0)
    if obj.size == 0 or samples < 2:
        return
    q = r["x_obj"].reshape(-1, samples, samples, 3)
    sid = r["sid"].reshape(q.shape[:3])
    ok = np.isfinite(q).all(axis=-1)
    dx = _subcell_steps(q, ok, sid, 2)[obj]
    dy = _subcell_steps(q, ok, sid, 1)[obj]
    alb = np.asarray(ctx.albedo_cell(r["x_obj"][obj], dx, dy), np.float32).reshape(-1, 3)
    change = alb - r["albedo"][obj]
    r["gain"][obj] += change * r["irr"][obj, None]
    r["amb"][obj] += change * np.float32(ctx.settings.ambient)
    r["albedo"][obj] = alb


def _warm_up(scene) -> None:
    """Build a scene's lazy caches (mesh, ray engine, bounds) before threads share it."""
    mesh_fn = getattr(scene, "mesh", None)
    if callable(mesh_fn):
        mesh_fn()
    getattr(scene, "bounds", None)
    scene.intersect(np.zeros((1, 3)), np.array([[0.0, 0.0, -1.0]]))


def _all_neighbours(mask: np.ndarray) -> np.ndarray:
    """True where ``mask`` holds at the pixel and its 8 neighbours (outside counts as true)."""
    m = np.pad(mask, 1, constant_values=True)
    out = mask.copy()
    h, w = mask.shape
    for dy in (0, 1, 2):
        for dx in (0, 1, 2):
            out &= m[dy:dy + h, dx:dx + w]
    return out
