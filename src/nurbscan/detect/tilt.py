"""The grid's tilt in a photograph, and detection of a tilted photograph in its level image.

The detector reads the two families of grid edges from the image's x and y gradients: it
expects the vertical bands within some tens of degrees of the image's columns (a photograph
turned by 90, 180 or 270 degrees, mirrored or transposed is handled by the colour windows,
:mod:`.orientation`). A photograph turned by an angle in between (a board held at 40 degrees,
a camera on a tilted tripod) mixes the two families in both gradients: on the fuzz benchmark,
2 of about 230 views turned by 30-150 degrees came out with 1-7 % of their lines labelled
wrongly, the labels still consistent with the code's windows.

So the two families' normals are measured first, as the two modes of the gradient's
direction (:func:`grid_tilt`), and a photograph in which one of them lies within
:data:`MIN_MARGIN_DEG` of a diagonal, where the detector's rule for telling the families
apart (the normal nearer the y axis is the horizontal bands') flips from tile to tile, is
detected in its image turned level (:func:`cv2.warpAffine`, bilinear, on a canvas that holds
all of it), the result mapped back to the photograph.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import cv2
import numpy as np

from ._threads import in_halves

#: The detector tells the families apart by their normals, the one nearer the image's y axis
#: taken as the horizontal bands' (:func:`~nurbscan.detect.oblique.family_normals`, per tile).
#: Where the two normals are about as far from the y axis (a grid turned by about 45
#: degrees), tiles take either family for the other; when the two angles to the x axis differ
#: by less than twice this (degrees), the photograph is read in its image turned level
#: instead. A rectangular grid turned by t has the margin |45 - t|: the upright teapot views
#: about 37 (perspective), the real photographs of the shared set 21 or more (a board held
#: turned), the oblique and sheared test views (normals at 50 and 92, 20 and 60 degrees) 19
#: and 20, the 640 x 480 synthetic view of narrow bands 11, all read as they are; the fuzz
#: benchmark's wrong labels came at margins of 0 to 3 degrees (tests/test_reliability.py).
MIN_MARGIN_DEG = 8.0
#: Below this share of the gradient's weight within :data:`MODE_WIDTH_DEG` of the two modes
#: there is no grid direction to speak of (noise, blobs, a blank image), and the photograph is
#: read as it is.
MIN_CONCENTRATION = 0.3
#: Half width of a family's mode of gradient directions (degrees), and the least separation of
#: the two modes.
MODE_WIDTH_DEG, MODE_SEPARATION_DEG = 8, 20
#: The directions are measured on the photograph reduced to at most this many pixels on its
#: longer side (:data:`cv2.INTER_AREA`): the grid's direction, not its detail.
TILT_SIDE_PX = 640


@dataclass(frozen=True)
class Tilt:
    """The grid's tilt in a photograph.

    Attributes
    ----------
    degrees : float
        The turn (degrees, anticlockwise on the screen, x right and y down, as
        :func:`cv2.getRotationMatrix2D`) that took the grid from level: the mean of its two
        families' normals' angles to the image axes (modulo 90, in (-45, 45] for a
        rectangular grid).
    margin : float
        Half the difference of the two families' normals' angles to the x axis (0 to 45
        degrees): how far the photograph is from the turn at which the detector takes one
        family for the other.
    concentration : float
        Share of the gradient's weight (squared magnitude) near the two families' normals.
    """

    degrees: float
    margin: float
    concentration: float

    @property
    def needs_levelling(self) -> bool:
        """True when the photograph is read in its level image (:func:`detect_tilted`)."""
        return self.concentration >= MIN_CONCENTRATION and self.margin < MIN_MARGIN_DEG


def _wrap90(a: float) -> float:
    """``a`` (degrees) modulo 180, in (-90, 90]."""
    a = (a + 90.0) % 180.0 - 90.0
    return 90.0 if a == -90.0 else a


def grid_tilt(image: np.ndarray) -> Tilt:
    """The tilt of the grid's two families of lines in ``image`` (H, W[, C]), any dtype.

    Notes
    -----
    1. The image is reduced (longer side :data:`TILT_SIDE_PX`; an 8- or 16-bit one in its own
       type), made grey (the channels' mean) and differentiated (3 x 3 Sobel).
    2. The gradient directions modulo 180 degrees, weighted by the squared magnitude, make a
       histogram of 1-degree bins, smoothed (circular, sigma 2 degrees); its highest peak and
       the highest at least :data:`MODE_SEPARATION_DEG` from it are the families' normals
       (each refined to the weighted mean of its bins within 3 degrees).
    3. The normal nearer the x axis is the vertical bands' (angle ``dA`` from it), the other
       the horizontal bands' (``dB`` from the y axis); the tilt is ``-(dA + dB) / 2`` (the
       image's y axis points down: an anticlockwise turn on the screen is a negative angle
       in (x, y)), the margin half the difference of the two normals' angles to the x axis.
    """
    a = np.asarray(image)
    if a.ndim not in (2, 3) or a.dtype.kind not in "buif" or min(a.shape[:2]) < 3:
        return Tilt(0.0, 45.0, 0.0)  # not an image: the detector's first stage says why
    h, w = a.shape[:2]
    scale = TILT_SIDE_PX / max(h, w)
    small = (max(1, round(w * scale)), max(1, round(h * scale)))
    if a.ndim == 3 and a.dtype in (np.uint8, np.uint16) and a.shape[2] <= 4:
        if scale < 1.0:  # reduced first, in its own type (8 instead of 40 ms at 7.1 MP)
            a, scale = cv2.resize(np.ascontiguousarray(a), small,
                                  interpolation=cv2.INTER_AREA), 1.0
            a = a.reshape(small[1], small[0], -1)
        a = _channel_mean(a)
    elif a.ndim == 3:
        a = a.mean(axis=2, dtype=np.float32)
    a = a.astype(np.float32, copy=False)
    if scale < 1.0:
        a = cv2.resize(a, small, interpolation=cv2.INTER_AREA)
    gx = cv2.Sobel(a, cv2.CV_32F, 1, 0, ksize=3).ravel()
    gy = cv2.Sobel(a, cv2.CV_32F, 0, 1, ksize=3).ravel()

    def directions(part):  # the pixels' 1-degree bins and weights, element by element (the
        # two halves side by side: _threads)
        x, y = gx[part], gy[part]
        m2 = x.astype(np.float64) ** 2 + y.astype(np.float64) ** 2
        ok = np.isfinite(m2) & (m2 > 0)
        phi = np.degrees(np.arctan2(y[ok], x[ok])) % 180.0
        return np.minimum(phi.astype(np.int64), 179), m2[ok]

    bins, weight = in_halves(directions, len(gx))
    total = weight.sum()
    if not len(weight) or total <= 0:
        return Tilt(0.0, 45.0, 0.0)
    hist = np.bincount(bins, weights=weight, minlength=180) / total
    k = np.exp(-0.5 * (np.arange(-6, 7) / 2.0) ** 2)
    smooth = np.convolve(np.r_[hist[-6:], hist, hist[:6]], k / k.sum(), mode="valid")
    centre = np.arange(180) + 0.5
    modes, near = [], np.zeros(180, bool)
    for _ in range(2):
        p = centre[np.argmax(np.where(near, -1.0, smooth))]
        off_all = (centre - p + 90) % 180 - 90  # signed circular distance to the peak
        dist = np.abs(off_all)
        d3 = dist <= 3
        off = off_all[d3]
        modes.append((p + np.sum(off * hist[d3]) / max(hist[d3].sum(), 1e-300)) % 180)
        near |= dist < MODE_SEPARATION_DEG
    share = float(sum(hist[np.abs((centre - m + 90) % 180 - 90) <= MODE_WIDTH_DEG].sum()
                      for m in modes))
    dx = [min(m, 180.0 - m) for m in modes]  # each normal's angle to the x axis, 0-90
    va, hb = (0, 1) if dx[0] <= dx[1] else (1, 0)
    tilt = -(_wrap90(modes[va]) + _wrap90(modes[hb] - 90.0)) / 2.0
    margin = abs(dx[0] - dx[1]) / 2.0
    return Tilt(float(tilt), float(margin), min(share, 1.0))


def _channel_mean(a: np.ndarray) -> np.ndarray:
    """``a.mean(axis=2, dtype=np.float32)`` of an 8- or 16-bit image (H, W, C <= 4), the same
    values: the channels' sum is exact in float32 and divided once, as numpy's mean does.
    OpenCV's split and adds instead of numpy's strided reduction: 12 instead of 100 ms on a
    7.1 MP view (one thread)."""
    planes = cv2.split(np.ascontiguousarray(a))
    s = planes[0].astype(np.float32)
    for c in planes[1:]:
        s = cv2.add(s, c, dtype=cv2.CV_32F)
    s /= np.float32(len(planes))
    return s


def level_transform(size: tuple[int, int], degrees: float) -> tuple[np.ndarray, tuple[int, int]]:
    """The affine map (2, 3) from a photograph of ``size`` (width, height) to its image turned
    by ``-degrees`` about its centre, on a canvas (width, height) that holds all of it."""
    w, h = size
    M = cv2.getRotationMatrix2D(((w - 1) / 2.0, (h - 1) / 2.0), -degrees, 1.0)
    c, s = abs(M[0, 0]), abs(M[0, 1])
    nw, nh = int(np.ceil(w * c + h * s)), int(np.ceil(w * s + h * c))
    M[0, 2] += (nw - w) / 2.0
    M[1, 2] += (nh - h) / 2.0
    return M, (nw, nh)


def _warp(image: np.ndarray | None, M: np.ndarray, size: tuple[int, int]):
    if image is None:
        return None
    a = np.asarray(image)
    if a.dtype == np.float64:
        a = a.astype(np.float32)
    return cv2.warpAffine(a, M, size, flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                          borderValue=0)


def _apply(M: np.ndarray, x: np.ndarray, y: np.ndarray):
    x = np.asarray(x, np.float64)
    y = np.asarray(y, np.float64)
    return M[0, 0] * x + M[0, 1] * y + M[0, 2], M[1, 0] * x + M[1, 1] * y + M[1, 2]


def detect_tilted(image, white, pattern, options, tilt: Tilt, epipolar=None,
                  timings: dict | None = None):
    """:func:`~nurbscan.detect.detect_grid` of a photograph whose grid is tilted by
    ``tilt``: detected in its level image (:func:`level_transform`), the points and
    intersections mapped back to the photograph (pixel centres at integers both ways, as
    :func:`cv2.warpAffine`); the rig's ``epipolar`` prediction is asked at the photograph's
    pixels. A warning in the result says so."""
    from .core import detect_grid

    h, w = np.asarray(image).shape[:2]
    M, size = level_transform((w, h), tilt.degrees)
    back = cv2.invertAffineTransform(M)
    level_epipolar = epipolar
    if epipolar is not None:
        def level_epipolar(pixels, direction, coord):
            pix = np.asarray(pixels, np.float64)
            x, y = _apply(back, pix[:, 0], pix[:, 1])
            return epipolar(np.c_[x, y], direction, coord)
    result = detect_grid(_warp(image, M, size), pattern, _warp(white, M, size), options,
                         epipolar=level_epipolar, timings=timings)
    x, y = _apply(back, result.x, result.y)
    cam = np.asarray(result.cam, np.float64).reshape(-1, 2)
    cx, cy = _apply(back, cam[:, 0], cam[:, 1])
    note = f"image: the grid is tilted by {tilt.degrees:.1f} degrees; decoded level"
    return replace(result, image_size=(w, h), x=x, y=y, cam=np.c_[cx, cy],
                   warnings=tuple(result.warnings) + (note,))
