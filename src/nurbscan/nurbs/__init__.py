"""NURBS curves and surfaces (Piegl and Tiller, The NURBS Book, 2nd ed.)."""

from .basis import (
    approximation_knots,
    averaging_knots,
    basis_function_derivatives,
    basis_functions,
    basis_matrix,
    chord_length_params,
    find_span,
    greville_abscissae,
    uniform_knots,
)
from .conic import circle, conic_arc, conic_weight, ellipse, elliptic_arc, tangent_intersection
from .construct import (
    GordonParts,
    gordon_surface,
    make_compatible,
    merge_knot_vectors,
    refine_knot_vector,
    reparametrize_family,
    reparametrize_piecewise,
    ruled_surface,
    skin,
    skin_params,
)
from .curve import NurbsCurve, evaluate_many
from .fit import fit_curve, fit_curve_lstsq, fit_curves
from .intersect import (
    CurveIntersections,
    LineSurfaceHits,
    closest_point_curve,
    closest_point_surface,
    closest_points_curves,
    intersect_curve_sets,
    intersect_curves,
    intersect_line_surface,
    intersect_lines_surface,
)
from .surface import NurbsSurface

__all__ = [
    "NurbsCurve",
    "NurbsSurface",
    "approximation_knots",
    "averaging_knots",
    "basis_function_derivatives",
    "basis_functions",
    "basis_matrix",
    "chord_length_params",
    "evaluate_many",
    "find_span",
    "fit_curve",
    "fit_curve_lstsq",
    "fit_curves",
    "greville_abscissae",
    "uniform_knots",
    # conics, intersections, constructed surfaces
    "CurveIntersections",
    "GordonParts",
    "LineSurfaceHits",
    "circle",
    "closest_point_curve",
    "closest_point_surface",
    "closest_points_curves",
    "conic_arc",
    "conic_weight",
    "ellipse",
    "elliptic_arc",
    "gordon_surface",
    "intersect_curve_sets",
    "intersect_curves",
    "intersect_line_surface",
    "intersect_lines_surface",
    "make_compatible",
    "merge_knot_vectors",
    "refine_knot_vector",
    "reparametrize_family",
    "reparametrize_piecewise",
    "ruled_surface",
    "skin",
    "skin_params",
    "tangent_intersection",
]
