"""``nurbscan detect``: find, trace and decode the grid's edge lines in a photograph."""

from ._todo import register_todo


def register(sub) -> None:
    """Add the ``detect`` sub-command."""
    register_todo(sub, "detect", "Find, trace and decode the grid's edge lines in a photograph", 5)
