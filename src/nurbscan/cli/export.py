"""``nurbscan export``: write a model as glb, obj, ply, stl, 3dm or igs."""

from ._todo import register_todo


def register(sub) -> None:
    """Add the ``export`` sub-command."""
    register_todo(sub, "export", "Write a model as glb, obj, ply, stl, 3dm or igs", 8)
