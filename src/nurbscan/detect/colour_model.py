"""Each line's colour class, learned from the photograph.

A real camera does not see the pattern's colours: the projector's primaries, the camera's
response (gamma, crosstalk, white balance, saturation), ambient light and the surface's albedo
all change them (cyan and green lines can look nearly white, red orange). The colour classes
are therefore learned from the image, and only their *number* and their *order of hue* are
taken from the pattern. The steps:

1. The colour of a line at each of its centres is the line's contrast in each channel, its
   height above the mean of the two sides (:func:`line_contrast`): ambient light and the
   projector's black level are smooth across a thin line and drop out, and so does the
   crossing line of the other direction (constant across this line). With a white-light
   image each channel's contrast is divided by the white image's channel there (the
   surface's albedo and the projector's white); the colour is then reduced to its
   chromaticity ``c / (c_r + c_g + c_b)`` (independent of brightness, so of the line's
   width, focus and a global gain of the level; a gamma changes it but keeps the hue order).
2. The chromaticities of one direction's centres are clustered into as many classes as the
   pattern uses colours in that direction (k-means, OpenCV ``kmeans``, several attempts), and
   each chain takes the class of most of its centres (:func:`fit_colour_model`).
3. Classes are matched to the pattern's colours by hue: the Hungarian assignment
   (``scipy.optimize.linear_sum_assignment``) of the cyclic hue distance between the class
   centres and the pattern colours, the matching restricted to assignments that keep the
   cyclic hue order when that costs little more. The decoder then checks the assignment
   against the code itself (:func:`~nurbscan.detect.line_grid.detect_lines` tries the other
   assignments and keeps the one whose windows occur in the pattern most often).
"""

from __future__ import annotations

import colorsys
import itertools
from dataclasses import dataclass

import cv2
import numpy as np
from scipy.optimize import linear_sum_assignment

from .ridges import RidgePoints


def _bilinear(img: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Bilinear samples (N, C) of ``img`` (H, W, C) at (x, y) px, clamped to the image."""
    h, w = img.shape[:2]
    x = np.clip(x, 0, w - 1.001)
    y = np.clip(y, 0, h - 1.001)
    x0, y0 = np.floor(x).astype(np.int64), np.floor(y).astype(np.int64)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    return ((img[y0, x0] * (1 - fx) + img[y0, x0 + 1] * fx) * (1 - fy)
            + (img[y0 + 1, x0] * (1 - fx) + img[y0 + 1, x0 + 1] * fx) * fy)


def line_contrast(image: np.ndarray, points: RidgePoints, offset: float = 5.0,
                  white: np.ndarray | None = None, smooth: float = 0.7) -> np.ndarray:
    """Each channel's contrast of the line at each centre, (N, 3) (module notes, step 1).

    The colour at the centre minus the mean of the colours ``offset`` px to either side along
    the normal (the image smoothed by a Gaussian of ``smooth`` px, sampled bilinearly): ambient
    light, the projector's black level and a crossing line of the other direction (constant
    along this line's normal) drop out. Divided by the white-light image's channel at the centre
    (smoothed over 2 px) when ``white`` is given. The difference is used rather than the
    second derivative because a channel that saturates at the line's peak keeps its height
    difference better than its curvature (a clipped peak is flat).

    Parameters
    ----------
    image, white : ndarray (H, W, 3) float
        The photograph and an optional white-light image of the same view.
    points : RidgePoints
    offset : float
        Distance of the background samples from the centre, px (beyond the line's blur,
        within the gap to the next line).
    """
    img = cv2.GaussianBlur(np.ascontiguousarray(image, dtype=np.float32), (0, 0), smooth)
    x, y, nx, ny = points.x, points.y, points.nx, points.ny
    peak = _bilinear(img, x, y)
    side = 0.5 * (_bilinear(img, x + offset * nx, y + offset * ny)
                  + _bilinear(img, x - offset * nx, y - offset * ny))
    out = (peak - side).astype(np.float64)
    if white is not None:
        w = cv2.GaussianBlur(np.ascontiguousarray(white, dtype=np.float32), (0, 0), 2.0)
        floor = max(1e-3, 0.02 * float(np.percentile(w, 99)))
        out /= np.maximum(_bilinear(w, x, y), floor)
    return out


def chromaticity(contrast: np.ndarray) -> np.ndarray:
    """``c / sum(c)`` of the (clipped non-negative) contrasts, (N, 3); NaN where all are 0."""
    c = np.clip(contrast, 0.0, None)
    s = c.sum(1, keepdims=True)
    with np.errstate(all="ignore"):
        return np.where(s > 0, c / s, np.nan)


def hue(rgb: np.ndarray) -> np.ndarray:
    """Hue angle (radians, 0 red, 2 pi / 3 green) of colours (K, 3), any positive scale."""
    rgb = np.asarray(rgb, dtype=np.float64)
    top = rgb.max(1, keepdims=True)
    top[top == 0] = 1.0
    return np.array([colorsys.rgb_to_hsv(*row)[0] * 2 * np.pi for row in rgb / top])


def _cyclic(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cyclic distance of angles, radians."""
    return np.abs(np.angle(np.exp(1j * (a - b))))


def match_by_hue(class_rgb: np.ndarray, palette_rgb: np.ndarray, slack: float = 0.35
                 ) -> np.ndarray:
    """Palette entry of each class (module notes, step 3), (K,) int.

    The Hungarian assignment of the cyclic hue distances; if an assignment that keeps the
    classes' cyclic hue order costs at most ``slack`` radians more in total, it is taken
    instead (a camera shifts hues, but rarely reorders them).
    """
    hc, hp = hue(class_rgb), hue(palette_rgb)
    cost = _cyclic(hc[:, None], hp[None, :])
    r, c = linear_sum_assignment(cost)
    best = np.empty(len(hc), np.int64)
    best[r] = c
    k = len(hc)
    oc, op = np.argsort(hc), np.argsort(hp)
    rotations = []
    for s in range(k):
        a = np.empty(k, np.int64)
        a[oc] = op[np.roll(np.arange(k), -s)]
        rotations.append((cost[np.arange(k), a].sum(), a))
    rc, ra = min(rotations, key=lambda t: t[0])
    if rc <= cost[np.arange(k), best].sum() + slack:
        return ra
    return best


@dataclass(frozen=True)
class ColourModel:
    """Colour classes of one direction's lines.

    Attributes
    ----------
    centres : ndarray (K, 3)
        Chromaticity of each class (k-means centre).
    codes : ndarray (K,) int
        Pattern colour code of each class (index into ``LinePattern.colours``).
    """

    centres: np.ndarray
    codes: np.ndarray

    def classify(self, chroma: np.ndarray) -> np.ndarray:
        """Class (nearest centre) of each chromaticity (N, 3); -1 where it is NaN."""
        d = np.linalg.norm(chroma[:, None, :] - self.centres[None], axis=2)
        cls = np.argmin(np.nan_to_num(d, nan=np.inf), axis=1)
        cls[~np.isfinite(d).all(1)] = -1
        return cls

    def permuted(self, codes) -> ColourModel:
        """The same classes with other codes."""
        return ColourModel(self.centres, np.asarray(codes, np.int64))


def fit_colour_model(chroma: np.ndarray, palette_rgb: np.ndarray, codes_used,
                     attempts: int = 5, max_samples: int = 20000, seed: int = 0
                     ) -> ColourModel | None:
    """Cluster one direction's centre chromaticities (N, 3) into ``len(codes_used)`` classes and
    match them to those codes' palette colours (module notes, steps 2 and 3).

    Returns None when there are fewer centres than classes.
    """
    codes_used = np.asarray(codes_used, np.int64)
    k = len(codes_used)
    ok = np.isfinite(chroma).all(1)
    data = chroma[ok]
    if len(data) < max(k, 1) * 3:
        return None
    if len(data) > max_samples:
        data = data[np.random.default_rng(seed).choice(len(data), max_samples, replace=False)]
    cv2.setRNGSeed(seed)
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 100, 1e-5)
    _, _, centres = cv2.kmeans(data.astype(np.float32), k, None, crit, attempts,
                               cv2.KMEANS_PP_CENTERS)
    centres = centres.astype(np.float64)
    match = match_by_hue(centres, np.asarray(palette_rgb, np.float64)[codes_used])
    return ColourModel(centres=centres, codes=codes_used[match])


def all_assignments(model: ColourModel):
    """Every assignment of the model's codes to its classes (the decoder's check), the hue
    match first."""
    yield model
    for perm in itertools.permutations(range(len(model.codes))):
        p = model.codes[list(perm)]
        if not np.array_equal(p, model.codes):
            yield model.permuted(p)


def chain_classes(cls: np.ndarray, chain: np.ndarray, nchains: int, k: int,
                  min_share: float = 0.6, counts: bool = False):
    """The class most of each chain's centres take, (C,) int (-1 when fewer than ``min_share``
    of them agree), and that share (C,); with ``counts`` also the (C, k) class counts."""
    ok = cls >= 0
    tab = np.zeros((nchains, k))
    np.add.at(tab, (chain[ok], cls[ok]), 1.0)
    tot = tab.sum(1)
    best = tab.argmax(1)
    with np.errstate(all="ignore"):
        share = np.where(tot > 0, tab.max(1) / tot, 0.0)
    best[share < min_share] = -1
    if counts:
        return best, share, tab
    return best, share
