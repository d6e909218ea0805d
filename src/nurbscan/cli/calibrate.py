"""``nurbscan calibrate``: calibrate camera, projector and turntable from target images."""

from ._todo import register_todo


def register(sub) -> None:
    """Add the ``calibrate`` sub-command."""
    register_todo(sub, "calibrate", "Calibrate camera, projector, turntable from target images", 6)
