"""Read a projector image of straight coloured lines on black into a :class:`LinePattern`.

The image is the one the projector shows (a file made by nurbscan or by another project), not a
photograph: lines are axis-aligned, lit along their whole length and separated by black.
:func:`read_line_pattern` finds every line's exact edges, its colour, the window length of the
code and the rule the crossings were drawn with; docs/patterns.md describes what it accepts.
"""

from __future__ import annotations

import colorsys
import os
from pathlib import Path

import numpy as np

from ..errors import NurbscanError
from ..io import read_image
from .grid import DEFAULT_COLOURS
from .lines import LineFamily, LinePattern, window_length

#: Names given to the colours found: the nearest (in RGB) of these, each used once; the last
#: group is used only when the first cannot name every colour (its costs carry a penalty).
STANDARD_COLOURS: tuple[tuple[str, tuple[int, int, int]], ...] = (
    ("red", (255, 0, 0)),
    ("yellow", (255, 255, 0)),
    ("lime", (128, 255, 0)),
    ("green", (0, 255, 0)),
    ("cyan", (0, 255, 255)),
    ("blue", (0, 0, 255)),
    ("purple", (128, 0, 255)),
    ("magenta", (255, 0, 255)),
    ("white", (255, 255, 255)),
)
EXTRA_COLOURS: tuple[tuple[str, tuple[int, int, int]], ...] = (
    ("orange", (255, 128, 0)),
    ("spring-green", (0, 255, 128)),
    ("azure", (0, 128, 255)),
    ("rose", (255, 0, 128)),
    ("grey", (128, 128, 128)),
    ("olive", (128, 128, 0)),
    ("teal", (0, 128, 128)),
    ("navy", (0, 0, 128)),
    ("maroon", (128, 0, 0)),
    ("violet", (128, 0, 128)),
    ("dark-green", (0, 128, 0)),
)
_EXTRA_PENALTY = 1000.0

#: More distinct colours than this among the lit pixels: not a clean projector image (lines
#: and their crossings give a few dozen at most).
MAX_COLOURS = 256


def read_line_pattern(
    image: str | os.PathLike | np.ndarray,
    *,
    source: str | None = None,
    lit_threshold: float = 0.2,
    min_coverage: float = 0.99,
) -> LinePattern:
    """Read a projector image made of straight coloured lines on black.

    Parameters
    ----------
    image : path-like or ndarray
        The projector image: a PNG / TIFF file (8 or 16 bit), or an (H, W, 3) array (uint8,
        uint16, or float in [0, 1]). Lines are vertical (constant x) and / or horizontal
        (constant y), lit along the image's whole height / width, separated by black.
    source : str, optional
        Names the input in error messages (default: the file name, or "image").
    lit_threshold : float
        A pixel is lit where its brightest channel exceeds this fraction of the image's
        brightest sample (default 0.2).
    min_coverage : float
        A column (row) is part of a vertical (horizontal) line where at least this fraction of
        its pixels is lit (default 0.99; crossings are lit in any case).

    Returns
    -------
    pattern : LinePattern
        Lines in order of increasing coordinate, edges ``first lit pixel - 0.5`` and
        ``last lit pixel + 0.5`` (projector px), palette of the distinct line colours, window
        from :func:`~nurbscan.pattern.lines.window_length`, crossing rule observed.

    Raises
    ------
    NurbscanError
        One line naming the input: unreadable file, no lines, lit pixels that belong to no
        full-length axis-aligned line, a colour sequence whose windows repeat up to n = 6.

    Notes
    -----
    The steps, each a vectorised pass over the image:

    1. quantise to 8-bit RGB and mark the lit pixels; more than :data:`MAX_COLOURS` distinct
       lit colours mean a lossy or blurred image, refused (:func:`_lit_mask`);
    2. line columns / rows: those lit along (nearly) their whole length; every other lit
       pixel must lie on one of them, else the image holds a shape that is not a straight
       full-length line (:func:`_line_axes`);
    3. lines: the runs of consecutive line columns (rows), edges half a pixel outside the
       run's first and last pixel (:func:`_runs`); a first or last line that touches the
       image border and is narrower than the widest line is cut by the border and dropped
       (:func:`_uncut`);
    4. colour of each line: its most frequent RGB away from the crossings, i.e. on the rows
       (columns) that are not part of a line of the other direction (:func:`_line_colours`);
    5. palette: the distinct line colours, in nurbscan's own code order when they are all
       nurbscan colours (so its own grid reads back with its own codes), else by hue; named
       by the nearest standard colour, each name once (:func:`_palette`);
    6. crossing rule: which of channel-wise max, vertical on top, horizontal on top every
       crossing pixel agrees with (:func:`_crossing_rule`);
    7. window length: the smallest n <= 6 with unique runs of codes in each direction.
    """
    rgb, source = _as_rgb8(image, source)
    height, width = rgb.shape[:2]
    lit = _lit_mask(rgb, lit_threshold, source)
    col_line, row_line = _line_axes(lit, min_coverage, source)
    runs = {"vertical": _uncut(_runs(col_line), width),
            "horizontal": _uncut(_runs(row_line), height)}
    colours = {
        "vertical": _line_colours(rgb, lit, runs["vertical"], ~row_line, axis=1),
        "horizontal": _line_colours(rgb, lit, runs["horizontal"], ~col_line, axis=0),
    }
    palette, codes = _palette(np.concatenate([colours["vertical"], colours["horizontal"]]))
    crossing = _crossing_rule(rgb, runs, colours)
    fams = _families(runs, codes)
    window = window_length({k: f.codes for k, f in fams.items() if f is not None},
                           source=source)
    try:
        return LinePattern(width=width, height=height, colours=palette, window=window,
                           vertical=fams["vertical"], horizontal=fams["horizontal"],
                           crossing=crossing)
    except NurbscanError as exc:
        raise NurbscanError(f"{source}: {exc}") from None


# ---------------------------------------------------------------------- steps


def _as_rgb8(image, source: str | None) -> tuple[np.ndarray, str]:
    """The image as uint8 RGB (H, W, 3) and the name used in messages."""
    if isinstance(image, str | os.PathLike):
        source = source or str(image)
        path = Path(image)
        try:
            img = read_image(path, as_float=True)
        except NurbscanError as exc:
            raise NurbscanError(f"{exc}" if source == str(path) else f"{source}: {exc}") \
                from None
        return np.rint(np.clip(img, 0.0, 1.0) * 255.0).astype(np.uint8), source
    source = source or "image"
    img = np.asarray(image)
    if img.ndim == 2:
        img = np.repeat(img[:, :, None], 3, axis=2)
    if img.ndim != 3 or img.shape[2] not in (3, 4) or img.shape[0] < 1 or img.shape[1] < 1:
        raise NurbscanError(f"{source}: expected an (H, W, 3) RGB image, got shape {img.shape}")
    img = img[:, :, :3]
    if img.dtype == np.uint8:
        return np.ascontiguousarray(img), source
    if img.dtype == np.uint16:
        return np.rint(img / 257.0).astype(np.uint8), source
    if np.issubdtype(img.dtype, np.floating):
        if not np.all(np.isfinite(img)):
            raise NurbscanError(f"{source}: image holds NaN or infinite samples")
        return np.rint(np.clip(img, 0.0, 1.0) * 255.0).astype(np.uint8), source
    raise NurbscanError(f"{source}: unsupported sample type {img.dtype}")


def _lit_mask(rgb: np.ndarray, threshold: float, source: str) -> np.ndarray:
    """Pixels whose brightest channel exceeds ``threshold`` x the image maximum, (H, W) bool."""
    peak = rgb.max(axis=2)
    top = int(peak.max())
    if top == 0:
        raise NurbscanError(f"{source}: no lines (the image is black)")
    lit = peak > threshold * top
    packed = (rgb[..., 0].astype(np.int32) << 16) | (rgb[..., 1].astype(np.int32) << 8) | rgb[
        ..., 2]
    distinct = len(np.unique(packed[lit]))
    if distinct > MAX_COLOURS:
        raise NurbscanError(
            f"{source}: not a clean projector image: {distinct} distinct colours among its lit "
            f"pixels (more than {MAX_COLOURS}: lossy compression, blur or a photograph?); give "
            "the lossless image the projector shows"
        )
    return lit


def _line_axes(lit: np.ndarray, min_coverage: float, source: str):
    """(column is part of a vertical line (W,), row is part of a horizontal line (H,))."""
    height, width = lit.shape
    col_line = lit.mean(axis=0) >= min_coverage
    row_line = lit.mean(axis=1) >= min_coverage
    if col_line.all() or row_line.all():
        raise NurbscanError(
            f"{source}: no dark gaps: every {'column' if col_line.all() else 'row'} is lit, "
            "not lines on black"
        )
    stray = lit & ~col_line[None, :] & ~row_line[:, None]
    if stray.any():
        ys, xs = np.nonzero(stray)
        what = ("no lines: no column or row is lit along its length"
                if not (col_line.any() or row_line.any()) else
                "lines that are not straight")
        raise NurbscanError(
            f"{source}: {what}: {len(xs)} lit pixels (e.g. x={xs[0]}, y={ys[0]}) are on no "
            f"full-length axis-aligned line (a column or row lit over {min_coverage:.0%} of "
            "its length)"
        )
    return col_line, row_line


def _runs(mask: np.ndarray) -> np.ndarray:
    """First and last index of each run of True, int64 (N, 2)."""
    d = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    return np.stack([np.flatnonzero(d == 1), np.flatnonzero(d == -1) - 1], axis=1)


def _uncut(runs: np.ndarray, size: int) -> np.ndarray:
    """Drop a first / last line that touches the image border and is narrower than the widest.

    Such a line is cut by the border (e.g. a pattern generated larger and cropped): the edge
    at the border is the image's, not the line's, and its centre is wrong.
    """
    if len(runs) < 2:
        return runs
    widths = runs[:, 1] - runs[:, 0] + 1
    keep = np.ones(len(runs), bool)
    keep[0] = not (runs[0, 0] == 0 and widths[0] < widths.max())
    keep[-1] = not (runs[-1, 1] == size - 1 and widths[-1] < widths.max())
    return runs[keep]


def _families(runs: dict, codes: np.ndarray) -> dict[str, LineFamily | None]:
    """A :class:`LineFamily` per direction from its runs (codes: vertical lines first)."""
    nv = len(runs["vertical"])
    code_of = {"vertical": codes[:nv], "horizontal": codes[nv:]}
    return {name: None if len(r) == 0 else LineFamily(
        name, tuple(code_of[name].tolist()), tuple((r[:, 0] - 0.5).tolist()),
        tuple((r[:, 1] + 0.5).tolist())) for name, r in runs.items()}


def _line_colours(rgb, lit, runs: np.ndarray, free: np.ndarray, axis: int) -> np.ndarray:
    """Most frequent lit RGB of each line away from crossings, uint8 (N, 3).

    ``axis`` 1 for vertical lines (runs of columns; ``free`` marks the rows without a
    horizontal line), 0 for horizontal lines (runs of rows; ``free`` the free columns).
    """
    if len(runs) == 0:
        return np.zeros((0, 3), np.uint8)
    size = rgb.shape[1] if axis == 1 else rgb.shape[0]
    line_of = np.full(size, -1, np.int64)
    idx = np.arange(size)
    j = np.searchsorted(runs[:, 0], idx, side="right") - 1
    inside = (j >= 0) & (idx <= runs[np.maximum(j, 0), 1])
    line_of[inside] = j[inside]
    packed = (rgb[..., 0].astype(np.int64) << 16) | (rgb[..., 1].astype(np.int64) << 8) | rgb[
        ..., 2]
    if axis == 1:
        sel = lit & free[:, None] & (line_of >= 0)[None, :]
        ids = np.broadcast_to(line_of[None, :], sel.shape)[sel]
    else:
        sel = lit & free[None, :] & (line_of >= 0)[:, None]
        ids = np.broadcast_to(line_of[:, None], sel.shape)[sel]
    pairs, counts = np.unique(ids * (1 << 24) + packed[sel], return_counts=True)
    line, colour = pairs >> 24, pairs & 0xFFFFFF
    order = np.lexsort((-counts, line))  # per line, the most frequent colour first
    first = order[np.r_[True, line[order][1:] != line[order][:-1]]]
    best = np.zeros(len(runs), np.int64)
    best[line[first]] = colour[first]
    return np.stack([(best >> 16) & 255, (best >> 8) & 255, best & 255], axis=1).astype(
        np.uint8)


def _palette(line_rgb: np.ndarray):
    """(palette ((name, rgb), ...), code of each line (N,)) from the lines' RGB (N, 3)."""
    found, inverse = np.unique(line_rgb, axis=0, return_inverse=True)  # (K, 3), (N,)
    keys = [tuple(int(c) for c in rgb) for rgb in found]
    own = {rgb: k for k, (_, rgb) in enumerate(DEFAULT_COLOURS)}
    if all(k in own for k in keys):
        order = sorted(range(len(keys)), key=lambda i: own[keys[i]])
        names = [DEFAULT_COLOURS[own[keys[i]]][0] for i in order]
    else:
        order = sorted(range(len(keys)), key=lambda i: _hue_key(keys[i]))
        names = _names(found[order].astype(np.float64))
    rank = np.empty(len(keys), np.int64)
    rank[order] = np.arange(len(keys))
    palette = tuple((name, keys[i]) for name, i in zip(names, order, strict=True))
    return palette, rank[inverse.reshape(-1)]


def _hue_key(rgb: tuple[int, int, int]) -> tuple:
    """Sort key: saturated colours by hue (red, yellow, green, cyan, blue, magenta), then greys."""
    h, s, v = colorsys.rgb_to_hsv(*(c / 255.0 for c in rgb))
    return (s < 0.1, h if s >= 0.1 else 0.0, -v, -s)


def _names(rgb: np.ndarray) -> list[str]:
    """Nearest standard colour name of each RGB (K, 3), each name used once.

    An assignment (Hungarian method, scipy's ``linear_sum_assignment``) of minimal total RGB
    distance to :data:`STANDARD_COLOURS`, then :data:`EXTRA_COLOURS`; a colour left without a
    name (more colours than names) is named by its hex code.
    """
    from scipy.optimize import linear_sum_assignment

    table = STANDARD_COLOURS + EXTRA_COLOURS
    ref = np.array([c for _, c in table], np.float64)
    cost = np.linalg.norm(rgb[:, None, :] - ref[None, :, :], axis=2)
    cost[:, len(STANDARD_COLOURS):] += _EXTRA_PENALTY
    names = [f"#{int(r):02x}{int(g):02x}{int(b):02x}" for r, g, b in rgb]
    for i, j in zip(*linear_sum_assignment(cost), strict=True):
        names[i] = table[j][0]
    return names


def _crossing_rule(rgb: np.ndarray, runs: dict, colours: dict) -> str:
    """The rule every crossing pixel agrees with: "max", "horizontal-over" or "vertical-over".

    Rules are tried in that order; "unknown" if none explains every crossing. Without
    crossings (one direction only) the answer is "max".
    """
    rv, rh = runs["vertical"], runs["horizontal"]
    if len(rv) == 0 or len(rh) == 0:
        return "max"

    def pixels(r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixel indices covered by the runs and the run (line) each belongs to."""
        lengths = r[:, 1] - r[:, 0] + 1
        line = np.repeat(np.arange(len(r)), lengths)
        start = np.repeat(r[:, 0] - np.r_[0, np.cumsum(lengths)[:-1]], lengths)
        return start + np.arange(lengths.sum()), line

    xs, vi = pixels(rv)
    ys, hi = pixels(rh)
    seen = rgb[ys[:, None], xs[None, :]].astype(np.int64)  # (Ny, Nx, 3)
    v = colours["vertical"][vi][None, :, :].astype(np.int64)
    h = colours["horizontal"][hi][:, None, :].astype(np.int64)
    rules = {"max": np.maximum(v, h), "horizontal-over": np.broadcast_to(h, seen.shape),
             "vertical-over": np.broadcast_to(v, seen.shape)}
    for name, want in rules.items():
        if np.array_equal(seen, want):
            return name
    return "unknown"
