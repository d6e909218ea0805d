"""Grid detection in one photograph: :func:`detect_grid`, the list of its stages.

method.md section 2. Each stage is a function of its own module, with typed inputs and
outputs (frozen dataclasses):

=================  ==========================================  =========================
stage              function                                    returns
=================  ==========================================  =========================
normalise          :func:`.prepare.prepare`                    :class:`.prepare.Prepared`
edge points        :func:`.chains.find_edges`                  :class:`.chains.Edges`
chains             :func:`.chains.trace_chains`                :class:`.chains.Chains`
colour reading     :func:`.crossings.read_colours`             :class:`.crossings.Reading`
orientation        :func:`.orientation.grid_orientation`       :class:`.orientation.
                                                               Orientation` (a turned
                                                               photograph: detected upright,
                                                               :func:`detect_turned`)
decoding           :func:`.labels.decode_labels`               :class:`.labels.Labels`
family fits        :func:`.families.family_labels`             :class:`.labels.Labels`
refinement         :func:`.refine.select_points`,              :class:`.refine.Lines`
                   :func:`.refine.refine_points`
intersections      :func:`.intersections.intersect_lines`      :class:`.intersections.
                                                               Intersections`
line checks        :func:`.checks.check_lines`                 the kept lines
result             :func:`finish`                              :class:`DetectionResult`
=================  ==========================================  =========================

The options are :class:`~nurbscan.detect.options.DetectOptions`, one group per stage.

Bad input (documented behaviour): an image that is not a 2-D grey or colour array, that holds
non-finite values, or a white image of another size raises
:class:`~nurbscan.errors.NurbscanError` (one line). A black, overexposed, blank or unrelated
image, or a pattern that does not match the photograph, gives an *empty* result whose
``warnings`` say why (and a :class:`UserWarning`); the command line turns an empty result into
a one-line error.

The helpers that lived here before the stages had modules of their own are re-exported under
their old names (``from nurbscan.detect.core import propagate_pairs`` keeps working).
"""

from __future__ import annotations

import time
import warnings as _warnings

import numpy as np

from .chains import (  # noqa: F401  (re-exported)
    Edges,
    _along_across,
    _chains,
    attach_points,
    chain_end_residual,
    chain_tails,
    extend_lines,
    find_edges,
    trace_chains,
)
from .checks import (  # noqa: F401
    PLANE_K,
    PLANE_TOL,
    check_extent,
    check_lines,
    plane_support,
    row_disagreement,
    row_support,
)
from .crossings import clean_crossings, read_colours  # noqa: F401
from .families import (  # noqa: F401
    _plane_at,
    epipolar_check,
    epipolar_coordinates,
    epipolar_labels,
    family_coordinates,
    family_labels,
    local_plane,
)
from .intersections import (  # noqa: F401
    INTERSECTION_FIT_RMS,
    _intersections,
    grid_consistency,
    grid_intersections,
    intersect_lines,
)
from .labels import (  # noqa: F401
    _adjacent,
    _assign_votes,
    _row_neighbours,
    _until_stable,
    check_adjacency,
    check_band_width,
    decode_labels,
    group_median,
    interpolate_labels,
    nearest_band,
    point_coordinates,
    pooled_labels,
    propagate_collinear,
    propagate_labels,
    propagate_pairs,
    row_consistent,
    row_order,
)
from .lines import smooth_chains
from .normalize import noise_level  # noqa: F401
from .options import DetectOptions
from .orientation import Orientation, grid_orientation, to_photograph
from .prepare import (  # noqa: F401
    FINE_BAND_PX,
    NoGrid,
    Prepared,
    as_float_image,
    as_float_planes,
    auto_sigma,
    band_width_px,
    per_band_for_noise,
    prepare,
)
from .refine import Lines, refine_points, select_points
from .result import DetectionResult
from .tilt import detect_tilted, grid_tilt

#: Corner points (``corner_dominance``) extend a final line when within this (camera px) of
#: the straight line through its other points within 6 chain positions (1280 x 960 teapot:
#: 0.15 px gave coverage 0.6907 against 0.571, RMS 0.048 px).
CORNER_RESIDUAL = 0.1

_DEFAULT = DetectOptions()


def detect_grid(image, pattern, white=None, options: DetectOptions = _DEFAULT, *,
                epipolar=None, timings: dict | None = None, **legacy) -> DetectionResult:
    """Find, trace and decode the grid's edge lines in one photograph.

    Parameters
    ----------
    image : ndarray (H, W, 3) (or (H, W)), uint8, uint16 or float in [0, 1]
        The object under the projected grid (gamma-encoded as cameras write images).
    pattern : nurbscan.pattern.Pattern
        The projected pattern.
    white : ndarray like ``image``, optional
        The same view under white light (albedo and shading normalisation).
    options : DetectOptions
        The options, one group per stage (:mod:`~nurbscan.detect.options`).
    epipolar : callable, optional
        ``other_coordinate(pixels (N, 2), direction, coord (N,)) -> (N,)``: the other
        projector coordinate at camera pixels on projector edges, from a calibrated rig
        (:func:`nurbscan.reconstruct.light.other_coordinate`; ``nurbscan reconstruct`` passes
        it). With it, where the bands are resolved, the lines the colour windows left are
        labelled by the epipolar prediction (:func:`~nurbscan.detect.families.family_labels`).
    timings : dict, optional
        Filled with the wall time of each stage, s (``"normalise_s"``, ``"edges_s"``, ...).
    **legacy
        The keyword options of the single-function detector (``fit_rounds=0``, ...), for
        one release: applied with :meth:`DetectOptions.replace`, with a
        :class:`DeprecationWarning`.

    Returns
    -------
    DetectionResult
        Only lines labelled with confidence; empty (with ``warnings``) when no grid is found.

    Notes
    -----
    The stages (module notes): normalise the photograph and measure its scale; find the
    edge points; trace them into chains; read the band crossings' colours and the colour
    windows' votes; find the grid's orientation from the windows (a photograph rotated by
    90, 180 or 270 degrees, mirrored or transposed is detected upright and the result mapped
    back, :func:`detect_turned`); decode and propagate the labels; label more from the
    family fits (and the rig); select and re-measure the labelled lines' points; intersect
    the lines; check the lines against their rows and intersections; smooth the chains,
    extend them by the corner points and return the result.
    """
    if legacy:
        _warnings.warn("detect_grid: keyword options are deprecated, pass "
                       "options=DetectOptions().replace(...)", DeprecationWarning, stacklevel=2)
        if "epipolar" in legacy:
            epipolar = legacy.pop("epipolar")
        options = options.replace(**legacy)
    o = options
    if o.decoding.find_orientation:
        tilt = grid_tilt(image)
        if tilt.needs_levelling:
            return detect_tilted(image, white, pattern, o, tilt, epipolar, timings)
    clock = _Clock(timings)
    try:
        prep = clock("normalise", prepare(image, white, pattern, o.image, o.edges.sigma,
                                          o.edges.sigma_per_band))
        edges = clock("edges", find_edges(prep, o.edges))
        chains = clock("chains", trace_chains(edges, prep, o.chains.min_length))
        reading = clock("reading", read_colours(chains, prep, pattern, o.reading))
        if o.decoding.find_orientation:
            turn = grid_orientation(reading.spans)
            if not (turn.upright or turn.roles_known):
                raise NoGrid("image: grid orientation ambiguous: the photograph is turned "
                             f"({turn.describe()}, or transposed so), and its bands do not "
                             "tell which family is the vertical bands'", prep.size)
            if not turn.upright:
                return detect_turned(image, white, pattern, o, turn, prep.size, epipolar,
                                     timings)
        labels = clock("decoding", decode_labels(chains, reading, prep, pattern, o.decoding))
        labels = clock("families", family_labels(labels, chains, reading, prep, pattern,
                                                 o.fits, o.decoding.min_votes,
                                                 o.decoding.min_agreement, epipolar))
        refine = not o.image.chroma_subsampled
        sel = select_points(chains, reading, labels, prep, o.refine, refine)
        lines = clock("refine", refine_points(sel, chains, reading, prep, pattern, o.refine,
                                              refine, epipolar is not None))
        coord = lines.coordinates(pattern)
        inter = clock("intersections", intersect_lines(lines, coord, reading.pitch_px, prep,
                                                       pattern))
        lines, coord, inter = clock("checks", check_lines(lines, coord, inter, prep, pattern,
                                                          o.checks, o.chains.min_length))
        result = clock("result", finish(lines, coord, inter, edges, prep, o))
        check_extent(result)
        return result
    except NoGrid as e:
        _warnings.warn(e.reason, UserWarning, stacklevel=2)
        return DetectionResult.empty(e.size, (e.reason,))


def detect_turned(image, white, pattern, options: DetectOptions, turn: Orientation,
                  size: tuple[int, int], epipolar=None,
                  timings: dict | None = None) -> DetectionResult:
    """:func:`detect_grid` of the upright image of a photograph of ``size`` (width, height)
    turned by ``turn`` (:func:`~nurbscan.detect.orientation.grid_orientation`), mapped back
    to the photograph (:func:`~nurbscan.detect.orientation.to_photograph`); the rig's
    ``epipolar`` prediction is asked at the photograph's pixels."""
    upright_size = size[::-1] if turn.transpose else size
    turned = epipolar
    if epipolar is not None:
        def turned(pixels, direction, coord):
            pix = np.asarray(pixels, np.float64)
            x, y = turn.to_photograph(pix[:, 0], pix[:, 1], upright_size)
            return epipolar(np.c_[x, y], direction, coord)
    options = options.replace(find_orientation=False)
    with _warnings.catch_warnings():
        _warnings.simplefilter("ignore", UserWarning)  # the reason is in the result
        result = detect_grid(turn.apply(image), pattern, turn.apply(white), options,
                             epipolar=turned, timings=timings)
    if result.nlines == 0 and result.warnings:
        _warnings.warn(result.warnings[0], UserWarning, stacklevel=3)
    return to_photograph(result, turn, size)


class _Clock:
    """Wall time of each stage into ``timings`` (a dict, or None for none)."""

    def __init__(self, timings: dict | None):
        self.timings, self.t = timings, time.perf_counter()

    def __call__(self, name: str, value):
        if self.timings is not None:
            t = time.perf_counter()
            self.timings[f"{name}_s"] = round(t - self.t, 4)
            self.t = t
        return value


def finish(lines: Lines, coord: np.ndarray, inter, edges: Edges, prep: Prepared,
           options: DetectOptions) -> DetectionResult:
    """The result: the final chains smoothed (``smooth_reach``), extended by the corner points
    that continue them (:func:`~nurbscan.detect.chains.extend_lines`), and the intersections.
    """
    px, py, strength, line = lines.x, lines.y, lines.strength, lines.line
    ldir, ledge, lab = lines.direction, lines.edge, lines.band
    w, h = prep.size
    smooth_reach = options.chains.smooth_reach
    if smooth_reach > 0 and len(px):
        # after every point filter (they judge the points as measured) and the intersections:
        # the points' noise is partly independent from row to row, and a local weighted line
        # along each chain lowers it (the squared strength is the inverse variance)
        vk = ldir[line] == 0
        a = smooth_chains(*_along_across(px, py, vk), line,
                          strength.astype(np.float64) ** 2, smooth_reach)
        px, py = np.where(vk, a, px), np.where(vk, py, a)
    if edges.corners is not None and len(px):
        # the corner pixels' points extend the final lines where they continue them (after
        # every filter and the intersections, which they leave as they are)
        px, py, strength, line = extend_lines(px, py, strength, line, ldir, ledge,
                                              edges.corners, (h, w),
                                              options.refine.min_strength, CORNER_RESIDUAL)
    counts = np.bincount(line, minlength=len(lab))
    stop = np.cumsum(counts)
    start = stop - counts
    return DetectionResult(
        image_size=(w, h), x=px, y=py, strength=strength.astype(np.float32), line=line,
        direction=ldir, band=lab, edge=ledge, coord=coord, start=start, stop=stop,
        votes=lines.votes, agreement=lines.agreement, cam=inter.cam, proj=inter.proj,
        cross_band=inter.band, cross_edge=inter.edge, cross_line=inter.line, warnings=())
