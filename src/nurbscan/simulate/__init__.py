"""Synthetic scanner: exact scenes (``scenes``) and their rendering under the projected grid."""

from .scenes import (
    Cylinder,
    Plane,
    Scene,
    Sphere,
    Teapot,
    Torus,
    make_scene,
    scene_from_dict,
)

__all__ = [
    "Cylinder",
    "Plane",
    "Scene",
    "Sphere",
    "Teapot",
    "Torus",
    "make_scene",
    "scene_from_dict",
]
from .render import RenderedView, RenderSettings, render_view  # noqa: E402,I001
from .rig import default_rig, scale_camera  # noqa: E402
from .scan import simulate_scan  # noqa: E402
from .target import BoardScene, Chessboard  # noqa: E402

__all__ += [
    "BoardScene",
    "Chessboard",
    "RenderSettings",
    "RenderedView",
    "default_rig",
    "render_view",
    "scale_camera",
    "simulate_scan",
]
