"""Reading the grid from one photograph: sub-pixel edges, line tracing and PRMVS decoding.

method.md section 2. :func:`detect_grid` (options: :class:`DetectOptions`) returns a
:class:`DetectionResult` (saved as ``lines.json``); :func:`evaluate_detection` measures one
against the simulator's truth.
"""

from .core import detect_grid, grid_intersections
from .edges import EdgePoints, detect_edge_points
from .evaluate import evaluate_detection
from .lines import trace_lines
from .normalize import Normalised, edge_signal, normalize
from .options import DetectOptions
from .overlay import draw_overlay
from .result import DetectionResult, load_detection

__all__ = [
    "DetectOptions",
    "DetectionResult",
    "EdgePoints",
    "Normalised",
    "detect_edge_points",
    "detect_grid",
    "draw_overlay",
    "edge_signal",
    "evaluate_detection",
    "grid_intersections",
    "load_detection",
    "normalize",
    "trace_lines",
]
