"""Merging the views into one model of the object (issue 32).

* :mod:`.fusion` - one triangle mesh of the object for VR (screened Poisson of the views'
  samples, trimmed to the data, coloured from the white-light images).
"""

from .fusion import FusedMesh, FusionOptions, fuse_model, fuse_samples, read_fused, write_fused

__all__ = ["FusedMesh", "FusionOptions", "fuse_model", "fuse_samples", "read_fused",
           "write_fused"]
