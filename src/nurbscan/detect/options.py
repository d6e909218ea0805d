"""The options of :func:`~nurbscan.detect.detect_grid`, grouped by the stage they tune.

:class:`DetectOptions` holds one frozen group per stage (``image``, ``edges``, ``chains``,
``reading``, ``decoding``, ``fits``, ``refine``, ``checks``), each with its defaults and
their measured reasons. Callers say what they change by name::

    DetectOptions().replace(fit_rounds=0, read_along="pixels")
    DetectOptions().replace(refine=RefineOptions(min_paired=0))

Field names are unique across the groups, so :meth:`DetectOptions.replace` takes them
without their group. ``to_dict`` / ``from_dict`` give the JSON round trip (nested by group).
The tuning that nothing changes is kept in named module constants beside the stage that uses
it; the option docs below name them in capitals: :mod:`~nurbscan.detect.chains`
(``SIGMA_ALONG``), :mod:`~nurbscan.detect.crossings` (``WIDTH_TOL``, ``DARK_LEVEL``),
:mod:`~nurbscan.detect.labels` (``MIN_CONSENSUS``, ``PROPAGATION_ROUNDS``,
``COLLINEAR_UNKNOWN``, ``POOL_TOL``, ``LINE_WIDTH_TOL``, ``INTERPOLATION_ROUNDS``,
``INTERPOLATION_SPAN``, ``INTERPOLATION_TOL``, ``REQUIRE_COLOUR``),
:mod:`~nurbscan.detect.families` (``FIT_RADIUS``, ``FIT_RMS``, ``FIT_TOL``,
``EPIPOLAR_RADIUS``, ``EPIPOLAR_ROUNDS``), :mod:`~nurbscan.detect.refine`
(``CROSSING_MARGIN``, ``KEEP_UNPAIRED``, ``UNREFINED``, ``TAIL_RESIDUAL``,
``TAIL_RESIDUAL_EPIPOLAR``), :mod:`~nurbscan.detect.checks` (``PLANE_K``, ``PLANE_TOL``) and
:mod:`~nurbscan.detect.core` (``CORNER_RESIDUAL``).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field, fields
from typing import Any

from ..errors import NurbscanError


class _Group:
    """Common behaviour of the option groups: dict round trip and checks of choices."""

    #: field -> allowed values
    _CHOICES: dict[str, tuple] = {}

    def __post_init__(self) -> None:
        for name, allowed in self._CHOICES.items():
            value = getattr(self, name)
            if value not in allowed:
                quoted = [f"'{a}'" for a in allowed]
                text = ", ".join(quoted[:-1]) + " or " + quoted[-1]
                raise NurbscanError(f"{name}={value!r}: must be {text}")

    def to_dict(self) -> dict[str, Any]:
        return {f.name: getattr(self, f.name) for f in fields(self)}

    @classmethod
    def from_dict(cls, d) -> _Group:
        names = {f.name for f in fields(cls)}
        unknown = sorted(set(d) - names)
        if unknown:
            raise NurbscanError(f"detect options, {cls.__name__}: unknown "
                                f"{', '.join(unknown)}")
        return cls(**d)


@dataclass(frozen=True)
class ImageOptions(_Group):
    """The photograph and its normalisation (:func:`~nurbscan.detect.prepare.prepare`).

    Parameters
    ----------
    gamma : float
        The images' encoding gamma; they are linearised by ``v ** gamma`` (1 = linear data).
    window : int
        Local normalisation window without a white image, px.
    chroma_subsampled : bool
        The photograph is a JPEG with subsampled colour (4:2:2, 4:2:0:
        :func:`nurbscan.io.chroma_subsampled`; the readers of files, ``nurbscan detect``,
        ``reconstruct`` and ``calibrate``, pass it). Its colour channels' edges are blurred
        and displaced: the edge signal then weighs the channels as JPEG's own luma
        (``LUMA_601``, full resolution; :func:`~nurbscan.detect.normalize.normalize`'s
        ``weights``) and the points are not re-measured per channel (no ``refine``). 7.1 MP
        teapot view at 1x noise through JPEG 4:2:0 at quality 95: RMS 0.104 px (1 wrong
        line over 20 px) -> 0.080 px without the re-measurement -> 0.069 px with the luma
        weights too, no wrong line, coverage 0.668 -> 0.668 -> 0.666; 4:2:2: 0.078 -> 0.068
        -> 0.062 px, coverage 0.692 -> 0.673 -> 0.671. 1280 x 960 view, 4:2:0: 0.084 ->
        0.072 -> 0.065 px, coverage 0.526 -> 0.500 -> 0.471 (the price of accuracy in its
        narrow bands); 4:2:2: 1 wrong line -> none. JPEG 4:4:4 is a full-colour image
        (0.0497 px with the re-measurement, 0.058 px without).
    """

    gamma: float = 2.2
    window: int = 31
    chroma_subsampled: bool = False

    def __post_init__(self) -> None:
        if not self.gamma > 0:
            raise NurbscanError(f"gamma={self.gamma!r}: must be positive")


@dataclass(frozen=True)
class EdgeOptions(_Group):
    """The edge points (:func:`~nurbscan.detect.chains.find_edges`).

    Parameters
    ----------
    sigma : float, optional
        Scale of the Gaussian derivative filters across the edges, camera px; default
        :func:`auto_sigma` of the band width measured in a first pass.
    sigma_per_band : float, optional
        The default ``sigma`` is the band width over this (:func:`auto_sigma`); by default
        10 at the noise of the default render and 8 from a noise 2.5 times that
        (:func:`per_band_for_noise` of the measured noise). A narrower filter resolves more
        of the bands that the surface squeezes (``nurbscan reconstruct`` uses 10: teapot
        demo scan, Gordon coverage 84.2 -> 86.2 %).
    threshold : float
        Least gradient of an edge in the normalised signal, per px.
    dominance : float
        Gradient dominance of an edge point's class
        (:func:`~nurbscan.detect.edges.detect_edge_points`); below 1 edge pixels next to a
        crossing band's corner also join their lines, so more lines are traced through and
        labelled (7.1 MP teapot, with ``dominance=0.5, corner_keep=1, refit_residual=0.15``:
        coverage 53.3 -> 57.2 %, labels 99.88 %, RMS 0.054 -> 0.058 px; a few intersections
        of short lines go wrong). Default 1: one class per pixel, as before.
    corner_dominance : float
        Edge points found only with a gradient dominance below ``dominance`` and at least this
        (the corner pixels beside a crossing band, where the other family's gradient dominates
        but the edge's row (column) profile still peaks) are not traced. Where the bands are
        resolved (``FINE_BAND_PX``), after every filter and the grid intersections, those of at
        least ``min_strength`` extend the final lines they continue (:func:`extend_lines`), each
        kept when it lies within ``CORNER_RESIDUAL`` camera px of the straight line through its
        line's other points within 6 chain positions. The lines, their labels and the
        intersections stay as they are. 1 disables (``nurbscan reconstruct`` does: with its
        point filters off they reached the curve fits unchecked, Gordon coverage 90.09 -> 89.86
        %; and the calibration, whose points are all fitted). 7.1 MP teapot view 0 at 1x noise:
        coverage 0.6666 -> 0.6863 (within 2 px of a crossing band 0.448 -> 0.531), RMS 0.0458 ->
        0.0468 px; demo scan views 0-7: coverage 0.6910 -> 0.7123, RMS 0.0442 -> 0.0453 px,
        labels unchanged; 1280 x 960 teapot: 0.542 -> 0.571 (``CORNER_RESIDUAL`` 0.15: view 0
        0.6907, RMS 0.048 px). Tracing them instead (``dominance=0.5``: 0.6918 on view 0) let a
        squeezed spout side take a body edge's band across the depth step (two wrong lines over
        20 px in demo view 5).
    families : bool
        Tell vertical-band from horizontal-band edge pixels by the two families' local
        directions (:func:`~nurbscan.detect.oblique.family_normals`) instead of by ``|g_x|``
        against ``|g_y|``: where the vertical bands tilt past 45 degrees (the teapot's lid)
        they are otherwise read as horizontal and spoil that family's decoding too. 7.1 MP
        teapot views 0-7, with the slope-following tracer and the tilt-aware refinement:
        coverage 0.625 -> 0.661, RMS 0.046 -> 0.042 px, labels 99.999 %, no wrong line
        (without it the refinement keeps the misread lid edges: RMS 0.093 px). Only where
        the bands are resolved (``FINE_BAND_PX``): bands 3 px wide give the gradient
        directions spurious modes (a 640 x 480 view of the calibration board has one at 45
        degrees).
    oblique : bool
        Find and re-measure each family's edges by its own component of the gradient, the
        derivative along the other family's edges (``families``;
        :func:`~nurbscan.detect.oblique.across_operators`), instead of the row and column
        derivatives, which the crossing bands' edges disturb where the two families are not
        upright (only with ``families``, where the bands are resolved). 7.1 MP teapot view
        (the other options at their defaults): coverage 0.690 -> 0.702 (within 2 px of a
        crossing band 0.551 -> 0.590), RMS 0.0449 -> 0.0400 px, intersections 0.156 ->
        0.137 px; teapot demo scan reconstruction: Gordon coverage 90.09 -> 90.24 %, Gordon
        mean 0.0128 -> 0.0122 mm.
    fit_line : {"balanced", "row"}
        With ``oblique``, the line along which each edge point's profile is fitted (first
        pass and re-measurement): "balanced", the line on which a crossing band's two shifts
        of the profile's peak cancel (:func:`~nurbscan.detect.oblique.fit_slopes`, module notes
        of :mod:`~nurbscan.detect.oblique`), or the pixel row (column). 7.1 MP teapot view 0,
        row -> balanced: at 1x noise coverage 0.7009 -> 0.7240 (within 2 px of a crossing
        band 0.588 -> 0.639), RMS 0.0398 -> 0.0371 px, intersections 0.138 -> 0.147 px; at 0x
        0.7390 -> 0.7555, 0.0294 -> 0.0260 px; at 3x 0.6040 -> 0.6291, 0.0646 -> 0.0623 px;
        demo scan views 0-7: coverage 0.7347 -> 0.7565, RMS 0.0396 -> 0.0365 px, no wrong
        line; 1280 x 960 teapot: 0.5590 -> 0.5780, 0.0528 -> 0.0532 px; calibration
        benchmark, held-out pose 0.0149 -> 0.0143 mm; demo reconstruction: Gordon mean
        0.01200 -> 0.01209 mm, coverage 90.05 -> 90.00 %.
    camera_blur : float
        The camera lens's blur, Gaussian sigma in camera px, used by the balanced fit line
        (part of the blur that mixes the two families; the simulator's default 0.5). 7.1 MP
        view at 1x noise, 0 -> 1 px: coverage 0.7235 -> 0.7277, RMS 0.0372 -> 0.0377 px.
    """

    sigma: float | None = None
    sigma_per_band: float | None = None
    threshold: float = 0.06
    dominance: float = 1.0
    corner_dominance: float = 0.3
    families: bool = True
    oblique: bool = True
    fit_line: str = "balanced"
    camera_blur: float = 0.5

    _CHOICES = {"fit_line": ("balanced", "row")}

    def __post_init__(self) -> None:
        if self.sigma is not None and not self.sigma > 0:
            raise NurbscanError(f"sigma={self.sigma!r}: must be positive")
        if not 0 < self.dominance <= 1 or not 0 < self.corner_dominance <= 1:
            raise NurbscanError(f"dominance={self.dominance!r}, corner_dominance="
                                f"{self.corner_dominance!r}: need 0 < dominance <= 1 and "
                                "0 < corner_dominance <= 1")
        super().__post_init__()


@dataclass(frozen=True)
class ChainOptions(_Group):
    """The chains: tracing (:func:`~nurbscan.detect.chains.trace_chains`) and the smoothing
    of the final ones.

    Parameters
    ----------
    min_length : int
        Fewest points of an edge line.
    smooth_reach : int
        Half-width (camera px along the edge) of the local weighted line that smooths each
        final chain (:func:`~nurbscan.detect.lines.smooth_chains`); 0 keeps the points as
        measured. The intersections are fitted to the measured points. 7.1 MP teapot view:
        RMS 0.0468 -> 0.0427 px; demo scan views 0.0453 -> 0.0422 px (mean of 8).
    """

    min_length: int = 4
    smooth_reach: int = 3


@dataclass(frozen=True)
class ReadingOptions(_Group):
    """The band crossings and their colours (:func:`~nurbscan.detect.crossings.read_colours`).

    Parameters
    ----------
    read_along : {"grid", "pixels"}
        The runs along which band crossings are paired and colour windows read (each
        family's "rows", :func:`~nurbscan.detect.decode.band_crossings`): "grid", along the
        other family's edges (:func:`~nurbscan.detect.decode.oblique_runs`, where the bands
        are resolved and the families told apart), or "pixels", the pixel rows (columns).
        Where the surface shears the grid the pixel column leaves each cell after one band
        and reads no window (the teapot's lid and the turning sides); along the grid the
        cells of one column line up. 7.1 MP teapot view 0, pixels -> grid: at 1x noise
        coverage 0.7592 -> 0.7841, RMS 0.0398 -> 0.0429 px, intersections 0.174 -> 0.165 px;
        at 0x 0.7824 -> 0.7986, 0.0275 -> 0.0284 px; at 3x 0.6800 -> 0.6966, 0.0687 -> 0.0701
        px; demo scan views 0-7: 0.7885 -> 0.8029, RMS 0.0388 -> 0.0416 px (at most 0.0446,
        with ``TAIL_RESIDUAL`` 3), labels 100 %, no wrong line; a view sheared by 40 degrees
        (``tests/test_detect.py``): 0.717 -> 0.842 (0.722 -> 0.843 with the default
        ``min_checked_length``). About 0.2 s more on a 7.1 MP view.
    corner_keep : float
        A rising / falling pair counts as a band crossing (its points kept) only where both
        points' gradient across their edge is at least this times the one along it; 0 keeps
        all (with ``dominance < 1`` use 1: the corner pixels then serve only tracing and
        labelling).
    min_width : float
        (This and ``KEEP_UNPAIRED``, ``partner_drops``, ``min_row_support``,
        ``max_row_residual``, ``keep_unsupported``, ``INTERPOLATION_ROUNDS``,
        ``collinear_rounds`` and ``pool_gap`` apply where the bands are resolved, at least
        ``FINE_BAND_PX`` = 4 px wide; narrower bands use the plain rules: no unpaired points,
        no width, partner or row checks, no labels by interpolation, unknown colours or
        pooled votes.)
        Keep the points of band crossings at least this many ``sigma`` wide only: the edges
        of narrower (squeezed) bands are biased outwards (7.1 MP teapot, sigma 1.46 px: RMS
        0.16 px for bands 4-5 px wide, 0.085 px at 5-6 px, 0.05 px above 6 px); 0 keeps all.
    """

    read_along: str = "grid"
    corner_keep: float = 0.0
    min_width: float = 3.5

    _CHOICES = {"read_along": ("grid", "pixels")}

    def __post_init__(self) -> None:
        if not self.corner_keep >= 0:
            raise NurbscanError(f"corner_keep={self.corner_keep!r}: must be >= 0")
        super().__post_init__()


@dataclass(frozen=True)
class DecodeOptions(_Group):
    """Decoding and propagation of the labels (:func:`~nurbscan.detect.labels.decode_labels`).

    Parameters
    ----------
    min_votes, min_agreement : int, float
        Least votes for, and share of votes of, a line's band index.
    pool_gap : float
        Pool the window votes of the pieces of one edge before they are decided
        (:func:`pooled_labels`): pieces are joined across gaps up to ``pool_gap`` times
        ``join_gap`` whose end fits predict each other within ``POOL_TOL`` camera px (looser
        than the joins that carry labels: a wrong join here only mixes votes, which then
        disagree). ``pool_gap=0`` disables. On the teapot's lid the tilted vertical bands cut
        every horizontal edge into cell-long pieces, none with votes from three window
        positions. 7.1 MP teapot views 0-7 at 1x noise: coverage 0.6733 -> 0.6848, RMS 0.0419
        -> 0.0435 px (most of it one piece of an occluding contour in view 1, right label,
        2.5 px off), labels 99.998 %, no wrong line; demo Gordon coverage 53.2 -> 54.8 %.
        Only where the bands are resolved (``FINE_BAND_PX``): on 3 px bands the loose joins
        link neighbouring edges and wrong labels reach the calibration.
    collinear_rounds : int
        Further rounds of :func:`propagate_collinear` alone (labels carried along the pieces of
        one edge cut by crossing bands) after the propagation above.
    find_orientation : bool
        Find the grid's orientation from the colour windows
        (:func:`~nurbscan.detect.orientation.grid_orientation`) and, when the photograph is
        rotated by 90, 180 or 270 degrees, mirrored or transposed, detect its upright image
        and map the result back (a warning says so); before that, a photograph whose grid is
        turned by about 45 degrees (:data:`~nurbscan.detect.tilt.MIN_MARGIN_DEG`) is read in
        its image turned level (:func:`~nurbscan.detect.tilt.detect_tilted`). False reads it
        as upright.
    """

    min_votes: int = 3
    min_agreement: float = 0.9
    pool_gap: float = 2.0
    collinear_rounds: int = 5
    find_orientation: bool = True


@dataclass(frozen=True)
class FamilyOptions(_Group):
    """Labels from the family fits (:func:`~nurbscan.detect.families.family_labels`).

    Parameters
    ----------
    fit_rounds : int
        Rounds of labels from the family's own camera-to-projector map, after the colour
        windows, their propagation and :func:`interpolate_labels`, where the bands are
        resolved: every point of an unlabelled line gets its projector coordinate from a
        local plane through the labelled points of its family within ``FIT_RADIUS`` camera
        pitches (:func:`family_coordinates`; none where their RMS residual exceeds
        ``FIT_RMS`` projector px or where it would extrapolate), the candidate edge must
        agree with the edge count of the point's row (column) towards its labelled
        neighbours (:func:`row_consistent`) or, with ``read_along`` "grid", of its grid run
        (a pixel column through slanted bands of the other family misses the edges hidden
        in them; 7.1 MP teapot view 0 at 1x: coverage 0.7942 -> 0.7980, RMS 0.0437 ->
        0.0439 px; 0x 0.8097 -> 0.8137; 3x 0.7100 -> 0.7153, 0.0716 -> 0.0740 px; demo
        scan views 0-7 0.8132 -> 0.8155, RMS 0.0421 -> 0.0424 px, worst view 0.0449 ->
        0.0456 px, no wrong line), and a line takes the band its points vote for
        within ``FIT_TOL`` pitches, with the points that fit no edge voting against
        (:func:`epipolar_labels` with ``dissent``) and its colour not contradicting it. 0
        disables (``nurbscan reconstruct`` does: with the rig the epipolar prediction labels
        these pieces, and the two together gave Gordon coverage 90.09 -> 90.01 %). 7.1 MP
        teapot view 0 at 1x noise: coverage 0.6588 -> 0.6677, RMS 0.0453 -> 0.0466 px; demo
        scan views 0-7: coverage 0.6848 -> 0.6917, RMS 0.0435 -> 0.0454 px, labels 99.998 %,
        no wrong line (without the row check, three rounds: 0.6981, but a handle's side
        squeezed between two surfaces took a band three pitches off: one wrong line over
        20 px); about 0.1 s per round on a 7.1 MP view (a third round: +0.001).
    fit_reach : float
        How far (pattern pitches) the plane of ``fit_rounds`` may predict beyond the least and
        largest coordinate of the labelled points it is fitted to, for the points of lines at
        least one pitch long (shorter ones must lie two projector px inside, the rule for
        all before); negative values demand that much inside. One pitch lets each round label
        the next edges beyond the last labelled row (column): where the bands of the other
        direction slant across a surface that turns away (the teapot's lower body) the colour
        windows fail on the outer rows, and the row check (:func:`row_consistent`) still counts
        the edges to the labelled neighbours. 7.1 MP teapot view 0 at 1x noise: coverage
        0.7240 -> 0.7278, RMS 0.0371 -> 0.0374 px; demo scan views 0-7: 0.7565 -> 0.7601, RMS
        0.0365 -> 0.0366 px, labels 100 %, no wrong line; 1280 x 960 teapot: 0.5780 -> 0.5803.
        For short lines too it gave 0.7320 on view 0, but on the 1280 x 960 view a 12 px
        piece of the lid's occluding contour took the hidden edge of the band beside it
        (its grid intersection 6 px off); with 4 rounds, one wrong line over 20 px.
    """

    fit_rounds: int = 2
    fit_reach: float = 1.0


@dataclass(frozen=True)
class RefineOptions(_Group):
    """The decoded lines' points: selection, re-measurement and point filters
    (:mod:`~nurbscan.detect.refine`).

    Parameters
    ----------
    min_strength : float
        Least edge derivative (:attr:`~nurbscan.detect.edges.EdgePoints.strength`) of an
        edge point kept in the result, per px.
    max_residual : float
        Drop edge points farther than this (px) from the straight line through their chain
        neighbours (:func:`~nurbscan.detect.lines.local_residual`); 0 keeps them.
    min_paired : int
        Fewest points of a labelled line that are one edge of a band crossing (a rising /
        falling pair of plausible width along the row or column); lines with fewer are
        dropped. Where a band is squeezed or half hidden its partner edge is often missing:
        ``nurbscan reconstruct`` keeps such lines (0) and leaves them to the network's
        crossing test (teapot demo scan: Gordon coverage 83.4 -> 84.2 %).
    refit_residual : float
        After refinement, drop points farther than this (px) from the straight line through
        their chain neighbours; 0 keeps them. The distance is perpendicular to that line
        (:func:`~nurbscan.detect.lines.local_residual`; so is ``max_residual``'s): measured
        along the pixel row (column) instead, the edges that slant across their rows (the
        vertical bands on the teapot's lower body and lid) lost their points to noise
        enlarged by ``sqrt(1 + slope^2)``. 7.1 MP teapot view 0, along the row ->
        perpendicular: at 1x noise coverage 0.7431 -> 0.7537, RMS 0.0391 -> 0.0396 px,
        intersections 0.155 -> 0.161 px; at 0x 0.7781 -> 0.7820, 0.0269 -> 0.0276 px; at 3x
        0.6512 -> 0.6632, 0.0653 -> 0.0660 px; demo scan views 0-7: 0.7744 -> 0.7845, RMS
        0.0396 -> 0.0402 px, no wrong line; 1280 x 960 view 0.5944 -> 0.6012, 0.0559 ->
        0.0568 px.
    partner_drops : {"unmeasured", "all", "none"}
        After the refinement, drop a point whose crossing's other edge point (same row, same
        band) was dropped: "all" whatever dropped it, "unmeasured" only when it went for
        want of a clean re-measurement (``UNREFINED``), "none" never. A partner dropped as a
        kink off its re-measured neighbours (``refit_residual``, a disturbed corner on its
        side of the band) leaves the point alone with "unmeasured": 7.1 MP teapot view 0 at
        1x noise, coverage 0.7525 ("all") -> 0.7592, RMS 0.0394 -> 0.0398 px, intersections
        0.161 -> 0.174 px; demo views 0-7 0.7835 -> 0.7885, RMS 0.0383 -> 0.0388 px. "none" also
        keeps the points beside unmeasured partners, among them the turn of an edge into a
        crossing band of its colour (demo view 5: 14 points 6-19 px off, RMS 0.087 px).
    end_residual : float
        Drop the first and the last point of every chain when farther than this (camera px)
        from the straight line through the chain's next points (:func:`chain_end_residual`);
        0 keeps them. A chain ends where a crossing band's corner, an occluding contour or a
        gap disturbs the profile on one side only, so its ends are the least exact points: on
        the 7.1 MP teapot view 0 at 1x noise, 0.1 % of the points (errors over 0.46 px) carry
        13 % of the squared error, and half of the points over 0.27 px are chain ends. Views
        0-7 at 1x noise: mean RMS 0.0494 -> 0.0460 px, coverage 0.629 -> 0.625 (0.1 px:
        0.0454 px, 0.624).
    """

    min_strength: float = 0.12
    max_residual: float = 0.3
    min_paired: int = 2
    refit_residual: float = 0.2
    partner_drops: str = "unmeasured"
    end_residual: float = 0.15

    _CHOICES = {"partner_drops": ("unmeasured", "all", "none")}


@dataclass(frozen=True)
class CheckOptions(_Group):
    """The checks of the lines against their rows and intersections
    (:func:`~nurbscan.detect.checks.check_lines`).

    Parameters
    ----------
    min_row_support : float
        Drop lines with a smaller share of points supported by labelled neighbours in their
        row or column (:func:`row_support`); 0 keeps them.
    max_row_residual : float
        Drop points farther than this (camera px) from the extrapolation of the two labelled
        edges beside them in their row (column) when they have no neighbour on the other
        side (:func:`row_support`); 0 keeps them. On the 7.1 MP teapot such points beyond
        1.2 px have an RMS error of 0.3 px. Also drop lines that no consistent grid
        intersection confirms and whose supported points lie, on median, farther than this
        across the line from their rows' prediction (:func:`row_disagreement`): demo scan
        view 4, a 14 px edge inside the crossing of two red bands, 0.4 -> 5 px off its
        labelled edge, took the RMS from 0.039 to 0.055 px; without it, 0.041 px (coverage
        0.7604 -> 0.7597; 7.1 MP teapot view 0: 0.7537 -> 0.7525).
    keep_unsupported : bool
        Keep points with no labelled neighbours within two pitches in their row or column
        (:func:`row_support`; 7.1 MP teapot: 2.6 % of the points, RMS 0.14-0.17 px).
    plane_radius : float
        Before those three filters, a point without support in its row (column) or farther
        than ``max_row_residual`` from its row's extrapolation is supported after all when
        it lies within ``PLANE_TOL`` camera px of the edge that a plane through the
        ``PLANE_K`` nearest points of other lines of its family, within ``plane_radius``
        pattern pitches, predicts (:func:`plane_support`): where the other family's bands
        slant across a surface (the teapot's lower body) they hide a piece's neighbours in
        most of its rows, and where the band spacing changes along a row its extrapolation
        is poor (a row's extrapolation a quarter pitch off or more is left to the row: the
        line's label is misread, and pieces of one misread edge would support each other).
        ``plane_radius=0`` disables. 7.1 MP teapot view 0: at 1x noise coverage 0.7282 ->
        0.7431, RMS 0.0375 -> 0.0391 px; at 0x 0.7645 -> 0.7781, 0.0263 -> 0.0269 px; at 3x
        0.6353 -> 0.6512, 0.0632 -> 0.0653 px; labels 100 %, no wrong line; demo scan views
        0-7: 0.7602 -> 0.7744, RMS 0.0366 -> 0.0396 px, no wrong line; 1280 x 960 view
        0.5803 -> 0.5944, 0.0534 -> 0.0559 px.
    new_end_residual : float
        The row-support filters (``max_row_residual``, ``keep_unsupported``) drop points and
        can leave a point beside them as a chain's new first or last point; after them the
        two ends of every chain are tested again, those farther than this (camera px) from
        the straight line through their chain's next points dropped, up to three times
        (:func:`chain_end_residual`; points beside a gap inside a chain are not tested); 0
        keeps them. 7.1 MP teapot view 0: RMS 0.0466
        -> 0.0458 px, coverage 0.6677 -> 0.6666 (with ``dominance=0.5``: the points off by
        more than 1 px 16 -> 10, carrying 68 -> 55 % of the squared error); demo scan views
        0-7: RMS 0.0454 -> 0.0442 px, coverage 0.6917 -> 0.6910.
    min_checked_length : float
        Drop lines shorter than this many pattern pitches (in camera px, from the measured
        band width; one point per px) that have no consistent grid intersection
        (:func:`grid_consistency`); 0 (default) keeps them. Half a pitch (about 12 px on
        the teapot views) once dropped a 9 px piece read as the other family's at the bottom
        of the teapot (demo scan view 4, RMS 0.0417 -> 0.0523 px without the check); the end
        test ``TAIL_RESIDUAL`` and the grid runs (``read_along``) now keep such pieces out,
        and the check drops mostly exact short pieces (7.1 MP teapot view 0 at 1x noise:
        the 4,398 points it drops have p95 error 0.157 px against 0.099 px for the points
        kept, RMS 0.22 px from a few outliers; coverage 0.7841 -> 0.7942, RMS 0.0429 ->
        0.0437 px without it). Demo views 0-7 with 0.5 / 0: mean coverage 0.8029 / 0.8132, mean RMS
        0.0416 / 0.0421 px, worst view 0.0446 / 0.0449 px, no wrong line over 20 px.
    refuse_one_family : bool
        Refuse the whole decoding (an empty result with the reason) when the lines of one
        family are labelled and not one of the other
        (:func:`~nurbscan.detect.checks.check_labels`: a view rotated by 90 degrees, 1-2 % of
        its labels right); False keeps them.
    """

    min_row_support: float = 0.1
    max_row_residual: float = 1.0
    keep_unsupported: bool = False
    plane_radius: float = 2.0
    new_end_residual: float = 0.5
    min_checked_length: float = 0.0
    refuse_one_family: bool = True


#: The groups of :class:`DetectOptions`: attribute name -> class.
GROUPS: dict[str, type] = {
    "image": ImageOptions, "edges": EdgeOptions, "chains": ChainOptions,
    "reading": ReadingOptions, "decoding": DecodeOptions, "fits": FamilyOptions,
    "refine": RefineOptions, "checks": CheckOptions,
}

#: field name -> its group's attribute name (field names are unique across the groups)
FIELD_GROUP: dict[str, str] = {f.name: g for g, c in GROUPS.items() for f in fields(c)}


@dataclass(frozen=True)
class DetectOptions:
    """Every option of :func:`~nurbscan.detect.detect_grid`, one group per stage.

    Attributes
    ----------
    image : ImageOptions
        Linearisation and normalisation of the photograph.
    edges : EdgeOptions
        Edge points (filter scale, threshold, families, fit line).
    chains : ChainOptions
        Tracing, and the smoothing of the final chains.
    reading : ReadingOptions
        Band crossings and the colours read on them.
    decoding : DecodeOptions
        The labels from the colour windows and their propagation.
    fits : FamilyOptions
        The labels from each family's own camera-to-projector map (the family fits).
    refine : RefineOptions
        The decoded lines' points: selection, re-measurement, point filters.
    checks : CheckOptions
        The checks of the lines against their rows and grid intersections.
    """

    image: ImageOptions = field(default_factory=ImageOptions)
    edges: EdgeOptions = field(default_factory=EdgeOptions)
    chains: ChainOptions = field(default_factory=ChainOptions)
    reading: ReadingOptions = field(default_factory=ReadingOptions)
    decoding: DecodeOptions = field(default_factory=DecodeOptions)
    fits: FamilyOptions = field(default_factory=FamilyOptions)
    refine: RefineOptions = field(default_factory=RefineOptions)
    checks: CheckOptions = field(default_factory=CheckOptions)

    def replace(self, **changes) -> DetectOptions:
        """A copy with ``changes``: a group's name with a group (or a dict of its fields),
        or a field's name (of any group) with its value. Unknown names raise
        :class:`~nurbscan.errors.NurbscanError`."""
        groups = {g: getattr(self, g) for g in GROUPS}
        per: dict[str, dict] = {}
        for name, value in changes.items():
            if name in GROUPS:
                if isinstance(value, dict):
                    groups[name] = dataclasses.replace(groups[name], **value)
                elif isinstance(value, GROUPS[name]):
                    groups[name] = value
                else:
                    raise NurbscanError(f"detect options: {name} must be a "
                                        f"{GROUPS[name].__name__} or a dict")
            elif name in FIELD_GROUP:
                per.setdefault(FIELD_GROUP[name], {})[name] = value
            else:
                raise NurbscanError(f"detect options: unknown option {name!r}")
        for g, ch in per.items():
            groups[g] = dataclasses.replace(groups[g], **ch)
        return DetectOptions(**groups)

    def changes(self) -> dict[str, Any]:
        """The fields that differ from the defaults, by name (flat)."""
        default = DetectOptions()
        out = {}
        for g in GROUPS:
            mine, theirs = getattr(self, g).to_dict(), getattr(default, g).to_dict()
            out.update({k: v for k, v in mine.items() if v != theirs[k]})
        return out

    def to_dict(self) -> dict[str, dict[str, Any]]:
        """Nested dict (group -> field -> value), JSON-ready."""
        return {g: getattr(self, g).to_dict() for g in GROUPS}

    @classmethod
    def from_dict(cls, d) -> DetectOptions:
        """Inverse of :meth:`to_dict`; missing groups and fields keep their defaults."""
        unknown = sorted(set(d) - set(GROUPS))
        if unknown:
            raise NurbscanError(f"detect options: unknown group {', '.join(unknown)}")
        return cls(**{g: GROUPS[g].from_dict(v) for g, v in d.items()})
