"""The two band families' local frames: their normals, each family's own edge derivative, and
the fit lines along which :func:`~nurbscan.detect.edges.detect_edge_points` and
:func:`~nurbscan.detect.refine.refine_by_channels` sample the edge profiles.

method.md section 2. :func:`family_normals` finds the local normals of the vertical and the
horizontal bands' edges (per tile, from a histogram of the gradient directions);
:func:`across_operators` turns them into per-pixel vectors whose product with the gradient is
each family's own derivative (the derivative along the other family's edges, which does not see
them); :func:`fit_slopes` gives the line through each edge pixel along which its profile is
fitted, and :func:`_along_line` samples images along those lines (cubic convolution across
them).

The sub-pixel position of an edge point is the vertex of a parabola fitted to the logarithm
of its family's derivative at three samples across the edge (:mod:`~nurbscan.detect.edges`).
Near a crossing band the edge is not isolated, and where the two families are not
perpendicular the fit is taken along a slanted line instead of the row (column),
:func:`fit_slopes`. There the vertical family's component is ``a = V'(s_v) K(s_h)``, with
``s_v = n_v . p`` and ``s_h = n_h . p`` (:func:`~nurbscan.detect.normalize.edge_signal`:
``K`` is the crossing band's shading of the edge, ``sum_c v_c (1 - H h_c)``). The projector's
defocus blurs ``V`` and ``H`` apart (the pattern is separable in the projector), but the blur
applied in the camera (lens, pixel, the derivative filter: variance ``s_m^2``) mixes the two
factors. With ``K`` locally ``exp(k s_h)``, a Gaussian turns ``V'(s_v) exp(k s_h)`` into the
blurred ``V'`` at ``s_v + s_m^2 k cos(phi)`` times ``exp(k s_h)`` (``cos(phi) = n_v . n_h``;
the Gaussian shift theorem): along a line of constant ``s_h`` the profile's peak is off the
edge by ``-s_m^2 k cos(phi)``. Along a line in direction ``e`` the factor ``exp(k s_h)`` adds
``s_f^2 k (n_h . e) / (n_v . e)``, with ``s_f`` the width of the blurred profile in ``s_v``
(from the parabola's curvature along the row). The two cancel on the line with
``(n_h . e) / (n_v . e) = (s_m^2 / s_f^2) cos(phi)``, between the other family's edge
direction (where only the first shift remains) and the family's own normal (where the second
overcorrects). On an upright grid (``cos(phi) = 0``, ``n_h`` along y) it is the row
(figures: :func:`~nurbscan.detect.detect_grid`'s ``fit_line``).
"""

from __future__ import annotations

import cv2
import numpy as np

from .._jit import njit
from ._threads import in_halves, parallel_map


def family_normals(gx: np.ndarray, gy: np.ndarray, strong: np.ndarray, tile: int = 48,
                   bins: int = 36, min_ratio: float = 0.15, min_separation: float = 0.35,
                   pixels: tuple | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Local normal directions of the vertical and the horizontal band edges (radians).

    The gradient directions ``atan2(gy, gx)`` (mod pi) of the ``strong`` pixels are
    histogrammed (``bins`` bins, weighted by the gradient magnitude) per ``tile`` x ``tile``
    px tile and smoothed over the 3 x 3 neighbouring tiles and the neighbouring bins; the two
    highest peaks at least ``min_separation`` apart (the second at least ``min_ratio`` of the
    first) are the two families' normals, and the one nearer the image's y axis is the
    horizontal bands' (in the projector the bands are upright; in the camera the horizontal
    ones stay closer to horizontal, nearly along the epipolar lines of a camera beside the
    projector). Tiles with one family or none take the image axes (0 and pi / 2). This is a
    histogram of oriented gradients (Dalal and Triggs 2005) read for its two modes.

    Parameters
    ----------
    gx, gy : ndarray (H, W)
        Gradient of the edge signal.
    strong : ndarray (H, W) bool
        Edge pixels to count.
    pixels : (iy, ix, gx, gy), optional
        ``np.nonzero(strong)`` and the gradient there, when the caller has them.

    Returns
    -------
    theta_v, theta_h : ndarray (ceil(H / tile), ceil(W / tile)) float64
        Normal angle of each family per tile, radians in [0, pi).
    """
    h, w = gx.shape
    ty, tx = -(-h // tile), -(-w // tile)
    if pixels is None:
        iy, ix = np.nonzero(strong)
        ax, ay = gx[iy, ix], gy[iy, ix]
    else:
        iy, ix, ax, ay = pixels

    def keys(part):  # each pixel's (tile, bin) and weight, element by element (the two
        # halves side by side: _threads)
        phi = np.mod(np.arctan2(ay[part], ax[part]), np.pi)
        b = np.minimum((phi * (bins / np.pi)).astype(np.int64), bins - 1)
        t = (iy[part] // tile).astype(np.int64) * tx + ix[part] // tile
        return t * bins + b, np.hypot(ax[part], ay[part])

    key, weight = in_halves(keys, len(iy))
    hist = np.bincount(key, weights=weight,
                       minlength=ty * tx * bins).reshape(ty, tx, bins)
    from scipy.ndimage import uniform_filter1d

    hist = uniform_filter1d(uniform_filter1d(hist, 3, axis=0, mode="nearest"), 3, axis=1,
                            mode="nearest")
    hist = 0.5 * hist + 0.25 * (np.roll(hist, 1, axis=2) + np.roll(hist, -1, axis=2))
    centre = (np.arange(bins) + 0.5) * (np.pi / bins)

    def peak(hh):
        k = np.argmax(hh, axis=2)
        v0 = np.take_along_axis(hh, k[..., None], 2)[..., 0]
        vm = np.take_along_axis(hh, ((k - 1) % bins)[..., None], 2)[..., 0]
        vp = np.take_along_axis(hh, ((k + 1) % bins)[..., None], 2)[..., 0]
        den = vm - 2 * v0 + vp
        with np.errstate(all="ignore"):
            d = np.where(den < 0, 0.5 * (vm - vp) / den, 0.0)
        return np.mod(centre[k] + np.clip(d, -0.5, 0.5) * (np.pi / bins), np.pi), v0

    a1, v1 = peak(hist)
    sep = np.abs(np.mod(centre[None, None, :] - a1[..., None] + np.pi / 2, np.pi) - np.pi / 2)
    a2, v2 = peak(np.where(sep >= min_separation, hist, 0.0))
    two = (v1 > 0) & (v2 >= min_ratio * v1)
    # the horizontal family's normal is the one nearer pi / 2
    d1, d2 = np.abs(a1 - np.pi / 2), np.abs(a2 - np.pi / 2)
    th = np.where(d1 <= d2, a1, a2)
    tv = np.where(d1 <= d2, a2, a1)
    return np.where(two, tv, 0.0), np.where(two, th, np.pi / 2)


def across_operators(theta_v: np.ndarray, theta_h: np.ndarray, shape: tuple[int, int]
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Per-pixel vectors that take each family's own edge derivative from the gradient.

    With the families' unit normals ``n_v``, ``n_h`` (angles ``theta_v``, ``theta_h`` per tile,
    :func:`family_normals`), a gradient is ``g = a n_v + b n_h``: ``a`` from the vertical-band
    edges, ``b`` from the horizontal ones. The derivative along the horizontal edges' tangent
    ``m_v`` (perpendicular to ``n_h``) does not see the horizontal edges at all, and
    ``g . m_v / (n_v . m_v) = a``; likewise ``b`` along the vertical edges' tangent. Where the
    families are upright these are the plain ``g_x`` and ``g_y``; on a surface seen
    obliquely, where the two families meet at a shallow angle, ``g_x`` also carries the tilted
    horizontal edges (their derivative across the row) and shifts the vertical edges'
    peaks near every crossing band, while ``a`` keeps only the vertical edge: the
    maximum of ``|a|`` along the row lies on the vertical edge as that of ``|g_x|`` does
    on an upright grid. ``n_v . m_v`` is the sine of the angle between the families and is
    kept at least 0.25 (14.5 degrees).

    Returns
    -------
    across_v, across_h : tuple of two ndarray (H, W) float32
        The x and y components of ``m_v / (n_v . m_v)`` and of ``m_h / (n_h . m_h)``,
        bilinearly interpolated between the tile centres.
    """
    h, w = shape
    tv = np.where(theta_v > np.pi / 2, theta_v - np.pi, theta_v)  # n_v towards +x
    nv = np.stack([np.cos(tv), np.sin(tv)])
    nh = np.stack([np.cos(theta_h), np.sin(theta_h)])  # towards +y (theta_h in [0, pi))

    def operator(normals):  # one family's (the two side by side: _threads)
        n_own, n_other = normals
        m = np.stack([-n_other[1], n_other[0]])  # the other family's edge tangent
        dot = (m * n_own).sum(0)
        m = np.where(dot < 0, -m, m)
        a = m / np.maximum(np.abs(dot), 0.25)
        return tuple(_tiles_to_pixels(c, (h, w)) for c in a)

    out = parallel_map(operator, ((nv, nh), (nh, nv)))
    return out[0], out[1]


def _tiles_to_pixels(values: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Per-tile values (ty, tx) spread over the (H, W) pixels, bilinearly (float32)."""
    return cv2.resize(np.asarray(values, np.float32), (shape[1], shape[0]),
                      interpolation=cv2.INTER_LINEAR)


#: Largest |slope| of a fit line (:func:`fit_slopes`), px per px. The model of the module
#: notes (``K`` exponential over the samples' reach) holds near the line's centre only, and
#: the profile's curvature overstates ``1 / s_f^2`` next to a narrow band's other edge; steeper
#: lines cost accuracy where the bands are narrow (1280 x 960 teapot view, RMS against the
#: row: 0.0528 -> 0.0570 px with 1.5, 0.0531 px with 0.3; 7.1 MP view 0.0366 and 0.0369 px).
MAX_SLOPE = 0.3


def fit_slopes(n_own: np.ndarray, n_other: np.ndarray, axis: int, curvature: np.ndarray,
               mix_var: float) -> np.ndarray:
    """Slope of the line along which each edge point's profile is fitted (module notes).

    The line ``e`` through the edge pixel on which the crossing band's two shifts of the
    profile's peak cancel: ``(n_other . e) / (n_own . e) = r cos(phi)`` with
    ``r = mix_var / s_f^2``, ``s_f^2 = -n_own[axis]^2 / curvature`` the variance of the
    blurred edge profile (across the edge, px^2) and ``cos(phi) = n_own . n_other``.

    Parameters
    ----------
    n_own, n_other : ndarray (N, 2)
        Unit normals (x, y) of the point's family and of the other family (signs free).
    axis : int
        The search axis: 0 for vertical-band edges (rows; ``e = (1, slope)``), 1 for
        horizontal ones (columns; ``e = (slope, 1)``).
    curvature : ndarray (N,)
        Second difference of ``ln |derivative|`` along the search axis at the edge pixel
        (negative at a peak), per px^2.
    mix_var : float
        Variance of the blur applied in the camera (derivative filter, lens, pixel), px^2.

    Returns
    -------
    ndarray (N,) float64
        Offset along the other axis per px of the search axis, clipped to +-MAX_SLOPE; 0
        (to rounding) where the families are upright: then the row or column.

    Notes
    -----
    ``r`` is clipped to [0, 1] (the camera's blur is part of the profile's) and
    ``-curvature`` floored at 1e-3 (a flat profile: ``r`` near 0, the other family's edge
    direction). The model takes the camera's blur as isotropic: with a ``sigma_along``
    other than ``sigma`` in :func:`detect_edge_points` ``mix_var`` is only approximate.
    """
    b = 1 - axis
    own_a, own_b = n_own[:, axis], n_own[:, b]
    oth_a, oth_b = n_other[:, axis], n_other[:, b]
    sf2 = own_a * own_a / np.maximum(-np.asarray(curvature, np.float64), 1e-3)
    rc = np.clip(mix_var / np.maximum(sf2, 1e-6), 0.0, 1.0) * (own_a * oth_a + own_b * oth_b)
    den = oth_b - rc * own_b
    with np.errstate(divide="ignore", invalid="ignore"):
        sl = (rc * own_a - oth_a) / den
    return np.clip(np.nan_to_num(sl, nan=0.0), -MAX_SLOPE, MAX_SLOPE)


def _along_line(img: np.ndarray, ix: np.ndarray, iy: np.ndarray, axis: int,
                slope: np.ndarray, step) -> np.ndarray:
    """``img`` (H, W) at the (K,) ``step`` px along the fit lines through the pixels
    ``ix``, ``iy`` (N,), float64 (N, K), point by point (:func:`_line_samples`).

    A step is one px along the search axis (``axis`` 0: x, rows; 1: y, columns; one for all
    or (N,)) and ``slope`` (N,) px across it; between the pixels across, the image is
    interpolated by cubic convolution (Keys 1981, a = -0.5: exact for quadratics, where the
    linear interpolation's error across a tilted edge's profile would shift the fitted
    peak). The image's border clamps.

    References
    ----------
    .. [1] R. Keys, "Cubic convolution interpolation for digital image processing", IEEE
       Trans. Acoustics, Speech and Signal Processing 29(6), 1153-1160, 1981.
    """
    ix, iy = np.asarray(ix, np.int64), np.asarray(iy, np.int64)
    out = np.empty((len(ix), len(step)))
    along_x = np.broadcast_to(np.asarray(axis) == 0, ix.shape)
    _line_samples(img, ix, iy, np.ascontiguousarray(along_x),
                  np.ascontiguousarray(slope, np.float64), np.asarray(step, np.float64), out)
    return out


@njit(cache=True, nogil=True)
def _line_samples(img, ix, iy, along_x, slope, steps, out):
    """``out[i, k]``: ``img`` (H, W) at ``steps[k]`` px along point i's fit line
    (:func:`_along_line`): the four taps across, clamped at the border, weighted by Keys'
    cubic (float64) and summed in their order."""
    h, w = img.shape
    for i in range(len(ix)):
        ax = along_x[i]
        for k in range(len(steps)):
            st = steps[k]
            off = st * slope[i]
            f = np.floor(off)
            t = off - f
            w0 = ((-0.5 * t + 1.0) * t - 0.5) * t
            w1 = (1.5 * t - 2.5) * t * t + 1.0
            w2 = ((-1.5 * t + 2.0) * t + 0.5) * t
            w3 = (0.5 * t - 0.5) * t * t
            if ax:
                run = min(max(ix[i] + np.int64(st), 0), w - 1)
                a, top = np.int64(f) + iy[i], h - 1
            else:
                run = min(max(iy[i] + np.int64(st), 0), h - 1)
                a, top = np.int64(f) + ix[i], w - 1
            a0, a1 = min(max(a - 1, 0), top), min(max(a, 0), top)
            a2, a3 = min(max(a + 1, 0), top), min(max(a + 2, 0), top)
            if ax:
                v0, v1, v2, v3 = img[a0, run], img[a1, run], img[a2, run], img[a3, run]
            else:
                v0, v1, v2, v3 = img[run, a0], img[run, a1], img[run, a2], img[run, a3]
            out[i, k] = ((np.float64(v0) * w0 + np.float64(v1) * w1)
                         + np.float64(v2) * w2) + np.float64(v3) * w3

