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
(:func:`~nurbscan.detect.oblique.family_normals`): on a surface seen obliquely the vertical bands
can tilt past 45 degrees (the teapot's lid: the two families meet at about 33 degrees there), where
the plain rule ``|s_x| >= |s_y|`` would call them horizontal. Where the two families are upright the
rule is the plain one. With the families, ``s_x`` and ``s_y`` below stand for each family's own
component of the gradient (:func:`~nurbscan.detect.oblique.across_operators`: the derivative along
the other family's edges); they are the plain derivatives where the families are upright.

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
perpendicular the fit is taken along a slanted line instead of the row (column): the
families' normals, their own derivatives and the fit lines are
:mod:`~nurbscan.detect.oblique`'s (its notes derive the line). The re-measurement of the
labelled points in their band's colour channels is
:func:`~nurbscan.detect.refine.refine_by_channels`.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from .._jit import njit
from ..errors import NurbscanError
from ._pick import pick
from ._threads import parallel_map
from .oblique import _along_line, _tiles_to_pixels, across_operators, family_normals, fit_slopes

#: Edge classes: (direction, edge) -> class id.
CLASSES = {("v", 0): 0, ("v", 1): 1, ("h", 0): 2, ("h", 1): 3}

#: Side of the tiles of :func:`~nurbscan.detect.oblique.family_normals` in
#: :func:`detect_edge_points`, camera px.
FAMILY_TILE = 48


def work_window(mask: np.ndarray, margin: int, tile: int = 1) -> tuple[slice, slice]:
    """The rows and columns of ``mask`` (H, W) that hold its True pixels, widened by
    ``margin`` px on each side and to multiples of ``tile`` px from the image's origin (an
    image-sized window where ``mask`` has no True pixel).

    The filters of :func:`gradient` and the tile histograms of
    :func:`~nurbscan.detect.oblique.family_normals` give the same values inside such a window as
    over the whole image (the window's own border lies ``margin`` px away from every pixel that
    counts), at the cost of the window's pixels only: on the 7.1 MP teapot views the projector
    lights about 14 % of the image, in a window of about a third of it.
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
    s = np.asarray(signal, dtype=np.float32)
    if s.strides[-1] != s.itemsize:  # (OpenCV reads a window of rows as it is)
        s = np.ascontiguousarray(s)
    # cv2.sepFilter2D correlates: flip the odd kernel to convolve (the two side by side:
    # _threads)
    gx, gy = parallel_map(lambda k: cv2.sepFilter2D(s, cv2.CV_32F, *k,
                                                    borderType=cv2.BORDER_REFLECT),
                          ((dg[::-1].copy(), ga), (ga, dg[::-1].copy())))
    return gx, gy


def _row_norm(v: np.ndarray) -> np.ndarray:
    """``np.linalg.norm(v, axis=1, keepdims=True)`` of (N, 2) float64 vectors, the same values
    (``sqrt(x * x + y * y)``) without numpy's row-by-row reduction along the short axis
    (1.5 instead of 0.1 ms per 10^5 rows)."""
    return np.sqrt(v[:, :1] * v[:, :1] + v[:, 1:] * v[:, 1:])


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
        :func:`~nurbscan.detect.oblique.across_operators`; ``|g_x|`` or ``|g_y|`` without families),
        per px of the normalised signal.
    gx, gy : float32
        Gradient of the smoothed signal at the edge pixel.
    dominance : float32, optional
        The gradient's component along the point's family normal over the one along the
        other family's (``|g_x| / |g_y|`` for vertical-band edges without families): the
        largest ``dominance`` of :func:`detect_edge_points` that finds the point (for
        horizontal-band edges, whose test is strict, any smaller one).
    across : float32 (N, 2), optional
        The vector ``A`` whose product with the gradient, ``g . A``, is the point's own family's
        edge derivative (:func:`~nurbscan.detect.oblique.across_operators`; ``(1, 0)`` or ``(0, 1)``
        without families): the row (column) profile of ``g . A`` peaks at the point.
    slope : float32, optional
        The line of the sub-pixel fit through the edge pixel
        (:func:`~nurbscan.detect.oblique.fit_slopes`): its offset along y per px along x for
        vertical-band edges, along x per px along y for horizontal ones (0: the row or column). The
        point is ``(ix + d, iy + d slope)`` (vertical) or ``(ix + d slope, iy + d)``.
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
        names = [k for k, v in self.__dict__.items() if v is not None]
        got = dict(zip(names, pick(index, *(self.__dict__[k] for k in names)), strict=True))
        return EdgePoints(**{k: got.get(k) for k in self.__dict__})

def _at(img: np.ndarray, flat: np.ndarray) -> np.ndarray:
    """``img`` (H, W) at the flat pixel indices ``flat`` (the values of ``img[iy, ix]``, in
    one gather)."""
    return np.take(img.ravel(), flat)


def _subpixel(lm: np.ndarray, l0: np.ndarray, lp: np.ndarray,
              limit: float | np.ndarray = 0.5) -> np.ndarray:
    """Vertex of the parabola through ``(-1, lm), (0, l0), (1, lp)`` (N,), clipped to
    +-``limit``; 0 where the three samples are collinear."""
    den = lm - 2.0 * l0 + lp
    with np.errstate(divide="ignore", invalid="ignore"):
        d = 0.5 * (lm - lp) / den
    return np.clip(np.nan_to_num(d, nan=0.0), -limit, limit)


@njit(cache=True, nogil=True)
def _family_maxima(gx, gy, ax, ay, mask, axis, combine=True):
    """The magnitude (H, W) float32 of a family's derivative ``gx ax + gy ay`` (of ``gx``
    without ``combine``) and the flat indices (ascending) of the ``mask`` pixels where it is
    a maximum along the row (``axis`` 0: above the left neighbour's, at least the right
    one's; the first and last columns left out) or the column (1): the float32 operations of
    ``np.abs(gx * ax + gy * ay)`` and the comparisons, without the image-sized derivative
    and masks."""
    h, w = gx.shape
    amp = np.empty((h, w), np.float32)
    for r in range(h):
        for c in range(w):
            amp[r, c] = abs(gx[r, c] * ax[r, c] + gy[r, c] * ay[r, c]) if combine else abs(
                gx[r, c])
    count = 0
    out = np.empty(max(h * w // 16, 16), np.int64)
    for r in range(axis, h - axis):
        for c in range(1 - axis, w - 1 + axis):
            if not mask[r, c]:
                continue
            a = amp[r, c]
            if axis == 0:
                peak = a > amp[r, c - 1] and a >= amp[r, c + 1]
            else:
                peak = a > amp[r - 1, c] and a >= amp[r + 1, c]
            if peak:
                if count == len(out):
                    grown = np.empty(2 * len(out), np.int64)
                    grown[:count] = out
                    out = grown
                out[count] = r * w + c
                count += 1
    return amp, out[:count].copy()


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
        Classify by the local family directions (:func:`~nurbscan.detect.oblique.family_normals`,
        module notes).
    oblique : bool
        With ``families``, find each family's edges by its own component of the gradient
        (:func:`~nurbscan.detect.oblique.across_operators`: the derivative along the other family's
        edges) instead of ``g_x`` and ``g_y``; they differ where the families are not upright, where
        the crossing bands' tilted edges shift the row and column peaks of ``g_x`` and ``g_y``
        (figures: :func:`~nurbscan.detect.detect_grid`'s ``oblique``).
    fit_line : {"balanced", "row"}
        With ``oblique``, fit each point's profile along the line on which a crossing band's shifts
        of the peak cancel (:func:`~nurbscan.detect.oblique.fit_slopes`, the notes of
        :mod:`~nurbscan.detect.oblique`), or along the row (column). Without ``oblique`` (or on an
        upright grid) it is the row.
    camera_blur : float
        The camera lens's blur, Gaussian sigma in camera px: with the derivative filter's ``sigma``
        and the pixel (variance 1/12) the blur that mixes the families
        (:func:`~nurbscan.detect.oblique.fit_slopes`'s ``mix_var``, which takes ``sigma_along`` as
        ``sigma``).

    Returns
    -------
    EdgePoints
        With the balanced line a point lies up to ``MAX_SLOPE``
        (:data:`~nurbscan.detect.oblique.MAX_SLOPE`) px off its pixel's row (column) along the fit
        line (:attr:`EdgePoints.slope`); row and column groupings use the edge pixels ``ix``,
        ``iy``.

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
        fs = np.flatnonzero(strong)  # (flat pixel indices: one index for the gathers)
        sy, sx = np.divmod(fs, w)
        gxs, gys = _at(gx, fs), _at(gy, fs)
        tv, th = family_normals(gx, gy, strong, FAMILY_TILE, pixels=(sy, sx, gxs, gys))
        # |g . n|^2 = (|g|^2 + (gx^2 - gy^2) cos 2t + 2 gx gy sin 2t) / 2 for n at angle t,
        # with the doubled-angle vectors interpolated bilinearly between the tiles
        mag2, diff2, prod2 = gxs * gxs + gys * gys, gxs * gxs - gys * gys, 2.0 * gxs * gys
        del gxs, gys

        def component(t):  # one family's (the two side by side: _threads)
            c2, s2 = (_at(_tiles_to_pixels(f(2 * t), (h, w)), fs) for f in (np.cos, np.sin))
            r = np.hypot(c2, s2)
            return mag2 + (diff2 * c2 + prod2 * s2) / np.where(r > 0, r, 1.0)

        comp = parallel_map(component, (tv, th))
        vmask = np.zeros((h, w), bool)
        hmask = np.zeros((h, w), bool)
        d2 = dominance * dominance
        vmask.ravel()[fs] = comp[0] >= d2 * comp[1]
        hmask.ravel()[fs] = comp[1] > d2 * comp[0]
        # squared ratio of the vertical family's component to the horizontal one's
        ratio2 = np.zeros((h, w), np.float32)
        ratio2.ravel()[fs] = comp[0] / np.maximum(comp[1], 1e-20)
        del fs, sy, sx, comp, mag2, diff2, prod2

        def vratio(fl):
            return np.sqrt(np.maximum(_at(ratio2, fl), 0.0))

        if oblique and not (np.all(tv == 0.0) and np.all(th == np.pi / 2)):
            # each family's edges by its own gradient component, the derivative along the
            # other family's edges (the peaks of g_x, g_y move where a tilted crossing band's
            # edge adds to them)
            av, ah = across_operators(tv, th, (h, w))
            oblique_ops = True
    else:
        vmask = strong & (np.abs(gx) >= dominance * np.abs(gy))
        hmask = strong & (np.abs(gy) > dominance * np.abs(gx))

        def vratio(fl):
            return np.abs(_at(gx, fl)) / np.maximum(np.abs(_at(gy, fl)), 1e-10)

    def operator(a, axis, fl):
        if a is None:
            return np.repeat(np.eye(2, dtype=np.float32)[axis][None, :], len(fl), axis=0)
        return np.stack([_at(a[0], fl), _at(a[1], fl)], axis=1)

    def ln(a):  # the log-parabola samples, at the peaks only
        return np.log(np.maximum(a, 1e-6))

    balanced = fit_line == "balanced" and av is not None
    mix_var = sigma * sigma + camera_blur * camera_blur + 1.0 / 12.0

    def family(job):  # one family's points (the two side by side: _threads)
        axis, mask, a_own, a_other, cls0 = job
        # the magnitude of the family's own gradient component (the plain derivative without
        # the operators) and its maxima along the row (vertical) or column (horizontal), as
        # flat pixels (one index for the many gathers); the component itself at those only
        if oblique_ops:
            amp, fl = _family_maxima(gx, gy, a_own[0], a_own[1], mask, axis)
            der = _at(gx, fl) * _at(a_own[0], fl) + _at(gy, fl) * _at(a_own[1], fl)
        else:
            g = gx if axis == 0 else gy
            amp, fl = _family_maxima(g, g, g, g, mask, axis, False)
            der = _at(g, fl)
        iy, ix = np.divmod(fl, w)
        step = (0, 1) if axis == 0 else (1, 0)  # (dy, dx) of one step along the search axis
        lm, l0, lp = (ln(_at(amp, fl + k * (step[0] * w + step[1]))) for k in (-1, 0, 1))
        sl, limit = np.zeros(len(iy)), 0.5
        if balanced:
            # the operators A are parallel to the other family's edges: normals from them
            n_own = np.stack([-_at(a_other[1], fl), _at(a_other[0], fl)], 1).astype(np.float64)
            n_oth = np.stack([-_at(a_own[1], fl), _at(a_own[0], fl)], 1).astype(np.float64)
            n_own /= _row_norm(n_own)
            n_oth /= _row_norm(n_oth)
            sl = fit_slopes(n_own, n_oth, axis, lm - 2.0 * l0 + lp, mix_var)
            lm, lp = ln(_along_line(amp, ix, iy, axis, sl, (-1, 1))).T
            # a slanted line can cross the edge farther than 0.5 px from the pixel (up to ~1
            # px); the bound grows with the slope from the row's 0.5
            limit = np.minimum(1.0, 0.5 + 2.0 * np.abs(sl))
        d = _subpixel(lm, l0, lp, limit)
        jx, jy = ix + ox, iy + oy  # (the image's pixels)
        x, y = (jx + d, jy + d * sl) if axis == 0 else (jx + d * sl, jy + d)
        ratio = vratio(fl) if axis == 0 else 1.0 / np.maximum(vratio(fl), 1e-10)
        return (x, y, jx, jy, np.where(der > 0, cls0, cls0 + 1), _at(amp, fl),
                _at(gx, fl), _at(gy, fl), ratio, operator(a_own, axis, fl), sl)

    out = parallel_map(family, ((0, vmask, av, ah, 0), (1, hmask, ah, av, 2)))
    cat = [np.concatenate([o[k] for o in out]) for k in range(11)]
    return EdgePoints(x=cat[0].astype(np.float64), y=cat[1].astype(np.float64),
                      ix=cat[2].astype(np.int32), iy=cat[3].astype(np.int32),
                      cls=cat[4].astype(np.int8), strength=cat[5].astype(np.float32),
                      gx=cat[6].astype(np.float32), gy=cat[7].astype(np.float32),
                      dominance=cat[8].astype(np.float32),
                      across=cat[9].astype(np.float32), slope=cat[10].astype(np.float32))
