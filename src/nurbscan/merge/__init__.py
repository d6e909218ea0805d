"""The merge stage: the views of a scan into one model of the object (issue #32).

Data flows reconstruct -> merge -> export. The stage takes the views' curves, Gordon patches
and point samples and

* :mod:`.frame` - moves each view into the object (turntable) frame with the calibrated
  turntable and the view's table angle;
"""

from .frame import curve_to_object, object_transform, rig_to_object, surface_to_object

__all__ = [
    "curve_to_object",
    "object_transform",
    "rig_to_object",
    "surface_to_object",
]
