"""``nurbscan evaluate``: measure a model against ground truth (the paper's Table I)."""

from ._todo import register_todo


def register(sub) -> None:
    """Add the ``evaluate`` sub-command."""
    register_todo(sub, "evaluate", "Measure a model against ground truth (the paper's Table I)", 7)
