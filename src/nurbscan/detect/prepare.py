"""The normalise stage of :func:`~nurbscan.detect.detect_grid`: the photograph linearised,
screened, normalised (:func:`~nurbscan.detect.normalize.normalize`) and its scale measured.

:func:`prepare` returns a :class:`Prepared`: the normalised signal, the median band width
found by a cheap first pass (:func:`band_width_px`), the edge filter scale for it
(:func:`auto_sigma`) and whether the bands are resolved (:data:`FINE_BAND_PX`). A photograph
in which no grid can be found raises :class:`NoGrid` (``detect_grid`` returns an empty
result with the reason).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ._threads import parallel_map
from .decode import band_crossings
from .edges import detect_edge_points
from .normalize import (  # noqa: F401  (as_float_image, as_float_planes: re-exported)
    LUMA_601,
    Normalised,
    as_float_image,
    as_float_planes,
    channel_max,
    check_white_size,
    colour_image,
    linear_values,
    noise_level,
    normalize_photograph,
)


class NoGrid(Exception):
    """No grid in the photograph: ``reason`` (one line) and the image ``size`` (W, H)."""

    def __init__(self, reason: str, size: tuple[int, int]):
        super().__init__(reason)
        self.reason, self.size = reason, size


@dataclass(frozen=True)
class Prepared:
    """The normalised photograph and its scale.

    Attributes
    ----------
    normalised : Normalised
        Edge signal (H, W), valid mask and colour planes.
    size : (int, int)
        (W, H) of the photograph, px.
    band_px, pitch_px : float
        Median band width and one pattern pitch, camera px (NaN: no band found).
    sigma : float
        Edge filter scale, camera px.
    fine : bool
        The bands are resolved (at least :data:`FINE_BAND_PX` wide): the strict rules apply.
    """

    normalised: Normalised
    size: tuple[int, int]
    band_px: float
    pitch_px: float
    sigma: float
    fine: bool


def prepare(image, white, pattern, options, sigma: float | None = None,
            sigma_per_band: float | None = None) -> Prepared:
    """Linearise and screen the photograph, normalise it and measure its scale.

    ``options`` is :class:`~nurbscan.detect.options.ImageOptions`; ``sigma`` and
    ``sigma_per_band`` those of :class:`~nurbscan.detect.options.EdgeOptions` (default: the
    band width over :func:`per_band_for_noise` of the measured noise). Raises
    :class:`NoGrid` for a black or overexposed photograph.
    """
    gamma = options.gamma
    image = colour_image(image, "image")
    if white is not None:
        white = colour_image(white, "white image")
        check_white_size(white.shape[:2], image.shape[:2])
    h, w = image.shape[:2]
    # (screening on a subsample)
    sub = channel_max(linear_values(image[::4, ::4], "image", gamma))
    if np.percentile(sub, 99.5) < 0.08**gamma:
        raise NoGrid("image: too dark (black), no grid found", (w, h))
    if np.mean(sub > 0.98**gamma) > 0.5:
        raise NoGrid("image: overexposed (more than half the pixels saturated), no grid found",
                     (w, h))
    nrm = normalize_photograph(image, white, gamma, window=options.window,
                               weights=LUMA_601 if options.chroma_subsampled else None)
    sig = nrm.signal
    # the band width and, when the filter scale follows the noise, the noise level side by
    # side (_threads)
    jobs = [lambda: band_width_px(sig, pattern, nrm.valid)]
    if sigma is None and sigma_per_band is None:
        jobs.append(lambda: per_band_for_noise(noise_level(sig, nrm.valid)))
    band_px_est, *per_band = parallel_map(lambda job: job(), jobs)
    pitch_px_est = band_px_est * pattern.pitch / pattern.band  # one pattern pitch, camera px
    if sigma is None:
        sigma = auto_sigma(band_px_est, per_band[0] if per_band else sigma_per_band)
    # resolved bands (at least FINE_BAND_PX wide): the gaps beside a band can be sampled
    # clear of its edges' blur, and the stricter rules pay (7.1 MP teapot: RMS 0.054 ->
    # 0.048 px, coverage +3 %). Narrower bands (small or distant images) keep the plain rules:
    # there the gap samples fall on the edges' blur and the strict rules drop most lines.
    fine = bool(np.isfinite(band_px_est) and band_px_est >= FINE_BAND_PX)
    return Prepared(nrm, (w, h), band_px_est, pitch_px_est, sigma, fine)


def band_width_px(signal: np.ndarray, pattern, valid: np.ndarray | None = None) -> float:
    """Median width of the bands along the rows of a central crop (<= 768 px square), px.

    A first, cheap pass (edges at scale 1 px, rising / falling pairs along the rows) that
    sets the scale of the main pass; NaN when no band is found.
    """
    h, w = signal.shape
    c = 384
    y0, x0 = max(h // 2 - c, 0), max(w // 2 - c, 0)
    crop = signal[y0:y0 + 2 * c, x0:x0 + 2 * c]
    vc = None if valid is None else valid[y0:y0 + 2 * c, x0:x0 + 2 * c]
    pts = detect_edge_points(crop, sigma=1.0, valid=vc, families=False)
    k = pts.cls < 2
    o, st = band_crossings(pts.x[k], pts.iy[k], pts.cls[k] % 2, pattern.band / pattern.pitch)
    if len(st) < 10:
        return float("nan")
    a = pts.x[k][o]
    return float(np.median(a[st + 1] - a[st]))


#: Least band width (camera px) for the strict rules of :func:`detect_grid`. Bands 2.6-3.4 px
#: wide (a 640 x 480 camera's view of the calibration target) lose most lines to them; 4.2 px
#: (the teapot at 1280 x 960) and wider gain from them.
FINE_BAND_PX = 4.0


def auto_sigma(band_px: float, per_band: float = 8.0) -> float:
    """Edge filter scale for bands ``band_px`` wide: band / ``per_band`` (8), clipped to
    [0.8, 1.5] px.

    Wide enough to average the noise, narrow enough that a band's two edges (and the gaps'
    edges) do not bias each other: the Gaussian tail of the neighbouring edge at distance
    ``band_px`` is exp(-band^2 / (2 sigma^2)) <= exp(-32) of the peak at band = 8 sigma.
    ``band_px`` is the median width: where the surface squeezes the bands (the teapot's lower
    body, 4-6 px against a median of 10) a narrower filter still resolves them. 7.1 MP teapot
    views 0-7 (bands about 10 px): band / 7 -> band / 8 (sigma 1.46 -> 1.28 px) raises the
    coverage 0.661 -> 0.673 at RMS 0.042 px; a fixed sigma of 1.15 px gives 0.688 at
    0.046 px, 0.9 px 0.696 at 0.054 px and a wrong line. Smoothing more along the edges than
    across them (``sigma_along``) costs accuracy on the tilted edges (1.25 / 2.0 px: 0.055 px).
    """
    if not np.isfinite(band_px):
        return 1.0
    return float(np.clip(band_px / per_band, 0.8, 1.5))


def per_band_for_noise(noise: float) -> float:
    """Band width over edge filter scale (:func:`auto_sigma`) for a noise deviation ``noise``
    of the normalised signal (:func:`~nurbscan.detect.normalize.noise_level`): 10 up to
    0.025, 8 from 0.05, linear between (a narrower filter where the noise allows it, as in
    Canny's trade-off of localisation against noise). 7.1 MP teapot view: at default noise
    (0.020) band / 10 instead of band / 8 gives coverage 0.691 -> 0.702 at RMS 0.0402 ->
    0.0400 px (demo views 0-7: 0.723 -> 0.735, 0.0411 -> 0.0396 px), without noise 0.715 ->
    0.739 at 0.0343 -> 0.0294 px; at 3x noise (0.056) it would cost coverage 0.606 -> 0.574
    and RMS 0.0658 -> 0.0672 px.
    """
    if not np.isfinite(noise):
        return 8.0
    return float(10.0 - 2.0 * np.clip((noise - 0.025) / 0.025, 0.0, 1.0))
