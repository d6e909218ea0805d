"""The grid's orientation in the photograph, found from its colour windows: which family of
edges in the image belongs to the projector's vertical bands, and in which direction each
family's sequence runs.

:func:`detect_grid` reads the vertical bands' windows left to right along pixel rows and the
horizontal bands' top to bottom along columns. A photograph rotated by 90 or 270 degrees, or
mirrored or transposed, shows one family or both read backwards, or the families swapped; it
still decodes (every window of the sequence exists), with wrong labels. Read in the right
direction, two windows ``n`` crossings apart along a run decode to band indices ``n`` apart;
read backwards, that happens by chance only (the reversed sequence is another one): about one
window pair in ``q^n``. The direction in which a family's window pairs agree is its
direction (:func:`window_spans`). The two families of :meth:`~nurbscan.pattern.Pattern.create`
use the same sequence from band 0, so only the band count tells them apart: a family with
spans of agreeing windows beyond the other direction's band count is that longer direction's
(1920 x 1080 at pitch 32: 60 vertical, 33 horizontal bands). Within the first bands of both
(a crop of the grid's top left corner) the pattern is symmetric under the transposition and
one photograph cannot tell it; the upright reading is kept there.

:func:`grid_orientation` turns the spans into an :class:`Orientation`, the flips and the
transposition that make the photograph upright; :func:`detect_grid` then detects the upright
image and maps the result back (:func:`to_photograph`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..pattern.sequence import window_lookup, window_table

#: A family's reading direction is decided by at least ``MIN_SPANS`` spans of agreeing windows
#: (``2 n`` crossings) in one direction and ``SPAN_RATIO`` times as many as in the other; its
#: role (vertical or horizontal bands) likewise by spans beyond the other direction's band
#: count. Simulated teapot views 0 and 1 (768 x 576, pitch 32) in all eight orientations:
#: 350-629 agreeing spans per family in its direction, 0 in the other, 281-288 beyond the
#: horizontal band count in the vertical bands' family and 0 in the other; all eight decoded
#: as upright (709 and 712 lines, none wrong).
MIN_SPANS, SPAN_RATIO = 10, 4.0
#: Least share of a family's agreeing spans (in its reading direction) within the band counts.
#: The teapot view (1280 x 960, pitch 16) read with the reciprocal polynomial's grid: 51 % of
#: the column family's agreeing spans (rotated by 180 degrees) within them; the right grid,
#: upright or turned: 100 %.
RANGE_SHARE = 0.9


@dataclass(frozen=True)
class Orientation:
    """The change that makes a photograph upright: transpose (swap x and y) first, then
    mirror left to right (``flip_x``) and top to bottom (``flip_y``). ``roles_known``: the
    windows told which family is the vertical bands' (False: the photograph shows only bands
    within both directions' counts, where a transposed grid looks the same)."""

    transpose: bool = False
    flip_x: bool = False
    flip_y: bool = False
    roles_known: bool = True

    @property
    def upright(self) -> bool:
        """Whether the photograph is upright already."""
        return not (self.transpose or self.flip_x or self.flip_y)

    def describe(self) -> str:
        """How the photograph is turned from upright, in words (for warnings)."""
        names = {(False, False, False): "upright", (False, True, False): "mirrored left-right",
                 (False, False, True): "mirrored top-bottom",
                 (False, True, True): "rotated by 180 degrees",
                 (True, False, False): "transposed",
                 (True, True, False): "rotated by 90 degrees counter-clockwise",
                 (True, False, True): "rotated by 90 degrees clockwise",
                 (True, True, True): "transposed across the other diagonal"}
        return names[(self.transpose, self.flip_x, self.flip_y)]

    def apply(self, image: np.ndarray | None) -> np.ndarray | None:
        """The upright image (H', W'[, C]) of a photograph (H, W[, C])."""
        if image is None:
            return None
        a = np.asarray(image)
        if self.transpose:
            a = np.swapaxes(a, 0, 1)
        if self.flip_x:
            a = a[:, ::-1]
        if self.flip_y:
            a = a[::-1]
        return np.ascontiguousarray(a)

    def to_photograph(self, x: np.ndarray, y: np.ndarray, upright_size: tuple[int, int]):
        """Points (camera px, pixel centres at integers) of the upright image of
        ``upright_size`` (width, height) in the photograph: ``(x, y)`` arrays."""
        w, h = upright_size
        x = np.asarray(x, np.float64)
        y = np.asarray(y, np.float64)
        if self.flip_x:
            x = (w - 1) - x
        if self.flip_y:
            y = (h - 1) - y
        return (y, x) if self.transpose else (x, y)

    def to_upright(self, x: np.ndarray, y: np.ndarray, photo_size: tuple[int, int]):
        """Points of the photograph of ``photo_size`` (width, height) in its upright image."""
        w, h = photo_size
        x = np.asarray(x, np.float64)
        y = np.asarray(y, np.float64)
        if self.transpose:
            x, y, w, h = y, x, h, w
        if self.flip_x:
            x = (w - 1) - x
        if self.flip_y:
            y = (h - 1) - y
        return x, y


def window_spans(order: np.ndarray, start: np.ndarray, run: np.ndarray, codes: np.ndarray,
                 pattern) -> np.ndarray:
    """Spans of ``2 n`` consecutive band crossings of one family along its runs whose two
    windows agree, read forwards and backwards.

    Parameters
    ----------
    order, start, run : ndarray
        As in :func:`~nurbscan.detect.decode.window_votes`: the points sorted by (run,
        coordinate along it), the positions of the crossings' rising points in that order,
        and each point's run.
    codes : (K,) int
        Colour code of each crossing (-1 unknown).
    pattern : Pattern
        The projected grid.

    Returns
    -------
    (2, 4) int
        Per reading (0 forwards: the direction of the runs, 1 backwards), the spans whose
        first window's band index ``i`` and the second's (``n`` crossings on) are ``i + n``
        (forwards; backwards ``i - n``), with all ``2 n`` bands within the vertical or the
        horizontal band count: all of them, those within the vertical count only and those
        within the horizontal count only; the spans read (all their colours known); and the
        spans whose windows agree so wherever their band indices fall (a mismatching pattern,
        e.g. one whose sequence is this one's reversed, agrees at indices beyond the grid).
    """
    n = pattern.n
    out = np.zeros((2, 5), np.int64)
    k = len(start)
    if k < 2 * n:
        return out
    r = run[order][start]
    w0 = np.arange(k - 2 * n + 1)
    ok = np.ones(len(w0), bool)
    for j in range(1, 2 * n):
        ok &= (start[w0 + j] == start[w0 + j - 1] + 2) & (r[w0 + j] == r[w0])
    win = np.stack([codes[w0 + j] for j in range(2 * n)], 1)[ok]
    win = win[(win >= 0).all(1)]
    if not len(win):
        return out
    table = window_table(np.asarray(pattern.sequence), pattern.q, n)
    nx, ny = pattern.counts
    for reading, w in ((0, win), (1, win[:, ::-1])):
        a = window_lookup(w[:, :n], table, pattern.q)
        b = window_lookup(w[:, n:], table, pattern.q)
        agree = (a >= 0) & (b == a + n)
        first = a[agree]
        in_v, in_h = first + 2 * n <= nx, first + 2 * n <= ny
        out[reading] = ((in_v | in_h).sum(), (in_v & ~in_h).sum(), (in_h & ~in_v).sum(),
                        len(w), agree.sum())
    return out


def grid_orientation(spans: np.ndarray) -> Orientation:
    """The :class:`Orientation` that makes the photograph upright, from the spans
    (:func:`window_spans`) of its two families of edges.

    Parameters
    ----------
    spans : (2, 2, 5) int
        Per family of edges in the photograph (0: edges that run up and down, read along the
        pixel rows; 1: edges that run across, read along the columns), :func:`window_spans`.

    Notes
    -----
    1. Each family's reading direction: the one in which at least ``MIN_SPANS`` spans agree
       and ``SPAN_RATIO`` times as many as in the other; forwards for a family with fewer
       than ``MIN_SPANS`` agreeing either way (no evidence). A family whose spans agree in
       neither clearly, or whose agreeing spans fall beyond the grid's band counts (more
       than ``1 - RANGE_SHARE`` of them), does not show this pattern the right way: no
       orientation is found, and the photograph is read upright as before (the decoding
       then refuses a pattern that does not match; the grid of the reciprocal polynomial,
       whose sequence is this one's reversed, reads as this one rotated by 180 degrees
       except for the band indices).
    2. The roles: swapped when the family read along the columns has at least
       ``MIN_SPANS`` spans (in its direction) that fit the vertical band count only, and
       ``SPAN_RATIO`` times as many as the other family; or, for a projector with more
       horizontal than vertical bands, the same with the families exchanged.
    3. Transposed roles: the upright image is the photograph transposed; its x is the
       photograph's y, so the column family's direction gives ``flip_x`` and the row
       family's ``flip_y``.
    4. Neither swapped nor confirmed (spans beyond the short direction's count in the family
       that should hold them): ``roles_known`` False. :func:`detect_grid` then reads an
       upright photograph as before and refuses a turned one (a crop of a view transposed
       across the other diagonal, within the first 33 bands of both directions, was read
       as rotated by 180 degrees: 2 % of its labels right).
    """
    spans = np.asarray(spans)
    back = []
    for f in (0, 1):
        fw, bw = spans[f, 0, 4], spans[f, 1, 4]
        if max(fw, bw) < MIN_SPANS:
            back.append(False)
            continue
        if not (max(fw, bw) >= SPAN_RATIO * min(fw, bw)):
            return Orientation()
        r = int(bw > fw)
        if spans[f, r, 0] < RANGE_SHARE * spans[f, r, 4]:
            return Orientation()
        back.append(bool(r))

    def only(f, kind):  # spans that fit one direction's band count only (kind 1 v, 2 h)
        return spans[f, int(back[f]), kind]

    swapped = ((only(1, 1) >= MIN_SPANS and only(1, 1) >= SPAN_RATIO * only(0, 1))
               or (only(0, 2) >= MIN_SPANS and only(0, 2) >= SPAN_RATIO * only(1, 2)))
    if swapped:
        return Orientation(transpose=True, flip_x=back[1], flip_y=back[0])
    known = only(0, 1) >= MIN_SPANS or only(1, 2) >= MIN_SPANS
    return Orientation(flip_x=back[0], flip_y=back[1], roles_known=bool(known))


def to_photograph(result, orientation: Orientation, photo_size: tuple[int, int]):
    """A :class:`~nurbscan.detect.result.DetectionResult` of the upright image mapped back to
    the photograph of ``photo_size`` (width, height): its points and intersections; the
    labels, projector coordinates and warnings are the projector's and stay."""
    if orientation.upright:
        return result
    up = result.image_size
    x, y = orientation.to_photograph(result.x, result.y, up)
    cam = np.asarray(result.cam, np.float64).reshape(-1, 2)
    cx, cy = orientation.to_photograph(cam[:, 0], cam[:, 1], up)
    note = f"image: the photograph is {orientation.describe()}; decoded upright"
    return replace(result, image_size=tuple(photo_size), x=x, y=y, cam=np.c_[cx, cy],
                   warnings=tuple(result.warnings) + (note,))
