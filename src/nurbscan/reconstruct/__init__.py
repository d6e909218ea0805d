"""From labelled edge lines to 3-D NURBS curves and surfaces (method.md sections 5 and 6).

* :mod:`.light` - light surfaces of projector edges (exact, and the paper's conic ruled
  surface) and their intersection with camera rays;
* :mod:`.triangulate` - 2-D curves, 3-D points and 3-D curves of each labelled line;
* :mod:`.network` - the curve network, skins and Gordon patches of a view;
* :mod:`.view` - one view end to end (into the object frame: :mod:`nurbscan.merge`);
* :mod:`.pipeline` - a whole scan folder; :mod:`.model` - the model folder.
"""

from .light import compare_light_surfaces, intersect_exact, intersect_surface, paper_light_surface
from .model import Model, load_model
from .pipeline import reconstruct_scan
from .view import ViewResult, reconstruct_view

__all__ = [
    "Model",
    "ViewResult",
    "compare_light_surfaces",
    "intersect_exact",
    "intersect_surface",
    "load_model",
    "paper_light_surface",
    "reconstruct_scan",
    "reconstruct_view",
]
