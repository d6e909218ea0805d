"""The default scanner rig of the synthetic scanner, and scaled-down copies for quick runs.

The default rig is close to the paper's set-up: a 7.1 MP colour camera (3072 x 2304, 2.3 um
pixels, f = 12.5 mm) looking 20 degrees down onto a turntable, and a 1920 x 1080 DLP-style
projector (7.56 um micromirrors, f = 24 mm, principal point near the bottom edge of its image,
so that it throws its image above its optical axis, as office projectors do) beside the camera.
Both are Tsai models (method.md section 4) with moderate radial distortion: a corner pixel of
the camera moves by about 4 px, one of the projector by about 5 px.

Geometry (rig frame = camera frame, mm): the teapot's middle, 58.5 mm above the table top, sits
on the camera's optical axis at 600 mm. The projector's centre is 620 mm from that point,
turned 22 degrees about the vertical (the table axis) to the camera's right and raised 8
degrees; its pixel (960, 540) is aimed at the same point. The angle between the camera's and
the projector's optical axes is 20.6 degrees (:func:`axis_angle`); the triangulation angle at
the object's middle is 22.6 degrees. Across 8 table angles the teapot spans up to 76 % of the
camera's width and stays inside both images.
"""

from __future__ import annotations

import math

import numpy as np

from ..camera import Camera, Projector, Rig, Turntable

#: Working distance from the camera's centre to the middle of the object, mm.
WORKING_DISTANCE = 600.0
#: Camera tilt below the horizontal, radians.
CAMERA_TILT = math.radians(20.0)
#: Height of the aim point (the teapot's middle) above the table top, mm.
AIM_HEIGHT = 58.5
#: Projector placement: distance to the aim point (mm), turn about the vertical and elevation
#: relative to the camera's line of sight (radians).
PROJECTOR_DISTANCE = 620.0
PROJECTOR_TURN = math.radians(22.0)
PROJECTOR_RAISE = math.radians(8.0)


def _rodrigues(axis: np.ndarray, angle: float) -> np.ndarray:
    """Rotation matrix by ``angle`` (rad) about the unit vector ``axis`` (right-hand rule)."""
    k = np.asarray(axis, float) / np.linalg.norm(axis)
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(angle) * kx + (1 - math.cos(angle)) * kx @ kx


def _align(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The smallest rotation taking the direction ``a`` onto the direction ``b``."""
    a = a / np.linalg.norm(a)
    b = b / np.linalg.norm(b)
    ax = np.cross(a, b)
    s = np.linalg.norm(ax)
    if s < 1e-15:
        return np.eye(3)
    return _rodrigues(ax / s, math.atan2(s, float(a @ b)))


def _look_at(centre: np.ndarray, target: np.ndarray, down: np.ndarray) -> np.ndarray:
    """R (world to device) of a device at ``centre`` whose z axis points at ``target``.

    The device's y axis (image down) is the component of ``down`` perpendicular to z;
    x = y cross z (x right, y down, z forward: docs/conventions.md).
    """
    z = target - centre
    z = z / np.linalg.norm(z)
    y = down - (down @ z) * z
    y = y / np.linalg.norm(y)
    x = np.cross(y, z)
    return np.stack([x, y, z])


def up_vector(tilt: float = CAMERA_TILT) -> np.ndarray:
    """The table's up direction in the frame of a camera tilted ``tilt`` rad down."""
    return np.array([0.0, -math.cos(tilt), -math.sin(tilt)])


def default_rig() -> Rig:
    """The default rig (see the module notes): camera, projector and turntable, in mm.

    Returns
    -------
    Rig
        Camera 3072 x 2304, f = 12.5 mm, pixels 2.3 um, k1 = 1.0e-4 mm^-2 (R = I, T = 0);
        projector 1920 x 1080, f = 24 mm, pixels 7.56 um, principal point (960, 1000),
        k1 = 3.0e-5 mm^-2; turntable axis through the table centre, pointing up.
    """
    up = up_vector()
    aim = np.array([0.0, 0.0, WORKING_DISTANCE])
    table = aim - AIM_HEIGHT * up
    camera = Camera(
        width=3072, height=2304, f=12.5, cx=1539.3, cy=1148.6, dx=0.0023, dy=0.0023,
        sx=1.0, k1=1.0e-4, R=np.eye(3), T=np.zeros(3), name="camera",
    )
    # projector centre: the camera's line of sight from the aim point, turned about the
    # vertical and raised
    to_cam = -aim / np.linalg.norm(aim)
    side = np.cross(up, to_cam)
    side /= np.linalg.norm(side)
    d = _rodrigues(up, PROJECTOR_TURN) @ to_cam
    d = _rodrigues(np.cross(d, up), -PROJECTOR_RAISE) @ d
    centre = aim + PROJECTOR_DISTANCE * d
    width, height, f, dx = 1920, 1080, 24.0, 0.00756
    cx, cy = 960.0, 1000.0
    r0 = _look_at(centre, aim, -up)
    # the ray of pixel (960, 540) must run along r0's z axis
    ray = np.array([(960.0 - cx) * dx / f, (540.0 - cy) * dx / f, 1.0])
    rot = _align(np.array([0.0, 0.0, 1.0]), ray) @ r0
    projector = Projector(
        width=width, height=height, f=f, cx=cx, cy=cy, dx=dx, dy=dx, sx=1.0, k1=3.0e-5,
        R=rot, T=-rot @ centre, name="projector",
    )
    turntable = Turntable(point=table, direction=up)
    return Rig(camera=camera, projector=projector, turntable=turntable)


def _scaled(cam, width: int, height: int):
    """A copy of a Tsai camera with the same field of view at ``width`` x ``height`` px."""
    sx_ = cam.width / width
    sy_ = cam.height / height
    return type(cam)(
        width=int(width), height=int(height), f=cam.f,
        cx=(cam.cx + 0.5) / sx_ - 0.5, cy=(cam.cy + 0.5) / sy_ - 0.5,
        dx=cam.dx * sx_, dy=cam.dy * sy_, sx=cam.sx, k1=cam.k1, R=cam.R, T=cam.T,
        name=cam.name,
    )


def scale_camera(rig: Rig, width: int, height: int) -> Rig:
    """The rig with its camera resampled to ``width`` x ``height`` px, same field of view.

    The sensor keeps its size: the pixel pitch grows by the size ratio, the principal point
    moves with the pixel grid (pixel centres at integers: c' = (c + 0.5) / s - 0.5); f and
    k1 (mm^-2) are unchanged, so the camera sees the same scene through fewer, larger pixels.
    For quick runs and tests.
    """
    from ..errors import NurbscanError

    if int(width) < 16 or int(height) < 16:
        raise NurbscanError(f"camera size {width} x {height}: must be at least 16 x 16 px")
    return Rig(camera=_scaled(rig.camera, width, height), projector=rig.projector,
               turntable=rig.turntable)


def axis_angle(rig: Rig) -> float:
    """Angle between the camera's and the projector's optical axes, radians."""
    zc = np.asarray(rig.camera.R)[2]
    zp = np.asarray(rig.projector.R)[2]
    return float(np.arccos(np.clip(zc @ zp, -1.0, 1.0)))
