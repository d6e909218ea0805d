"""Any projector grid of straight coloured lines on black: :class:`LinePattern`.

nurbscan's own PRMVS grid (:class:`~nurbscan.pattern.grid.Pattern`) is one such grid; others
come from other projects (thin 3 px lines, 8 colours, one direction drawn over the other at the
crossings, a different pitch per direction). A :class:`LinePattern` holds what a decoder needs
and nothing about how the pattern was generated:

* the projector image size and the palette (code k -> name, RGB);
* for each direction present, a :class:`LineFamily`: every line's colour code and its two edges
  in projector px (docs/conventions.md: pixel centres at integers, so a line lighting the
  pixels a .. b has ``lower = a - 0.5`` and ``upper = b + 0.5``);
* the window length n: the smallest n for which every run of n consecutive codes along each
  direction is unique (:func:`window_length`), so that n consecutive lines read in a
  photograph name their first line (:meth:`LineFamily.lookup`);
* the crossing rule the image was drawn with.

Its JSON sidecar (``"type": "nurbscan.line-pattern"``) is read by
:func:`nurbscan.pattern.load_pattern` beside the PRMVS sidecar; docs/patterns.md lists its keys.
"""

from __future__ import annotations

import functools
import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import NurbscanError
from ..io import atomic_paths, write_image, write_json

LINE_PATTERN_TYPE = "nurbscan.line-pattern"
LINE_PATTERN_VERSION = 1

#: Largest window length :func:`window_length` tries.
MAX_WINDOW = 6

#: How the crossings of a vertical and a horizontal line were drawn.
CROSSINGS = ("max", "vertical-over", "horizontal-over", "unknown")

LINE_EDGE_CONVENTION = (
    "projector pixels, pixel centres at integers; a line lighting the pixels a .. b has "
    "lower = a - 0.5 (rising edge, dark to light in +x / +y) and upper = b + 0.5 (falling edge)"
)

_DIRECTION_NAMES = {"vertical": "vertical", "x": "vertical", "v": "vertical", 0: "vertical",
                    "horizontal": "horizontal", "y": "horizontal", "h": "horizontal",
                    1: "horizontal"}


def direction_name(direction: str | int) -> str:
    """Canonical direction name: ``"vertical"`` (alias "x", 0) or ``"horizontal"`` ("y", 1)."""
    key = direction.lower() if isinstance(direction, str) else direction
    if isinstance(key, bool) or not isinstance(key, str | int | np.integer):
        key = None
    name = _DIRECTION_NAMES.get(int(key) if isinstance(key, np.integer) else key)
    if name is None:
        raise NurbscanError(
            f"direction {direction!r}: must be 'vertical' (or 'x', 0) or 'horizontal' (or 'y', 1)"
        )
    return name


def _is_int(v: Any) -> bool:
    return isinstance(v, int | np.integer) and not isinstance(v, bool)


def _is_number(v: Any) -> bool:
    return isinstance(v, int | float | np.integer | np.floating) and not isinstance(v, bool)


def _window_keys(codes: np.ndarray, base: int) -> np.ndarray:
    """Integer key of each window (..., n) of codes in 0..base-1: first code most significant."""
    n = codes.shape[-1]
    weights = base ** np.arange(n - 1, -1, -1, dtype=np.int64)
    return codes.astype(np.int64) @ weights


def _unique_windows(codes: np.ndarray, n: int) -> bool:
    """Whether all runs of n consecutive codes in a 1-D sequence are distinct."""
    if len(codes) <= n:
        return True
    keys = _window_keys(np.lib.stride_tricks.sliding_window_view(codes, n), int(codes.max()) + 1)
    return len(np.unique(keys)) == len(keys)


def save_pattern_files(image_path: str | os.PathLike, image: np.ndarray, sidecar: dict
                       ) -> tuple[Path, Path]:
    """Write a pattern's image (PNG or TIFF, lossless) and its ``.json`` sidecar beside it,
    together atomically (:func:`nurbscan.io.atomic_paths`: never a new image beside an old
    sidecar); return the (image, sidecar) paths."""
    image_path = Path(image_path)
    if image_path.suffix.lower() not in (".png", ".tif", ".tiff"):
        raise NurbscanError(
            f"{image_path}: pattern image must be .png or .tif (lossless), not "
            f"{image_path.suffix or 'no suffix'!r}"
        )
    json_path = image_path.with_suffix(".json")
    with atomic_paths(image_path, json_path) as (tmp_image, tmp_json):
        write_image(tmp_image, image)
        write_json(tmp_json, sidecar)
    return image_path, json_path


def window_length(
    codes_per_direction: Mapping[str, Sequence[int]] | Sequence[Sequence[int] | None],
    max_n: int = MAX_WINDOW,
    source: str = "line pattern",
) -> int:
    """The smallest n such that every run of n consecutive codes in each direction is unique.

    Parameters
    ----------
    codes_per_direction : mapping or sequence of 1-D int sequences
        The colour codes of each direction's lines in order (``None`` entries are skipped);
        a mapping's keys name the directions in the error message.
    max_n : int
        Largest n tried (default 6).
    source : str
        Names the input in the error message.

    Returns
    -------
    n : int
        1 <= n <= max_n. Uniqueness at n implies it at n + 1, so n is the largest of the
        directions' own minima.

    Raises
    ------
    NurbscanError
        If some direction repeats a window of every length up to ``max_n``.
    """
    if isinstance(codes_per_direction, Mapping):
        items = list(codes_per_direction.items())
    else:
        items = [(f"direction {k}", c) for k, c in enumerate(codes_per_direction)]
    n_all = 1
    for name, codes in items:
        if codes is None:
            continue
        c = np.asarray(codes, dtype=np.int64).reshape(-1)
        if c.size and c.min() < 0:
            raise NurbscanError(f"{source}: {name} codes must be >= 0")
        n = next((n for n in range(1, max_n + 1) if _unique_windows(c, n)), None)
        if n is None:
            keys = _window_keys(np.lib.stride_tricks.sliding_window_view(c, max_n),
                                int(c.max()) + 1)
            _, first, counts = np.unique(keys, return_index=True, return_counts=True)
            at = int(first[counts > 1].min())
            raise NurbscanError(
                f"{source}: the {name} colour sequence repeats a window of every length up to "
                f"{max_n} (e.g. codes {c[at:at + max_n].tolist()} from line {at} occur again), "
                "so n consecutive lines cannot name their place"
            )
        n_all = max(n_all, n)
    return n_all


@dataclass(frozen=True)
class LineFamily:
    """The lines of one direction, in order of increasing projector coordinate.

    Attributes
    ----------
    direction : str
        ``"vertical"`` (lines of constant x) or ``"horizontal"`` (constant y); the aliases
        "x" / "y" / 0 / 1 are normalised.
    codes : tuple of int
        Colour code of each line (index into :attr:`LinePattern.colours`).
    lower, upper : tuple of float
        Coordinate of each line's rising edge (first lit pixel index - 0.5) and falling edge
        (last lit pixel index + 0.5), projector px; ``lower < upper <= next lower``.
    """

    direction: str
    codes: tuple[int, ...]
    lower: tuple[float, ...]
    upper: tuple[float, ...]

    def __post_init__(self) -> None:
        name = direction_name(self.direction)
        object.__setattr__(self, "direction", name)
        what = f"{name} lines"
        try:
            codes = tuple(self.codes)
            lower = tuple(self.lower)
            upper = tuple(self.upper)
        except TypeError:
            raise NurbscanError(f"{what}: codes, lower and upper must be sequences") from None
        if not codes:
            raise NurbscanError(f"{what}: no lines")
        if not len(codes) == len(lower) == len(upper):
            raise NurbscanError(
                f"{what}: {len(codes)} codes, {len(lower)} lower and {len(upper)} upper edges "
                "(need one of each per line)"
            )
        if not all(_is_int(c) and c >= 0 for c in codes):
            raise NurbscanError(f"{what}: codes must be integers >= 0")
        if not all(_is_number(v) and math.isfinite(v) for v in lower + upper):
            raise NurbscanError(f"{what}: edges must be finite numbers")
        lo = np.asarray(lower, dtype=np.float64)
        hi = np.asarray(upper, dtype=np.float64)
        bad = np.flatnonzero(hi <= lo)
        if bad.size:
            i = int(bad[0])
            raise NurbscanError(
                f"{what}: line {i} has upper edge {hi[i]} <= lower edge {lo[i]}"
            )
        bad = np.flatnonzero(lo[1:] < hi[:-1])
        if bad.size:
            i = int(bad[0])
            raise NurbscanError(
                f"{what}: line {i + 1} (lower {lo[i + 1]}) starts before line {i} ends "
                f"(upper {hi[i]}); lines must be in increasing order and not overlap"
            )
        object.__setattr__(self, "codes", tuple(int(c) for c in codes))
        object.__setattr__(self, "lower", tuple(float(v) for v in lo))
        object.__setattr__(self, "upper", tuple(float(v) for v in hi))

    # ------------------------------------------------------------------ derived
    @property
    def count(self) -> int:
        """Number of lines."""
        return len(self.codes)

    @property
    def centres(self) -> np.ndarray:
        """Centre coordinate of each line, ``(lower + upper) / 2``, px, shape (N,)."""
        return (np.asarray(self.lower) + np.asarray(self.upper)) / 2.0

    @property
    def widths(self) -> np.ndarray:
        """Width of each line, ``upper - lower``, px, shape (N,)."""
        return np.asarray(self.upper) - np.asarray(self.lower)

    @property
    def edges(self) -> np.ndarray:
        """``[[lower, upper], ...]`` of each line, px, shape (N, 2)."""
        return np.stack([np.asarray(self.lower), np.asarray(self.upper)], axis=1)

    @property
    def code_array(self) -> np.ndarray:
        """Colour codes as an int64 array, shape (N,)."""
        return np.asarray(self.codes, dtype=np.int64)

    @functools.cached_property
    def _tables(self) -> dict[int, tuple[np.ndarray, np.ndarray]]:
        return {}

    def _table(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """(sorted unique window keys, first-line index or -1 if ambiguous) for length n."""
        if n not in self._tables:
            codes = self.code_array
            if n > len(codes):
                self._tables[n] = (np.zeros(0, np.int64), np.zeros(0, np.int64))
            else:
                keys = _window_keys(np.lib.stride_tricks.sliding_window_view(codes, n),
                                    self._base)
                uniq, first, counts = np.unique(keys, return_index=True, return_counts=True)
                self._tables[n] = (uniq, np.where(counts == 1, first, -1).astype(np.int64))
        return self._tables[n]

    @property
    def _base(self) -> int:
        return max(self.codes) + 1

    def lookup(self, window_codes) -> np.ndarray:
        """Index of the first line of each window of n consecutive colour codes.

        Parameters
        ----------
        window_codes : array_like of int, shape (..., n)
            Codes of n consecutive lines read in the direction of increasing coordinate (left
            to right, top to bottom). A code that no line has (e.g. -1) makes the window
            invalid.

        Returns
        -------
        index : ndarray of int64, shape (...)
            i such that lines i .. i + n - 1 have these codes; -1 where no run of lines has
            them, or where several do (possible only for n shorter than the pattern's window).
            Binary search in the sorted window keys: O(log N) per window, no Python loop.
        """
        w = np.asarray(window_codes)
        if w.ndim == 0 or not np.issubdtype(w.dtype, np.integer):
            if w.ndim >= 1 and w.size == 0:
                w = w.astype(np.int64)
            elif w.ndim >= 1 and np.issubdtype(w.dtype, np.floating) and np.all(
                    np.isnan(w) | (w == np.round(w))):
                w = np.where(np.isnan(w), -1, w).astype(np.int64)
            else:
                raise NurbscanError(
                    f"{self.direction} lookup: window codes must be integers of shape (..., n)"
                )
        n = w.shape[-1]
        if n < 1:
            raise NurbscanError(f"{self.direction} lookup: empty window")
        uniq, first = self._table(n)
        valid = np.all((w >= 0) & (w < self._base), axis=-1)
        keys = _window_keys(np.clip(w, 0, self._base - 1), self._base)
        if uniq.size == 0:
            return np.full(keys.shape, -1, np.int64)
        pos = np.clip(np.searchsorted(uniq, keys), 0, uniq.size - 1)
        hit = valid & (uniq[pos] == keys)
        return np.where(hit, first[pos], -1).astype(np.int64)

    def lit(self, size: int) -> np.ndarray:
        """Index of the line lighting each pixel 0 .. size-1 (centre in [lower, upper)), or -1."""
        c = np.arange(size, dtype=np.float64)
        j = np.searchsorted(np.asarray(self.lower), c, side="right") - 1
        inside = (j >= 0) & (c < np.asarray(self.upper)[np.maximum(j, 0)])
        return np.where(inside, j, -1).astype(np.int64)

    def to_list(self) -> list[dict[str, Any]]:
        """The lines as JSON objects ``{"index", "code", "lower", "upper"}``."""
        rows = zip(self.codes, self.lower, self.upper, strict=True)
        return [{"index": i, "code": c, "lower": lo, "upper": hi}
                for i, (c, lo, hi) in enumerate(rows)]


@dataclass(frozen=True)
class LinePattern:
    """A projector grid of straight coloured lines on black, in one or both directions.

    Attributes
    ----------
    width, height : int
        Projector image size, px.
    colours : tuple of (str, (int, int, int))
        Palette: code k -> (name, RGB 0..255); names and RGBs distinct, none black.
    window : int
        n: the smallest n for which every run of n consecutive codes along each direction is
        unique (checked against :func:`window_length` on construction).
    vertical, horizontal : LineFamily or None
        The lines of each direction; at least one present. Lines lie inside the image.
    crossing : str
        How crossings were drawn: ``"max"`` (channel-wise max, nurbscan's own PRMVS),
        ``"vertical-over"``, ``"horizontal-over"`` (that direction's colour on top) or
        ``"unknown"``.
    """

    width: int
    height: int
    colours: tuple[tuple[str, tuple[int, int, int]], ...]
    window: int
    vertical: LineFamily | None
    horizontal: LineFamily | None
    crossing: str = "max"

    def __post_init__(self) -> None:
        for key in ("width", "height", "window"):
            v = getattr(self, key)
            if not _is_int(v) or v < 1:
                raise NurbscanError(f"line pattern {key}={v!r}: must be an integer >= 1")
            object.__setattr__(self, key, int(v))
        object.__setattr__(self, "colours", _check_palette(self.colours))
        if self.crossing not in CROSSINGS:
            raise NurbscanError(
                f"line pattern crossing={self.crossing!r}: must be one of {', '.join(CROSSINGS)}"
            )
        if self.vertical is None and self.horizontal is None:
            raise NurbscanError("line pattern: no lines in either direction")
        for name in ("vertical", "horizontal"):
            fam = getattr(self, name)
            if fam is None:
                continue
            if not isinstance(fam, LineFamily):
                raise NurbscanError(f"line pattern {name}: must be a LineFamily or None")
            if fam.direction != name:
                raise NurbscanError(
                    f"line pattern {name}: the family given holds {fam.direction} lines"
                )
            size = self.width if name == "vertical" else self.height
            if fam.lower[0] < -0.5 or fam.upper[-1] > size - 0.5:
                raise NurbscanError(
                    f"line pattern {name} lines: edges {fam.lower[0]} .. {fam.upper[-1]} leave "
                    f"the image (-0.5 .. {size - 0.5} px)"
                )
            if max(fam.codes) >= len(self.colours):
                raise NurbscanError(
                    f"line pattern {name} lines: code {max(fam.codes)} has no colour (palette of "
                    f"{len(self.colours)})"
                )
        n = window_length({f.direction: f.codes for f in self.families},
                          max_n=max(self.window, MAX_WINDOW))
        if self.window != n:
            raise NurbscanError(
                f"line pattern window={self.window}: the smallest window length with unique "
                f"runs of codes in each direction is {n}"
            )

    # ------------------------------------------------------------------ access
    def family(self, direction: str | int) -> LineFamily:
        """The lines of a direction ("vertical"/"x"/0 or "horizontal"/"y"/1)."""
        name = direction_name(direction)
        fam = getattr(self, name)
        if fam is None:
            raise NurbscanError(f"line pattern: has no {name} lines")
        return fam

    @property
    def families(self) -> tuple[LineFamily, ...]:
        """The families present, vertical first."""
        return tuple(f for f in (self.vertical, self.horizontal) if f is not None)

    @property
    def rgb(self) -> np.ndarray:
        """Palette as a uint8 array of shape (K, 3): row k is the RGB of code k."""
        return np.array([rgb for _, rgb in self.colours], dtype=np.uint8)

    def codes_used(self, direction: str | int) -> tuple[int, ...]:
        """Sorted distinct codes of a direction's lines."""
        return tuple(sorted(set(self.family(direction).codes)))

    # ------------------------------------------------------------------ image
    def render(self) -> np.ndarray:
        """The projector image, uint8 array of shape (height, width, 3), RGB.

        A pixel whose centre lies in a line's ``[lower, upper)`` takes its colour; where a
        vertical and a horizontal line cross, the crossing rule decides (``"unknown"`` is
        drawn as ``"max"``); black elsewhere.
        """
        rgb = np.concatenate([self.rgb, np.zeros((1, 3), np.uint8)])  # row -1: black

        def colour(fam: LineFamily | None, size: int) -> np.ndarray:
            if fam is None:
                return np.full(size, -1, np.int64)
            j = fam.lit(size)
            return np.where(j >= 0, fam.code_array[np.maximum(j, 0)], -1)

        cols = colour(self.vertical, self.width)  # (W,) code or -1
        rows = colour(self.horizontal, self.height)  # (H,)
        vc = rgb[cols][None, :, :]
        hc = rgb[rows][:, None, :]
        if self.crossing == "vertical-over":
            return np.where((cols >= 0)[None, :, None], vc, hc)
        if self.crossing == "horizontal-over":
            return np.where((rows >= 0)[:, None, None], hc, vc)
        return np.maximum(vc, hc)

    # ------------------------------------------------------------------ files
    def to_dict(self) -> dict[str, Any]:
        """The JSON sidecar (``"type": "nurbscan.line-pattern"``; docs/patterns.md)."""
        return {
            "type": LINE_PATTERN_TYPE,
            "version": LINE_PATTERN_VERSION,
            "width": self.width,
            "height": self.height,
            "colours": [{"code": k, "name": name, "rgb": list(rgb)}
                        for k, (name, rgb) in enumerate(self.colours)],
            "background": [0, 0, 0],
            "window": self.window,
            "crossing": self.crossing,
            "edge_convention": LINE_EDGE_CONVENTION,
            "counts": {name: (0 if getattr(self, name) is None else getattr(self, name).count)
                       for name in ("vertical", "horizontal")},
            "lines": {name: (None if getattr(self, name) is None
                             else getattr(self, name).to_list())
                      for name in ("vertical", "horizontal")},
        }

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], source: str = "line pattern") -> LinePattern:
        """Rebuild a line pattern from :meth:`to_dict` output, checking every key.

        ``source`` names the input in error messages (e.g. the file). ``counts``, if present,
        must agree with the lines.
        """
        if not isinstance(d, Mapping):
            raise NurbscanError(f"{source}: expected a JSON object, got {type(d).__name__}")
        if d.get("type") != LINE_PATTERN_TYPE:
            raise NurbscanError(
                f"{source}: 'type' is {d.get('type')!r}, expected {LINE_PATTERN_TYPE!r}"
            )

        def get(mapping: Mapping, key: str, check, what: str, where: str = ""):
            if key not in mapping:
                raise NurbscanError(f"{source}: missing key {where}{key!r}")
            v = mapping[key]
            if not check(v):
                raise NurbscanError(
                    f"{source}: key {where}{key!r} must be {what}, got {type(v).__name__} "
                    f"{v!r}"[:200]
                )
            return v

        version = get(d, "version", _is_int, "an integer")
        if version > LINE_PATTERN_VERSION:
            raise NurbscanError(
                f"{source}: version {version} is newer than supported ({LINE_PATTERN_VERSION})"
            )
        width = get(d, "width", _is_int, "an integer")
        height = get(d, "height", _is_int, "an integer")
        window = get(d, "window", _is_int, "an integer")
        crossing = get(d, "crossing", lambda v: isinstance(v, str), "a string")
        colours = get(d, "colours", lambda v: isinstance(v, list) and all(
            isinstance(c, Mapping) and isinstance(c.get("name"), str)
            and isinstance(c.get("rgb"), list) and len(c["rgb"]) == 3
            and all(_is_int(x) for x in c["rgb"]) for c in v), "a list of {name, rgb} objects")
        if any(c.get("code", k) != k for k, c in enumerate(colours)):
            raise NurbscanError(f"{source}: 'colours' must be listed in code order 0, 1, ...")
        lines = get(d, "lines", lambda v: isinstance(v, Mapping), "an object")
        fams = {}
        for name in ("vertical", "horizontal"):
            entries = get(lines, name, lambda v: v is None or isinstance(v, list),
                          "a list of lines or null", "lines.")
            if not entries:
                fams[name] = None
                continue
            for i, e in enumerate(entries):
                where = f"lines.{name}[{i}]."
                if not isinstance(e, Mapping):
                    raise NurbscanError(f"{source}: lines.{name}[{i}] must be an object")
                if get(e, "index", _is_int, "an integer", where) != i:
                    raise NurbscanError(
                        f"{source}: lines.{name}[{i}] has index {e['index']}, expected {i}"
                    )
                get(e, "code", _is_int, "an integer", where)
                for key in ("lower", "upper"):
                    get(e, key, lambda v: _is_number(v) and math.isfinite(v), "a number", where)
            try:
                fams[name] = LineFamily(name, tuple(e["code"] for e in entries),
                                        tuple(e["lower"] for e in entries),
                                        tuple(e["upper"] for e in entries))
            except NurbscanError as exc:
                raise NurbscanError(f"{source}: {exc}") from None
        try:
            pat = cls(width=width, height=height,
                      colours=tuple((c["name"], tuple(c["rgb"])) for c in colours),
                      window=window, vertical=fams["vertical"], horizontal=fams["horizontal"],
                      crossing=crossing)
        except NurbscanError as exc:
            raise NurbscanError(f"{source}: {exc}") from None
        if "counts" in d and d["counts"] != pat.to_dict()["counts"]:
            raise NurbscanError(f"{source}: 'counts' disagree with the lines")
        return pat

    def save(self, image_path: str | os.PathLike) -> tuple[Path, Path]:
        """Write the image (PNG or TIFF, lossless) and its ``.json`` sidecar, each atomically.

        Returns the (image, sidecar) paths.
        """
        return save_pattern_files(image_path, self.render(), self.to_dict())

    def summary(self) -> str:
        """One line describing the pattern."""
        parts = []
        for fam in self.families:
            w = fam.widths
            wtxt = f"{w[0]:g}" if np.all(w == w[0]) else f"{w.min():g}-{w.max():g}"
            parts.append(f"{fam.count} {fam.direction} lines {wtxt} px wide "
                         f"({len(set(fam.codes))} colours)")
        return (f"{self.width}x{self.height} px, {' + '.join(parts)}, palette "
                f"{', '.join(n for n, _ in self.colours)}, window {self.window}, "
                f"crossing {self.crossing}")


def _check_palette(colours) -> tuple[tuple[str, tuple[int, int, int]], ...]:
    """Palette as ((name, (r, g, b)), ...): at least one colour, distinct, none black."""
    try:
        out = tuple((str(name), tuple(int(c) for c in rgb)) for name, rgb in colours)
    except (TypeError, ValueError):
        raise NurbscanError("line pattern colours: need a list of (name, (r, g, b)) pairs") \
            from None
    if not out:
        raise NurbscanError("line pattern colours: empty palette")
    for name, rgb in out:
        if len(rgb) != 3 or not all(0 <= c <= 255 for c in rgb) or not any(rgb):
            raise NurbscanError(
                f"line pattern colour {name!r}: RGB {rgb} must be three values in 0..255, "
                "not black"
            )
    if len({rgb for _, rgb in out}) != len(out):
        raise NurbscanError("line pattern colours: two codes share the same RGB")
    if len({name for name, _ in out}) != len(out):
        raise NurbscanError("line pattern colours: two codes share the same name")
    return out
