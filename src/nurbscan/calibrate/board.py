"""The white part of a printed calibration board, found in its white-light photograph.

A checkerboard as people print it is glued on a larger white board whose size nobody writes
down; the projected grid that calibrates the projector is read on that white part. This
module finds it in the image, from the checkerboard corners alone:

1. The checkerboard field (the outer squares included) is mapped into the image by the
   board -> image homography of the detected inner corners (DLT, :func:`cv2.findHomography`);
   its white and black squares give the brightness of the board's white paint and of its
   black print (medians at the square centres).
2. Bright pixels: the white-light image (grey, smoothed by a Gaussian of 1 px) above the
   level halfway between black and white; the field is filled in so that the board's white
   parts on all its sides join through it.
3. The board: the connected bright region (8-connectivity) that holds the field, with its
   holes (a screw head, a label) filled.
4. Its usable part: the region eroded by ``border_px`` (off the board's outline, where the
   lines fall off the edge) less the field widened by ``field_pad`` squares (the printed
   squares and their sheet's edge change the lines' brightness).
"""

from __future__ import annotations

import cv2
import numpy as np


def field_outline(inner: tuple[int, int], square: float, pad: float = 0.0) -> np.ndarray:
    """Board-frame corners (4, 2) of the checkerboard field widened by ``pad`` squares, mm.

    The field of ``nx x ny`` inner corners spans ``[-s, nx s] x [-s, ny s]`` (one square
    beyond the outer inner corners; origin at the first inner corner, docs/scan-format.md).
    """
    nx, ny = inner
    a = -square * (1.0 + pad)
    bx, by = square * (nx + pad), square * (ny + pad)
    return np.array([[a, a], [bx, a], [bx, by], [a, by]], float)


def outside_field(xy: np.ndarray, inner: tuple[int, int], square: float,
                  pad: float) -> np.ndarray:
    """(K,) bool: board points (K, 2), mm, outside the field widened by ``pad`` squares."""
    o = field_outline(inner, square, pad)
    xy = np.asarray(xy, float)
    inside = (xy[:, 0] > o[0, 0]) & (xy[:, 0] < o[1, 0]) & (xy[:, 1] > o[0, 1]) \
        & (xy[:, 1] < o[2, 1])
    return ~inside & np.all(np.isfinite(xy), axis=1)


def white_area(white: np.ndarray, corners: np.ndarray, inner: tuple[int, int],
               square: float, border_px: float = 4.0, field_pad: float = 0.25) -> np.ndarray:
    """Mask of the board's white part around the checkerboard (module notes, steps 1-4).

    Parameters
    ----------
    white : ndarray, shape (H, W) or (H, W, 3)
        White-light photograph of the pose (uint8, uint16 or float in [0, 1]).
    corners : ndarray, shape (nx * ny, 2)
        Detected inner corners, camera px, OpenCV's order (:func:`detect_chessboard`).
    inner : (int, int)
        Inner corners ``(nx, ny)``.
    square : float
        Square size, mm (any unit: only the board's proportions matter).
    border_px : float
        Erosion off the white region's outline, px.
    field_pad : float
        Widening of the excluded checkerboard field, squares.

    Returns
    -------
    ndarray bool, shape (H, W)
        True on the usable white part of the board.
    """
    from .camera import _grey, board_points

    grey = cv2.GaussianBlur(_grey(white), (0, 0), 1.0)
    h, w = grey.shape
    nx, ny = inner
    board = board_points(inner, square)[:, :2]
    H, _ = cv2.findHomography(board, np.asarray(corners, float), 0)

    def to_image(xy):
        p = np.column_stack([xy, np.ones(len(xy))]) @ H.T
        return p[:, :2] / p[:, 2:]

    # square centres (-0.5 .. n - 0.5 squares) and their brightness
    gx, gy = np.meshgrid(np.arange(-1, nx) + 0.5, np.arange(-1, ny) + 0.5)
    cen = to_image(np.column_stack([gx.ravel(), gy.ravel()]) * square)
    ij = np.clip(np.round(cen).astype(int), 0, [w - 1, h - 1])
    val = grey[ij[:, 1], ij[:, 0]]
    parity = (np.floor(gx.ravel()) + np.floor(gy.ravel())) % 2 == 0
    a, b = np.median(val[parity]), np.median(val[~parity])
    level = 0.5 * (a + b)
    bright = (grey > level).astype(np.uint8)
    poly = np.round(to_image(field_outline(inner, square))).astype(np.int32)
    cv2.fillPoly(bright, [poly], 1)
    n, lab = cv2.connectedComponents(bright, connectivity=8)
    c = np.clip(np.round(to_image(np.array([[(nx - 1) / 2, (ny - 1) / 2]]) * square)[0]
                         ).astype(int), 0, [w - 1, h - 1])
    region = (lab == lab[c[1], c[0]]).astype(np.uint8)
    # fill holes: the background is what the outside of the region reaches from the border
    inv = np.pad(1 - region, 1, constant_values=1)
    _, lab2 = cv2.connectedComponents(inv, connectivity=4)
    region = (lab2[1:-1, 1:-1] != lab2[0, 0]).astype(np.uint8)
    r = int(np.ceil(border_px))
    if r > 0:
        k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
        region = cv2.erode(np.pad(region, r, constant_values=0), k)[r:-r, r:-r]
    field = np.zeros_like(region)
    cv2.fillPoly(field, [np.round(to_image(field_outline(inner, square, field_pad))
                                  ).astype(np.int32)], 1)
    return (region > 0) & (field == 0)
