"""Reading the grid from one photograph: sub-pixel edges, line tracing and PRMVS decoding.

method.md section 2. :func:`detect_grid` (PRMVS bands) and :func:`detect_lines` (thin lines of
any :class:`~nurbscan.pattern.LinePattern`) return a :class:`DetectionResult` (saved as
``lines.json``); :func:`evaluate_detection` measures one against the simulator's truth.
"""

from .core import detect_grid, grid_intersections
from .edges import EdgePoints, detect_edge_points
from .evaluate import evaluate_detection
from .line_grid import LineDetectOptions, detect_lines, line_intersections
from .lines import trace_lines
from .normalize import Normalised, edge_signal, normalize
from .overlay import draw_line_overlay, draw_overlay
from .result import DetectionResult, load_detection

__all__ = [
    "DetectionResult",
    "EdgePoints",
    "LineDetectOptions",
    "Normalised",
    "detect_edge_points",
    "detect_grid",
    "detect_lines",
    "draw_line_overlay",
    "draw_overlay",
    "edge_signal",
    "evaluate_detection",
    "grid_intersections",
    "line_intersections",
    "load_detection",
    "normalize",
    "trace_lines",
]
