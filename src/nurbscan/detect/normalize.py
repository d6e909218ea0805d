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
        With a white image, the float32 planes of the image and of the white image may be
        overwritten (the caller's linearised copies: saves six image-sized arrays); a white
        image given as a list of planes is emptied.

    Returns
    -------
    Normalised
        The edge signal, the valid mask and what is needed to read colours at points.
    """
    chans = chans_in = _planes(image, "image")
    # dark level: local minimum of the grid image (ambient light in the black gaps)
    dark = smooth_field(cv2.min(cv2.min(chans[0], chans[1]), chans[2]), window / 3, "min",
                        window)
    in_place = overwrite and white is not None  # (chans_in is needed without a white image)
    wp = None
    if white is not None:
        wp = list(_planes(white, "white image"))
        if in_place and isinstance(white, list):
            white.clear()  # (the caller's references go: its planes become the inverses)
        if wp[0].shape != chans[0].shape:
            raise NurbscanError(
                f"white image: size {wp[0].shape[1]}x{wp[0].shape[0]} does not match the grid "
                f"image's {chans[0].shape[1]}x{chans[0].shape[0]}"
            )
    wts = np.ones(3) if weights is None else np.asarray(weights, np.float64)
    if wts.shape != (3,) or not np.all(wts >= 0) or not wts.sum() > 0:
        raise NurbscanError(f"weights={weights!r}: need three non-negative channel weights")
    wts = (3.0 * wts / wts.sum()).astype(np.float32)
    # cv2.GaussianBlur(c, (0, 0), 0.7)'s own kernel and border, through sepFilter2D: the
    # same values, in half the time
    g = cv2.getGaussianKernel(7, 0.7, cv2.CV_32F)

    def channel(c):  # one channel's part (the channels side by side: _threads)
        ch = cv2.subtract(chans[c], dark, dst=chans[c] if in_place else None)
        if wp is None:
            return ch, None, None
        # the denominator: the blurred white minus the dark level (in the white plane's own
        # buffer where it is this function's to overwrite: one image-sized plane fewer per
        # channel)
        d = cv2.sepFilter2D(wp[c], cv2.CV_32F, g, g, dst=wp[c] if in_place else None,
                            borderType=cv2.BORDER_REFLECT_101)
        wp[c] = None
        return ch, cv2.subtract(d, dark, dst=d), None

    parts = parallel_map(channel, range(3))
    chans = tuple(ch for ch, _, _ in parts)
    if wp is not None:
        # lit where any channel's denominator is over the floor (one pass, no mask per
        # channel), then each denominator d becomes 1 / max(d, floor) in place
        den = [d for _, d, _ in parts]
        valid = np.empty(den[0].shape, np.bool_)
        _any_over(den[0], den[1], den[2], np.float32(floor), valid)
        parallel_map(lambda d: _inverse_floor(d, np.float32(floor)), den)
        inv = tuple(den)
        del den
    else:
        env = smooth_field(cv2.max(cv2.max(chans_in[0], chans_in[1]), chans_in[2]),
                           window / 3, "max", window)
        den = env - dark
        valid = den > floor
        inv = (1.0 / np.maximum(den, floor),)
    del parts
    dark = None  # (freed: one image-sized plane fewer below; the channels' jobs are done)
    inv3 = inv if len(inv) == 3 else inv * 3
    # signal = sum_c chans_c * (inv_c * wts_c), the terms after the first in a buffer of
    # 32 rows (it stays in the cache; a weight of 1 multiplies exactly: left out); the two
    # halves of the rows side by side (_threads)
    signal = np.empty_like(chans[0])

    def products(rows):
        term = np.empty((32, signal.shape[1]), signal.dtype)
        for r0 in range(rows.start, rows.stop, 32):
            r = slice(r0, min(r0 + 32, rows.stop))
            for c in range(3):
                out = signal[r] if c == 0 else term[:r.stop - r.start]
                if wts[c] == 1:
                    np.multiply(chans[c][r], inv3[c][r], out=out)
                else:
                    np.multiply(inv3[c][r], wts[c], out=out)
                    np.multiply(chans[c][r], out, out=out)
                if c:
                    signal[r] += out

    half = len(signal) // 2
    parallel_map(products, (slice(0, half), slice(half, len(signal))))
    # the normalised channels in place of the channels (the inverse planes are freed on
    # return: three image-sized planes fewer for the rest of the detection)
    for c in range(3):
        np.multiply(chans[c], inv3[c], out=chans[c])

    return Normalised(signal=signal, valid=valid, channels=chans)


@njit(cache=True, nogil=True)
def _any_over(d0, d1, d2, floor, out):
    """``out`` (H, W) bool: ``((d0 > floor) | (d1 > floor)) | (d2 > floor)`` over float32
    planes, in one pass."""
    for r in range(d0.shape[0]):
        for c in range(d0.shape[1]):
            out[r, c] = d0[r, c] > floor or d1[r, c] > floor or d2[r, c] > floor


@njit(cache=True, nogil=True)
def _inverse_floor(d, floor):
    """In place over an (H, W) float32 plane: ``1 / max(d, floor)``, the float32 operations
    of ``np.maximum`` and ``np.reciprocal`` (NaN stays NaN), in one pass."""
    one = np.float32(1.0)
    for r in range(d.shape[0]):
        for c in range(d.shape[1]):
            v = d[r, c]
            d[r, c] = one / (floor if v < floor else v)


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
