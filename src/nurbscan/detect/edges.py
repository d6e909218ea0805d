"""Sub-pixel edge points: zero crossings of the second directional derivative (Haralick 1984).

method.md section 2. The edge signal ``s`` (H, W) is smoothed by a Gaussian of scale ``sigma``
and differentiated (Gaussian derivative filters, :func:`gradient`), giving ``s_x`` and ``s_y``.
A pixel is an edge pixel where the second derivative across the edge crosses zero with negative
slope, i.e. where the first derivative has a strict local maximum across the edge. Edges are
classified by the gradient direction:

* *vertical* band edges, searched along the pixel row as maxima of ``|s_x|``, rising where
  ``s_x > 0`` (dark to light in +x) and falling where ``s_x < 0``;
* *horizontal* band edges, searched along the pixel column as maxima of ``|s_y|``, rising
  where ``s_y > 0`` and falling where ``s_y < 0``.

A pixel's family is the one whose local direction its gradient is closer to
(:func:`family_normals`): on a surface seen obliquely the vertical bands can tilt past 45
degrees (the teapot's lid: the two families meet at about 33 degrees there), where the plain
rule ``|s_x| >= |s_y|`` would call them horizontal. Where the two families are upright the
rule is the plain one. With the families, ``s_x`` and ``s_y`` below stand for each family's
own component of the gradient (:func:`across_operators`: the derivative along the other
family's edges); they are the plain derivatives where the families are upright.

For a straight edge the maximum of the derivative along any line across it lies on the edge,
so the row (column) search finds the same points as a search along the gradient, on the pixel
grid; and the vertical family's derivative ``s_x`` of the summed signal is not disturbed by
a crossing horizontal band (see :func:`~nurbscan.detect.normalize.edge_signal`), where the
gradient magnitude would be: the derivative along the band's edges does not see them. (The
plain row derivative has that property only for an upright crossing band.) The sub-pixel
position is the vertex of a quadratic fitted to ``ln |s_x|`` at the three samples across the
crossing (offsets -1, 0, +1):
``d = (l- - l+) / (2 (l- - 2 l0 + l+))``. The derivative of a Gaussian-blurred step is a
Gaussian, whose logarithm is exactly a parabola, so this fit of the zero of the second
derivative is unbiased for an isolated blurred step edge, at any tilt (the profile along a row
is then a wider Gaussian).

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

from dataclasses import dataclass

import cv2
import numpy as np

from ..errors import NurbscanError
from ._threads import parallel_map

#: Edge classes: (direction, edge) -> class id.
CLASSES = {("v", 0): 0, ("v", 1): 1, ("h", 0): 2, ("h", 1): 3}

#: Side of the tiles of :func:`family_normals` in :func:`detect_edge_points`, camera px.
FAMILY_TILE = 48


def work_window(mask: np.ndarray, margin: int, tile: int = 1) -> tuple[slice, slice]:
    """The rows and columns of ``mask`` (H, W) that hold its True pixels, widened by
    ``margin`` px on each side and to multiples of ``tile`` px from the image's origin (an
    image-sized window where ``mask`` has no True pixel).

    The filters of :func:`gradient` and the tile histograms of :func:`family_normals` give the
    same values inside such a window as over the whole image (the window's own border lies
    ``margin`` px away from every pixel that counts), at the cost of the window's pixels only:
    on the 7.1 MP teapot views the projector lights about 14 % of the image, in a window of
    about a third of it.
    """
    h, w = mask.shape
    x, y, bw, bh = cv2.boundingRect(np.ascontiguousarray(mask, np.bool_).view(np.uint8))
    if bw == 0 or bh == 0:
        return slice(0, h), slice(0, w)
    y0, x0 = max(y - margin, 0) // tile * tile, max(x - margin, 0) // tile * tile
    y1 = min(-(-(y + bh + margin) // tile) * tile, h)
    x1 = min(-(-(x + bw + margin) // tile) * tile, w)
    return slice(y0, y1), slice(x0, x1)


def gaussian_kernels(sigma: float) -> tuple[np.ndarray, np.ndarray]:
    """Sampled Gaussian ``G`` and derivative ``G'`` kernels (radius ceil(4 sigma)), float32."""
    r = max(int(np.ceil(4.0 * sigma)), 1)
    x = np.arange(-r, r + 1, dtype=np.float64)
    g = np.exp(-0.5 * (x / sigma) ** 2)
    g /= g.sum()
    dg = -x / sigma**2 * g
    dg -= dg.mean()  # exact zero response to a constant
    dg /= -(x * dg).sum()  # unit response to a unit ramp
    return g.astype(np.float32), dg.astype(np.float32)


def gradient(signal: np.ndarray, sigma: float, sigma_along: float | None = None
             ) -> tuple[np.ndarray, np.ndarray]:
    """Gaussian-derivative gradient ``(s_x, s_y)`` of ``signal`` (H, W), per px, float32.

    ``s_x`` is the x derivative of the signal smoothed by ``sigma`` across (x) and by
    ``sigma_along`` (default ``sigma``) along y, the direction of a vertical band's edge;
    ``s_y`` likewise with the axes exchanged. Smoothing along the edges lowers the noise
    without widening the edge profile, so neighbouring band edges do not interact more.
    """
    sa = sigma if sigma_along is None else sigma_along
    g, dg = gaussian_kernels(sigma)
    ga, _ = gaussian_kernels(sa)
    s = np.ascontiguousarray(signal, dtype=np.float32)
    # cv2.sepFilter2D correlates: flip the odd kernel to convolve (the two side by side:
    # _threads)
    gx, gy = parallel_map(lambda k: cv2.sepFilter2D(s, cv2.CV_32F, *k,
                                                    borderType=cv2.BORDER_REFLECT),
                          ((dg[::-1].copy(), ga), (ga, dg[::-1].copy())))
    return gx, gy


@dataclass(frozen=True)
class EdgePoints:
    """Sub-pixel edge points, arrays of shape (N,) (``across``: (N, 2)).

    Attributes
    ----------
    x, y : float64
        Sub-pixel position, camera px.
    ix, iy : int32
        The edge pixel (row/column search position).
    cls : int8
        0 vertical rising, 1 vertical falling, 2 horizontal rising, 3 horizontal falling.
    strength : float32
        Peak of the point's edge derivative (its own family's component of the gradient,
        :func:`across_operators`; ``|g_x|`` or ``|g_y|`` without families), per px of the
        normalised signal.
    gx, gy : float32
        Gradient of the smoothed signal at the edge pixel.
    dominance : float32, optional
        The gradient's component along the point's family normal over the one along the
        other family's (``|g_x| / |g_y|`` for vertical-band edges without families): the
        largest ``dominance`` of :func:`detect_edge_points` that finds the point (for
        horizontal-band edges, whose test is strict, any smaller one).
    across : float32 (N, 2), optional
        The vector ``A`` whose product with the gradient, ``g . A``, is the point's own
        family's edge derivative (:func:`across_operators`; ``(1, 0)`` or ``(0, 1)``
        without families): the row (column) profile of ``g . A`` peaks at the point.
    slope : float32, optional
        The line of the sub-pixel fit through the edge pixel (:func:`fit_slopes`): its offset
        along y per px along x for vertical-band edges, along x per px along y for horizontal
        ones (0: the row or column). The point is ``(ix + d, iy + d slope)`` (vertical) or
        ``(ix + d slope, iy + d)``.
    """

    x: np.ndarray
    y: np.ndarray
    ix: np.ndarray
    iy: np.ndarray
    cls: np.ndarray
    strength: np.ndarray
    gx: np.ndarray
    gy: np.ndarray
    dominance: np.ndarray | None = None
    across: np.ndarray | None = None
    slope: np.ndarray | None = None

    def take(self, index) -> EdgePoints:
        """The points selected by ``index`` (bool mask or integer indices)."""
        return EdgePoints(**{k: (None if v is None else v[index])
                             for k, v in self.__dict__.items()})


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
    phi = np.mod(np.arctan2(ay, ax), np.pi)
    b = np.minimum((phi * (bins / np.pi)).astype(np.int64), bins - 1)
    t = (iy // tile).astype(np.int64) * tx + ix // tile
    hist = np.bincount(t * bins + b, weights=np.hypot(ax, ay),
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


def line_taps(ix: np.ndarray, iy: np.ndarray, axis, slope: np.ndarray, step,
              shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Pixels and weights that sample images ``step`` px along the fit lines through pixels.

    A step is one px along the search axis and ``slope`` px across it; between the pixels
    across, the image is interpolated by cubic convolution (Keys 1981, a = -0.5: exact for
    quadratics, where the linear interpolation's error across a tilted edge's profile would
    shift the fitted peak). The image's border clamps. ``(img.ravel()[idx] * wts).sum(-1)``
    is the sample (:func:`sample_taps`); the taps serve every image of that shape.

    Parameters
    ----------
    ix, iy : ndarray (N,) int
        The edge pixels.
    axis : int or ndarray (N,) int
        The search axis of each point: 0 x (rows), 1 y (columns).
    slope : ndarray (N,)
        Offset across the search axis per step, px (:func:`fit_slopes`).
    step : ndarray (K,) of integers
        Steps along the search axis (whole px).
    shape : (int, int)
        The images' (H, W).

    Returns
    -------
    idx : ndarray (N, K, 4) int64
        Flat pixel indices of the four taps of each sample.
    wts : ndarray (N, K, 4) float64
        Their weights (summing to 1).

    References
    ----------
    .. [1] R. Keys, "Cubic convolution interpolation for digital image processing", IEEE
       Trans. Acoustics, Speech and Signal Processing 29(6), 1153-1160, 1981.
    """
    h, w = shape
    step = np.asarray(step, np.float64)
    along_x = np.broadcast_to(np.asarray(axis), np.shape(ix)) == 0
    off = np.asarray(slope, np.float64)[:, None, None] * step[None, :, None]
    f = np.floor(off)
    t = off - f
    wts = np.concatenate([((-0.5 * t + 1.0) * t - 0.5) * t, (1.5 * t - 2.5) * t * t + 1.0,
                          ((-1.5 * t + 2.0) * t + 0.5) * t, (0.5 * t - 0.5) * t * t], axis=2)
    ix, iy = np.asarray(ix, np.int64), np.asarray(iy, np.int64)
    # the coordinate along the search axis (one per step) and the four across it, clamped
    run = np.where(along_x, ix, iy)[:, None] + step.astype(np.int64)[None, :]  # (N, K)
    np.clip(run, 0, np.where(along_x, w - 1, h - 1)[:, None], out=run)
    across = f[..., 0].astype(np.int64)
    across += np.where(along_x, iy, ix)[:, None]
    across = across[:, :, None] + np.arange(-1, 3)[None, None, :]  # (N, K, 4)
    np.clip(across, 0, np.where(along_x, h - 1, w - 1)[:, None, None], out=across)
    vx = along_x[:, None, None]
    run = np.where(along_x[:, None], run, run * w)[:, :, None]
    return np.where(vx, across * w, across) + run, wts


def sample_taps(img: np.ndarray, idx: np.ndarray, wts: np.ndarray) -> np.ndarray:
    """``img`` (H, W) sampled with the taps of :func:`line_taps`, float64 (N, K)."""
    s = np.take(img.ravel(), idx).astype(np.float64)
    s *= wts
    return ((s[..., 0] + s[..., 1]) + s[..., 2]) + s[..., 3]  # (numpy's sum of 4, in order)


def _along_line(img: np.ndarray, ix: np.ndarray, iy: np.ndarray, axis: int,
                slope: np.ndarray, step) -> np.ndarray:
    """``img`` (H, W) at the (K,) ``step`` px along the fit lines through the pixels
    (:func:`line_taps`), float64 (N, K)."""
    return sample_taps(img, *line_taps(ix, iy, axis, slope, step, img.shape))


def _subpixel(lm: np.ndarray, l0: np.ndarray, lp: np.ndarray,
              limit: float | np.ndarray = 0.5) -> np.ndarray:
    """Vertex of the parabola through ``(-1, lm), (0, l0), (1, lp)`` (N,), clipped to
    +-``limit``; 0 where the three samples are collinear."""
    den = lm - 2.0 * l0 + lp
    with np.errstate(divide="ignore", invalid="ignore"):
        d = 0.5 * (lm - lp) / den
    return np.clip(np.nan_to_num(d, nan=0.0), -limit, limit)


def detect_edge_points(signal: np.ndarray, sigma: float = 1.0, threshold: float = 0.06,
                       valid: np.ndarray | None = None, sigma_along: float | None = None,
                       dominance: float = 1.0, families: bool = True,
                       oblique: bool = True, fit_line: str = "balanced",
                       camera_blur: float = 0.5) -> EdgePoints:
    """Find the sub-pixel edge points of ``signal`` (module notes).

    Parameters
    ----------
    signal : ndarray (H, W)
        Edge signal (normalised, bands near 1 on a black near 0).
    sigma : float
        Scale of the Gaussian derivative filters across the edges, camera px.
    sigma_along : float, optional
        Scale of the smoothing along the edges (default ``sigma``), camera px.
    threshold : float
        Least gradient magnitude of an edge, per px of the signal (a unit step blurred to a total
        scale t has a peak gradient 1 / (t sqrt(2 pi)), about 0.3 for t = 1.3).
    valid : ndarray (H, W) of bool, optional
        Pixels where edges may be found; the filters run over their window only
        (:func:`work_window`: the same points) where the image is a whole number of the
        families' tiles (``FAMILY_TILE``; the 7.1 MP camera's 3072 x 2304 px is) or without
        ``families``.
    dominance : float
        A pixel is a vertical-edge candidate where ``|gx| >= dominance |gy|`` and a
        horizontal-edge candidate where ``|gy| > dominance |gx|``; below 1 a pixel may be both
        (near a crossing band's corner the other direction's gradient dominates, yet the
        edge's row or column profile still has its peak there). With ``families`` the two
        components are taken along the local normals of the two families instead of x and y.
    families : bool
        Classify by the local family directions (:func:`family_normals`, module notes).
    oblique : bool
        With ``families``, find each family's edges by its own component of the gradient
        (:func:`across_operators`: the derivative along the other family's edges) instead of
        ``g_x`` and ``g_y``; they differ where the families are not upright, where the
        crossing bands' tilted edges shift the row and column peaks of ``g_x`` and ``g_y``
        (figures: :func:`~nurbscan.detect.detect_grid`'s ``oblique``).
    fit_line : {"balanced", "row"}
        With ``oblique``, fit each point's profile along the line on which a crossing band's
        shifts of the peak cancel (:func:`fit_slopes`, module notes), or along the row
        (column). Without ``oblique`` (or on an upright grid) it is the row.
    camera_blur : float
        The camera lens's blur, Gaussian sigma in camera px: with the derivative filter's
        ``sigma`` and the pixel (variance 1/12) the blur that mixes the families
        (:func:`fit_slopes`'s ``mix_var``, which takes ``sigma_along`` as ``sigma``).

    Returns
    -------
    EdgePoints
        With the balanced line a point lies up to ``MAX_SLOPE`` px off its pixel's row
        (column) along the fit line (:attr:`EdgePoints.slope`); row and column groupings
        use the edge pixels ``ix``, ``iy``.

    Raises
    ------
    NurbscanError
        For an unknown ``fit_line``.
    """
    if fit_line not in ("balanced", "row"):
        raise NurbscanError(f"fit_line={fit_line!r}: must be 'balanced' or 'row'")
    # the filters reflect the image at its border: no edges within 3 sigma + 1 px of it
    b = int(np.ceil(3.0 * max(sigma, sigma_along or 0.0))) + 1
    oy = ox = 0
    if valid is not None and (not families or (signal.shape[0] % FAMILY_TILE == 0
                                               and signal.shape[1] % FAMILY_TILE == 0)):
        # the work over the valid pixels' window only (:func:`work_window`: the same points;
        # with families, where the image is a whole number of tiles, which the tiles' values
        # are spread over: elsewhere the window would spread them differently)
        valid = np.array(valid, bool)
        valid[:b] = valid[-b:] = False
        valid[:, :b] = valid[:, -b:] = False
        r = max(int(np.ceil(4.0 * max(sigma, sigma_along or 0.0))), 1)
        rows, cols = work_window(valid, 2 * FAMILY_TILE + r + 8, FAMILY_TILE)
        signal, valid, oy, ox = signal[rows, cols], valid[rows, cols], rows.start, cols.start
    gx, gy = gradient(signal, sigma, sigma_along)
    h, w = gx.shape
    strong = cv2.magnitude(gx, gy) > threshold  # (the magnitude is not kept)
    if valid is not None:
        strong &= valid
    strong[:b] = strong[-b:] = False
    strong[:, :b] = strong[:, -b:] = False
    av = ah = None  # the image axes
    oblique_ops = False
    if families:
        # the gradient's components along the two families' local normals
        sy, sx = np.nonzero(strong)
        gxs, gys = gx[sy, sx], gy[sy, sx]
        tv, th = family_normals(gx, gy, strong, FAMILY_TILE, pixels=(sy, sx, gxs, gys))
        # |g . n|^2 = (|g|^2 + (gx^2 - gy^2) cos 2t + 2 gx gy sin 2t) / 2 for n at angle t,
        # with the doubled-angle vectors interpolated bilinearly between the tiles
        mag2, diff2, prod2 = gxs * gxs + gys * gys, gxs * gxs - gys * gys, 2.0 * gxs * gys
        del gxs, gys

        def component(t):  # one family's (the two side by side: _threads)
            c2, s2 = (_tiles_to_pixels(f(2 * t), (h, w))[sy, sx] for f in (np.cos, np.sin))
            r = np.hypot(c2, s2)
            return mag2 + (diff2 * c2 + prod2 * s2) / np.where(r > 0, r, 1.0)

        comp = parallel_map(component, (tv, th))
        vmask = np.zeros((h, w), bool)
        hmask = np.zeros((h, w), bool)
        d2 = dominance * dominance
        vmask[sy, sx] = comp[0] >= d2 * comp[1]
        hmask[sy, sx] = comp[1] > d2 * comp[0]
        # squared ratio of the vertical family's component to the horizontal one's
        ratio2 = np.zeros((h, w), np.float32)
        ratio2[sy, sx] = comp[0] / np.maximum(comp[1], 1e-20)
        del sy, sx, comp, mag2, diff2, prod2

        def vratio(iy, ix):
            return np.sqrt(np.maximum(ratio2[iy, ix], 0.0))

        if oblique and not (np.all(tv == 0.0) and np.all(th == np.pi / 2)):
            # each family's edges by its own gradient component, the derivative along the
            # other family's edges (the peaks of g_x, g_y move where a tilted crossing band's
            # edge adds to them)
            av, ah = across_operators(tv, th, (h, w))
            oblique_ops = True
    else:
        vmask = strong & (np.abs(gx) >= dominance * np.abs(gy))
        hmask = strong & (np.abs(gy) > dominance * np.abs(gx))

        def vratio(iy, ix):
            return np.abs(gx[iy, ix]) / np.maximum(np.abs(gy[iy, ix]), 1e-10)

    def operator(a, axis, iy, ix):
        if a is None:
            return np.repeat(np.eye(2, dtype=np.float32)[axis][None, :], len(iy), axis=0)
        return np.stack([a[0][iy, ix], a[1][iy, ix]], axis=1)

    def ln(a):  # the log-parabola samples, at the peaks only
        return np.log(np.maximum(a, 1e-6))

    balanced = fit_line == "balanced" and av is not None
    mix_var = sigma * sigma + camera_blur * camera_blur + 1.0 / 12.0

    def family(job):  # one family's points (the two side by side: _threads)
        axis, mask, a_own, a_other, cls0 = job
        # the family's own gradient component (the plain derivative without the operators)
        if oblique_ops:
            der = gx * a_own[0]
            der += gy * a_own[1]
        else:
            der = gx if axis == 0 else gy
        amp = np.abs(der)
        # maxima of the family's derivative along the row (vertical) or column (horizontal)
        c = np.zeros((h, w), bool)
        if axis == 0:
            c[:, 1:-1] = (mask[:, 1:-1] & (amp[:, 1:-1] > amp[:, :-2])
                          & (amp[:, 1:-1] >= amp[:, 2:]))
        else:
            c[1:-1, :] = (mask[1:-1, :] & (amp[1:-1, :] > amp[:-2, :])
                          & (amp[1:-1, :] >= amp[2:, :]))
        iy, ix = np.nonzero(c)
        del c
        step = (0, 1) if axis == 0 else (1, 0)  # (dy, dx) of one step along the search axis
        lm, l0, lp = (ln(amp[iy + k * step[0], ix + k * step[1]]) for k in (-1, 0, 1))
        sl, limit = np.zeros(len(iy)), 0.5
        if balanced:
            # the operators A are parallel to the other family's edges: normals from them
            n_own = np.stack([-a_other[1][iy, ix], a_other[0][iy, ix]], 1).astype(np.float64)
            n_oth = np.stack([-a_own[1][iy, ix], a_own[0][iy, ix]], 1).astype(np.float64)
            n_own /= np.linalg.norm(n_own, axis=1, keepdims=True)
            n_oth /= np.linalg.norm(n_oth, axis=1, keepdims=True)
            sl = fit_slopes(n_own, n_oth, axis, lm - 2.0 * l0 + lp, mix_var)
            lm, lp = ln(_along_line(amp, ix, iy, axis, sl, (-1, 1))).T
            # a slanted line can cross the edge farther than 0.5 px from the pixel (up to ~1
            # px); the bound grows with the slope from the row's 0.5
            limit = np.minimum(1.0, 0.5 + 2.0 * np.abs(sl))
        d = _subpixel(lm, l0, lp, limit)
        jx, jy = ix + ox, iy + oy  # (the image's pixels)
        x, y = (jx + d, jy + d * sl) if axis == 0 else (jx + d * sl, jy + d)
        ratio = vratio(iy, ix) if axis == 0 else 1.0 / np.maximum(vratio(iy, ix), 1e-10)
        return (x, y, jx, jy, np.where(der[iy, ix] > 0, cls0, cls0 + 1), amp[iy, ix],
                gx[iy, ix], gy[iy, ix], ratio, operator(a_own, axis, iy, ix), sl)

    out = parallel_map(family, ((0, vmask, av, ah, 0), (1, hmask, ah, av, 2)))
    cat = [np.concatenate([o[k] for o in out]) for k in range(11)]
    return EdgePoints(x=cat[0].astype(np.float64), y=cat[1].astype(np.float64),
                      ix=cat[2].astype(np.int32), iy=cat[3].astype(np.int32),
                      cls=cat[4].astype(np.int8), strength=cat[5].astype(np.float32),
                      gx=cat[6].astype(np.float32), gy=cat[7].astype(np.float32),
                      dominance=cat[8].astype(np.float32),
                      across=cat[9].astype(np.float32), slope=cat[10].astype(np.float32))


def refine_by_channels(channels, ix: np.ndarray, iy: np.ndarray, cls: np.ndarray,
                       colour: np.ndarray, x: np.ndarray, y: np.ndarray, sigma: float,
                       sigma_along: float | None = None, clean: float = 0.25,
                       normal: np.ndarray | None = None, across: np.ndarray | None = None,
                       slope: np.ndarray | None = None
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Second, per-channel sub-pixel pass for decoded edge points (method.md section 2).

    Where a band of the other direction crosses an edge, the crossing rule (channel-wise
    maximum) saturates the channels the two colours share, and near the crossing band's own
    edge those channels carry a corner structure whose gradient leaks into the row (column)
    derivative and shifts the fitted peak. A decoded point knows its band's colour
    (``colour``, (N, 3) bool): the edge is re-measured in the sum of the derivatives of those
    channels ``c`` of the colour that are *clean* at the point, i.e. whose derivative along the
    edge is at most ``clean`` times the one across it (no crossing band edge passes there),
    with the same log-parabola fit across the edge as :func:`detect_edge_points`. Using only
    the band's channels also leaves out the noise of the channels without an edge. The
    derivatives along and across the edge are taken along its tangent and normal (``normal``),
    so a tilted edge is judged as clean as an upright one.

    Parameters
    ----------
    channels : sequence of 3 ndarray (H, W) float32
        Normalised colour channels (indexed once each, from up to two threads at once,
        :mod:`~nurbscan.detect._threads`: a lazy sequence such as
        :meth:`~nurbscan.detect.normalize.Normalised.lazy_planes` holds one per thread).
    ix, iy : (N,) int
        Edge pixels; ``cls`` (N,) their classes (0..3, :data:`CLASSES`).
    colour : (N, 3) bool
        Channels lit in the point's band.
    x, y : (N,) float
        The first pass's sub-pixel positions, kept where no channel is clean or the peak of the
        channel sum is not at the edge pixel.
    sigma, sigma_along : float
        Filter scales, px (as in :func:`gradient`).
    clean : float
        Largest ratio of a channel's derivative along the edge to the one across it.
    normal : (N, 2) float, optional
        Unit normal of each edge (the first pass's gradient direction); default the row
        direction (1, 0) for vertical-band edges and the column direction (0, 1) otherwise.
    across : (N, 2) float, optional
        The edge derivative is ``g . across`` (:attr:`EdgePoints.across`, the derivative along
        the other family's edges); default ``g_x`` for vertical-band edges and ``g_y``
        otherwise.
    slope : (N,) float, optional
        The line of each point's fit (:attr:`EdgePoints.slope`, :func:`fit_slopes`); default
        the row (column).

    Returns
    -------
    x, y : (N,) float64
        Refined positions, camera px.
    refined : (N,) bool
        Points re-measured.
    """
    n = len(ix)
    x = np.asarray(x, np.float64).copy()
    y = np.asarray(y, np.float64).copy()
    if n == 0:
        return x, y, np.zeros(0, bool)
    vert = cls < 2
    sgn = np.where(cls % 2 == 0, 1.0, -1.0)
    axes = np.where(vert[:, None], [1.0, 0.0], [0.0, 1.0])
    if normal is None:
        normal = axes
    nx, ny = np.asarray(normal, np.float64).T
    # across-edge derivative samples at offsets -1, 0, +1, and the along-edge derivative
    acc = np.zeros((n, 3))
    used = np.zeros(n, np.int64)
    steps = np.array([-1.0, 0.0, 1.0])
    sl = np.zeros(n) if slope is None else np.asarray(slope, np.float64)
    ix, iy = np.asarray(ix, np.int64), np.asarray(iy, np.int64)
    mag = []
    if across is None:
        across = axes
    ux, uy = (np.asarray(across, np.float64).T[:, :, None] * sgn[None, :, None])

    # the filters over the points' window only (the same values there as over the image):
    # the reach of the filters and of the taps (a step and a cubic tap across) around them
    h, w = getattr(channels, "shape", None) or channels[0].shape
    m = max(int(np.ceil(4.0 * max(sigma, sigma_along or 0.0))), 1) + 8
    rows = slice(max(int(iy.min()) - m, 0), min(int(iy.max()) + m + 1, h))
    cols = slice(max(int(ix.min()) - m, 0), min(int(ix.max()) + m + 1, w))
    if hasattr(channels, "crop"):
        channels = channels.crop(rows, cols)
    else:
        channels = _Cropped(channels, rows, cols)
    jx, jy = ix - cols.start, iy - rows.start
    # (N, 3): the samples along each point's fit line, from taps shared by the images
    taps = line_taps(jx, jy, np.where(vert, 0, 1), sl, steps,
                     (rows.stop - rows.start, cols.stop - cols.start))

    def channel(c):  # one channel's profiles (the channels side by side: _threads)
        img = channels[c]  # (a lazy sequence computes each plane here)
        gx, gy = gradient(img, sigma, sigma_along)
        del img
        prof = sample_taps(gx, *taps) * ux + sample_taps(gy, *taps) * uy
        cx, cy = gx[jy, jx], gy[jy, jx]
        del gx, gy
        along = nx * cy - ny * cx
        normal_d = nx * cx + ny * cy
        ok = colour[:, c] & (np.abs(along) <= clean * np.abs(normal_d)) & (prof[:, 1] > 0)
        return prof, ok

    for prof, ok in parallel_map(channel, range(3)):  # (summed in the channels' order)
        mag.append(prof[:, 1])
        acc += np.where(ok[:, None], prof, 0.0)
        used += ok
    big = np.max(np.stack(mag, 1), axis=1)
    peak = (used > 0) & (acc[:, 1] > 0.3 * big) & (acc[:, 1] >= acc[:, 0]) \
        & (acc[:, 1] >= acc[:, 2]) & (acc.min(1) > 0)
    la = np.log(np.maximum(acc, 1e-9))
    d = _subpixel(la[:, 0], la[:, 1], la[:, 2])  # |d| <= 0.5: the centre sample is the peak
    x = np.where(peak, np.where(vert, ix + d, ix + d * sl), x)
    y = np.where(peak, np.where(vert, iy + d * sl, iy + d), y)
    return x, y, peak


class _Cropped:
    """The window ``(rows, cols)`` of each of a sequence of images, taken when indexed."""

    def __init__(self, images, rows: slice, cols: slice):
        self._images, self._rows, self._cols = images, rows, cols

    def __getitem__(self, c: int) -> np.ndarray:
        return self._images[c][self._rows, self._cols]
