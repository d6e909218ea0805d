"""Tsai's camera model, for the camera and, used the other way, for the projector.

Implements the model of Tsai (1987) exactly as written in ``docs/conventions.md`` and the
method's section 4 (the paper's eq. 6-8):

* world to camera: ``x = R X + T`` (mm);
* pinhole: ``Xu = f x / z``, ``Yu = f y / z`` (mm on the sensor);
* one radial term, written from *distorted* to *undistorted*:
  ``Xu = Xd (1 + k1 r^2)``, ``Yu = Yd (1 + k1 r^2)``, ``r^2 = Xd^2 + Yd^2`` (``k1`` in mm^-2);
* pixels: ``Xf = sx Xd / dx + Cx``, ``Yf = Yd / dy + Cy``.

Back-projection is closed form. Projection inverts the distortion, the cubic
``k1 rd^3 + rd - ru = 0`` in the distorted radius, by a vectorised Newton iteration that
converges monotonically from ``rd = ru`` (the cubic is convex for ``k1 > 0`` and concave for
``k1 < 0`` on the valid branch). For ``k1 < 0`` the undistorted radius has a maximum
``ru_max = 2 / (3 sqrt(3 |k1|))`` at ``rd = 1 / sqrt(3 |k1|)``; points beyond it are outside the
model's domain and are reported invalid.

OpenCV's model runs the other way (undistorted to distorted, a polynomial in the undistorted
radius), so the two are not the same model: :meth:`Camera.to_opencv` and
:meth:`Camera.from_opencv` convert by a least-squares fit over the image and return the largest
disagreement in pixels. Tsai's model is written here by hand because no maintained library
implements it with this sign convention.

References
----------
.. [1] R. Y. Tsai, "A versatile camera calibration technique for high-accuracy 3D machine
   vision metrology using off-the-shelf TV cameras and lenses", IEEE J. Robotics and
   Automation 3(4), 1987.
"""

from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from .errors import NurbscanError

__all__ = ["Camera", "Projector", "Rig", "Turntable", "load_rig", "rotation_matrix"]


def _frozen_array(value, shape: tuple[int, ...], name: str) -> np.ndarray:
    arr = np.array(value, dtype=float)
    if arr.shape != shape:
        raise NurbscanError(f"{name}: expected shape {shape}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise NurbscanError(f"{name}: contains non-finite values")
    arr.setflags(write=False)
    return arr


def rotation_matrix(axis, angle: float) -> np.ndarray:
    """Rotation by ``angle`` (radians) about ``axis`` (right-hand rule; Rodrigues' formula).

    Returns
    -------
    ndarray, shape (3, 3)
    """
    a = np.asarray(axis, float)
    a = a / np.linalg.norm(a)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1.0 - np.cos(angle)) * (K @ K)


def distorted_radius(ru, k1: float, iterations: int = 60) -> tuple[np.ndarray, np.ndarray]:
    """Solve Tsai's radial cubic ``rd (1 + k1 rd^2) = ru`` for the distorted radius.

    Parameters
    ----------
    ru : ndarray
        Undistorted radii, mm (>= 0).
    k1 : float
        Radial coefficient, mm^-2.

    Returns
    -------
    rd : ndarray
        Distorted radii, mm (NaN outside the domain).
    valid : ndarray of bool
        False where ``k1 < 0`` and ``ru`` exceeds the model's maximum undistorted radius.
    """
    ru = np.asarray(ru, float)
    valid = np.isfinite(ru)
    if k1 == 0.0:
        return ru.copy(), valid
    if k1 < 0.0:
        r_turn = 1.0 / np.sqrt(-3.0 * k1)
        valid &= ru < (2.0 / 3.0) * r_turn
    rd = np.where(valid, ru, 0.0)
    target = np.where(valid, ru, 0.0)
    for _ in range(iterations):
        g = rd * (1.0 + k1 * rd * rd) - target
        step = g / (1.0 + 3.0 * k1 * rd * rd)
        rd = rd - step
        if np.all(np.abs(step) <= 1e-15 * np.maximum(rd, 1e-300)):
            break
    return np.where(valid, rd, np.nan), valid


@dataclass(frozen=True)
class Camera:
    """Tsai's pinhole camera with one radial distortion term (Tsai 1987).

    Parameters
    ----------
    width, height : int
        Image size, px.
    f : float
        Focal length, mm.
    cx, cy : float
        Principal point (Tsai's Cx, Cy), px, pixel centres at integer coordinates.
    dx, dy : float
        Pixel pitch, mm/px.
    sx : float
        Horizontal scale factor (dimensionless).
    k1 : float
        Radial distortion, mm^-2, from distorted to undistorted sensor coordinates.
    R : array_like, shape (3, 3)
        World-to-camera rotation (orthonormal, det +1).
    T : array_like, shape (3,)
        World-to-camera translation, mm.
    name : str
        A label.
    """

    width: int
    height: int
    f: float
    cx: float
    cy: float
    dx: float = 0.0025
    dy: float = 0.0025
    sx: float = 1.0
    k1: float = 0.0
    R: np.ndarray = field(default_factory=lambda: np.eye(3))
    T: np.ndarray = field(default_factory=lambda: np.zeros(3))
    name: str = "camera"

    TYPE: ClassVar[str] = "nurbscan.camera"

    def __post_init__(self) -> None:
        label = self.name
        for key in ("width", "height"):
            v = getattr(self, key)
            if int(v) != v or v <= 0:
                raise NurbscanError(f"{label}: {key} must be a positive integer, got {v}")
            object.__setattr__(self, key, int(v))
        for key in ("f", "dx", "dy", "sx"):
            v = float(getattr(self, key))
            if not np.isfinite(v) or v <= 0:
                raise NurbscanError(f"{label}: {key} must be positive, got {v}")
            object.__setattr__(self, key, v)
        for key in ("cx", "cy", "k1"):
            v = float(getattr(self, key))
            if not np.isfinite(v):
                raise NurbscanError(f"{label}: {key} must be finite, got {v}")
            object.__setattr__(self, key, v)
        R = _frozen_array(self.R, (3, 3), f"{label}.R")
        if np.abs(R @ R.T - np.eye(3)).max() > 1e-9 or abs(np.linalg.det(R) - 1.0) > 1e-9:
            raise NurbscanError(f"{label}.R: not a rotation matrix (orthonormal, det +1)")
        object.__setattr__(self, "R", R)
        object.__setattr__(self, "T", _frozen_array(self.T, (3,), f"{label}.T"))

    # -- frames -------------------------------------------------------------------------
    @property
    def center(self) -> np.ndarray:
        """Optical centre in the world frame, ``-R^T T``, mm, shape (3,)."""
        return -self.R.T @ self.T

    @property
    def axis(self) -> np.ndarray:
        """Unit optical axis (camera +z) in the world frame, shape (3,)."""
        return self.R[2].copy()

    def to_camera(self, points) -> np.ndarray:
        """World points (..., 3) mm to the camera frame: ``x = R X + T``."""
        return np.asarray(points, float) @ self.R.T + self.T

    def with_pose(self, R, T) -> Camera:
        """A copy with another world-to-camera pose."""
        return dataclasses.replace(self, R=R, T=T)

    # -- sensor / pixel -------------------------------------------------------------------
    def pixel_to_sensor(self, pixels) -> np.ndarray:
        """Pixels (..., 2) to distorted sensor coordinates (Xd, Yd), mm."""
        px = np.asarray(pixels, float)
        return np.stack([(px[..., 0] - self.cx) * self.dx / self.sx,
                         (px[..., 1] - self.cy) * self.dy], axis=-1)

    def sensor_to_pixel(self, xy) -> np.ndarray:
        """Distorted sensor coordinates (..., 2), mm, to pixels."""
        xy = np.asarray(xy, float)
        return np.stack([self.sx * xy[..., 0] / self.dx + self.cx,
                         xy[..., 1] / self.dy + self.cy], axis=-1)

    def undistort(self, xd, yd) -> tuple[np.ndarray, np.ndarray]:
        """Tsai's radial term, distorted to undistorted sensor mm: ``Xu = Xd (1 + k1 r^2)``."""
        xd = np.asarray(xd, float)
        yd = np.asarray(yd, float)
        s = 1.0 + self.k1 * (xd * xd + yd * yd)
        return xd * s, yd * s

    def distort(self, xu, yu, return_valid: bool = False):
        """Inverse of :meth:`undistort`: undistorted to distorted sensor mm (the cubic in r).

        Returns ``(xd, yd)``, NaN outside the model's domain; with ``return_valid`` also the
        boolean mask of points inside it.
        """
        xu = np.asarray(xu, float)
        yu = np.asarray(yu, float)
        ru = np.hypot(xu, yu)
        rd, valid = distorted_radius(ru, self.k1)
        scale = np.where(ru > 0, rd / np.where(ru > 0, ru, 1.0), 1.0)
        out = (xu * scale, yu * scale)
        return (*out, valid) if return_valid else out

    # -- projection ----------------------------------------------------------------------
    def project(self, points, return_valid: bool = False):
        """Pixels of world points (Tsai's forward model).

        Parameters
        ----------
        points : array_like, shape (..., 3)
            World points, mm.
        return_valid : bool
            Also return the mask of points that project (in front of the camera, z > 0, and
            inside the distortion model's domain).

        Returns
        -------
        pixels : ndarray, shape (..., 2)
            Image coordinates, px; NaN where the point does not project.
        valid : ndarray of bool, shape (...)
            Only with ``return_valid``.
        """
        pc = self.to_camera(points)
        z = pc[..., 2]
        front = z > 0
        zs = np.where(front, z, 1.0)
        xd, yd, inside = self.distort(self.f * pc[..., 0] / zs, self.f * pc[..., 1] / zs,
                                      return_valid=True)
        valid = front & inside
        px = self.sensor_to_pixel(np.stack([xd, yd], axis=-1))
        px[~valid] = np.nan
        return (px, valid) if return_valid else px

    def back_project(self, pixels) -> tuple[np.ndarray, np.ndarray]:
        """Rays of pixels, closed form (the paper's eq. 6-8).

        Pixel -> distorted sensor (Xd, Yd) -> undistorted (Xu, Yu) -> the ray from the optical
        centre through (Xu, Yu, f) in the camera frame, turned into the world frame.

        Parameters
        ----------
        pixels : array_like, shape (..., 2)

        Returns
        -------
        origin : ndarray, shape (3,)
            Optical centre in the world frame, mm.
        directions : ndarray, shape (..., 3)
            Unit ray directions in the world frame.
        """
        sensor = self.pixel_to_sensor(pixels)
        xu, yu = self.undistort(sensor[..., 0], sensor[..., 1])
        d = np.stack([xu, yu, np.full_like(xu, self.f)], axis=-1)
        d = d @ self.R  # R^T d, for row vectors
        d /= np.linalg.norm(d, axis=-1, keepdims=True)
        return self.center, d

    # -- JSON ----------------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict (``"type"`` names the class)."""
        return {
            "type": self.TYPE, "version": 1, "name": self.name,
            "width": self.width, "height": self.height, "f": self.f, "cx": self.cx,
            "cy": self.cy, "dx": self.dx, "dy": self.dy, "sx": self.sx, "k1": self.k1,
            "R": self.R.tolist(), "T": self.T.tolist(),
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Camera:
        """Inverse of :meth:`to_dict`; a missing key raises :class:`NurbscanError`."""
        if not isinstance(d, dict):
            raise NurbscanError(f"{cls.TYPE}: expected an object, got {type(d).__name__}")
        if d.get("type", cls.TYPE) not in (Camera.TYPE, Projector.TYPE):
            raise NurbscanError(f"{cls.TYPE}: wrong type {d.get('type')!r}")
        keys = [f.name for f in dataclasses.fields(cls)]
        missing = [k for k in ("width", "height", "f", "cx", "cy") if k not in d]
        if missing:
            raise NurbscanError(f"{cls.TYPE}: missing key(s) {', '.join(missing)}")
        return cls(**{k: d[k] for k in keys if k in d})

    # -- OpenCV --------------------------------------------------------------------------
    def _grid(self, n: int = 41) -> np.ndarray:
        u = np.linspace(-0.5, self.width - 0.5, n)
        v = np.linspace(-0.5, self.height - 0.5, n)
        return np.stack(np.meshgrid(u, v), axis=-1).reshape(-1, 2)

    def to_opencv(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float]:
        """OpenCV's pinhole model closest to this camera.

        ``K = [[f sx / dx, 0, Cx], [0, f / dy, Cy], [0, 0, 1]]`` is exact. OpenCV distorts
        *undistorted* normalised coordinates by ``1 + k1 r^2 + k2 r^4 + k3 r^6``; that
        polynomial is fitted by linear least squares to Tsai's inverse distortion on a 41 x 41
        grid over the image (tangential terms zero).

        Returns
        -------
        K : ndarray (3, 3)
        dist : ndarray (5,)
            OpenCV's ``(k1, k2, p1, p2, k3)``.
        rvec, tvec : ndarray (3,)
            Rodrigues vector of ``R`` and ``T``.
        max_error : float
            Largest pixel distance between ``cv2.projectPoints`` with these and
            :meth:`project`, over the grid.
        """
        import cv2

        K = np.array([[self.f * self.sx / self.dx, 0, self.cx], [0, self.f / self.dy, self.cy],
                      [0, 0, 1.0]])
        sensor = self.pixel_to_sensor(self._grid())
        xu, yu = self.undistort(sensor[:, 0], sensor[:, 1])
        ru = np.hypot(xu, yu) / self.f
        rd = np.hypot(sensor[:, 0], sensor[:, 1]) / self.f
        keep = ru > 1e-9
        A = np.stack([ru**2, ru**4, ru**6], axis=1)[keep]
        coef = np.linalg.lstsq(A, rd[keep] / ru[keep] - 1.0, rcond=None)[0]
        dist = np.array([coef[0], coef[1], 0.0, 0.0, coef[2]])
        rvec = cv2.Rodrigues(self.R)[0].ravel()
        pts = np.stack([xu / self.f, yu / self.f, np.ones_like(xu)], axis=1)
        world = (pts - self.T) @ self.R  # camera-frame points at z = 1, to the world frame
        cv_px = cv2.projectPoints(world, rvec, self.T, K, dist)[0].reshape(-1, 2)
        err = float(np.max(np.linalg.norm(cv_px - self.project(world), axis=1)))
        return K, dist, rvec, self.T.copy(), err

    @classmethod
    def from_opencv(cls, K, dist, R, tvec, width: int, height: int, dx: float = 0.0025,
                    dy: float | None = None, name: str | None = None) -> tuple[Camera, float]:
        """Tsai camera closest to an OpenCV camera (K, distortion, pose).

        ``f = K[1, 1] dy`` and ``sx = K[0, 0] dx / f`` (the pitch ``dx, dy`` is not identifiable
        from images and must be given; ``dy`` defaults to ``dx``). Tsai's ``k1`` is fitted by
        least squares to OpenCV's radial distortion, inverted by Newton's method, over a
        41 x 41 grid of the image; tangential terms are ignored.

        Parameters
        ----------
        R : array_like
            Rotation matrix (3, 3) or Rodrigues vector (3,).

        Returns
        -------
        camera : Camera
        max_error : float
            Largest pixel distance between the two models' projections over the grid.
        """
        import cv2

        K = np.asarray(K, float)
        dist = np.zeros(5) if dist is None else np.asarray(dist, float).ravel()
        R = np.asarray(R, float)
        if R.shape != (3, 3):
            R = cv2.Rodrigues(R.reshape(3))[0]
        dy = dx if dy is None else dy
        f = K[1, 1] * dy
        sx = K[0, 0] * dx / f
        proto = cls(width=width, height=height, f=f, cx=K[0, 2], cy=K[1, 2], dx=dx, dy=dy,
                    sx=sx, R=R, T=np.asarray(tvec, float).reshape(3),
                    **({"name": name} if name else {}))
        grid = proto._grid()
        und = _opencv_undistort_radial(grid, K, dist)
        sensor = proto.pixel_to_sensor(grid)
        rd = np.hypot(sensor[:, 0], sensor[:, 1])
        ru = np.hypot(und[:, 0], und[:, 1]) * f
        keep = rd > 1e-9
        k1 = float(np.sum((ru / rd - 1.0)[keep] * rd[keep] ** 2) / np.sum(rd[keep] ** 4))
        cam = dataclasses.replace(proto, k1=k1)
        pts = np.concatenate([und, np.ones((len(und), 1))], axis=1)
        world = (pts - cam.T) @ cam.R
        err = float(np.nanmax(np.linalg.norm(cam.project(world) - grid, axis=1)))
        return cam, err


def _opencv_undistort_radial(pixels: np.ndarray, K: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """Undistorted normalised coordinates (N, 2) of pixels under OpenCV's radial model.

    Solves ``rd = ru (1 + k1 ru^2 + k2 ru^4 + k3 ru^6)`` for ``ru`` by Newton's method
    (tangential terms ignored).
    """
    k1, k2, k3 = dist[0], dist[1], (dist[4] if len(dist) > 4 else 0.0)
    xd = (pixels[:, 0] - K[0, 2]) / K[0, 0]
    yd = (pixels[:, 1] - K[1, 2]) / K[1, 1]
    rd = np.hypot(xd, yd)
    ru = rd.copy()
    for _ in range(50):
        r2 = ru * ru
        g = ru * (1 + r2 * (k1 + r2 * (k2 + r2 * k3))) - rd
        dg = 1 + r2 * (3 * k1 + r2 * (5 * k2 + 7 * k3 * r2))
        ru = ru - g / dg
    scale = np.where(rd > 0, ru / np.where(rd > 0, rd, 1.0), 1.0)
    return np.stack([xd * scale, yd * scale], axis=1)


@dataclass(frozen=True)
class Projector(Camera):
    """The projector: Tsai's model used as an inverse camera.

    :meth:`project` gives the projector pixel that lights a world point; :meth:`back_project`
    the light ray of a projector pixel.
    """

    name: str = "projector"
    TYPE: ClassVar[str] = "nurbscan.projector"


@dataclass(frozen=True)
class Turntable:
    """A turntable: its axis through ``point`` (mm, rig frame) along the unit ``direction``.

    ``direction`` points up, out of the table top; a table angle turns the table about it by
    the right-hand rule. The object (table) frame is defined in ``docs/conventions.md``.
    """

    point: np.ndarray
    direction: np.ndarray

    TYPE: ClassVar[str] = "nurbscan.turntable"

    def __post_init__(self) -> None:
        object.__setattr__(self, "point", _frozen_array(self.point, (3,), "turntable.point"))
        d = np.array(self.direction, float)
        n = np.linalg.norm(d) if d.shape == (3,) else 0.0
        if not n > 0:
            raise NurbscanError("turntable.direction: must be a non-zero 3-vector")
        object.__setattr__(self, "direction", _frozen_array(d / n, (3,), "turntable.direction"))

    def rotation(self, angle: float) -> np.ndarray:
        """Rotation (3, 3) of the table by ``angle`` radians about its axis."""
        return rotation_matrix(self.direction, angle)

    def frame(self) -> np.ndarray:
        """Columns ``x_t, y_t, z_t`` of the object frame in the rig frame, shape (3, 3).

        ``z_t`` is the axis; ``x_t`` the part of the rig's -z axis (towards the camera)
        perpendicular to it; ``y_t = z_t x x_t``.
        """
        z = self.direction
        x = np.array([0.0, 0.0, -1.0]) - z * (-z[2])
        if np.linalg.norm(x) < 1e-9:  # axis along the optical axis: fall back to rig x
            x = np.array([1.0, 0.0, 0.0]) - z * z[0]
        x /= np.linalg.norm(x)
        return np.stack([x, np.cross(z, x), z], axis=1)

    def to_rig(self, points_obj, angle: float) -> np.ndarray:
        """Object-frame points (..., 3) to the rig frame at table angle ``angle``."""
        M = self.rotation(angle) @ self.frame()
        return np.asarray(points_obj, float) @ M.T + self.point

    def from_rig(self, points_rig, angle: float) -> np.ndarray:
        """Rig-frame points (..., 3) to the object frame at table angle ``angle``."""
        M = self.rotation(angle) @ self.frame()
        return (np.asarray(points_rig, float) - self.point) @ M

    def to_dict(self) -> dict[str, Any]:
        return {"type": self.TYPE, "version": 1, "point": self.point.tolist(),
                "direction": self.direction.tolist()}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Turntable:
        try:
            return cls(point=d["point"], direction=d["direction"])
        except (KeyError, TypeError) as exc:
            raise NurbscanError(f"{cls.TYPE}: missing or bad key {exc}") from None


@dataclass(frozen=True)
class Rig:
    """A scanner: camera, projector and turntable, all in the rig frame (the camera's frame)."""

    camera: Camera
    projector: Projector
    turntable: Turntable

    TYPE: ClassVar[str] = "nurbscan.rig"

    def to_dict(self) -> dict[str, Any]:
        return {"type": self.TYPE, "version": 1, "camera": self.camera.to_dict(),
                "projector": self.projector.to_dict(), "turntable": self.turntable.to_dict()}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Rig:
        if not isinstance(d, dict) or d.get("type") != cls.TYPE:
            kind = d.get("type") if isinstance(d, dict) else type(d).__name__
            raise NurbscanError(f"not a rig file (type {kind!r})")
        try:
            return cls(camera=Camera.from_dict(d["camera"]),
                       projector=Projector.from_dict(d["projector"]),
                       turntable=Turntable.from_dict(d["turntable"]))
        except KeyError as exc:
            raise NurbscanError(f"rig: missing key {exc}") from None

    def save(self, path: str | os.PathLike) -> Path:
        """Write the rig as JSON, atomically."""
        from .io import write_json

        return write_json(path, self.to_dict())


def load_rig(path: str | os.PathLike) -> Rig:
    """Read a rig JSON file; errors name the file."""
    from .io import read_json

    try:
        return Rig.from_dict(read_json(path))
    except NurbscanError as exc:
        msg = str(exc)
        raise NurbscanError(msg if msg.startswith(str(path)) else f"{path}: {msg}") from None
