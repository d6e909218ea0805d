"""The taps of Keys' cubic convolution along fit lines, in numpy: the reference that
:func:`nurbscan.detect.oblique._along_line`'s compiled pass is checked against (it was the
detector's own sampling before that pass; nothing in the package uses it)."""

from __future__ import annotations

import numpy as np


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
    n, k = len(along_x), len(step)
    if n == 0:
        return np.zeros((0, k, 4), np.int64), np.zeros((0, k, 4))
    # computed step by step ((K, ...) rows of the points' length: numpy's inner loops run
    # over the points), then turned to (N, K, 4) (:func:`_to_points`)
    off = step[:, None] * np.asarray(slope, np.float64)[None, :]  # (K, N)
    f = np.floor(off)
    t = off - f
    wts = np.empty((k, 4, n))
    wts[:, 0] = ((-0.5 * t + 1.0) * t - 0.5) * t
    wts[:, 1] = (1.5 * t - 2.5) * t * t + 1.0
    wts[:, 2] = ((-1.5 * t + 2.0) * t + 0.5) * t
    wts[:, 3] = (0.5 * t - 0.5) * t * t
    ix, iy = np.asarray(ix, np.int64), np.asarray(iy, np.int64)
    # the coordinate along the search axis (one per step) and the four across it, clamped
    run = np.where(along_x, ix, iy)[None, :] + step.astype(np.int64)[:, None]  # (K, N)
    np.clip(run, 0, np.where(along_x, w - 1, h - 1)[None, :], out=run)
    across = f.astype(np.int64)
    across += np.where(along_x, iy, ix)[None, :]
    top = np.where(along_x, h - 1, w - 1)[None, :]
    if across.min() >= 1 and np.all(across <= top - 2):
        # no tap across clamped (the usual case): the four are one pixel row (column) apart
        # in the flat image
        stride = np.arange(-1, 3)[:, None] * np.where(along_x, w, 1)[None, :]  # (4, N)
        base = np.where(along_x[None, :], across * w + run, across + run * w)
        idx = base[:, None, :] + stride[None, :, :]
    else:
        across = across[:, None, :] + np.arange(-1, 3)[None, :, None]  # (K, 4, N)
        np.clip(across, 0, top[:, None, :], out=across)
        run = np.where(along_x[None, :], run, run * w)[:, None, :]
        idx = np.where(along_x[None, None, :], across * w, across) + run
    return _to_points(idx), _to_points(wts)


def _to_points(a: np.ndarray) -> np.ndarray:
    """A (K, 4, N) array as (N, K, 4), C-contiguous ."""
    k, _, n = a.shape
    return np.ascontiguousarray(a.reshape(4 * k, n).T).reshape(n, k, 4)


def sample_taps(img: np.ndarray, idx: np.ndarray, wts: np.ndarray) -> np.ndarray:
    """``img`` (H, W) sampled with the taps of :func:`line_taps`, float64 (N, K)."""
    s = np.take(img.ravel(), idx).astype(np.float64)
    s *= wts
    return ((s[..., 0] + s[..., 1]) + s[..., 2]) + s[..., 3]  # (numpy's sum of 4, in order)
