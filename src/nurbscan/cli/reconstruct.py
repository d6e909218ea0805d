"""``nurbscan reconstruct``: build 3-D NURBS curves and surfaces from a scan."""

from ._todo import register_todo


def register(sub) -> None:
    """Add the ``reconstruct`` sub-command."""
    register_todo(sub, "reconstruct", "Build 3-D NURBS curves and surfaces from a scan", 7)
