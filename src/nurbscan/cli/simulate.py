"""``nurbscan simulate``: render a synthetic scan of a scene."""

from ._todo import register_todo


def register(sub) -> None:
    """Add the ``simulate`` sub-command."""
    register_todo(sub, "simulate", "Render a synthetic scan of a scene", 3)
