"""``nurbscan report``: write a self-contained HTML scan report."""

from ._todo import register_todo


def register(sub) -> None:
    """Add the ``report`` sub-command."""
    register_todo(sub, "report", "Write a self-contained HTML scan report", 8)
