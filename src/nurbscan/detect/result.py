"""The result of grid detection: labelled sub-pixel edge lines and grid intersections.

Saved as ``lines.json`` (``"type": "nurbscan.detection"``), arrays as nested lists.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import NurbscanError
from ..io import write_json
from ..io.atomic import read_json

TYPE = "nurbscan.detection"
VERSION = 1

_ARRAYS = {
    # name: (dtype, decimals or None)
    "x": (np.float64, 4), "y": (np.float64, 4), "strength": (np.float32, 4),
    "line": (np.int64, None),
    "direction": (np.int64, None), "band": (np.int64, None), "edge": (np.int64, None),
    "coord": (np.float64, 4), "start": (np.int64, None), "stop": (np.int64, None),
    "votes": (np.int64, None), "agreement": (np.float64, 4),
    "cam": (np.float64, 4), "proj": (np.float64, 4), "cross_band": (np.int64, None),
    "cross_edge": (np.int64, None), "cross_line": (np.int64, None),
}


@dataclass(frozen=True)
class DetectionResult:
    """Decoded edge lines of one grid photograph (all coordinates px, pixel centres at integers).

    Attributes
    ----------
    image_size : (int, int)
        (width, height) of the photograph, camera px.
    x, y : ndarray float64 (N,)
        Sub-pixel edge points, camera px, grouped by line and ordered along each line.
    strength : ndarray float32 (N,)
        Gradient magnitude of the normalised edge signal at each point, per px.
    line : ndarray int64 (N,)
        Line id of each point (0 .. L - 1).
    direction : ndarray int64 (L,)
        0 for an edge of a vertical band ('v': its projector coordinate is an x), 1 for an edge
        of a horizontal band ('h': a y).
    band, edge : ndarray int64 (L,)
        Band (line) index in the pattern, and 0 rising / 1 falling (dark to light in +x or
        +y) for an edge of a band, 2 for the centre-line of a thin line
        (:func:`~nurbscan.detect.detect_lines`: a line too thin for two edges, measured by its
        ridge).
    coord : ndarray float64 (L,)
        Exact projector coordinate of the edge, or of the thin line's centre (edge 2), x for
        'v', y for 'h', projector px.
    start, stop : ndarray int64 (L,)
        The line's points are ``x[start:stop]``, ``y[start:stop]``.
    votes : ndarray int64 (L,)
        Windows that voted for the line's band index.
    agreement : ndarray float64 (L,)
        Share of the line's votes that agree with its label.
    cam : ndarray float64 (K, 2)
        Grid intersections: crossing of a vertical and a horizontal edge line, camera px.
    proj : ndarray float64 (K, 2)
        Their exact projector points (x of the vertical edge, y of the horizontal edge), px.
    cross_band, cross_edge : ndarray int64 (K, 2)
        (vertical, horizontal) band index and edge (0, 1, or 2 for a centre-line) of each
        intersection.
    cross_line : ndarray int64 (K, 2)
        (vertical, horizontal) line id of the segment ending nearest to the intersection.
    warnings : tuple of str
        Problems met (e.g. no grid found); empty when all went well.
    """

    image_size: tuple[int, int]
    x: np.ndarray
    y: np.ndarray
    strength: np.ndarray
    line: np.ndarray
    direction: np.ndarray
    band: np.ndarray
    edge: np.ndarray
    coord: np.ndarray
    start: np.ndarray
    stop: np.ndarray
    votes: np.ndarray
    agreement: np.ndarray
    cam: np.ndarray
    proj: np.ndarray
    cross_band: np.ndarray
    cross_edge: np.ndarray
    cross_line: np.ndarray
    warnings: tuple[str, ...] = field(default=())

    @classmethod
    def empty(cls, image_size: tuple[int, int], warnings: tuple[str, ...] = ()
              ) -> DetectionResult:
        """A result without lines (e.g. no grid found)."""
        z = {k: np.zeros((0, 2) if k in ("cam", "proj", "cross_band", "cross_edge",
                                          "cross_line") else 0, dt)
             for k, (dt, _) in _ARRAYS.items()}
        return cls(image_size=tuple(int(v) for v in image_size), warnings=tuple(warnings), **z)

    @property
    def nlines(self) -> int:
        """Number of labelled lines."""
        return len(self.band)

    @property
    def point_direction(self) -> np.ndarray:
        """Direction (0 'v', 1 'h') of each point, (N,)."""
        return self.direction[self.line]

    @property
    def point_band(self) -> np.ndarray:
        """Band index of each point, (N,)."""
        return self.band[self.line]

    @property
    def point_edge(self) -> np.ndarray:
        """Edge (0 rising, 1 falling, 2 centre-line) of each point, (N,)."""
        return self.edge[self.line]

    def line_lengths(self) -> np.ndarray:
        """Arc length of each line's polyline through its points in order, camera px, (L,)."""
        same = self.line[1:] == self.line[:-1]
        seg = np.hypot(np.diff(self.x), np.diff(self.y))
        return np.bincount(self.line[1:][same], weights=seg[same], minlength=self.nlines)

    def polyline(self, i: int) -> np.ndarray:
        """Points of line ``i`` in order, (n, 2) camera px."""
        s = slice(int(self.start[i]), int(self.stop[i]))
        return np.stack([self.x[s], self.y[s]], axis=1)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dictionary (``"type": "nurbscan.detection"``)."""
        d: dict[str, Any] = {"type": TYPE, "version": VERSION,
                             "image_size": list(self.image_size),
                             "warnings": list(self.warnings)}
        for k, (_, dec) in _ARRAYS.items():
            a = np.asarray(getattr(self, k))
            d[k] = (np.round(a.astype(np.float64), dec) if dec is not None else a).tolist()
        return d

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], source: str = "detection") -> DetectionResult:
        """Inverse of :meth:`to_dict`; a malformed dictionary raises NurbscanError."""
        if not isinstance(d, Mapping) or d.get("type") != TYPE:
            raise NurbscanError(f"{source}: not a nurbscan detection result (type {TYPE!r})")
        try:
            kw = {}
            for k, (dt, _) in _ARRAYS.items():
                a = np.asarray(d[k], dtype=dt)
                if k in ("cam", "proj", "cross_band", "cross_edge", "cross_line"):
                    a = a.reshape(-1, 2)
                kw[k] = a
            size = tuple(int(v) for v in d["image_size"])
            warnings = tuple(str(w) for w in d.get("warnings", ()))
        except (KeyError, TypeError, ValueError) as exc:
            raise NurbscanError(f"{source}: malformed detection result ({exc})") from None
        n, nl = len(kw["x"]), len(kw["band"])
        if any(len(kw[k]) != n for k in ("y", "strength", "line")) or any(
                len(kw[k]) != nl for k in ("direction", "edge", "coord", "start", "stop")):
            raise NurbscanError(f"{source}: malformed detection result (array lengths differ)")
        return cls(image_size=size, warnings=warnings, **kw)

    def save(self, path: str | os.PathLike) -> Path:
        """Write ``lines.json`` atomically."""
        return write_json(path, self.to_dict(), indent=None)


def load_detection(path: str | os.PathLike) -> DetectionResult:
    """Read a ``lines.json`` written by :meth:`DetectionResult.save`."""
    return DetectionResult.from_dict(read_json(path), source=str(path))
