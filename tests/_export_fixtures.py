"""Shared fixtures of tests/test_export.py and tests/test_report.py: small model folders.

A sphere of radius 60 mm about (0, 0, 60) (the simulator's default sphere scene) made of four
rational biquadratic patches (a quarter of the azimuth each, Piegl and Tiller's surface of
revolution, section 8.5), one patch per "view"; a teapot Bezier patch; rational circles and
polynomial curves. The rig is the simulator's default at a quarter of its resolution.
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np

from nurbscan.nurbs import NurbsCurve, NurbsSurface
from nurbscan.reconstruct import Model
from nurbscan.simulate.rig import default_rig
from nurbscan.simulate.scenes import load_bpt

R = 60.0
CENTRE = np.array([0.0, 0.0, 60.0])
ANGLES = [0.0, 0.5 * math.pi, math.pi, 1.5 * math.pi]


def camera_azimuth(view: int) -> float:
    """Azimuth (rad, object frame) of the camera centre of a view of :func:`small_rig`."""
    rig = small_rig()
    c = rig.turntable.from_rig(np.asarray(rig.camera.center)[None], ANGLES[view])[0]
    return math.atan2(c[1], c[0])


def quarter_sphere(k: int, radius: float = R, centre=CENTRE) -> NurbsSurface:
    """Patch k of 4: a quarter of the azimuth (u) centred on view k's camera, polar profile
    south to north (v); the four patches close up (the camera turns by pi/2 per view)."""
    a0 = camera_azimuth(0) + k * 0.5 * math.pi * _turn_sign() - 0.25 * math.pi
    dirs = [np.array([math.cos(a), math.sin(a)]) for a in (a0, a0 + 0.25 * math.pi,
                                                          a0 + 0.5 * math.pi)]
    circ = [dirs[0], dirs[1] / math.cos(0.25 * math.pi), dirs[2]]
    wu = np.array([1.0, math.cos(0.25 * math.pi), 1.0])
    prof = [(0.0, -1.0), (1.0, -1.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)]  # (r, z)
    s2 = math.sqrt(0.5)
    wv = np.array([1.0, s2, 1.0, s2, 1.0])
    P = np.array([[[c[0] * r * radius, c[1] * r * radius, z * radius] for r, z in prof]
                  for c in circ]) + centre
    W = wu[:, None] * wv[None, :]
    return NurbsSurface(2, 2, [0, 0, 0, 1, 1, 1], [0, 0, 0, 0.5, 0.5, 1, 1, 1], P, W)


def teapot_patch() -> NurbsSurface:
    """The first Bezier patch of the Utah teapot as a bicubic surface (mm, scale 20)."""
    patches = load_bpt(scale=20.0)
    P = np.asarray(patches[0], float)
    U = [0, 0, 0, 0, 1, 1, 1, 1]
    return NurbsSurface(3, 3, U, U, P)


def curves() -> list:
    """A rational full circle (9 points) and a polynomial cubic with interior knots."""
    s2 = math.sqrt(0.5)
    ang = np.arange(9) * 0.25 * math.pi
    rad = np.where(np.arange(9) % 2 == 1, 1 / s2, 1.0) * R
    P = np.column_stack([rad * np.cos(ang), rad * np.sin(ang), np.full(9, 60.0)])
    w = np.where(np.arange(9) % 2 == 1, s2, 1.0)
    circle = NurbsCurve(2, [0, 0, 0, .25, .25, .5, .5, .75, .75, 1, 1, 1], P, w)
    rng = np.random.default_rng(3)
    cubic = NurbsCurve(3, [10, 10, 10, 10, 13.5, 17, 30, 30, 30, 30],
                       rng.normal(0, 30, (6, 3)) + [0, 0, 60])
    return [circle, cubic]


def _turn_sign() -> float:
    """+1 if the camera's azimuth in the object frame grows with the table angle, else -1."""
    d = camera_azimuth(1) - camera_azimuth(0)
    return 1.0 if math.sin(d) > 0 else -1.0


def small_rig(scale: int = 4):
    """The default rig with the camera at 1/scale of its resolution (same geometry)."""
    rig = default_rig()
    c = rig.camera
    cam = dataclasses.replace(c, width=c.width // scale, height=c.height // scale,
                              cx=c.cx / scale, cy=c.cy / scale, dx=c.dx * scale,
                              dy=c.dy * scale)
    return dataclasses.replace(rig, camera=cam)


def sphere_model(with_teapot: bool = False) -> Model:
    """Four sphere patches (views 0-3), curves, optionally a teapot patch (view 0)."""
    surfaces = [{"kind": "gordon", "view": k, "patch": 0, "vertical": [0, 1],
                 "horizontal": [0, 1], "n_curves": [3, 5], "surface": quarter_sphere(k)}
                for k in range(4)]
    surfaces += [{**surfaces[0], "kind": "horizontal_skin"}]
    if with_teapot:
        surfaces.append({"kind": "vertical_skin", "view": 0, "patch": 1, "vertical": [0, 1],
                         "horizontal": [0, 1], "n_curves": [4, 4], "surface": teapot_patch()})
    cs = [{"kind": kind, "view": 0, "direction": kind.split("_")[0], "band": i, "edge": 0,
           "coord": float(i), "curve": c}
          for i, (kind, c) in enumerate(zip(("horizontal_line", "vertical_line"), curves(),
                                            strict=True))]
    views = [{"index": k, "table_angle": a} for k, a in enumerate(ANGLES)]
    return Model(curves=cs, surfaces=surfaces, views=views)


def make_folders(root: Path, colours=None) -> Path:
    """Write ``root/scan`` (scan.json, white images, truth/rig.json, truth/scene.json: a sphere
    of radius R + 0.1) and ``root/model``; return the model folder.

    ``colours``: RGB uint8 per view for the white images (uniform images).
    """
    import cv2

    rig = small_rig()
    scan = root / "scan"
    (scan / "views").mkdir(parents=True, exist_ok=True)
    (scan / "truth").mkdir(exist_ok=True)
    colours = colours or [(200, 30, 30), (30, 200, 30), (30, 30, 200), (200, 200, 30)]
    views = []
    for k, a in enumerate(ANGLES):
        img = np.empty((rig.camera.height, rig.camera.width, 3), np.uint8)
        img[:] = colours[k][::-1]  # BGR on disk
        cv2.imwrite(str(scan / "views" / f"view_{k:02d}_white.png"), img)
        views.append({"index": k, "table_angle": a, "white": f"views/view_{k:02d}_white.png",
                      "grid": f"views/view_{k:02d}_grid.png"})
    (scan / "scan.json").write_text(json.dumps({"type": "nurbscan.scan", "version": 1,
                                                "views": views}))
    rig.save(scan / "truth" / "rig.json")
    (scan / "truth" / "scene.json").write_text(json.dumps(
        {"type": "nurbscan.scene", "version": 1, "name": "sphere", "radius": R + 0.1,
         "center": CENTRE.tolist()}))
    m = sphere_model()
    m.meta = {"source": str(scan), "calibration": str(scan / "truth" / "rig.json")}
    m.save(root / "model")
    return root / "model"
