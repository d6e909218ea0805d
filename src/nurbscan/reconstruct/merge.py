"""Deprecated location: the object-frame maps moved to :mod:`nurbscan.merge.frame`.

Kept as a thin re-export so that ``nurbscan.reconstruct.merge`` stays importable.
"""

from ..merge.frame import (  # noqa: F401
    curve_to_object,
    object_transform,
    rig_to_object,
    surface_to_object,
)
