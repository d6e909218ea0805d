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


def _line_colours(result: DetectionResult, pattern) -> np.ndarray:
    """RGB (L, 3) of each line's band: from ``pattern.sequence`` (PRMVS) or the families' codes
    (a LinePattern)."""
    rgb = np.asarray(pattern.rgb)
    if hasattr(pattern, "sequence"):
        return rgb[np.asarray(pattern.sequence)[result.band]]
    out = np.zeros((result.nlines, 3), np.uint8)
    for d, name in enumerate(("vertical", "horizontal")):
        sel = result.direction == d
        if sel.any():
            codes = np.asarray(pattern.family(name).codes)
            out[sel] = rgb[codes[result.band[sel]]]
    return out


def draw_line_overlay(image, result: DetectionResult, pattern, dim: float = 0.45,
                      scale: int = 2, label_gap: float = 120.0) -> np.ndarray:
    """Decoded lines of any pattern drawn over a dimmed, enlarged copy of the photograph.

    Each line (edges and centre-lines, ``edge = 2``) is drawn as its polyline in its band's
    colour, labelled ``V12`` / ``H7`` (``r`` / ``f`` appended for a rising / falling edge) at
    its middle (the longest pieces first, one label of a line per ``label_gap`` camera px),
    with a dark outline so that the label reads on any background; grid
    intersections are white dots. ``scale`` enlarges the picture (nearest neighbour) so that
    labels of lines a few px apart stay legible.

    Returns
    -------
    ndarray (scale H, scale W, 3) uint8, RGB.
    """
    img = as_float_image(image)
    base = np.ascontiguousarray((img * dim * 255).astype(np.uint8))
    canvas = cv2.resize(base, None, fx=scale, fy=scale, interpolation=cv2.INTER_NEAREST)
    cols = _line_colours(result, pattern)
    shift = 4
    font = 0.3 * scale / 2 + 0.05
    for i in range(result.nlines):
        pts = (result.polyline(i) + 0.5) * scale - 0.5
        col = tuple(int(c) for c in cols[i])
        fixed = np.round(pts * (1 << shift)).astype(np.int32)
        cv2.polylines(canvas, [fixed[:, None, :]], False, col, 1, cv2.LINE_AA, shift)
    placed: dict[str, list] = {}
    for i in np.argsort(-(result.stop - result.start), kind="stable"):  # longest first
        pts = (result.polyline(int(i)) + 0.5) * scale - 0.5
        if len(pts) < 10:
            continue
        col = tuple(int(c) for c in cols[i])
        mx, my = pts[len(pts) // 2]
        e = int(result.edge[i])
        text = f"{'VH'[result.direction[i]]}{result.band[i]}{'rf'[e] if e < 2 else ''}"
        near = placed.setdefault(text, [])
        if any(np.hypot(mx - qx, my - qy) < label_gap * scale for qx, qy in near):
            continue  # one label of a line per label_gap px
        near.append((mx, my))
        org = (int(mx) + 2, int(my) - 2) if result.direction[i] == 0 else (int(mx), int(my) - 3)
        cv2.putText(canvas, text, org, cv2.FONT_HERSHEY_SIMPLEX, font, (0, 0, 0), 3,
                    cv2.LINE_AA)
        cv2.putText(canvas, text, org, cv2.FONT_HERSHEY_SIMPLEX, font, col, 1, cv2.LINE_AA)
    for cx, cy in np.round((result.cam + 0.5) * scale - 0.5).astype(int):
        cv2.circle(canvas, (int(cx), int(cy)), 1, (255, 255, 255), -1)
    return canvas
