"""Reading a scan folder's ``scan.json`` (docs/scan-format.md) into a :class:`Scan`.

Every path in ``scan.json`` (pattern, views, calibration poses) is resolved *inside* the scan
folder: an absolute path or one that leaves the folder (``../``, also through a linked
folder; the file itself may be a symbolic link)
is refused with a one-line :class:`~nurbscan.errors.NurbscanError` naming ``scan.json``
(issue #34). Table angles are returned in radians whatever ``angle_unit`` says.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath, PureWindowsPath
from typing import Any

from ..errors import NurbscanError
from .atomic import read_json

__all__ = ["Scan", "ScanPose", "ScanView", "load_scan"]

SCAN_TYPE = "nurbscan.scan"


@dataclass(frozen=True)
class ScanView:
    """One view of the object: its table angle (radians) and its two images (absolute paths)."""

    index: int
    table_angle: float
    grid: Path
    white: Path | None = None


@dataclass(frozen=True)
class ScanPose:
    """One calibration pose: ``kind`` ``"free"`` or ``"turntable"`` and its two images."""

    index: int
    kind: str
    white: Path
    grid: Path | None = None
    table_angle: float | None = None


@dataclass(frozen=True)
class Scan:
    """A scan folder as described by its ``scan.json`` (docs/scan-format.md).

    Attributes
    ----------
    folder : Path
        The scan folder (absolute).
    image_size : (int, int)
        Camera image width and height, px.
    bit_depth : int
        8 or 16.
    pattern_image, pattern_sidecar : Path
        The projector image and its JSON sidecar (``pattern.png``, ``pattern.json``).
    views : tuple of ScanView
        The object's views, table angles in radians.
    target : dict
        The calibration target (``{}`` when the scan has no calibration).
    poses : tuple of ScanPose
        The calibration poses.
    source : dict
        Free-form provenance.
    """

    folder: Path
    image_size: tuple[int, int]
    bit_depth: int
    pattern_image: Path
    pattern_sidecar: Path
    views: tuple[ScanView, ...] = ()
    target: dict = field(default_factory=dict)
    poses: tuple[ScanPose, ...] = ()
    source: dict = field(default_factory=dict)

    @property
    def calibration_folder(self) -> Path:
        """``folder / "calibration"`` (what :func:`nurbscan.calibrate_scan` takes)."""
        return self.folder / "calibration"


def load_scan(folder: str | os.PathLike, allow_outside: bool = False) -> Scan:
    """Read ``scan.json`` of a scan folder, every path resolved inside the folder.

    Parameters
    ----------
    folder : path-like
        The scan folder, or its ``scan.json``.
    allow_outside : bool
        Accept absolute paths and paths leaving the scan folder (a scan whose images live
        elsewhere, by the user's choice: ``--allow-outside-paths`` on the command line).

    Returns
    -------
    Scan

    Raises
    ------
    NurbscanError
        One line naming ``scan.json``: missing, not JSON, not a ``nurbscan.scan``, a missing
        or malformed entry, or a path that is absolute or leaves the scan folder.

    Examples
    --------
    >>> import json, tempfile
    >>> from pathlib import Path
    >>> from nurbscan import load_scan
    >>> d = Path(tempfile.mkdtemp())
    >>> doc = {"type": "nurbscan.scan", "version": 1, "image_size": [640, 480],
    ...        "angle_unit": "degrees",
    ...        "views": [{"index": 0, "table_angle": 90, "grid": "views/v0_grid.png"}]}
    >>> _ = (d / "scan.json").write_text(json.dumps(doc))
    >>> scan = load_scan(d)
    >>> scan.image_size, round(scan.views[0].table_angle, 6)
    ((640, 480), 1.570796)
    >>> scan.views[0].grid == d.resolve() / "views" / "v0_grid.png"
    True
    >>> doc["views"][0]["grid"] = "../elsewhere.png"
    >>> _ = (d / "scan.json").write_text(json.dumps(doc))
    >>> load_scan(d)  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    nurbscan.errors.NurbscanError: ...scan.json: views[0].grid '../elsewhere.png' leaves ...
    """
    path = Path(folder)
    if path.name == "scan.json" and not path.is_dir():
        path = path.parent
    root = path.resolve()
    src = path / "scan.json"
    if not src.is_file():
        raise NurbscanError(f"{src}: not found (a scan folder holds scan.json; "
                            "docs/scan-format.md)")
    doc = read_json(src)

    def inside(value: Any, src: Path, what: str) -> Path:
        return _inside(root, allow_outside, value, src, what)

    if not isinstance(doc, dict) or doc.get("type") != SCAN_TYPE:
        raise NurbscanError(f"{src}: not a nurbscan scan (\"type\": {SCAN_TYPE!r})")
    size = _size(doc.get("image_size"), src)
    unit = str(doc.get("angle_unit", "radians")).lower()
    if unit not in ("radians", "rad", "degrees", "deg"):
        raise NurbscanError(f"{src}: angle_unit {unit!r}: expected 'radians' or 'degrees'")
    scale = math.pi / 180.0 if unit.startswith("deg") else 1.0
    pat = doc.get("pattern", {}) or {}
    if not isinstance(pat, dict):
        raise NurbscanError(f"{src}: pattern: expected an object")
    views = tuple(
        ScanView(index=_index(v, n, src, f"views[{n}]"),
                 table_angle=_angle(v.get("table_angle", 0.0), scale, src, f"views[{n}]"),
                 grid=inside(_need(v, "grid", src, f"views[{n}]"), src,
                              f"views[{n}].grid"),
                 white=inside(v["white"], src, f"views[{n}].white")
                 if v.get("white") else None)
        for n, v in enumerate(_objects(doc.get("views", []), src, "views")))
    calib = doc.get("calibration", {}) or {}
    if not isinstance(calib, dict):
        raise NurbscanError(f"{src}: calibration: expected an object")
    poses = tuple(
        ScanPose(index=_index(p, n, src, f"calibration.poses[{n}]"),
                 kind=_kind(p.get("kind", "free"), src, f"calibration.poses[{n}]"),
                 white=inside(_need(p, "white", src, f"calibration.poses[{n}]"), src,
                               f"calibration.poses[{n}].white"),
                 grid=inside(p["grid"], src, f"calibration.poses[{n}].grid")
                 if p.get("grid") else None,
                 table_angle=_angle(p["table_angle"], scale, src, f"calibration.poses[{n}]")
                 if p.get("table_angle") is not None else None)
        for n, p in enumerate(_objects(calib.get("poses", []), src, "calibration.poses")))
    depth = doc.get("bit_depth", 8)
    if depth not in (8, 16) or isinstance(depth, bool):
        raise NurbscanError(f"{src}: bit_depth {depth!r}: expected 8 or 16")
    return Scan(folder=root, image_size=size, bit_depth=int(depth),
                pattern_image=inside(pat.get("image", "pattern.png"), src,
                                      "pattern.image"),
                pattern_sidecar=inside(pat.get("sidecar", "pattern.json"), src,
                                        "pattern.sidecar"),
                views=views, target=_object(calib.get("target"), src, "calibration.target"),
                poses=poses, source=_object(doc.get("source"), src, "source"))


def _object(value: Any, src: Path, what: str) -> dict:
    if value is None:
        return {}
    if not isinstance(value, dict):
        raise NurbscanError(f"{src}: {what}: expected an object, got {type(value).__name__}")
    return dict(value)


def _kind(value: Any, src: Path, what: str) -> str:
    if value not in ("free", "turntable"):
        raise NurbscanError(f"{src}: {what}.kind {value!r}: expected 'free' or 'turntable'")
    return value


def _inside(root: Path, allow: bool, value: Any, src: Path, what: str) -> Path:
    """``root / value`` resolved, refusing (unless ``allow``) absolute paths and paths leaving
    ``root``."""
    if not isinstance(value, str) or not value.strip():
        raise NurbscanError(f"{src}: {what}: expected a relative path, got {value!r}")
    if allow:
        return (root / value).resolve()
    if (PurePosixPath(value).is_absolute() or PureWindowsPath(value).is_absolute()
            or PureWindowsPath(value).drive):
        raise NurbscanError(f"{src}: {what} {value!r} is absolute; give a path inside the "
                            "scan folder (or allow it: --allow-outside-paths)")
    # the folders on the way are resolved (a linked folder leading out is refused); the file
    # itself may be a symbolic link (the real-photograph scans link their read-only images)
    lex = Path(os.path.normpath(root / value))
    parent = lex.parent.resolve()
    p = parent / lex.name
    if (lex != root and root not in lex.parents) or (parent != root
                                                     and root not in parent.parents):
        raise NurbscanError(f"{src}: {what} {value!r} leaves the scan folder (allow it: "
                            "--allow-outside-paths)")
    return p


def _objects(value: Any, src: Path, what: str) -> list:
    if not isinstance(value, list) or not all(isinstance(v, dict) for v in value):
        raise NurbscanError(f"{src}: {what}: expected a list of objects")
    return value


def _need(d: dict, key: str, src: Path, what: str) -> Any:
    if key not in d:
        raise NurbscanError(f"{src}: {what}: missing {key!r}")
    return d[key]


def _index(d: dict, default: int, src: Path, what: str) -> int:
    v = d.get("index", default)
    if isinstance(v, bool) or not isinstance(v, int):
        raise NurbscanError(f"{src}: {what}.index: expected an integer, got {v!r}")
    return v


def _angle(value: Any, scale: float, src: Path, what: str) -> float:
    try:
        a = float(value)
    except (TypeError, ValueError):
        a = math.nan
    if not math.isfinite(a):
        raise NurbscanError(f"{src}: {what}.table_angle: expected a finite number, "
                            f"got {value!r}")
    return a * scale


def _size(value: Any, src: Path) -> tuple[int, int]:
    ok = (isinstance(value, list | tuple) and len(value) == 2
          and all(isinstance(v, int) and not isinstance(v, bool) and v > 0 for v in value))
    if not ok:
        raise NurbscanError(f"{src}: image_size: expected [width, height] in px, got {value!r}")
    return int(value[0]), int(value[1])
