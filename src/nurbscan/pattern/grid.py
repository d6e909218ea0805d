"""The projected colour grid: bands coloured by a de Bruijn sequence, with exact edges.

method.md section 1. A projector image of ``width`` x ``height`` pixels holds

* vertical bands i = 0 .. nx - 1 lighting the columns ``x0 + i*pitch .. x0 + i*pitch + band - 1``
  in the colour of code ``sequence[i]``, and
* horizontal bands j = 0 .. ny - 1 lighting the rows ``y0 + j*pitch .. y0 + j*pitch + band - 1``
  in the colour of code ``sequence[j]`` -- the *same* sequence in both directions,

on black. Colour codes: magenta 0, red 1, green 2, yellow 3, cyan 4 (RGB 101, 100, 010, 110,
011), and for q = 6, 7 also blue 5 (001) and white 6 (111). **Crossing rule**: where a vertical
and a horizontal band cross, the light adds: the pixel is the channel-wise maximum (bitwise OR)
of the two colours. The band counts are the most that fit, ``(size - offset - band) // pitch + 1``,
with (x0, y0) chosen to centre the grid; a count may not exceed the sequence length q^n.

Edges (docs/conventions.md: pixel centres at integers, a pixel covers [i - 0.5, i + 0.5]):
band i has its *rising* edge (dark to light going in +x, or +y) at ``x0 + i*pitch - 0.5`` and its
*falling* edge at ``x0 + i*pitch + band - 0.5``, exactly, in projector pixels.

Directions are named by the bands: ``"vertical"`` (alias ``"x"``) for the vertical bands, whose
edges are x coordinates, and ``"horizontal"`` (alias ``"y"``) for the horizontal bands.
"""

from __future__ import annotations

import functools
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import NurbscanError
from ..io.atomic import read_json
from .lines import (
    LINE_PATTERN_TYPE,
    LineFamily,
    LinePattern,
    save_pattern_files,
    window_length,
)
from .sequence import (
    check_field,
    check_primitive,
    de_bruijn,
    default_poly,
    format_poly,
    window_lookup,
    window_table,
)

TYPE = "nurbscan.pattern"
VERSION = 1

#: Colour of each code on black (name, RGB 0..255): 5 for q = 5, up to 7 (all 3-bit colours).
DEFAULT_COLOURS: tuple[tuple[str, tuple[int, int, int]], ...] = (
    ("magenta", (255, 0, 255)),
    ("red", (255, 0, 0)),
    ("green", (0, 255, 0)),
    ("yellow", (255, 255, 0)),
    ("cyan", (0, 255, 255)),
    ("blue", (0, 0, 255)),
    ("white", (255, 255, 255)),
)

CROSSING = "max"
CROSSING_RULE = (
    "where a vertical and a horizontal band cross the light adds: the pixel is the channel-wise "
    "maximum (bitwise OR) of the two colours"
)
EDGE_CONVENTION = (
    "projector pixels, pixel centres at integers; band i lights pixels offset + i*pitch .. "
    "offset + i*pitch + band - 1; rising edge (dark to light in +x / +y) at "
    "offset + i*pitch - 0.5, falling edge at offset + i*pitch + band - 0.5"
)

_DIRECTIONS = {"vertical": 0, "x": 0, "v": 0, "horizontal": 1, "y": 1, "h": 1}
_EDGES = {"rising": 0, "falling": 1}


def _axis(direction: str) -> int:
    """0 for the vertical bands (x), 1 for the horizontal bands (y)."""
    try:
        return _DIRECTIONS[str(direction).lower()]
    except KeyError:
        raise NurbscanError(
            f"direction {direction!r}: must be 'vertical' (or 'x') or 'horizontal' (or 'y')"
        ) from None


def _is_int(v: Any) -> bool:
    return isinstance(v, int | np.integer) and not isinstance(v, bool)


def sidecar_path(image_path: str | os.PathLike) -> Path:
    """The JSON sidecar beside a pattern image: same name, suffix ``.json``."""
    return Path(image_path).with_suffix(".json")


@dataclass(frozen=True)
class Pattern:
    """A PRMVS colour grid for a projector (see the module notes for the geometry).

    Attributes
    ----------
    width, height : int
        Projector image size, px.
    pitch, band : int
        Band pitch and band width, px (1 <= band < pitch, so bands are separated by black).
    q, n : int
        Number of colours (a prime) and window length.
    poly : str
        Primitive polynomial over GF(q) in the notation of :mod:`nurbscan.pattern.sequence`
        (normalised to the canonical form).
    colours : tuple of (str, (int, int, int))
        Name and RGB (0..255) of each code 0..q-1; none black, all distinct.
    offsets : (int, int)
        (x0, y0): first lit column of vertical band 0 and first lit row of horizontal band 0.
    sequence : tuple of int
        The de Bruijn sequence of ``poly`` (length q^n); checked against ``poly``.
    """

    width: int
    height: int
    pitch: int
    band: int
    q: int
    n: int
    poly: str
    colours: tuple[tuple[str, tuple[int, int, int]], ...]
    offsets: tuple[int, int]
    sequence: tuple[int, ...]

    # ------------------------------------------------------------------ construction
    def __post_init__(self) -> None:
        for key in ("width", "height", "pitch", "band", "q", "n"):
            v = getattr(self, key)
            if not _is_int(v) or v < 1:
                raise NurbscanError(f"pattern {key}={v!r}: must be an integer >= 1")
            object.__setattr__(self, key, int(v))
        if self.band >= self.pitch:
            raise NurbscanError(
                f"pattern band={self.band}, pitch={self.pitch}: the band must be narrower than "
                "the pitch (bands are separated by black)"
            )
        check_field(self.q, self.n)
        coeffs = check_primitive(self.poly, self.q, self.n)
        object.__setattr__(self, "poly", format_poly(coeffs, self.q))
        seq = tuple(int(s) for s in self.sequence)
        if seq != tuple(de_bruijn(self.q, self.n, coeffs).tolist()):
            raise NurbscanError(
                f"pattern sequence: not the de Bruijn sequence of polynomial {self.poly!r} "
                f"over GF({self.q})"
            )
        object.__setattr__(self, "sequence", seq)
        object.__setattr__(self, "colours", self._check_colours(self.colours, self.q))
        offs = tuple(self.offsets)
        if len(offs) != 2 or not all(_is_int(o) and o >= 0 for o in offs):
            raise NurbscanError(f"pattern offsets={self.offsets!r}: need two integers >= 0")
        object.__setattr__(self, "offsets", (int(offs[0]), int(offs[1])))
        for name, size, off in (("vertical", self.width, offs[0]), ("horizontal", self.height,
                                                                      offs[1])):
            count = self.nbands(name)
            if count > len(seq):
                raise NurbscanError(
                    f"pattern: {count} {name} bands ({'width' if name == 'vertical' else 'height'}"
                    f" {size} px at pitch {self.pitch}) exceed the "
                    f"sequence length q^n = {len(seq)}; use a larger pitch, a smaller image, "
                    "or a longer window n"
                )
            if count < self.n:
                raise NurbscanError(
                    f"pattern: only {count} {name} bands fit ({size} px, offset {off}, pitch "
                    f"{self.pitch}); at least n = {self.n} are needed to decode a window"
                )

    @staticmethod
    def _check_colours(colours, q: int) -> tuple[tuple[str, tuple[int, int, int]], ...]:
        try:
            out = tuple((str(name), tuple(int(c) for c in rgb)) for name, rgb in colours)
        except (TypeError, ValueError):
            raise NurbscanError(
                "pattern colours: need a list of (name, (r, g, b)) pairs"
            ) from None
        if len(out) != q:
            raise NurbscanError(f"pattern colours: {len(out)} given, q = {q} codes need {q}")
        for name, rgb in out:
            if len(rgb) != 3 or not all(0 <= c <= 255 for c in rgb) or not any(rgb):
                raise NurbscanError(
                    f"pattern colour {name!r}: RGB {rgb} must be three values in 0..255, not black"
                )
        if len({rgb for _, rgb in out}) != q:
            raise NurbscanError("pattern colours: two codes share the same RGB")
        return out

    @classmethod
    def create(
        cls,
        width: int = 1920,
        height: int = 1080,
        pitch: int = 16,
        band: int = 6,
        q: int = 5,
        n: int = 3,
        poly: str | Sequence[int] | None = None,
        colours: Sequence[tuple[str, Sequence[int]]] | None = None,
    ) -> Pattern:
        """Build a grid with as many bands as fit, centred in the projector image.

        ``poly`` defaults to :func:`~nurbscan.pattern.sequence.default_poly` ("1403" for
        q = 5, n = 3); ``colours`` to :data:`DEFAULT_COLOURS` (available for q <= 7).
        """
        check_field(q, n)
        for key, v in (("width", width), ("height", height), ("pitch", pitch), ("band", band)):
            if not _is_int(v) or v < 1:
                raise NurbscanError(f"pattern {key}={v!r}: must be an integer >= 1")
        if poly is None:
            poly = default_poly(q, n)
        coeffs = check_primitive(poly, q, n)
        if colours is None:
            if q > len(DEFAULT_COLOURS):
                raise NurbscanError(
                    f"pattern colours: no default colour table for q = {q} (at most "
                    f"{len(DEFAULT_COLOURS)} colours on black); give the colours"
                )
            colours = DEFAULT_COLOURS[:q]
        offsets = []
        for size in (width, height):
            count = max((size - band) // pitch + 1, 0)
            span = (count - 1) * pitch + band if count else 0
            offsets.append(max((size - span) // 2, 0))
        return cls(
            width=width, height=height, pitch=pitch, band=band, q=q, n=n,
            poly=format_poly(coeffs, q), colours=tuple(colours), offsets=tuple(offsets),
            sequence=tuple(de_bruijn(q, n, coeffs).tolist()),
        )

    # ------------------------------------------------------------------ geometry
    def nbands(self, direction: str) -> int:
        """Number of bands in a direction: ``(size - offset - band) // pitch + 1`` (>= 0)."""
        a = _axis(direction)
        size = (self.width, self.height)[a]
        return max((size - self.offsets[a] - self.band) // self.pitch + 1, 0)

    @property
    def counts(self) -> tuple[int, int]:
        """(number of vertical bands, number of horizontal bands)."""
        return self.nbands("vertical"), self.nbands("horizontal")

    @property
    def rgb(self) -> np.ndarray:
        """Colour table, uint8 array of shape (q, 3): row k is the RGB of code k."""
        return np.array([rgb for _, rgb in self.colours], dtype=np.uint8)

    def band_codes(self, direction: str) -> np.ndarray:
        """Colour code of each band in a direction, int64 array of shape (nbands,)."""
        return np.asarray(self.sequence[: self.nbands(direction)], dtype=np.int64)

    def _edges(self, direction: str) -> np.ndarray:
        a = _axis(direction)
        start = self.offsets[a] + self.pitch * np.arange(self.nbands(direction)) - 0.5
        return np.stack([start, start + self.band], axis=1).astype(np.float64)

    @property
    def vertical_edges(self) -> np.ndarray:
        """x of the (rising, falling) edge of each vertical band, px, shape (nx, 2)."""
        return self._edges("vertical")

    @property
    def horizontal_edges(self) -> np.ndarray:
        """y of the (rising, falling) edge of each horizontal band, px, shape (ny, 2)."""
        return self._edges("horizontal")

    def edge_coordinate(self, direction: str, band_index, edge) -> np.ndarray:
        """Exact projector coordinate of band edges, vectorised.

        Parameters
        ----------
        direction : str
            ``"vertical"`` (x coordinates) or ``"horizontal"`` (y coordinates).
        band_index : array_like of int
            Band indices; any outside 0 .. nbands - 1 (e.g. -1 from :meth:`lookup`) give NaN.
        edge : array_like of int or str
            0 / ``"rising"`` or 1 / ``"falling"``; broadcast against ``band_index``.

        Returns
        -------
        coord : ndarray of float64, broadcast shape
            ``offset + i*pitch - 0.5`` (rising) or ``offset + i*pitch + band - 0.5``
            (falling), projector px.
        """
        a = _axis(direction)
        idx = np.asarray(band_index)
        e = np.asarray(edge)
        if e.dtype.kind in "US":
            bad = ~np.isin(e, list(_EDGES))
            if np.any(bad):
                raise NurbscanError(f"edge {e[bad].flat[0]!r}: must be 'rising' or 'falling'")
            e = (e == "falling").astype(np.int64)
        elif np.any((e != 0) & (e != 1)):
            raise NurbscanError("edge: must be 0 (rising) or 1 (falling)")
        valid = (idx >= 0) & (idx < self.nbands(direction))
        if idx.dtype.kind not in "iu":  # (whole numbers as they are)
            valid &= idx == np.round(idx)
        coord = self.offsets[a] + self.pitch * idx.astype(np.float64) - 0.5 + self.band * e
        return np.where(valid, coord, np.nan)

    def stripe_field(self, coord, direction: str) -> np.ndarray:
        """Index of the band lit at projector coordinate(s) ``coord``, -1 where dark.

        Parameters
        ----------
        coord : array_like of float
            x (for ``"vertical"``) or y (for ``"horizontal"``) in projector px.

        Returns
        -------
        index : ndarray of int64, same shape
            i where ``rising_i <= coord < falling_i`` (half-open), else -1 (also for NaN).
        """
        a = _axis(direction)
        c = np.asarray(coord, dtype=np.float64)
        t = c - (self.offsets[a] - 0.5)
        with np.errstate(invalid="ignore"):
            i = np.floor(t / self.pitch)
            inside = np.isfinite(t) & (t - i * self.pitch < self.band)
            inside &= (i >= 0) & (i < self.nbands(direction))
        return np.where(inside, i, -1).astype(np.int64)

    # ------------------------------------------------------------------ decoding
    @functools.cached_property
    def _table(self) -> np.ndarray:
        return window_table(np.asarray(self.sequence), self.q, self.n, cyclic=False)

    def lookup(self, codes, direction: str | None = None) -> np.ndarray:
        """Band index of the first band of each window of n consecutive colour codes.

        Parameters
        ----------
        codes : array_like of int, shape (..., n)
            Colour codes of n consecutive bands read in the direction of increasing coordinate
            (left to right, top to bottom). A code outside 0..q-1 (e.g. -1) makes the window
            invalid.
        direction : str, optional
            Restrict to windows that exist in this direction (start index <= nbands - n).
            Without it, windows of the longer direction are accepted.

        Returns
        -------
        index : ndarray of int64, shape (...)
            Index of the window's first band, or -1. O(1) per window (dense table of size q^n).
        """
        count = max(self.counts) if direction is None else self.nbands(direction)
        idx = window_lookup(codes, self._table, self.q)
        return np.where((idx >= 0) & (idx + self.n <= count), idx, -1)

    # ------------------------------------------------------------------ image
    def render(self) -> np.ndarray:
        """The projector image, uint8 array of shape (height, width, 3), RGB.

        Pixel (x, y) takes the colour of the vertical band lit at x and of the horizontal band
        lit at y, combined by the crossing rule (channel-wise max); black elsewhere.
        """
        rgb = np.concatenate([self.rgb, np.zeros((1, 3), np.uint8)])  # row -1: black
        seq = np.asarray(self.sequence, dtype=np.int64)
        vi = self.stripe_field(np.arange(self.width), "vertical")
        hi = self.stripe_field(np.arange(self.height), "horizontal")
        cols = rgb[np.where(vi >= 0, seq[np.maximum(vi, 0)], -1)]  # (W, 3)
        rows = rgb[np.where(hi >= 0, seq[np.maximum(hi, 0)], -1)]  # (H, 3)
        return np.maximum(cols[None, :, :], rows[:, None, :])

    # ------------------------------------------------------------------ files
    def _bands_dict(self) -> dict[str, list[dict[str, Any]]]:
        out = {}
        for name in ("vertical", "horizontal"):
            edges = self._edges(name)
            codes = self.band_codes(name)
            out[name] = [
                {"index": i, "code": int(codes[i]), "rising": float(edges[i, 0]),
                 "falling": float(edges[i, 1])}
                for i in range(len(codes))
            ]
        return out

    def to_dict(self) -> dict[str, Any]:
        """The JSON sidecar: everything a decoder needs (see :func:`load_pattern`)."""
        nx, ny = self.counts
        return {
            "type": TYPE,
            "version": VERSION,
            "q": self.q,
            "n": self.n,
            "poly": self.poly,
            "poly_notation": "coefficients from the highest degree down, monic; "
                             "a[k+n] = -(c[n-1] a[k+n-1] + ... + c[0] a[k]) mod q",
            "sequence": list(self.sequence),
            "window_key": "first code most significant: sum code[k] * q^(n-1-k)",
            "colours": [{"code": k, "name": name, "rgb": list(rgb)}
                        for k, (name, rgb) in enumerate(self.colours)],
            "background": [0, 0, 0],
            "width": self.width,
            "height": self.height,
            "pitch": self.pitch,
            "band": self.band,
            "offsets": list(self.offsets),
            "crossing": CROSSING,
            "crossing_rule": CROSSING_RULE,
            "edge_convention": EDGE_CONVENTION,
            "counts": {"vertical": nx, "horizontal": ny},
            "bands": self._bands_dict(),
        }

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], source: str = "pattern") -> Pattern:
        """Rebuild a pattern from :meth:`to_dict` output, checking every key it relies on.

        ``source`` names the input in error messages (e.g. the file). The derived parts
        (``counts``, ``bands``), if present, must agree with the rebuilt pattern.
        """
        if not isinstance(d, Mapping):
            raise NurbscanError(f"{source}: expected a JSON object, got {type(d).__name__}")
        if d.get("type") != TYPE:
            raise NurbscanError(f"{source}: 'type' is {d.get('type')!r}, expected {TYPE!r}")

        def get(key: str, check, what: str):
            if key not in d:
                raise NurbscanError(f"{source}: missing key {key!r}")
            v = d[key]
            if not check(v):
                raise NurbscanError(
                    f"{source}: key {key!r} must be {what}, got {type(v).__name__} {v!r}"[:200]
                )
            return v

        def int_list(length=None):
            return lambda v: isinstance(v, list) and all(_is_int(x) for x in v) and (
                length is None or len(v) == length)

        version = get("version", _is_int, "an integer")
        if version > VERSION:
            raise NurbscanError(f"{source}: version {version} is newer than supported ({VERSION})")
        kw = {k: get(k, _is_int, "an integer")
              for k in ("width", "height", "pitch", "band", "q", "n")}
        poly = get("poly", lambda v: isinstance(v, str), "a string")
        sequence = get("sequence", int_list(), "a list of integers")
        offsets = get("offsets", int_list(2), "a list of two integers")
        colours = get("colours", lambda v: isinstance(v, list) and all(
            isinstance(c, Mapping) and isinstance(c.get("name"), str)
            and int_list(3)(c.get("rgb")) for c in v), "a list of {name, rgb} objects")
        if d.get("crossing", CROSSING) != CROSSING:
            raise NurbscanError(f"{source}: crossing rule {d['crossing']!r} is not supported")
        try:
            pat = cls(**kw, poly=poly, sequence=tuple(sequence), offsets=tuple(offsets),
                      colours=tuple((c["name"], tuple(c["rgb"])) for c in colours))
        except NurbscanError as exc:
            raise NurbscanError(f"{source}: {exc}") from None
        if "counts" in d and d["counts"] != {"vertical": pat.counts[0],
                                            "horizontal": pat.counts[1]}:
            raise NurbscanError(f"{source}: 'counts' disagree with width/height/pitch/offsets")
        if "bands" in d and d["bands"] != pat._bands_dict():
            raise NurbscanError(f"{source}: 'bands' (codes or edges) disagree with the pattern")
        return pat

    def save(self, image_path: str | os.PathLike) -> tuple[Path, Path]:
        """Write the image (PNG or TIFF, lossless) and its ``.json`` sidecar, each atomically.

        Returns the (image, sidecar) paths.
        """
        return save_pattern_files(image_path, self.render(), self.to_dict())

    def to_line_pattern(self) -> LinePattern:
        """The same grid as a :class:`~nurbscan.pattern.lines.LinePattern`.

        Same size, palette (code k -> colour k), band codes and edges (rising -> ``lower``,
        falling -> ``upper``) and crossing rule ``"max"``; its window is the smallest n with
        unique runs of codes along each direction (:func:`~nurbscan.pattern.lines.window_length`),
        which is at most :attr:`n` and smaller when the grid holds few bands.
        """
        fams = {}
        for name in ("vertical", "horizontal"):
            edges = self._edges(name)
            fams[name] = LineFamily(name, tuple(self.band_codes(name).tolist()),
                                    tuple(edges[:, 0].tolist()), tuple(edges[:, 1].tolist()))
        window = window_length({k: f.codes for k, f in fams.items()}, max_n=max(self.n, 6))
        return LinePattern(width=self.width, height=self.height, colours=self.colours,
                           window=window, vertical=fams["vertical"],
                           horizontal=fams["horizontal"], crossing=CROSSING)

    def summary(self) -> str:
        """One line describing the pattern."""
        nx, ny = self.counts
        return (
            f"{self.width}x{self.height} px, {nx} vertical + {ny} horizontal bands, pitch "
            f"{self.pitch} px, band {self.band} px, GF({self.q}) window {self.n}, polynomial "
            f"{self.poly}, de Bruijn length {len(self.sequence)}"
        )


def load_pattern(json_path: str | os.PathLike) -> Pattern | LinePattern:
    """Read a pattern from its JSON sidecar, by the sidecar's ``"type"``.

    ``"nurbscan.pattern"`` (written by :meth:`Pattern.save`) gives a :class:`Pattern`;
    ``"nurbscan.line-pattern"`` (written by :meth:`LinePattern.save` or
    ``nurbscan pattern --from-image``) gives a :class:`~nurbscan.pattern.lines.LinePattern`.

    Raises :class:`NurbscanError` naming the file for a missing file, invalid JSON, an unknown
    type, a missing key, a value of the wrong type, or contents that disagree with each other.
    """
    json_path = Path(json_path)
    d = read_json(json_path)
    if isinstance(d, Mapping) and d.get("type") == LINE_PATTERN_TYPE:
        return LinePattern.from_dict(d, source=str(json_path))
    return Pattern.from_dict(d, source=str(json_path))
