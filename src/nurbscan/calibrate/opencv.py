"""Calibration interchange with OpenCV's ``FileStorage`` YAML (issue #35).

A :class:`~nurbscan.camera.Rig` is written as ``cv2.stereoCalibrate`` describes a stereo pair,
camera = first camera, projector = second (a projector-camera pair calibrated elsewhere is read
the same way), and read back into a rig.

Keys
----
Written (``style="stereo"``, OpenCV's stereoCalibrate names) / (``style="procam"``, the
source project of /work/shared/real/procam-colour-grid, ``reference/calibration.yml``):

============  ===========  ================================================================
stereo        procam       meaning
============  ===========  ================================================================
``K1``        ``camK``     camera matrix ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]``, px
``D1``        ``camKc``    camera distortion ``(k1, k2, p1, p2, k3)`` (OpenCV's order)
``K2``        ``prjK``     projector matrix, px
``D2``        ``prjKc``    projector distortion
``R``         ``R``        rotation camera -> projector frame, ``x_prj = R x_cam + T``
``T``         ``T``        translation, mm (3 x 1)
``E``, ``F``  ``E``, ``F``  essential ``[T]_x R`` and fundamental ``K2^-T E K1^-1`` matrices
============  ===========  ================================================================

Read: either set, also ``M1``/``M2`` (OpenCV's stereo_calib sample) and ``cameraMatrix1``/
``distCoeffs1``/``cameraMatrix2``/``distCoeffs2`` (the Python names of stereoCalibrate's
results); distortion with 4, 5, 8, 12 or 14 coefficients; ``E``, ``F`` and anything else are
ignored. nurbscan adds (and reads when present) what OpenCV's file does not hold:
``camSize``/``prjSize`` (``[width, height]``, px), ``camPixelPitch``/``prjPixelPitch``
(``[dx, dy]``, mm/px) and ``turntablePoint``/``turntableDirection`` (the table axis in the
camera frame, mm).

Models
------
OpenCV's radial model maps undistorted to distorted normalised coordinates with up to three
radial and two tangential terms; Tsai's (nurbscan's, :mod:`nurbscan.camera`) has one radial
term from distorted to undistorted. Writing, OpenCV's ``k1, k2, k3`` are fitted to Tsai's
``k1`` (:meth:`Camera.to_opencv`, ``p1 = p2 = 0``); reading, Tsai's ``k1`` is fitted to OpenCV's
whole distortion by least squares over the image (:meth:`Camera.from_opencv`). ``R`` and
``T`` convert exactly, and so does ``K`` (``f = fy dy``, ``sx = fx dx / f``; the pixel pitch is
not in ``K`` and does not change any projection in px) when that leaves at most 0.01 px; with
tangential (``p1, p2``) or strong higher terms ``f``, ``sx``, ``Cx``, ``Cy`` and ``k1`` are
refitted together by least squares on the pixel distance over the image (a decentring
distortion is mostly a shift of the principal point). Each conversion's error, RMS and largest
distance in px between the two models over a grid of about 64 x 48 pixels covering the whole
image (corners and edges included, rays at 1 m), is returned in an :class:`OpenCVConversion`
and a :class:`UserWarning` is raised when the largest exceeds ``warn_px`` (0.1 px).
"""

from __future__ import annotations

import dataclasses
import math
import os
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..camera import Camera, Projector, Rig, Turntable
from ..errors import NurbscanError

__all__ = ["OpenCVConversion", "read_opencv", "write_opencv"]

STYLES = {"stereo": ("K1", "D1", "K2", "D2"), "procam": ("camK", "camKc", "prjK", "prjKc")}
_ALIASES = {
    "K1": ("K1", "camK", "M1", "cameraMatrix1"),
    "D1": ("D1", "camKc", "distCoeffs1"),
    "K2": ("K2", "prjK", "M2", "cameraMatrix2"),
    "D2": ("D2", "prjKc", "distCoeffs2"),
}
DEFAULT_PITCH = 0.0025  # mm/px; any value gives the same projections in px


@dataclass(frozen=True)
class OpenCVConversion:
    """A rig and the error of converting it between Tsai's and OpenCV's model.

    Attributes
    ----------
    rig : Rig
        The rig read (or the one written).
    camera_rms_px, camera_max_px, projector_rms_px, projector_max_px : float
        RMS and largest distance, px, between the Tsai and the OpenCV projection of the same
        rays over a grid covering each device's whole image.
    turntable : str
        Where the rig's turntable came from: ``"file"``, ``"given"`` or ``"placeholder"`` (not
        in the file: an axis through the point the two optical axes pass closest to, along
        the camera's -y; calibrate the table before a multi-view scan).
    """

    rig: Rig
    camera_rms_px: float
    camera_max_px: float
    projector_rms_px: float
    projector_max_px: float
    turntable: str = "file"

    def summary(self) -> str:
        """One line: the conversion errors."""
        note = {"file": "", "given": ", turntable given",
                "placeholder": ", turntable: placeholder (not in the file)"}[self.turntable]
        return (f"Tsai k1 <-> OpenCV distortion: camera RMS {self.camera_rms_px:.4f} px "
                f"(max {self.camera_max_px:.4f}), projector RMS {self.projector_rms_px:.4f} px "
                f"(max {self.projector_max_px:.4f}){note}")


def conversion_error(device: Camera, K, dist, grid: int = 64) -> tuple[float, float]:
    """``(rms_px, max_px)`` between Tsai's projection and ``cv2.projectPoints`` of the same rays.

    The rays are those of :meth:`Camera._grid_pixels` (Tsai's closed-form back-projection,
    paper eq. 6-8), taken at 1000 mm in the device frame; pixels past the fold of the model
    (``k1 < 0``) are left out.
    """
    import cv2

    cam = dataclasses.replace(device, R=np.eye(3), T=np.zeros(3))
    _, d = cam.back_project(cam._grid_pixels(grid))
    d = d[np.all(np.isfinite(d), axis=1)]
    pts = d / d[:, 2:3] * 1000.0
    cv_px = cv2.projectPoints(pts.reshape(-1, 1, 3), np.zeros(3), np.zeros(3),
                              np.asarray(K, float), np.asarray(dist, float))[0].reshape(-1, 2)
    e = np.hypot(*(cv_px - cam.project(pts)).T)
    if not len(e) or not np.all(np.isfinite(e)):
        return math.inf, math.inf
    return float(np.sqrt(np.mean(e * e))), float(e.max())


def write_opencv(rig: Rig, path: str | os.PathLike, style: str = "stereo",
                 warn_px: float = 0.1) -> OpenCVConversion:
    """Write a rig as OpenCV FileStorage YAML (keys in the module notes), atomically.

    Parameters
    ----------
    rig : Rig
        The rig; its camera frame becomes OpenCV's first camera frame.
    path : path-like
        Output file (``.yml`` / ``.yaml``).
    style : {"stereo", "procam"}
        Key names: stereoCalibrate's (``K1, D1, K2, D2``) or the source project's
        (``camK, camKc, prjK, prjKc``).
    warn_px : float
        Warn when a device's largest conversion error exceeds this, px.

    Returns
    -------
    OpenCVConversion
        The rig and the conversion error of each device (OpenCV's polynomial fitted to
        Tsai's ``k1``).

    Examples
    --------
    >>> import tempfile, cv2
    >>> from pathlib import Path
    >>> from nurbscan import Camera, Projector, Rig, Turntable, write_opencv
    >>> cam = Camera(width=640, height=480, f=8.0, cx=319.5, cy=239.5, dx=0.01, dy=0.01,
    ...              k1=1e-3)
    >>> prj = Projector(width=800, height=600, f=10.0, cx=399.5, cy=299.5, dx=0.01, dy=0.01,
    ...                 T=[-100.0, 0.0, 0.0])
    >>> rig = Rig(cam, prj, Turntable(point=[0, 50, 500], direction=[0, -1, 0]))
    >>> path = Path(tempfile.mkdtemp()) / "stereo.yml"
    >>> report = write_opencv(rig, path)
    >>> report.camera_max_px < 0.01
    True
    >>> fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    >>> float(fs.getNode("K1").mat()[0, 0]), fs.getNode("T").mat().ravel().tolist()
    (800.0, [-100.0, 0.0, 0.0])
    """
    import cv2

    if style not in STYLES:
        raise NurbscanError(f"style {style!r}: expected one of {', '.join(STYLES)}")
    k1n, d1n, k2n, d2n = STYLES[style]
    cam, prj = rig.camera, rig.projector
    K1, D1 = cam.opencv_matrix(), cam.to_opencv()[1]
    K2, D2 = prj.opencv_matrix(), prj.to_opencv()[1]
    R = prj.R @ cam.R.T
    T = prj.T - R @ cam.T
    tx = np.array([[0.0, -T[2], T[1]], [T[2], 0.0, -T[0]], [-T[1], T[0], 0.0]])
    E = tx @ R
    F = np.linalg.inv(K2).T @ E @ np.linalg.inv(K1)
    point = cam.R @ rig.turntable.point + cam.T
    direction = cam.R @ rig.turntable.direction
    fs = cv2.FileStorage(".yml", cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_MEMORY)
    for key, m in ((k1n, K1), (d1n, D1.reshape(1, -1)), (k2n, K2), (d2n, D2.reshape(1, -1)),
                   ("R", R), ("T", T.reshape(3, 1)), ("E", E), ("F", F),
                   ("camSize", np.array([[cam.width, cam.height]], float)),
                   ("prjSize", np.array([[prj.width, prj.height]], float)),
                   ("camPixelPitch", np.array([[cam.dx, cam.dy]])),
                   ("prjPixelPitch", np.array([[prj.dx, prj.dy]])),
                   ("turntablePoint", point.reshape(3, 1)),
                   ("turntableDirection", direction.reshape(3, 1))):
        fs.write(key, np.ascontiguousarray(m, dtype=np.float64))
    text = fs.releaseAndGetString()
    from ..io import write_text

    write_text(path, text)
    return _report(rig, K1, D1, K2, D2, "file", warn_px, str(path))


def read_opencv(path: str | os.PathLike, image_size: tuple[int, int] | None = None,
                projector_size: tuple[int, int] | None = None,
                camera_pitch: float | None = None, projector_pitch: float | None = None,
                turntable: Turntable | None = None, warn_px: float = 0.1) -> OpenCVConversion:
    """Read an OpenCV FileStorage stereo calibration (keys in the module notes) into a rig.

    Parameters
    ----------
    path : path-like
        The YAML (or XML / JSON) file.
    image_size, projector_size : (int, int), optional
        Camera and projector image ``(width, height)``, px (default: the file's ``camSize`` /
        ``prjSize``; an error when neither gives them).
    camera_pitch, projector_pitch : float, optional
        Pixel pitch, mm/px (default: the file's, else 0.0025; it scales ``f`` and ``k1`` but no
        projection in px).
    turntable : Turntable, optional
        The table axis in the camera frame (default: the file's, else a placeholder, see
        :class:`OpenCVConversion`).
    warn_px : float
        Warn when a device's largest conversion error exceeds this, px.

    Returns
    -------
    OpenCVConversion
        The rig (camera frame = rig frame) and each device's conversion error (Tsai's ``k1``
        fitted to OpenCV's distortion).

    Raises
    ------
    NurbscanError
        One line naming the file: missing, unreadable, a key missing or malformed.
    """
    import cv2

    path = Path(path)
    src = str(path)
    if not path.is_file():
        raise NurbscanError(f"{src}: not found")
    try:
        fs = cv2.FileStorage(src, cv2.FILE_STORAGE_READ)
        ok = fs.isOpened()
    except (cv2.error, SystemError):  # a parse error surfaces as either
        ok = False
    if not ok:
        raise NurbscanError(f"{src}: not an OpenCV FileStorage file (YAML, XML or JSON)")
    try:
        keys = set(fs.root().keys())

        def mat(names, shape=None, required=True):
            for n in names:
                if n in keys:
                    m = fs.getNode(n).mat()
                    if m is None:
                        raise NurbscanError(f"{src}: {n}: not a matrix")
                    m = np.asarray(m, float)
                    if shape is not None and m.size != math.prod(shape):
                        raise NurbscanError(f"{src}: {n}: expected {math.prod(shape)} values, "
                                            f"got shape {m.shape}")
                    if not np.all(np.isfinite(m)):
                        raise NurbscanError(f"{src}: {n}: contains non-finite values")
                    return m if shape is None else m.reshape(shape)
            if required:
                raise NurbscanError(f"{src}: missing key {' / '.join(names)}")
            return None

        K1, K2 = mat(_ALIASES["K1"], (3, 3)), mat(_ALIASES["K2"], (3, 3))
        D1 = mat(_ALIASES["D1"], required=False)
        D2 = mat(_ALIASES["D2"], required=False)
        R, T = mat(("R",)), mat(("T",), (3,))
        cam_size = _size(image_size, mat(("camSize",), (2,), False), src, "camera image size",
                         "--image-size W H")
        prj_size = _size(projector_size, mat(("prjSize",), (2,), False), src,
                         "projector image size", "--projector-size W H")
        cam_pitch = _pitch(camera_pitch, mat(("camPixelPitch",), (2,), False))
        prj_pitch = _pitch(projector_pitch, mat(("prjPixelPitch",), (2,), False))
        tp = mat(("turntablePoint",), (3,), False)
        td = mat(("turntableDirection",), (3,), False)
    except cv2.error as exc:  # a node of the wrong kind (a string where a matrix is)
        msg = (exc.err or str(exc)).strip().splitlines()[0]
        raise NurbscanError(f"{src}: not an OpenCV calibration of the expected form "
                            f"({msg})") from None
    finally:
        fs.release()
    D1 = np.zeros(5) if D1 is None else D1.ravel()
    D2 = np.zeros(5) if D2 is None else D2.ravel()
    try:
        cam = _from_opencv(Camera, K1, D1, np.eye(3), np.zeros(3), cam_size, cam_pitch)
        prj = _from_opencv(Projector, K2, D2, R, T, prj_size, prj_pitch)
        if turntable is not None:
            table, origin = turntable, "given"
        elif tp is not None and td is not None:
            table, origin = Turntable(point=tp, direction=td), "file"
        else:
            table, origin = _placeholder_table(cam, prj), "placeholder"
        rig = Rig(cam, prj, table)
    except NurbscanError as exc:
        raise NurbscanError(f"{src}: {exc}") from None
    return _report(rig, K1, D1, K2, D2, origin, warn_px, src)


def _from_opencv(cls, K, dist, R, T, size, pitch, exact_px: float = 0.01):
    """Tsai's model of an OpenCV device: :meth:`Camera.from_opencv` (exact ``K``, ``k1`` fitted);
    when that leaves more than ``exact_px`` (tangential or strong higher terms), ``f``, ``sx``,
    ``Cx``, ``Cy`` and ``k1`` are refitted jointly to OpenCV's image of the same rays
    (:func:`_refit`): a decentring distortion is mostly a shift of the principal point."""
    dev, _ = cls.from_opencv(K, dist, R, T, *size, dx=pitch[0], dy=pitch[1])
    if conversion_error(dev, K, dist)[1] <= exact_px:
        return dev
    better = _refit(dev, K, dist)
    return better if conversion_error(better, K, dist)[0] < conversion_error(dev, K, dist)[0] \
        else dev


def _refit(dev: Camera, K, dist, grid: int = 64) -> Camera:
    """Least squares (scipy, trust region) of ``f, sx, Cx, Cy, k1`` on the pixel distance
    between Tsai's projection and ``cv2.projectPoints`` of rays over the whole image."""
    import cv2
    from scipy.optimize import least_squares

    K = np.asarray(K, float)
    dist = np.asarray(dist, float)
    px = dev._grid_pixels(grid)
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-14)
    if hasattr(cv2, "undistortPointsIter"):  # OpenCV 4
        norm = cv2.undistortPointsIter(px.reshape(-1, 1, 2), K, dist, None, None, crit)
    else:  # OpenCV 5
        norm = cv2.undistortPoints(px.reshape(-1, 1, 2), K, dist, None, None, None, crit)
    rays = np.column_stack([norm.reshape(-1, 2), np.ones(len(px))]) * 1000.0
    target = cv2.projectPoints(rays.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K,
                               dist)[0].reshape(-1, 2)
    ok = np.all(np.isfinite(target), axis=1)
    rays, target = rays[ok], target[ok]
    r_max2 = float(np.max(np.sum(dev.pixel_to_sensor(px) ** 2, axis=1)))
    base = dataclasses.replace(dev, R=np.eye(3), T=np.zeros(3))

    def make(x):
        return dataclasses.replace(base, f=dev.f * x[0], sx=dev.sx * x[1], cx=dev.cx + x[2],
                                   cy=dev.cy + x[3], k1=x[4] / r_max2)

    def residual(x):
        r = (make(x).project(rays) - target).ravel()
        return np.where(np.isfinite(r), r, 1e3)

    x0 = np.array([1.0, 1.0, 0.0, 0.0, dev.k1 * r_max2])
    sol = least_squares(residual, x0, x_scale=[1e-3, 1e-3, 1.0, 1.0, 1e-3], method="trf")
    return dataclasses.replace(make(sol.x), R=dev.R, T=dev.T)


def _report(rig, K1, D1, K2, D2, origin, warn_px, src) -> OpenCVConversion:
    c_rms, c_max = conversion_error(rig.camera, K1, D1)
    p_rms, p_max = conversion_error(rig.projector, K2, D2)
    rep = OpenCVConversion(rig, c_rms, c_max, p_rms, p_max, origin)
    if max(c_max, p_max) > warn_px:
        warnings.warn(f"{src}: {rep.summary()}: Tsai's single radial term cannot hold "
                      "OpenCV's distortion exactly", UserWarning, stacklevel=3)
    return rep


def _size(given, stored, src, what, option) -> tuple[int, int]:
    v = given if given is not None else (None if stored is None else stored.tolist())
    if v is None:
        raise NurbscanError(f"{src}: no {what} in the file; give it ({option})")
    try:
        w, h = (int(round(float(x))) for x in v)
    except (TypeError, ValueError):
        raise NurbscanError(f"{src}: {what} {v!r}: expected (width, height)") from None
    if w < 1 or h < 1:
        raise NurbscanError(f"{src}: {what} {v!r}: must be positive")
    return w, h


def _pitch(given, stored) -> tuple[float, float]:
    if given is not None:
        return float(given), float(given)
    if stored is not None:
        return float(stored[0]), float(stored[1])
    return DEFAULT_PITCH, DEFAULT_PITCH


def _placeholder_table(cam: Camera, prj: Projector) -> Turntable:
    """An axis along the camera's -y through the point where the optical axes pass closest
    (on the camera axis; 500 mm in front of the camera when they do not converge)."""
    c1, a1 = cam.center, cam.axis
    c2, a2 = prj.center, prj.axis
    w = c1 - c2
    b = float(a1 @ a2)
    den = 1.0 - b * b
    t = (b * float(a2 @ w) - float(a1 @ w)) / den if den > 1e-9 else 500.0
    t = t if 10.0 < t < 1e5 else 500.0
    return Turntable(point=c1 + t * a1, direction=-cam.R[1])
