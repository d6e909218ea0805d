"""nurbscan: single-shot colour-grid structured light to NURBS curves and surfaces.

The pipeline, one module or sub-package per stage, data flowing one way::

    pattern -> (simulate | real images) -> detect -> nurbs fit -> reconstruct -> merge -> export
                                    calibrate ----^                      evaluate <- ground truth

Conventions (millimetres, radians, right-handed frames, pixel centres at integer coordinates)
are written once in ``docs/conventions.md``.
"""

__version__ = "0.1.0"

from .errors import NurbscanError

__all__ = ["NurbscanError", "__version__"]
