"""The planar calibration target of the synthetic scanner: a chessboard on a matte white board.

Board coordinates (mm): the origin is the first inner corner, x runs along a row of inner
corners (``cols`` of them), y along a column (``rows``), z = 0 is the printed face and +z points
into the board (OpenCV's convention, so ``cv2.findChessboardCorners`` order matches). Inner
corner (i, j) is at (i * square, j * square, 0). The squares span
[-square, cols * square] x [-square, rows * square]; the square containing (x, y) is black when
floor(x / square) + floor(y / square) is even (so the square just below and right of corner
(0, 0) is black). A white margin of ``margin`` mm surrounds the squares; beyond it the board
ends.

A board pose (R, T) maps board to frame: X = R P + T.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import NurbscanError
from .render import step_coverage

TYPE = "nurbscan.chessboard"
VERSION = 1


def _factors(j: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """g and g_s of :meth:`Chessboard.albedo_cell` on square ``j`` of an axis with ``n`` inner
    corners (squares -1 .. n - 1): 1 on the squares, and signed +1 / -1 on even / odd ones."""
    g = ((j >= -1) & (j <= n - 1)).astype(float)
    return g, np.where(j % 2 == 0, g, -g)


@dataclass(frozen=True)
class Chessboard:
    """A printed chessboard target.

    Attributes
    ----------
    cols, rows : int
        Inner corners along x and along y (default 9 x 7, i.e. 10 x 8 squares).
    square : float
        Square size, mm (default 20).
    margin : float
        White border around the squares, mm (default 20).
    black, white : float
        Albedo of the black squares and of the white board (matte print).
    """

    cols: int = 9
    rows: int = 7
    square: float = 20.0
    margin: float = 20.0
    black: float = 0.05
    white: float = 0.85

    def __post_init__(self) -> None:
        if self.cols < 2 or self.rows < 2 or self.square <= 0 or self.margin < 0:
            raise NurbscanError(
                f"chessboard {self.cols} x {self.rows}, square {self.square} mm, margin "
                f"{self.margin} mm: need at least 2 x 2 inner corners and a positive square")

    @property
    def extent(self) -> tuple[float, float, float, float]:
        """Board outline (x0, x1, y0, y1) in board mm."""
        s, m = self.square, self.margin
        return (-s - m, self.cols * s + m, -s - m, self.rows * s + m)

    def corners(self) -> np.ndarray:
        """Inner corners in board mm, shape (rows * cols, 3), row by row (x fastest)."""
        i, j = np.meshgrid(np.arange(self.cols), np.arange(self.rows))
        return np.stack([i.ravel() * self.square, j.ravel() * self.square,
                         np.zeros(i.size)], axis=1)

    def albedo_at(self, p: np.ndarray) -> np.ndarray:
        """Albedo (N,) at board points ``p`` (N, 2 or 3) mm: black, white, or 0 off the board."""
        x, y = p[:, 0], p[:, 1]
        s = self.square
        ix, iy = np.floor(x / s), np.floor(y / s)
        inside_sq = (ix >= -1) & (ix <= self.cols - 1) & (iy >= -1) & (iy <= self.rows - 1)
        black = inside_sq & ((ix + iy) % 2 == 0)
        return np.where(black, self.black, self.white)

    def albedo_cell(self, p: np.ndarray, dx: np.ndarray, dy: np.ndarray) -> np.ndarray:
        """Mean albedo (N,) over the parallelograms p + dx s + dy t, s, t uniform in [-1/2, 1/2].

        ``p``, ``dx``, ``dy`` (N, 2 or 3) are board points and the cell's side vectors, mm
        (a pixel's or a sub-pixel cell's footprint on the board). The black squares are
        B(x, y) = [g(x) g(y) + g_s(x) g_s(y)] / 2, with g the indicator of the squared
        area along one axis and g_s = g times the square wave (+1 on even squares, -1 on odd
        ones); each one-axis factor is averaged *exactly* over the footprint's projection on
        its axis (a trapezoid, :func:`~nurbscan.simulate.render.step_coverage`) and the mean
        of each product is taken as the product of the means. That is exact wherever one
        factor is constant over the cell (along every edge away from the corners) and for
        cells whose sides run along the board axes; so a printed edge moves continuously
        with the board, unlike a point-sampled texture (which snaps to the sub-samples).
        """
        s = self.square
        means = []
        for axis, n in ((0, self.cols), (1, self.rows)):
            x, a, b = p[:, axis], np.abs(dx[:, axis]), np.abs(dy[:, axis])

            if np.all(a + b < s):
                # a footprint narrower than a square meets at most the nearest boundary k s
                k = np.clip(np.rint(x / s), -1, n)
                f = step_coverage(x - k * s, a, b)  # its share beyond boundary k
                (g0, gs0), (g1, gs1) = _factors(k - 1, n), _factors(k, n)
                means.append((g0 + f * (g1 - g0), gs0 + f * (gs1 - gs0)))
                continue
            breaks = np.arange(-1, n + 1) * s  # every square boundary along this axis
            f = step_coverage(x[:, None] - breaks, a[:, None], b[:, None])
            cover = f[:, :-1] - f[:, 1:]  # share of the footprint in each square
            g, gs = _factors(np.arange(-1, n), n)
            means.append((cover @ g, cover @ gs))
        (gx, gsx), (gy, gsy) = means
        black = 0.5 * (gx * gy + gsx * gsy)
        return self.white + (self.black - self.white) * black

    def to_dict(self) -> dict[str, Any]:
        """The target description stored in ``scan.json`` (docs/scan-format.md)."""
        return {"type": TYPE, "version": VERSION, "inner_corners": [self.cols, self.rows],
                "square_mm": self.square, "margin_mm": self.margin, "first_square_dark": True,
                "origin": "first inner corner; x along a row of inner corners, y along a "
                          "column, z into the board",
                "albedo": {"black": self.black, "white": self.white}}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], source: str = "calibration target") -> Chessboard:
        """Rebuild from :meth:`to_dict` output."""
        if not isinstance(d, Mapping) or d.get("type") != TYPE:
            raise NurbscanError(f"{source}: not a {TYPE!r} object")
        try:
            cols, rows = (int(v) for v in d["inner_corners"])
            alb = d.get("albedo", {})
            return cls(cols=cols, rows=rows, square=float(d["square_mm"]),
                       margin=float(d.get("margin_mm", 20.0)),
                       black=float(alb.get("black", 0.05)), white=float(alb.get("white", 0.85)))
        except (KeyError, TypeError, ValueError) as exc:
            raise NurbscanError(f"{source}: bad chessboard description ({exc})") from None


class BoardScene:
    """A chessboard at a pose in the object frame, as a scene for the renderer.

    ``intersect`` is the exact ray / rectangle intersection (closed form); ``albedo`` is the
    chessboard texture at object-frame points.

    Parameters
    ----------
    board : Chessboard
    R, T : array_like, shapes (3, 3), (3,)
        Pose, board to object frame: X_obj = R P + T.
    """

    name = "chessboard"
    self_shadowing = False  # a plane (shadow rays are cast for the table's points only)

    def __init__(self, board: Chessboard, R: np.ndarray, T: np.ndarray):
        self.board = board
        self.R = np.asarray(R, float)
        self.T = np.asarray(T, float)

    def to_board(self, points: np.ndarray) -> np.ndarray:
        """Object-frame points (N, 3) to board coordinates (N, 3)."""
        return np.einsum("ij,jk->ik", np.asarray(points, float) - self.T, self.R)

    def intersect(self, origins, directions) -> dict[str, np.ndarray]:
        """First hit of rays (object frame) with the board rectangle; scenes' result format."""
        d = np.asarray(directions, float)
        d = d / np.linalg.norm(d, axis=-1, keepdims=True)
        o = np.broadcast_to(np.asarray(origins, float), d.shape)
        nrm = self.R[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.einsum("ij,j->i", self.T - o, nrm) / np.einsum("ij,j->i", d, nrm)
            p = o + t[:, None] * d
            pb = self.to_board(p)
        x0, x1, y0, y1 = self.board.extent
        hit = np.isfinite(t) & (t > 0) & (pb[:, 0] >= x0) & (pb[:, 0] <= x1) \
            & (pb[:, 1] >= y0) & (pb[:, 1] <= y1)
        n = len(d)
        out_n = np.broadcast_to(-nrm, (n, 3)).copy()
        return {
            "t": np.where(hit, t, np.nan),
            "points": np.where(hit[:, None], p, np.nan),
            "normals": np.where(hit[:, None], out_n, np.nan),
            "surface_id": np.where(hit, 0, -1),
            "uv": np.where(hit[:, None], pb[:, :2], np.nan),
            "hit": hit,
        }

    def albedo(self, points: np.ndarray) -> np.ndarray:
        """Chessboard albedo (N, 3) at object-frame points (N, 3) on the board."""
        a = self.board.albedo_at(self.to_board(points))
        return np.repeat(a[:, None], 3, axis=1)

    def albedo_cell(self, points: np.ndarray, dx: np.ndarray, dy: np.ndarray) -> np.ndarray:
        """Mean chessboard albedo (N, 3) over cells at object-frame points (N, 3) with
        object-frame side vectors ``dx``, ``dy`` (N, 3) mm (:meth:`Chessboard.albedo_cell`)."""
        a = self.board.albedo_cell(self.to_board(points), np.asarray(dx, float) @ self.R,
                                   np.asarray(dy, float) @ self.R)
        return np.repeat(a[:, None], 3, axis=1)

    def to_dict(self) -> dict[str, Any]:
        return {"type": "nurbscan.board_scene", "version": 1, "board": self.board.to_dict(),
                "R": self.R.tolist(), "T": self.T.tolist()}


def _rot(axis: str, angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    if axis == "x":
        return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
    if axis == "y":
        return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


#: Free poses: (tilt about the board's x axis, about its y axis, in-plane turn) in degrees,
#: and the offset (mm, rig frame) of the board's centre from the aim point.
FREE_POSES = (
    ((0, 0, 0), (0, 0, 0)),
    ((25, 0, 3), (0, -15, 20)),
    ((-25, 0, -4), (0, 15, -20)),
    ((0, 28, 5), (-20, 0, 10)),
    ((0, -28, -3), (20, 0, -10)),
    ((18, 20, 8), (-10, -10, 30)),
    ((-18, -20, -8), (10, 10, -30)),
    ((20, -20, 12), (15, -10, 0)),
    ((-20, 20, -12), (-15, 10, 0)),
    ((10, 10, 30), (0, 0, 40)),
    ((-12, 12, -25), (0, 0, -40)),
    ((30, 8, 0), (5, 0, 15)),
)

#: Table angles (degrees) of the turntable poses (board on a stand on the table).
TABLE_POSE_ANGLES = (-40.0, 0.0, 40.0)


def free_board_poses(board: Chessboard, aim: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """The free poses (board to rig frame), facing the camera around the aim point ``aim``.

    Returns a list of (R, T) with X_rig = R P + T; the board's centre goes to ``aim`` plus the
    pose's offset, turned by the pose's tilts (varied, up to 30 degrees: a well-posed
    calibration, Zhang 2000).
    """
    x0, x1, y0, y1 = board.extent
    centre = np.array([(x0 + x1) / 2, (y0 + y1) / 2, 0.0])
    out = []
    for (ax, ay, az), off in FREE_POSES:
        r = _rot("x", math.radians(ax)) @ _rot("y", math.radians(ay)) @ _rot("z", math.radians(az))
        t = np.asarray(aim, float) + np.asarray(off, float) - r @ centre
        out.append((r, t))
    return out


def table_board_pose(board: Chessboard, lean: float = math.radians(45.0),
                     setback: float = 40.0) -> tuple[np.ndarray, np.ndarray]:
    """The board on the table, leaning back on a stand, facing the camera at table angle 0.

    Returns (R, T), board to object frame. The board's lower edge rests on the table top
    (z = 0), ``setback`` mm in front of the axis (towards the camera, +x), centred sideways; the
    board leans back by ``lean`` rad from the vertical (so that its top stays inside the
    projector's image and the camera, looking down, sees it nearly face on).
    """
    # upright: board x -> object y, board y -> object -z, board z -> object -x
    upright = np.array([[0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    c, s = math.cos(lean), math.sin(lean)
    tilt = np.array([[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]])  # about object y: top back
    r = tilt @ upright
    x0, x1, y0, y1 = board.extent
    bottom_mid = np.array([(x0 + x1) / 2, y1, 0.0])
    t = np.array([setback, 0.0, 0.0]) - r @ bottom_mid
    return r, t
