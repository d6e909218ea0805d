"""nurbscan: single-shot colour-grid structured light to NURBS curves and surfaces.

The pipeline, one module or sub-package per stage, data flowing one way::

    pattern -> (simulate | real images) -> detect -> nurbs fit -> reconstruct -> merge -> export
                                    calibrate ----^                      evaluate <- ground truth

Conventions (millimetres, radians, right-handed frames, pixel centres at integer coordinates)
are written once in ``docs/conventions.md``.

The names below are the Python API (docs/python.md); each is imported from its stage's module
on first use, so ``import nurbscan`` stays cheap:

=====================  ============================================================
:func:`load_scan`      read a scan folder's ``scan.json`` (:mod:`nurbscan.io.scan`)
:func:`simulate_scan`  render a synthetic scan folder (:mod:`nurbscan.simulate`)
:func:`make_scene`     a synthetic object by name (teapot, sphere, ...)
:func:`calibrate_scan` camera, projector and turntable from the calibration images
:func:`reconstruct_scan` every view of a scan to a merged :class:`Model`
:func:`load_model`     read a model folder (``model.json``, ``points.npz``)
:func:`export_model`   write a model as glb, obj, ply, stl, 3dm or igs
:func:`detect_grid`    find and decode the grid's edge lines in one photograph
:class:`Pattern`       nurbscan's PRMVS colour grid (:mod:`nurbscan.pattern`)
:class:`LinePattern`   any grid of straight coloured lines on black
:func:`load_pattern`   read a pattern sidecar (either kind)
:class:`Rig`           camera, projector and turntable (:mod:`nurbscan.camera`)
:class:`Camera`        Tsai's camera model; :class:`Projector` the same as an inverse camera
:func:`load_rig`       read a rig JSON
:func:`read_opencv`    a rig from OpenCV FileStorage YAML; :func:`write_opencv` the reverse
:class:`NurbsCurve`    NURBS curve; :class:`NurbsSurface` NURBS surface
:func:`fit_curve`      approximate points by a B-spline within a tolerance
=====================  ============================================================

Examples
--------
A pattern, rendered as the projector shows it (an RGB image, H x W x 3, uint8):

>>> import numpy as np
>>> import nurbscan
>>> pattern = nurbscan.Pattern.create(width=320, height=240, pitch=16, band=6)
>>> image = pattern.render()
>>> image.shape, image.dtype.name
((240, 320, 3), 'uint8')
>>> pattern.counts  # vertical and horizontal bands
(20, 15)

A NURBS curve: the quarter circle of radius 10 mm as a rational quadratic (Piegl and Tiller,
eq. 7.1), evaluated at its ends and middle:

>>> w = np.sqrt(0.5)
>>> arc = nurbscan.NurbsCurve(degree=2, knots=[0, 0, 0, 1, 1, 1],
...                           control_points=[[10, 0], [10, 10], [0, 10]], weights=[1, w, 1])
>>> np.round(arc.evaluate([0.0, 0.5, 1.0]), 6) + 0.0
array([[10.      ,  0.      ],
       [ 7.071068,  7.071068],
       [ 0.      , 10.      ]])

A rig from its JSON file, projecting a point 500 mm in front of the camera:

>>> import tempfile
>>> from pathlib import Path
>>> cam = nurbscan.Camera(width=640, height=480, f=8.0, cx=319.5, cy=239.5, dx=0.01, dy=0.01)
>>> prj = nurbscan.Projector(width=800, height=600, f=10.0, cx=399.5, cy=299.5, dx=0.01,
...                          dy=0.01, T=[-100.0, 0.0, 0.0])
>>> table = nurbscan.Turntable(point=[0.0, 50.0, 500.0], direction=[0.0, -1.0, 0.0])
>>> path = nurbscan.Rig(cam, prj, table).save(Path(tempfile.mkdtemp()) / "calib.json")
>>> rig = nurbscan.load_rig(path)
>>> rig.camera.project([[0.0, 0.0, 500.0], [50.0, 0.0, 500.0]])
array([[319.5, 239.5],
       [399.5, 239.5]])

A bad input is one :class:`NurbscanError` naming it:

>>> nurbscan.load_rig("no/such/calib.json")  # doctest: +ELLIPSIS
Traceback (most recent call last):
...
nurbscan.errors.NurbscanError: no/such/calib.json: ...
"""

__version__ = "0.1.0"

from .errors import NurbscanError

#: Public name -> module it lives in (imported on first use, PEP 562).
_LAZY = {
    "load_scan": "nurbscan.io.scan",
    "Scan": "nurbscan.io.scan",
    "simulate_scan": "nurbscan.simulate",
    "make_scene": "nurbscan.simulate",
    "calibrate_scan": "nurbscan.calibrate",
    "reconstruct_scan": "nurbscan.reconstruct",
    "Model": "nurbscan.reconstruct",
    "load_model": "nurbscan.export",
    "export_model": "nurbscan.export",
    "detect_grid": "nurbscan.detect",
    "Pattern": "nurbscan.pattern",
    "LinePattern": "nurbscan.pattern",
    "load_pattern": "nurbscan.pattern",
    "Rig": "nurbscan.camera",
    "Camera": "nurbscan.camera",
    "Projector": "nurbscan.camera",
    "Turntable": "nurbscan.camera",
    "load_rig": "nurbscan.camera",
    "read_opencv": "nurbscan.calibrate.opencv",
    "write_opencv": "nurbscan.calibrate.opencv",
    "NurbsCurve": "nurbscan.nurbs",
    "NurbsSurface": "nurbscan.nurbs",
    "fit_curve": "nurbscan.nurbs",
}

__all__ = ["NurbscanError", "__version__", *_LAZY]


def __getattr__(name: str):
    """Import a public name from its module on first use (PEP 562)."""
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'nurbscan' has no attribute {name!r}")
    from importlib import import_module  # here, not at the top: import nurbscan stays cheap

    value = getattr(import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))
