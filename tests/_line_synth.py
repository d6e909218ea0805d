"""A rendered photograph of a LinePattern on a plane (tests of nurbscan.detect.line_grid).

The projector image (``pattern.render()``) is mapped into the camera by a known homography
(projector px -> camera px) with 4x supersampling (area average), then, in linear light:
an albedo (a plane over most of the image, with an optional chessboard of dark squares, on a
grey background), ambient light, a 3 x 3
colour matrix (the projector's primaries seen by the camera's filters), clipping at 1,
Gaussian blur, noise, and an encoding gamma; written as uint8. The truth is the homography.
"""

from __future__ import annotations

import cv2
import numpy as np


def de_bruijn(k: int, n: int) -> list[int]:
    """De Bruijn sequence B(k, n), cyclic: the Fredricksen-Kessler-Maiorana (Lyndon word)
    algorithm, an oracle independent of nurbscan.pattern's sequences."""
    a = [0] * k * n
    seq: list[int] = []

    def db(t, p):
        if t > n:
            if n % p == 0:
                seq.extend(a[1:p + 1])
        else:
            a[t] = a[t - p]
            db(t + 1, p)
            for j in range(a[t - p] + 1, k):
                a[t] = j
                db(t + 1, t)

    db(1, 1)
    return seq


def default_homography(width: int = 640, height: int = 480, tilt: float = 0.0003,
                       angle: float = 0.05) -> np.ndarray:
    """Projector 800 x 600 -> camera: a slight rotation, scale 0.78 and perspective."""
    c, s = np.cos(angle), np.sin(angle)
    a = np.array([[0.78 * c, -0.78 * s, 0.0], [0.78 * s, 0.78 * c, 0.0], [0.0, 0.0, 1.0]])
    p = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [tilt, 0.5 * tilt, 1.0]])
    m = p @ a
    # centre the projector image's centre in the camera image
    ctr = m @ np.array([400.0, 300.0, 1.0])
    ctr = ctr[:2] / ctr[2]
    t = np.array([[1.0, 0.0, width / 2 - ctr[0]], [0.0, 1.0, height / 2 - ctr[1]], [0, 0, 1]])
    return t @ m


def render_photo(pattern, hmat: np.ndarray, width: int = 640, height: int = 480,
                 gamma: float = 1 / 2.2, colour_matrix: np.ndarray | None = None,
                 ambient: float = 0.35, background: float = 0.25, gain: float = 0.9,
                 blur: float = 0.7, noise: float = 0.01, squares: bool = False,
                 white: bool = False, seed: int = 0) -> np.ndarray:
    """The camera image (H, W, 3) uint8 of ``pattern`` (or of white light, ``white``)."""
    rng = np.random.default_rng(seed)
    proj = (np.ones((pattern.height, pattern.width, 3), np.float32) if white
            else pattern.render().astype(np.float32) / 255.0)
    ss = 4
    # big pixel u covers camera coordinate (u + 0.5) / ss - 0.5 (pixel centres at integers)
    half = (ss - 1) / 2.0
    up = np.array([[ss, 0.0, half], [0.0, ss, half], [0.0, 0.0, 1.0]]) @ hmat
    big = cv2.warpPerspective(proj, up, (width * ss, height * ss), flags=cv2.INTER_LINEAR,
                              borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    lit = cv2.resize(big, (width, height), interpolation=cv2.INTER_AREA)
    # the plane: a region of the camera image (its border is not the projector's)
    yy, xx = np.mgrid[0:height, 0:width]
    inside = ((xx > 0.04 * width) & (xx < 0.97 * width) & (yy > 0.03 * height)
              & (yy < 0.96 * height)).astype(np.float32)
    albedo = np.full((height, width), 0.85, np.float32)
    if squares:
        sq = ((xx // 40 + yy // 40) % 2 == 0) & (np.abs(xx - width / 2) < 120) \
            & (np.abs(yy - height / 2) < 80)
        albedo[sq] = 0.08
    albedo = albedo * inside + background * (1 - inside)
    m = np.eye(3) if colour_matrix is None else np.asarray(colour_matrix, np.float32)
    col = lit @ m.T
    img = albedo[:, :, None] * (gain * col + ambient)
    img = cv2.GaussianBlur(img.astype(np.float32), (0, 0), blur)
    img = img + rng.normal(0.0, noise, img.shape).astype(np.float32)
    img = np.clip(img, 0.0, 1.0) ** gamma
    return np.round(img * 255).astype(np.uint8)


def random_colour_matrix(seed: int, crosstalk: float = 0.25) -> np.ndarray:
    """A camera's view of the projector's primaries: identity-dominant with crosstalk and
    channel gains (rows: camera R, G, B)."""
    rng = np.random.default_rng(seed)
    m = np.eye(3) + rng.uniform(0.0, crosstalk, (3, 3)) * (1 - np.eye(3))
    return m * rng.uniform(0.7, 1.0, (3, 1))
