"""An overlay picture of a detection: each decoded line in its band's colour with its label."""

from __future__ import annotations

import cv2
import numpy as np

from .core import as_float_image
from .result import DetectionResult


def draw_overlay(image, result: DetectionResult, pattern, dim: float = 0.35,
                 label_spacing: float | None = None) -> np.ndarray:
    """Draw the decoded lines over a dimmed copy of the photograph.

    Each line is drawn as its polyline in the colour of its band (the pattern's colour table);
    labels ``V12r`` / ``H7f`` (direction, band index, rising / falling) are written at the middle
    of the longer lines, at most one per ``label_spacing`` x ``label_spacing`` px cell (default
    1/25 of the image width) so that they stay readable; grid intersections are white dots.

    Returns
    -------
    ndarray (H, W, 3) uint8, RGB.
    """
    img = as_float_image(image)
    canvas = np.ascontiguousarray((img * dim * 255).astype(np.uint8))
    rgb = pattern.rgb
    codes = np.asarray(pattern.sequence)
    h, w = canvas.shape[:2]
    thick = max(1, int(round(min(w, h) / 1500)))
    font = max(0.3, min(w, h) / 2500.0)
    cell = label_spacing or max(w / 25.0, 30.0)
    shift = 4
    used: set[tuple[int, int]] = set()
    length = result.stop - result.start
    for i in np.argsort(-length):  # one draw call per line, longest first
        pts = result.polyline(int(i))
        col = tuple(int(c) for c in rgb[codes[result.band[i]]])
        fixed = np.round(pts * (1 << shift)).astype(np.int32)
        cv2.polylines(canvas, [fixed[:, None, :]], False, col, thick, cv2.LINE_AA, shift)
        if len(pts) < 12:
            continue
        mx, my = pts[len(pts) // 2]
        key = (int(mx // cell), int(my // cell))
        if key in used:
            continue
        used.add(key)
        text = f"{'VH'[result.direction[i]]}{result.band[i]}{'rf'[result.edge[i]]}"
        cv2.putText(canvas, text, (int(mx) + 2, int(my) - 2), cv2.FONT_HERSHEY_SIMPLEX, font,
                    col, thick, cv2.LINE_AA)
    for cx, cy in np.round(result.cam).astype(int):
        cv2.circle(canvas, (int(cx), int(cy)), thick, (255, 255, 255), -1)
    return canvas
