"""Synthetic camera images of a pattern with a known projector-coordinate field (for tests).

A stand-in for the simulator: the camera sees the projector image through a smooth warp (a
homography plus a sinusoidal displacement field), rendered at ``ss`` x supersampling (the
projector pixel containing each sub-sample's projector point) and area-averaged, then blurred
(Gaussian PSF), mixed by a 3x3 colour crosstalk matrix, shaded by a smooth albedo field and
given Gaussian noise. The exact projector coordinate (x, y) of every camera pixel centre is
returned, in the same form as the simulator's truth arrays.
"""

from __future__ import annotations

import cv2
import numpy as np

#: Mild crosstalk: row = camera channel, column = projector primary.
CROSSTALK = np.array([[0.92, 0.08, 0.02], [0.06, 0.90, 0.10], [0.02, 0.10, 0.88]], np.float32)


def _field(xc: np.ndarray, yc: np.ndarray, w: int, h: int, pw: int, ph: int, amp: float):
    """Projector (x, y) px of camera points (xc, yc) px: homography + sinusoidal displacement."""
    u = xc / w - 0.5
    v = yc / h - 0.5
    den = 1.0 + 0.08 * u - 0.05 * v
    X = (0.85 * u + 0.06 * v) / den
    Y = (-0.04 * u + 0.85 * v) / den
    X = X + amp * np.sin(2.6 * v + 1.0) * 0.03 + amp * 0.02 * np.sin(3.1 * u)
    Y = Y + amp * np.sin(2.2 * u + 0.3) * 0.03
    return (X + 0.5) * pw, (Y + 0.5) * ph


def synth_view(pattern, width: int = 640, height: int = 480, noise: float = 0.01,
               blur: float = 0.5, ss: int = 2, gamma: float = 2.2, amp: float = 1.0, seed: int = 0,
               crosstalk: np.ndarray | None = CROSSTALK, shading: bool = True, field=None):
    """Render a warped view of ``pattern``.

    ``field(xc, yc, w, h, pw, ph)`` (optional) maps camera points (px) to projector points
    (px) instead of the default warp.

    Returns
    -------
    grid : ndarray float32 (H, W, 3) in [0, 1]
        Camera image of the pattern (gamma-encoded with ``gamma``, 8-bit levels).
    white : ndarray float32 (H, W, 3)
        The same view under white light.
    px, py : ndarray float32 (H, W)
        Exact projector coordinate of each camera pixel centre, projector px.
    """
    rng = np.random.default_rng(seed)
    proj = cv2.GaussianBlur(pattern.render().astype(np.float32) / 255.0, (0, 0), 0.6)
    pw, ph = pattern.width, pattern.height
    # sub-sample centres of camera pixel (i, j): i - 0.5 + (k + 0.5) / ss
    xs = (np.arange(width * ss, dtype=np.float64) + 0.5) / ss - 0.5
    ys = (np.arange(height * ss, dtype=np.float64) + 0.5) / ss - 0.5
    if field is None:
        def field(xc, yc, w, h, pw, ph):
            return _field(xc, yc, w, h, pw, ph, amp)
    Xs, Ys = field(xs[None, :], ys[:, None], width, height, pw, ph)
    mx = Xs.astype(np.float32)
    my = Ys.astype(np.float32)
    hi = cv2.remap(proj, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
    del Xs, Ys, mx, my
    img = cv2.resize(hi, (width, height), interpolation=cv2.INTER_AREA)
    white = np.ones_like(img)
    if blur > 0:
        img = cv2.GaussianBlur(img, (0, 0), blur)
    if crosstalk is not None:
        img = img @ crosstalk.T
        white = white @ crosstalk.T
    if shading:
        yy, xx = np.mgrid[0:height, 0:width].astype(np.float32)
        sh = 0.55 + 0.35 * np.cos(xx / width * 2.0 + 0.4) * np.cos(yy / height * 1.5 - 0.2)
        alb = np.stack([np.full_like(sh, 0.95), np.full_like(sh, 0.85), np.full_like(sh, 0.8)], 2)
        img = img * (sh[..., None] * alb)
        white = white * (sh[..., None] * alb)
    img = img + rng.normal(0, noise, img.shape).astype(np.float32) + 0.02
    white = white + rng.normal(0, noise, img.shape).astype(np.float32) + 0.02
    px, py = field(np.arange(width, dtype=np.float64)[None, :],
                   np.arange(height, dtype=np.float64)[:, None], width, height, pw, ph)
    img = np.round(np.clip(img, 0, 1) ** (1 / gamma) * 255) / 255
    white = np.round(np.clip(white, 0, 1) ** (1 / gamma) * 255) / 255
    return (img.astype(np.float32), white.astype(np.float32),
            px.astype(np.float32), py.astype(np.float32))
