"""The projected pattern: PRMVS sequences over GF(q) and the colour grid built from them.

method.md section 1. :mod:`.sequence` makes m-sequences and de Bruijn sequences from primitive
polynomials (notation: base-q digits from the highest degree down, e.g. ``"1403"`` =
x^3 + 4x^2 + 3 over GF(5), or a comma list ``"1,4,0,3"``) and looks windows up; :mod:`.grid`
lays them out as vertical and horizontal colour bands with exact edge coordinates, renders the
projector image and writes / reads its JSON sidecar; :mod:`.lines` holds any grid of straight
coloured lines on black (:class:`LinePattern`, e.g. a foreign projector's pattern, or nurbscan's
own via :meth:`Pattern.to_line_pattern`), and :func:`load_pattern` reads either sidecar.
"""

from .grid import DEFAULT_COLOURS, Pattern, load_pattern, sidecar_path
from .lines import LINE_PATTERN_TYPE, LineFamily, LinePattern, window_length
from .sequence import (
    check_primitive,
    de_bruijn,
    default_poly,
    find_primitive,
    format_poly,
    is_primitive,
    m_sequence,
    parse_poly,
    recurrence_period,
    window_keys,
    window_lookup,
    window_table,
)

__all__ = [
    "DEFAULT_COLOURS",
    "LINE_PATTERN_TYPE",
    "LineFamily",
    "LinePattern",
    "Pattern",
    "check_primitive",
    "de_bruijn",
    "default_poly",
    "find_primitive",
    "format_poly",
    "is_primitive",
    "load_pattern",
    "m_sequence",
    "parse_poly",
    "recurrence_period",
    "sidecar_path",
    "window_keys",
    "window_length",
    "window_lookup",
    "window_table",
]
