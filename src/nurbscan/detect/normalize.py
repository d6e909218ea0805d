"""Colour and albedo normalisation of a grid photograph (method.md section 2, first step).

The camera sees ``I_c = a(x) * s(x) * sum_k M_ck P_k(x) + b_c`` per channel c: projector primaries
P_k in {0, 1}, a 3x3 crosstalk mix M, surface albedo and shading ``a s`` and ambient b. Two
normalisations give an image whose lit bands are near 1 and whose black gaps are near 0:

* with a white-light image ``W`` (every primary on): ``N = (I - dark) / max(W - dark, floor)``
  per channel, which cancels albedo, shading and the row sums of M;
* without it: local background ``bg`` (a grey-level minimum filter, smoothed) and local envelope
  ``env`` (a maximum filter of the brightest channel, smoothed) give
  ``N = (I - bg) / max(env - bg, floor)``.

The edge signal is the sum of the normalised channels (:func:`edge_signal`), which keeps each
band's edge profile undisturbed where it meets a band of the other direction. The large-scale
fields (dark level, envelope) are computed at a quarter of the resolution.

The per-pixel arithmetic is one compiled pass (:func:`_normalised_pixel`, numba: the float32
operations numpy's ufuncs made in five passes over the planes, in the same order), and
:func:`normalize_photograph` does all of it, and the linearisation, over the window the white
image lights only (a quarter of a 7.1 MP teapot view): the normalise stage of a 7.1 MP
teapot view takes 0.09 instead of 0.16 s, with the same values.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from .._jit import njit
from ..errors import NurbscanError
from ._threads import parallel_map


def smooth_field(a: np.ndarray, sigma: float, op: str | None = None, size: int = 1
                 ) -> np.ndarray:
    """A smooth background field of ``a`` (H, W): optional grey erosion / dilation by a
    ``size`` x ``size`` square (``op`` "min" / "max"), then a Gaussian of ``sigma`` px.

    Computed at a quarter of the resolution (area-averaged) and enlarged bilinearly, which is
    exact enough for fields that vary over tens of pixels and 16x cheaper.
    """
    h, w = a.shape
    f = 4 if min(h, w) >= 256 else 1
    small = cv2.resize(a, (max(w // f, 1), max(h // f, 1)), interpolation=cv2.INTER_AREA) \
        if f > 1 else a
    k = max(int(round(size / f)) | 1, 1)
    if op == "min":
        small = cv2.erode(small, np.ones((k, k), np.uint8))
    elif op == "max":
        small = cv2.dilate(small, np.ones((k, k), np.uint8))
    small = cv2.GaussianBlur(small, (0, 0), max(sigma / f, 0.5), borderType=cv2.BORDER_REFLECT)
    if f == 1:
        return small
    return cv2.resize(small, (w, h), interpolation=cv2.INTER_LINEAR)


def channel_min(img: np.ndarray) -> np.ndarray:
    """Per-pixel minimum over the 3 channels, (H, W) float32."""
    return np.minimum(np.minimum(img[..., 0], img[..., 1]), img[..., 2])


def channel_max(img: np.ndarray) -> np.ndarray:
    """Per-pixel maximum over the 3 channels, (H, W) float32."""
    return np.maximum(np.maximum(img[..., 0], img[..., 1]), img[..., 2])


@dataclass(frozen=True)
class Normalised:
    """A normalised grid image (module notes), kept in a form that is cheap for 7 MP images.

    Attributes
    ----------
    signal : ndarray (H, W) float32
        Edge signal: the sum over channels of the normalised image (:func:`edge_signal`).
    valid : ndarray (H, W) bool
        Pixels whose denominator is above the floor (lit by the projector).
    channels : tuple of 3 ndarray (H, W) float32
        The normalised channels: the linear image's channels minus the dark level, times
        ``1 / denominator`` (float32 products, as the signal's terms).

    From :func:`normalize_photograph`, the signal and channels are 0 outside the window of
    the lit pixels (:func:`lit_window`), and nothing there is valid.
    """

    signal: np.ndarray
    valid: np.ndarray
    channels: tuple

    def colour_at(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Normalised colour (N, 3) at points (x, y) px (bilinear)."""
        from .decode import bilinear_at, bilinear_taps

        taps = bilinear_taps(self.signal.shape, x, y)  # (the same for the three planes)
        return np.stack([bilinear_at(c, taps) for c in self.channels], axis=1)

    def planes(self) -> list[np.ndarray]:
        """The three normalised channels, (H, W) float32 each."""
        return list(self.channels)

    def lazy_planes(self) -> _LazyPlanes:
        """The three normalised channels as a sequence of windows (:meth:`_LazyPlanes.crop`)."""
        return _LazyPlanes(self)

    def image(self) -> np.ndarray:
        """The full normalised image (H, W, 3) float32 (for inspection; not used inside)."""
        return np.stack(self.planes(), axis=2)


class _LazyPlanes:
    """:meth:`Normalised.planes`, each plane over the window ``(rows, cols)`` of slices only
    (with :meth:`crop`), taken when indexed."""

    def __init__(self, nrm: Normalised, window: tuple = (slice(None), slice(None))):
        self._nrm, self._window = nrm, window

    @property
    def shape(self) -> tuple[int, int]:
        """(H, W) of the planes (of the window)."""
        return self._nrm.signal[self._window].shape

    def crop(self, rows: slice, cols: slice) -> _LazyPlanes:
        """The planes over the window ``(rows, cols)`` (slices with steps of 1) of these."""
        r, c = self._window
        r0, c0 = r.start or 0, c.start or 0
        return _LazyPlanes(self._nrm, (slice(r0 + (rows.start or 0), r0 + rows.stop),
                                       slice(c0 + (cols.start or 0), c0 + cols.stop)))

    def __len__(self) -> int:
        return 3

    def __getitem__(self, c: int) -> np.ndarray:
        if not -3 <= c < 3:
            raise IndexError(c)
        return self._nrm.channels[c][self._window]


def as_float_image(image, what: str = "image", gamma: float = 1.0) -> np.ndarray:
    """An (H, W, 3) float32 copy of ``image``, scaled to [0, 1] and raised to ``gamma``.

    uint8 / uint16 data are scaled by their full scale and linearised through a look-up table;
    grey images are repeated in the three channels; float data must be finite.
    """
    return linear_values(colour_image(image, what), what, gamma)


def colour_image(image, what: str = "image") -> np.ndarray:
    """``image`` as an (H, W, 3) array of its own sample type (a view of the first three
    channels; a grey image repeated in three), checked: at least 16 x 16 px, of integer or
    float samples. Raises :class:`~nurbscan.errors.NurbscanError` (naming ``what``)."""
    a = np.asarray(image)
    if a.ndim == 2:
        a = np.repeat(a[:, :, None], 3, axis=2)
    if a.ndim != 3 or a.shape[2] not in (3, 4) or a.shape[0] < 16 or a.shape[1] < 16:
        raise NurbscanError(f"{what}: expected an (H, W, 3) image of at least 16 x 16 px, "
                            f"got shape {a.shape}")
    if a.dtype.kind not in "fiu":
        raise NurbscanError(f"{what}: unsupported sample type {a.dtype}")
    return a[:, :, :3]


def linear_values(a: np.ndarray, what: str = "image", gamma: float = 1.0) -> np.ndarray:
    """The float32 linear values of the samples ``a`` (any shape; checked by
    :func:`colour_image`): 8 / 16-bit values over their full scale through a look-up table
    raised to ``gamma``, floats (which must be finite) clipped at 0 and raised to ``gamma``."""
    if a.dtype in (np.uint8, np.uint16):
        lut = _table(a.dtype, gamma)
        if a.dtype == np.uint8:  # OpenCV's table look-up: same values, several times faster
            return cv2.LUT(np.ascontiguousarray(a), lut)
        return lut[a]
    a = a.astype(np.float32)
    if not np.all(np.isfinite(a)):
        raise NurbscanError(f"{what}: holds NaN or infinite values")
    a = np.clip(a, 0.0, None)
    return a**gamma if gamma != 1 else a


def as_float_planes(image, what: str = "image", gamma: float = 1.0) -> tuple:
    """The three colour planes of :func:`as_float_image`, each (H, W) float32 and contiguous.

    8-bit images are split first and each plane looked up (OpenCV), which avoids an
    interleaved (H, W, 3) float copy and its split: 60 instead of 135 ms for 7.1 MP.
    """
    a = np.asarray(image)
    if a.dtype == np.uint8 and a.ndim == 3 and a.shape[2] in (3, 4) and min(a.shape[:2]) >= 16:
        lut = _table(a.dtype, gamma)
        return tuple(cv2.LUT(c, lut) for c in cv2.split(np.ascontiguousarray(a[:, :, :3])))
    return tuple(cv2.split(as_float_image(image, what, gamma)))


def _planes(image, what: str) -> tuple:
    """Three contiguous (H, W) float32 planes of an (H, W, 3) array or a sequence of 3 planes."""
    if isinstance(image, tuple | list):
        planes = tuple(np.ascontiguousarray(c, dtype=np.float32) for c in image)
        if len(planes) == 3 and all(p.ndim == 2 and p.shape == planes[0].shape
                                    for p in planes):
            return planes
        raise NurbscanError(f"{what}: expected 3 colour planes of one size")
    img = np.asarray(image, dtype=np.float32)
    if img.ndim != 3 or img.shape[2] != 3:
        raise NurbscanError(f"{what}: expected an (H, W, 3) colour image, got shape {img.shape}")
    return tuple(cv2.split(img))


#: ITU-R BT.601 luma weights of R, G, B, as JPEG's Y'CbCr defines them.
LUMA_601 = (0.299, 0.587, 0.114)


def normalize(image: np.ndarray, white: np.ndarray | None = None, window: int = 31,
              floor: float = 0.03, weights=None, overwrite: bool = False) -> Normalised:
    """Normalise a (linear) grid image for albedo, shading and illumination.

    Parameters
    ----------
    image : ndarray (H, W, 3), float32, linear in the light, or its three (H, W) planes
        The photograph of the object under the grid.
    white : ndarray (H, W, 3) or three planes, optional
        The same view under full white light; must have the image's size.
    window : int
        Side of the local minimum / maximum filters (dark level, and the envelope when there is
        no white image), camera px (about two band pitches).
    floor : float
        Smallest denominator (fraction of full scale): darker pixels count as unlit.
    weights : sequence of 3 float, optional
        Weights of the normalised channels in the edge signal (scaled to sum to 3; default
        equal, :func:`edge_signal`). Any positive weights keep its crossing-band property;
        for a JPEG with subsampled colour the luma weights (``LUMA_601``) leave out most of
        the blurred colour.
    overwrite : bool
        The float32 planes of the image and of the white image may be overwritten (the
        caller's linearised copies: saves six image-sized arrays); a white image given as a
        list of planes is emptied.

    Returns
    -------
    Normalised
        The edge signal, the valid mask and what is needed to read colours at points.

    See Also
    --------
    normalize_photograph : the same from the camera's values, over the lit window only.
    """
    chans = _planes(image, "image")
    wts = _weights(weights)
    wp = None
    if white is not None:
        wp = list(_planes(white, "white image"))
        if overwrite and isinstance(white, list):
            white.clear()  # (the caller's references go: its planes become the blurred ones)
        check_white_size(wp[0].shape, chans[0].shape)
    # dark level: local minimum of the grid image (ambient light in the black gaps)
    dark = smooth_field(cv2.min(cv2.min(chans[0], chans[1]), chans[2]), window / 3, "min",
                        window)
    if wp is None:
        # the envelope: a local maximum of the brightest channel, the one denominator of all
        # three channels
        env = smooth_field(cv2.max(cv2.max(chans[0], chans[1]), chans[2]), window / 3, "max",
                           window)
        wp = [env] * 3
    else:
        wp = _blurred(wp, overwrite)
    shape = chans[0].shape
    out = list(chans) if overwrite else [np.empty(shape, np.float32) for _ in range(3)]
    out += [np.empty(shape, np.float32), np.empty(shape, np.bool_)]
    _in_row_halves(lambda r0, r1: _normalise_planes(*chans, *wp, dark, np.float32(floor), wts,
                                                    *out, r0, r1), 0, shape[0])
    return Normalised(signal=out[3], valid=out[4], channels=tuple(out[:3]))


def normalize_photograph(image: np.ndarray, white: np.ndarray | None, gamma: float = 1.0,
                         window: int = 31, floor: float = 0.03, weights=None) -> Normalised:
    """:func:`normalize` of a photograph and its white image as the camera wrote them
    (linearised by ``v ** gamma``), computed over the window the white image lights only.

    The projector lights a part of the frame (on the 7.1 MP teapot views 16 % of it, in a
    window of a quarter of it). Where no white channel is above ``floor / 2`` within 3 px
    (the reach of the white image's blur), no blurred white minus a non-negative dark level is
    above ``floor``: such a pixel is unlit and its denominator is ``floor`` exactly. So the
    normalised values inside the bounding box of the lit pixels, widened by
    :data:`LIT_MARGIN`, are those of :func:`normalize` of the whole photograph, bit for bit;
    outside it the signal and channels are 0 and nothing is valid (no later stage reads
    there: :data:`LIT_MARGIN`). The dark level's minimum over the channels is taken on the
    camera's values and then linearised (the look-up table is non-decreasing: the same
    values). Photographs that are not 8 or 16-bit colour images, or without a white image,
    are normalised whole (:func:`normalize` of :func:`as_float_planes`).

    Parameters
    ----------
    image, white : ndarray (H, W, 3) (or (H, W)), uint8, uint16 or float in [0, 1]
        The photograph and its white image (gamma-encoded), :func:`as_float_image`'s inputs.
    gamma : float
        The images' encoding gamma.
    window, floor, weights
        As :func:`normalize`.

    Returns
    -------
    Normalised
        Image-sized planes (H, W).
    """
    image, white = np.asarray(image), None if white is None else np.asarray(white)
    if not (white is not None and _integer_colour(image) and _integer_colour(white)
            and image.shape[:2] == white.shape[:2] and min(image.shape[:2]) >= 256):
        lin, wl = parallel_map(lambda iw: None if iw[0] is None else
                               as_float_planes(iw[0], iw[1], gamma=gamma),
                               ((image, "image"), (white, "white image")))
        return normalize(lin, None if wl is None else list(wl), window=window, floor=floor,
                         weights=weights, overwrite=True)
    wts = _weights(weights)
    h, w = image.shape[:2]

    def lit_white():  # the lit window and the white image's planes there
        rows, cols = lit_window(white, gamma, floor)
        return rows, cols, as_float_planes(white[rows, cols], "white image", gamma=gamma)

    # (the dark level and the white image side by side, then the white planes' blurs side by
    # side: _threads)
    dark, (rows, cols, wl) = parallel_map(lambda job: job(), (
        lambda: dark_level(image, gamma, window), lit_white))
    wl = _blurred(list(wl), True)
    if wl[0].shape == (h, w):  # (the whole frame lit: the channels in the white's planes)
        out = [*wl, np.empty((h, w), np.float32), np.empty((h, w), np.bool_)]
    else:
        out = [np.empty((h, w), np.float32) for _ in range(4)] + [np.empty((h, w), np.bool_)]
    # (the photograph's values looked up in the pass itself: no linear copy of it)
    img, lut = np.ascontiguousarray(image), _table(image.dtype, gamma)
    y0, y1, x0, x1 = rows.start, rows.stop, cols.start, cols.stop

    def half(r0, r1):  # the window's rows r0:r1, and 0 beside them and above (below) them
        top = 0 if r0 == y0 and r1 > r0 else r0  # (an empty half zeroes nothing)
        bottom = h if r1 == y1 else r1
        for a in out:
            a[top:r0], a[r1:bottom], a[r0:r1, :x0], a[r0:r1, x1:] = 0, 0, 0, 0
        _normalise_values(img, lut, *wl, dark, np.float32(floor), wts, *out, r0, r1, y0, x0)

    _in_row_halves(half, y0, y1)
    return Normalised(signal=out[3], valid=out[4], channels=tuple(out[:3]))


#: Margin of :func:`normalize_photograph`'s window around the lit pixels, px: the edge stage
#: works over the valid pixels' window widened by two family tiles (48 px), its filter's
#: radius (at most 6 px) and 8 px and rounded out to whole tiles (at most 3 tiles + 14 px;
#: :func:`~nurbscan.detect.edges.detect_edge_points`), the blur of the white image reaches
#: 3 px each way, and the colour reading and re-measurement read within a few band widths of
#: the edge points.
LIT_MARGIN = 192


def lit_window(white: np.ndarray, gamma: float, floor: float,
               margin: int = LIT_MARGIN) -> tuple[slice, slice]:
    """The rows and columns of the bounding box of the pixels of ``white`` (H, W, 3+) uint8 or
    uint16, gamma-encoded) with a channel whose linear value is above ``floor / 2``, widened
    by ``margin`` px (:func:`normalize_photograph`); the whole image when none is."""
    h, w = white.shape[:2]
    lut = _table(white.dtype, gamma)
    t = int(np.count_nonzero(lut <= np.float32(floor / 2))) - 1  # (lut is non-decreasing)
    dark = cv2.inRange(np.ascontiguousarray(white[:, :, :3]), (0, 0, 0), (t, t, t))
    x, y, bw, bh = cv2.boundingRect(cv2.bitwise_not(dark))
    if bw == 0 or bh == 0:
        return slice(0, h), slice(0, w)
    return (slice(max(y - margin, 0), min(y + bh + margin, h)),
            slice(max(x - margin, 0), min(x + bw + margin, w)))


def dark_level(image: np.ndarray, gamma: float, window: int = 31) -> np.ndarray:
    """:func:`normalize`'s dark level (H, W) float32 of an (H, W, 3+) uint8 or uint16
    photograph: the smoothed local minimum (:func:`smooth_field`) of the least channel,
    taken on the camera's values and then linearised by ``v ** gamma`` (a non-decreasing
    table: the minimum of the linear channels)."""
    c = cv2.split(np.ascontiguousarray(image[:, :, :3]))
    low = cv2.min(cv2.min(c[0], c[1]), c[2])
    del c
    lut = _table(image.dtype, gamma)
    lin = cv2.LUT(low, lut) if image.dtype == np.uint8 else lut[low]
    return smooth_field(lin, window / 3, "min", window)


def _integer_colour(a: np.ndarray) -> bool:
    """An (H, W, 3 or 4) array of 8 or 16-bit camera values."""
    return a.ndim == 3 and a.shape[2] in (3, 4) and a.dtype in (np.uint8, np.uint16)


def _table(dtype, gamma: float) -> np.ndarray:
    """The linearisation table of 8 or 16-bit values: ``(v / top) ** gamma``, float32."""
    top = 255 if dtype == np.uint8 else 65535
    return ((np.arange(top + 1, dtype=np.float64) / top) ** gamma).astype(np.float32)


def _weights(weights) -> np.ndarray:
    """The channels' weights in the edge signal, scaled to sum to 3, float32 (3,)."""
    wts = np.ones(3) if weights is None else np.asarray(weights, np.float64)
    if wts.shape != (3,) or not np.all(wts >= 0) or not wts.sum() > 0:
        raise NurbscanError(f"weights={weights!r}: need three non-negative channel weights")
    return (3.0 * wts / wts.sum()).astype(np.float32)


def check_white_size(white: tuple, image: tuple) -> None:
    """Raise :class:`~nurbscan.errors.NurbscanError` when the white image's (H, W) ``white``
    is not the grid image's ``image``."""
    if white != image:
        raise NurbscanError(f"white image: size {white[1]}x{white[0]} does not match the grid "
                            f"image's {image[1]}x{image[0]}")


def _blurred(planes: list, in_place: bool) -> list:
    """The white image's planes blurred by a Gaussian of 0.7 px (the three side by side:
    _threads), in their own buffers when ``in_place``."""
    # cv2.GaussianBlur(c, (0, 0), 0.7)'s own kernel and border, through sepFilter2D: the
    # same values, in half the time
    g = cv2.getGaussianKernel(7, 0.7, cv2.CV_32F)
    return parallel_map(lambda c: cv2.sepFilter2D(c, cv2.CV_32F, g, g,
                                                  dst=c if in_place else None,
                                                  borderType=cv2.BORDER_REFLECT_101), planes)


def _in_row_halves(fn, r0: int, r1: int) -> None:
    """``fn(r0, mid)`` and ``fn(mid, r1)``, the two halves of the rows ``r0:r1``, side by side
    (_threads)."""
    mid = (r0 + r1) // 2
    parallel_map(lambda rows: fn(*rows), ((r0, mid), (mid, r1)))


@njit(cache=True, nogil=True)
def _normalised_pixel(x0, x1, x2, dk, d0, d1, d2, floor, wts):
    """One pixel of the normalisation, float32 throughout: ``x_c - dk`` (the linear channels
    over the dark level ``dk``) times ``1 / max(d_c - dk, floor)`` (``d_c`` the blurred white,
    or the envelope; NaN stays NaN); the signal ``(t_0 + t_1) + t_2`` with
    ``t_c = x_c * (inv_c * wts_c)`` (the normalised channel for a weight of 1), and whether
    some ``d_c - dk > floor``. Returns ``(n_0, n_1, n_2, signal, valid)``."""
    one = np.float32(1.0)
    x0, x1, x2 = x0 - dk, x1 - dk, x2 - dk
    d0, d1, d2 = d0 - dk, d1 - dk, d2 - dk
    v0 = one / (floor if d0 < floor else d0)
    v1 = one / (floor if d1 < floor else d1)
    v2 = one / (floor if d2 < floor else d2)
    a0, a1, a2 = x0 * v0, x1 * v1, x2 * v2
    t0 = a0 if wts[0] == 1 else x0 * (v0 * wts[0])
    t1 = a1 if wts[1] == 1 else x1 * (v1 * wts[1])
    t2 = a2 if wts[2] == 1 else x2 * (v2 * wts[2])
    return a0, a1, a2, (t0 + t1) + t2, (d0 > floor) | (d1 > floor) | (d2 > floor)


@njit(cache=True, nogil=True)
def _normalise_planes(i0, i1, i2, w0, w1, w2, dark, floor, wts, n0, n1, n2, signal, valid,
                      r0, r1):
    """Rows ``r0:r1`` of the normalisation of the linear planes ``i_c`` (H, W) with the
    denominators' planes ``w_c`` and the ``dark`` level (:func:`_normalised_pixel`), into
    ``n_c``, ``signal`` and ``valid`` (which may be the planes ``i_c`` themselves)."""
    for r in range(r0, r1):
        for c in range(dark.shape[1]):
            n0[r, c], n1[r, c], n2[r, c], signal[r, c], valid[r, c] = _normalised_pixel(
                i0[r, c], i1[r, c], i2[r, c], dark[r, c], w0[r, c], w1[r, c], w2[r, c],
                floor, wts)


@njit(cache=True, nogil=True)
def _normalise_values(img, lut, w0, w1, w2, dark, floor, wts, n0, n1, n2, signal, valid,
                      r0, r1, y0, x0):
    """Rows ``r0:r1`` of the normalisation of the photograph ``img`` (H, W, 3+) of 8 or
    16-bit values, linearised by the table ``lut``, over the window at ``(y0, x0)`` of the
    blurred white planes ``w_c`` (h, w): :func:`_normalised_pixel` with the image-sized
    ``dark`` level, into the image-sized ``n_c``, ``signal`` and ``valid``."""
    for r in range(r0, r1):
        for c in range(x0, x0 + w0.shape[1]):
            n0[r, c], n1[r, c], n2[r, c], signal[r, c], valid[r, c] = _normalised_pixel(
                lut[img[r, c, 0]], lut[img[r, c, 1]], lut[img[r, c, 2]], dark[r, c],
                w0[r - y0, c - x0], w1[r - y0, c - x0], w2[r - y0, c - x0], floor, wts)


def edge_signal(norm: np.ndarray) -> np.ndarray:
    """The sum of the normalised channels, float32 (H, W).

    Where a vertical band (colour v, 0/1 per channel) meets a horizontal band of colour h, the
    light of each channel is ``V_c + H_c - V_c H_c`` (the crossing rule, for 0/1 channels), so
    along a row at a fixed height ``sum_c N_c = const + V(x) sum_c v_c (1 - H_c)``: the row
    derivative of the sum is the vertical band's profile times a constant, and its edges are
    not displaced by the crossing band (likewise for columns).
    """
    return np.ascontiguousarray(norm[..., 0] + norm[..., 1] + norm[..., 2], dtype=np.float32)


def noise_level(signal: np.ndarray, valid: np.ndarray | None = None, step: int = 3) -> float:
    """Standard deviation of the white noise in ``signal`` (H, W), robust to its edges.

    Immerkaer's estimator: the 3 x 3 mask ``[[1, -2, 1], [-2, 4, -2], [1, -2, 1]]`` (the
    difference of two Laplacians) cancels every locally linear structure and passes white
    noise of deviation s with deviation 6 s; the median of its absolute response over the
    ``valid`` pixels (every ``step``-th row and column), over 6 x 0.6745 (the median of a
    unit half-normal), gives s. The median leaves out the band edges, whose curvature the
    mask does pass. Default-noise teapot views (normalised signal): 0.020; 3x noise 0.056;
    noise-free renders 0.004 (aliasing and interpolation).

    References
    ----------
    .. [1] J. Immerkaer, "Fast noise variance estimation", Computer Vision and Image
       Understanding 64(2), 300-302, 1996.
    """
    k = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], np.float32)
    signal = np.asarray(signal, np.float32)
    h, w = signal.shape
    rows, cols = slice(0, h), slice(0, w)
    if valid is not None:
        # over the valid pixels' window, widened by the mask's reach (the same samples: a
        # third of the work on a 7.1 MP teapot view)
        from .edges import work_window

        valid = np.asarray(valid, bool)
        rows, cols = work_window(valid, 1)
    # the sampled pixels: rows and columns 1, 1 + step, ... below h - 1 and w - 1
    r0, c0 = (max(a, 1) + (1 - max(a, 1)) % step - a for a in (rows.start, cols.start))
    r1, c1 = min(rows.stop, h - 1) - rows.start, min(cols.stop, w - 1) - cols.start
    r = np.abs(cv2.filter2D(signal[rows, cols], -1, k,
                            borderType=cv2.BORDER_REFLECT))[r0:r1:step, c0:c1:step]
    if valid is not None:
        r = r[valid[rows, cols][r0:r1:step, c0:c1:step]]
    if r.size == 0:
        return float("nan")
    return float(np.median(r) / (6.0 * 0.6745))
