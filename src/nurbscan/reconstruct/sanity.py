"""Refusing a reconstruction that could only be wrong or empty (issue #34).

:func:`check_rig` refuses a calibration no scanner has (camera and projector at one place, a
lens distortion that folds the image); :func:`check_model` refuses a model without a single
decoded line. Both raise :class:`~nurbscan.errors.NurbscanError` with one line, so that
``nurbscan reconstruct`` exits with status 2 and writes nothing instead of an empty model.
"""

from __future__ import annotations

import numpy as np

from ..errors import NurbscanError

#: Smallest camera-projector baseline, mm: below it the light surfaces meet the camera rays at
#: grazing angles (a zero baseline triangulates nothing).
MIN_BASELINE_MM = 1.0
#: Largest radial distortion ``k1 rd^2`` at the image corners (Tsai's ``Xu = Xd (1 + k1 r^2)``):
#: 100 % outwards; inwards the model folds at ``-1/3`` (:attr:`Camera.max_distorted_radius`).
MAX_DISTORTION = 1.0


def corner_distortion(device) -> float:
    """``k1 rd^2`` at the farthest image corner of a camera or projector (dimensionless).

    The corners' distorted sensor radius ``rd`` from Tsai's pixel map
    ``Xf = sx Xd / dx + Cx``, ``Yf = Yd / dy + Cy`` (pixel corners at -0.5 and W - 0.5).
    """
    u = np.array([-0.5, device.width - 0.5])
    v = np.array([-0.5, device.height - 0.5])
    xd = (u - device.cx) * device.dx / device.sx
    yd = (v - device.cy) * device.dy
    rd2 = float(np.max(xd[:, None] ** 2 + yd[None, :] ** 2))
    return float(device.k1) * rd2


def check_rig(rig, source: str = "calibration") -> None:
    """Refuse a rig that cannot triangulate: a baseline under :data:`MIN_BASELINE_MM`, or a
    camera or projector whose distortion at the image corners exceeds :data:`MAX_DISTORTION`
    outwards or reaches the fold (``-1/3``) inwards."""
    base = float(np.linalg.norm(np.asarray(rig.camera.center) - np.asarray(rig.projector.center)))
    if not base >= MIN_BASELINE_MM:
        raise NurbscanError(f"{source}: camera and projector {base:.3g} mm apart (baseline "
                            f"under {MIN_BASELINE_MM} mm): nothing can be triangulated")
    for name, dev in (("camera", rig.camera), ("projector", rig.projector)):
        c = corner_distortion(dev)
        if not -1.0 / 3.0 < c <= MAX_DISTORTION:
            raise NurbscanError(f"{source}: {name} k1 = {dev.k1:.3g} mm^-2 distorts the image "
                                f"corners by {100 * c:.3g} % (k1 rd^2; a lens does "
                                f"between -33 % and {100 * MAX_DISTORTION:.0f} %)")


def check_model(model, source: str, warnings: list[str] = ()) -> None:
    """Refuse a model without a decoded line in any view (``warnings``: the views' detection
    warnings, the first of which is quoted)."""
    if model.curves or model.surfaces or len(model.points):
        return
    why = f" ({warnings[0]})" if warnings else ""
    raise NurbscanError(f"{source}: no grid line decoded in any of the {len(model.views)} "
                        f"view(s){why}; nothing written")
