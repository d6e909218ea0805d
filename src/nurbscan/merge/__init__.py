"""The merge stage: the views of a scan into one model of the object (issue #32).

Data flows reconstruct -> merge -> export. The stage takes the views' curves, Gordon patches
and points and

* :mod:`.frame` - moves each view into the object (turntable) frame with the calibrated
  turntable and the view's table angle, and rigidly by a correction;
* :mod:`.table` - tells the object from the turntable's top and the room (the calibrated
  table plane with a margin, the table's cylinder);
* :mod:`.register` - refines every view's pose jointly (pairwise point-to-plane ICP and a pose
  graph, Open3D), and says when the object is a surface of revolution that cannot fix the
  turn about the axis;
* :mod:`.views` - all of it on a model (:func:`merge_views`), recorded in ``model.json``;
* :mod:`.fusion` - one triangle mesh of the object for VR (screened Poisson of the views'
  samples, trimmed to the data, coloured from the white-light images).
"""

from .frame import (
    curve_to_object,
    moved_curve,
    moved_points,
    moved_surface,
    object_transform,
    rig_to_object,
    surface_to_object,
)
from .fusion import FusedMesh, FusionOptions, fuse_model, fuse_samples, read_fused, write_fused
from .register import Correction, Registration, RegistrationOptions, register_views
from .table import TableOptions, off_object, patch_off_object
from .views import (
    DEFAULT_MERGE,
    MergeOptions,
    MergeWarning,
    apply_registration,
    leave_out_table,
    merge_views,
)

__all__ = [
    "DEFAULT_MERGE",
    "Correction",
    "FusedMesh",
    "FusionOptions",
    "MergeOptions",
    "MergeWarning",
    "Registration",
    "RegistrationOptions",
    "TableOptions",
    "apply_registration",
    "curve_to_object",
    "fuse_model",
    "fuse_samples",
    "leave_out_table",
    "merge_views",
    "moved_curve",
    "moved_points",
    "moved_surface",
    "object_transform",
    "off_object",
    "patch_off_object",
    "read_fused",
    "register_views",
    "rig_to_object",
    "surface_to_object",
    "write_fused",
]
