"""Only the object: what lies on the turntable's top, below it or beside it is left out.

A real turntable is in every photograph, and where its top is bright enough the grid is
decoded there too: a scan of the teapot on a grey table (albedo 0.3) gives as many Gordon
patches on the table as on the teapot. The calibrated turntable gives the table plane exactly
(the object frame's ``z = 0``, docs/conventions.md) and its axis (``x = y = 0``); everything at
or below ``z = margin`` and everything outside the table's cylinder (radius ``radius``) is not
the object.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from ..errors import NurbscanError


@dataclass(frozen=True)
class TableOptions:
    """Where the object ends and the table begins.

    Attributes
    ----------
    margin : float
        Height above the table plane (mm) up to which a point counts as the table's: the
        table's own points scatter by the triangulation noise and the calibrated plane may be
        off by a few tenths of a mm. Default 0.5 mm.
    radius : float
        Radius of the table's cylinder about the axis (mm); anything farther from the axis is
        the room, not the object. Default 150 mm (the simulated table's top).
    patch_share : float
        A patch is left out when more than this share of its samples lies in the table's zone.
        Default 0.25.
    """

    margin: float = 0.5
    radius: float = 150.0
    patch_share: float = 0.25

    def __post_init__(self) -> None:
        if not (np.isfinite(self.margin) and self.margin >= 0):
            raise NurbscanError(f"table margin {self.margin}: must be a finite number >= 0 mm")
        if not (np.isfinite(self.radius) and self.radius > 0):
            raise NurbscanError(f"table radius {self.radius}: must be a finite number > 0 mm")
        if not 0 <= self.patch_share < 1:
            raise NurbscanError(f"table patch share {self.patch_share}: must be in [0, 1)")

    def to_dict(self) -> dict:
        """JSON-ready dict."""
        return asdict(self)


def off_object(points: np.ndarray, options: TableOptions = TableOptions()) -> np.ndarray:
    """Which object-frame points (N, 3), mm, are the table's or the room's: (N,) bool.

    True where ``z <= margin`` (on or below the table plane) or ``x^2 + y^2 > radius^2``
    (outside the table's cylinder); NaN points count as off the object too.
    """
    P = np.asarray(points, float).reshape(-1, 3)
    with np.errstate(invalid="ignore"):
        on = ~(P[:, 2] > options.margin)
        on |= ~(np.einsum("ij,ij->i", P[:, :2], P[:, :2]) <= options.radius ** 2)
    return on


def patch_off_object(samples: np.ndarray, options: TableOptions = TableOptions()) -> bool:
    """Whether a patch whose object-frame samples are ``samples`` (N, 3) is the table's:
    more than ``options.patch_share`` of them :func:`off_object`."""
    off = off_object(samples, options)
    return bool(off.size == 0 or off.mean() > options.patch_share)
