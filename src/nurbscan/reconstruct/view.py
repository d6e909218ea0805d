"""Reconstruction of one view: labelled lines -> 3-D curves -> network -> Gordon patches."""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from .network import NetLine, Patch, build_network, line_curves
from .triangulate import Line3D, drop_occluded, triangulate_lines


@dataclass
class ViewResult:
    """Everything reconstructed from one view, in the rig frame (mm).

    Attributes
    ----------
    lines : list of Line3D
        Every labelled chain: its 2-D curve, 3-D points and 3-D curve.
    vlines, hlines : list of NetLine
        The network's vertical and horizontal edges (chains joined per edge).
    patches : list of Patch
        Skins and Gordon surface of each complete rectangle of the network.
    cells : (int, int)
        Complete cells and all cells of the network.
    times : dict
        Seconds spent per stage.
    crossing_tol : float
        The crossing tolerance used, mm.
    """

    lines: list[Line3D]
    vlines: list[NetLine]
    hlines: list[NetLine]
    patches: list[Patch]
    cells: tuple[int, int]
    times: dict = field(default_factory=dict)
    crossing_tol: float = 0.0

    def line_curves(self):
        """Validated 3-D line curves (see :func:`nurbscan.reconstruct.network.line_curves`)."""
        return line_curves(self.vlines, self.hlines)

    @property
    def edge_points(self) -> np.ndarray:
        """All triangulated edge points of the confirmed network lines, (N, 3) mm."""
        pts = [ln.points for ln in self.vlines + self.hlines]
        return np.concatenate(pts) if pts else np.zeros((0, 3))


def reconstruct_view(det, rig, pattern=None, *, min_curves: int = 3,
                     crossing_tol: float | None = None, knot_spacing: float = 12.0,
                     occlusion_px: float | None = None) -> ViewResult:
    """Reconstruct one view from its detection result (method.md section 5, steps 1-4).

    Parameters
    ----------
    det : DetectionResult (or an object with its arrays)
        Labelled edge lines of the view's grid photograph.
    rig : Rig
        Calibrated camera and projector (Tsai fields), rig frame = camera frame.
    min_curves : int
        Smallest Gordon patch, in curves per direction.
    crossing_tol : float, optional
        Largest disagreement (mm) of a vertical and a horizontal curve at their crossing.
        Default: 1.2 camera pixel footprints at the object (``1.2 depth dy / f`` at the median
        depth of the view's points: 0.13 mm for the default rig at 600 mm). A curve labelled
        one band off misses its crossings by a band width (over 1 mm), so the test still
        finds it; what the tolerance trades is the exactness of the crossings near the band
        corners and at grazing views against complete cells. Teapot demo scan (7.1 MP, rig
        calibrated from the images): 0.6 footprints, Gordon coverage 65.7 %, Gordon mean
        0.0047 mm; 1.2 footprints, 70.6 % and 0.0057 mm (with five-crossing validated runs,
        :func:`~nurbscan.reconstruct.network.complete_cells`, so that the line curves keep
        their accuracy). For the cells it grows where the surface is seen obliquely, by
        ``1 / max(cos, 0.3)`` (the camera centre is the ``viewpoint`` of
        :func:`~nurbscan.reconstruct.network.complete_cells`): 77.3 -> 83.4 %.
    pattern : Pattern, optional
        The projected grid: the largest gap bridged along an edge is ``2 pitch + band + 1``
        projector px (an edge is lost where a band of the other direction crosses it, and a
        chain between two crossings may be missing), the 3-D curves' knot spacing is the
        pitch, and a patch reaches past its rectangle over samples at most ``band + 4`` px
        apart (the gap a crossing band leaves); without it the default grid's pitch 16 and
        band 6 px.
    knot_spacing : float
        Knot spacing of the 2-D curve fits, camera px.
    occlusion_px : float or None
        Samples within this many camera px of a sample more than 1 mm nearer the camera are
        dropped before the network is built (:func:`~nurbscan.reconstruct.triangulate.
        drop_occluded`: the edge beside an occluding contour is shifted by its blur); None
        (the default) keeps them. Measured on the teapot demo scan: at 1024 x 768, 3 px takes
        the CAD set's worst sample from 0.550 to 0.390 mm at a trace of coverage; at 3072 x
        2304 (the demo), 3 px leaves the Gordon patches' worst sample at 0.892 mm and costs
        coverage (90.5 -> 90.3 %, Gordon mean 0.01186 -> 0.01200 mm), 9 px 17 points of it
        (docs/accuracy.md), so it is not on by default.
    """
    t0 = time.perf_counter()
    lines = triangulate_lines(det, rig, knot_spacing=knot_spacing, min_points=4)
    if occlusion_px is not None:
        lines = drop_occluded(lines, rig.camera, radius=occlusion_px)
    t1 = time.perf_counter()
    if crossing_tol is None:
        pts = [ln.points for ln in lines if len(ln.points)]
        depth = float(np.median(np.concatenate(pts)[:, 2])) if pts else 600.0
        cam = rig.camera
        crossing_tol = 1.2 * depth * float(cam.dy) / float(cam.f)
    if pattern is None:
        pitch, band = 16.0, 6.0
    elif hasattr(pattern, "families"):  # a LinePattern: its closest line spacing and width
        pitch = min(float(np.median(np.diff(f.centres))) for f in pattern.families)
        band = max(float(np.median(f.widths)) for f in pattern.families)
    else:
        pitch, band = float(pattern.pitch), float(pattern.band)
    vl, hl, patches, mask = build_network(lines, min_curves=min_curves,
                                          crossing_tol=crossing_tol,
                                          gap=2.0 * pitch + band + 1.0, knot_spacing=pitch,
                                          viewpoint=rig.camera.center,
                                          extend_gap=band + 4.0)
    t2 = time.perf_counter()
    return ViewResult(lines=lines, vlines=vl, hlines=hl, patches=patches,
                      cells=(int(mask.sum()), int(mask.size)),
                      times={"triangulate_s": t1 - t0, "network_s": t2 - t1},
                      crossing_tol=float(crossing_tol))
