"""The strong multi-shot peer: N-step phase shifting unwrapped by complementary Gray code.

What desktop structured-light scanners use when the object holds still (SLStudio, most
commercial scanners): sinusoidal fringes shifted N times resolve a small fraction of a projector
pixel (Srinivasan, Liu and Halioua 1984, "Automated phase-measuring profilometry of 3-D diffuse
objects", Appl. Opt. 23(18); Geng 2011, "Structured-light 3D surface imaging: a tutorial",
Adv. Opt. Photon. 3, section 3.3; Zhang 2018, "High-speed 3D shape measurement with structured
light methods: A review", Opt. Lasers Eng. 106, section 2.2). For one view and each direction
(projector columns ``x``, then rows ``y``):

1. **Patterns** (:class:`PhaseShift`). ``steps`` = N >= 4 fringe images of period ``T``
   projector px, image n at projector pixel x (grey level of 255)::

       I_n(x) = 1/2 + 1/2 cos(phi(x) - 2 pi n / N),   phi(x) = 2 pi (x + 1/2) / T,

   quantised to 8 bits (a projector shows integers), so that phi = 0 on the left border of
   pixel 0 and a period spans exactly T pixels; then the ``m + 1`` bit planes (most
   significant first) of the Gray code of the half-period index ``j = floor(x / (T / 2))``,
   ``m = ceil(log2(ceil(size / T)))``: the complementary Gray code of Zhang, Su, Xiang and Sun
   2012 ("3-D shape measurement based on complementary Gray-code light", Opt. Lasers Eng. 50,
   574-579), whose first m planes are the ordinary m-bit Gray code of the period index and
   whose last plane, half a period finer, gives a second period index shifted by half a period.
   2 (N + m + 1) images per view (24 for N = 4, T = 16 at 1920 x 1080).
2. **Rendering**: every image is one band per projector pixel with its grey level (or a stripe
   set for the Gray code), rendered by :func:`nurbscan.peers.graycode.render_stripe_images`
   exactly as the Gray-code peer: the same ray-traced view, the same light model (the
   projector's Gaussian defocus integrated over each camera pixel's footprint), the same sensor
   (lens blur, shot and read noise, gamma, 8 bits) and grey conversion.
3. **Decoding** (:func:`decode`), vectorised over the pixels: the grey images are linearised by
   the camera's response (``camera_gamma``, a radiometric calibration of the camera; the
   phase of a gamma-encoded sinusoid would carry harmonics); the N-step least-squares phase
   (Geng 2011 eq. 13, Zhang 2018 eq. 4) ``phi_w = atan2(sum I_n sin d_n, sum I_n cos d_n)``,
   ``d_n = 2 pi n / N``, taken into [0, 2 pi); the average ``A = mean I_n`` and the modulation
   ``B = (2 / N) |sum I_n exp(i d_n)|``; each Gray bit is 1 where its image exceeds A (the
   threshold halfway between its black and its white). With the half-period index j decoded
   (Gray to binary), ``k1 = floor(j / 2)`` and ``k2 = floor((j + 1) / 2)`` (Zhang et al. 2012
   eq. 7)::

       Phi = phi_w + 2 pi k2          if phi_w <= pi / 2
             phi_w + 2 pi k1          if pi / 2 < phi_w < 3 pi / 2
             phi_w + 2 pi (k2 - 1)    if phi_w >= 3 pi / 2,

   so that the period index is always read from a code whose own transitions are a quarter
   period away (no period-border jumps). The projector coordinate is
   ``x = Phi T / (2 pi) - 1/2`` px. A pixel is kept where both directions' modulation is at
   least ``min_modulation`` (the shadow mask) and the coordinates lie in the projector image.
4. **Triangulation** with the same calibrated rig and the same function as the Gray-code peer
   (:func:`nurbscan.reconstruct.intersect_exact`): the camera ray meets the exact light surface
   of the sub-pixel column ``x``; the row decoded independently is the check (points whose
   projector row differs from the decoded one by more than ``epipolar_tolerance`` px are
   dropped: wrong period orders, mixed pixels at silhouettes).

The phase noise of N-step phase shifting is ``sigma_phi = sqrt(2 / N) sigma_I / B``
(intensity noise sigma_I; Zhang 2018 section 2.2), hence ``sigma_x = T sigma_phi / (2 pi)``:
a few hundredths of a projector pixel at T = 16 px on a matte surface.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..errors import NurbscanError
from .graycode import StripeCapture, _runs, render_stripe_images, view_figures

TYPE = "nurbscan.phase_shift"
VERSION = 1
_FIRST_KIND = 1000  # noise stream kinds of the images (the Gray-code peer's start at 2)
_FIELDS = ("width", "height", "period", "steps", "camera_gamma", "min_modulation",
           "epipolar_tolerance")


@dataclass(frozen=True)
class PhaseShift:
    """The N-step phase-shift pattern set of a projector and its decoder options.

    Attributes
    ----------
    width, height : int
        Projector size, px.
    period : int
        Fringe period T, projector px (even, >= 4). Default 16.
    steps : int
        Phase steps N per direction (>= 4; N >= 4 makes the phase immune to the harmonics up
        to order N - 2 of the camera's response). Default 4.
    camera_gamma : float
        Encoding gamma of the camera's images, undone before decoding (radiometric
        calibration; 1 = linear images). Default 2.2.
    min_modulation : float
        Least fringe modulation B of a decoded pixel, as a fraction of the full scale of the
        linearised image (the shadow mask). Default 0.02 (the dark table top, albedo 0.03,
        stays below it).
    epipolar_tolerance : float
        Largest difference (projector px) between the decoded projector row and the row of the
        triangulated point. Default 1.
    """

    width: int = 1920
    height: int = 1080
    period: int = 16
    steps: int = 4
    camera_gamma: float = 2.2
    min_modulation: float = 0.02
    epipolar_tolerance: float = 1.0
    type: str = field(default=TYPE, repr=False)

    def __post_init__(self) -> None:
        def integer(name: str, lo: int, hi: int) -> None:
            v = getattr(self, name)
            if not isinstance(v, int | np.integer) or not lo <= v <= hi:
                raise NurbscanError(f"phase shift {name}={v!r}: must be an integer {lo}..{hi}")

        integer("width", 2, 1 << 15)
        integer("height", 2, 1 << 15)
        integer("steps", 4, 64)
        integer("period", 4, 1 << 15)
        if self.period % 2:
            raise NurbscanError(f"phase shift period={self.period}: must be even")
        for name in ("camera_gamma", "epipolar_tolerance"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and math.isfinite(v) and v > 0):
                raise NurbscanError(f"phase shift {name}={v!r}: must be a finite number > 0")
        v = self.min_modulation
        if not (isinstance(v, int | float) and 0 <= v < 1):
            raise NurbscanError(f"phase shift min_modulation={v!r}: must be in [0, 1)")

    @classmethod
    def for_projector(cls, projector, **kw: Any) -> PhaseShift:
        """The pattern set at a projector's size."""
        return cls(width=int(projector.width), height=int(projector.height), **kw)

    def size(self, direction: str) -> int:
        """Projector size across the fringes of ``direction`` ("vertical": the width), px."""
        return self.width if direction == "vertical" else self.height

    def gray_bits(self, direction: str) -> int:
        """Planes m + 1 of the complementary Gray code across ``direction``."""
        periods = -(-self.size(direction) // self.period)
        return max(int(math.ceil(math.log2(periods))), 0) + 1

    @property
    def n_images(self) -> int:
        """Images projected per view: N fringes and m + 1 Gray planes per direction."""
        return sum(self.steps + self.gray_bits(d) for d in ("vertical", "horizontal"))

    def fringe_levels(self, direction: str) -> np.ndarray:
        """Grey levels (N, size) uint8 of the N fringe images (module notes, step 1)."""
        x = np.arange(self.size(direction))
        phi = 2 * np.pi * (x + 0.5) / self.period
        d = 2 * np.pi * np.arange(self.steps)[:, None] / self.steps
        return np.rint(127.5 + 127.5 * np.cos(phi[None, :] - d)).astype(np.uint8)

    def gray_levels(self, direction: str) -> np.ndarray:
        """Grey levels (m + 1, size) uint8 (0 or 255) of the Gray-code planes, MSB first."""
        nb = self.gray_bits(direction)
        j = np.arange(self.size(direction)) // (self.period // 2)
        g = j ^ (j >> 1)
        bits = (g[None, :] >> (nb - 1 - np.arange(nb))[:, None]) & 1
        return (255 * bits).astype(np.uint8)

    def images(self) -> list[tuple[str, np.ndarray, np.ndarray | None]]:
        """The projector images as bands ``(direction, edges (n, 2), levels (n,) or None)``.

        Order: the N fringes across x, the Gray planes across x, then the same across y. A
        fringe image is one band per projector pixel ``[x - 1/2, x + 1/2]`` at its level; a
        Gray plane is its runs of white (docs/conventions.md: pixel centres at integers).
        """
        out: list[tuple[str, np.ndarray, np.ndarray | None]] = []
        for direction in ("vertical", "horizontal"):
            x = np.arange(self.size(direction), dtype=float)
            cells = np.stack([x - 0.5, x + 0.5], axis=1)
            for lv in self.fringe_levels(direction):
                keep = lv > 0
                out.append((direction, cells[keep], lv[keep]))
            for lv in self.gray_levels(direction):
                out.append((direction, _runs(lv), None))
        return out

    def projector_images(self) -> list[np.ndarray]:
        """The projector images as a projector shows them, each (height, width) uint8."""
        out = []
        for direction in ("vertical", "horizontal"):
            for lv in np.concatenate([self.fringe_levels(direction),
                                      self.gray_levels(direction)]):
                if direction == "vertical":
                    out.append(np.broadcast_to(lv[None, :], (self.height, self.width)).copy())
                else:
                    out.append(np.broadcast_to(lv[:, None], (self.height, self.width)).copy())
        return out

    def to_dict(self) -> dict[str, Any]:
        return {"type": TYPE, "version": VERSION, **{k: getattr(self, k) for k in _FIELDS}}

    @classmethod
    def from_dict(cls, d: Any, source: str = "phase shift") -> PhaseShift:
        if not isinstance(d, dict) or d.get("type") != TYPE:
            raise NurbscanError(f"{source}: not a {TYPE!r} object")
        extra = set(d) - {"type", "version", *_FIELDS}
        if extra:
            raise NurbscanError(f"{source}: unknown keys {sorted(extra)}")
        return cls(**{k: v for k, v in d.items() if k not in ("type", "version")})


def render_phase_shift(scene, rig, code: PhaseShift | None = None, angle: float = 0.0,
                       settings=None, seed: int = 0, stream: int = 0, mode: str = "fast",
                       workers: int | None = None, base=None) -> StripeCapture:
    """Render one view of ``scene`` under the whole phase-shift set (module notes, step 2).

    Parameters
    ----------
    scene : nurbscan.simulate.scenes.Scene
    rig : nurbscan.camera.Rig
        The true rig (rendering).
    code : PhaseShift, optional
        Default: the set at the projector's size.
    angle : float
        Table angle, radians.
    settings : nurbscan.simulate.RenderSettings, optional
    seed, stream : int
        Noise seed and stream of the view; image k uses the noise stream kind ``1000 + k``.
    mode : {"fast", "exact"}
        As :func:`nurbscan.peers.graycode.render_gray_code`.
    workers : int, optional
    base : RenderedView, optional
        As :func:`nurbscan.peers.graycode.render_stripe_images` (a shared dark render).

    Returns
    -------
    StripeCapture
        ``images`` in :meth:`PhaseShift.images` order, grey (H, W).
    """
    code = code or PhaseShift.for_projector(rig.projector)
    if (code.width, code.height) != (int(rig.projector.width), int(rig.projector.height)):
        raise NurbscanError(f"phase shift {code.width} x {code.height}: not the projector's "
                            f"size {rig.projector.width} x {rig.projector.height}")
    return render_stripe_images(scene, rig, code.images(), angle, settings, seed, stream, mode,
                                workers, first_kind=_FIRST_KIND, base=base)


def _linearise(img: np.ndarray, gamma: float) -> np.ndarray:
    """Camera grey image (8 or 16 bit) to linear [0, 1] float32 by its gamma (a lookup)."""
    img = np.asarray(img)
    top = 65535 if img.dtype == np.uint16 else 255
    lut = np.power(np.arange(top + 1, dtype=np.float64) / top, gamma).astype(np.float32)
    return lut[img]


def wrapped_phase(images: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """N-step phase, average and modulation of linear fringe images (module step 3).

    Parameters
    ----------
    images : list of N ndarray (H, W) float
        Linear images ``I_n = A + B cos(phi - 2 pi n / N)``.

    Returns
    -------
    phi : ndarray (H, W)
        Wrapped phase in [0, 2 pi), radians (Geng 2011 eq. 13).
    average, modulation : ndarray (H, W)
        A and B, same units as the images.
    """
    n = len(images)
    d = 2 * np.pi * np.arange(n) / n
    s = sum(np.float32(math.sin(a)) * im for a, im in zip(d, images, strict=True))
    c = sum(np.float32(math.cos(a)) * im for a, im in zip(d, images, strict=True))
    phi = np.mod(np.arctan2(s, c), 2 * np.pi)
    return phi, sum(images) / n, (2.0 / n) * np.hypot(s, c)


def unwrap(phi: np.ndarray, bits: list[np.ndarray], average: np.ndarray,
           period: int) -> np.ndarray:
    """Projector coordinate (px) from the wrapped phase and the complementary Gray code.

    Parameters
    ----------
    phi : ndarray (H, W)
        Wrapped phase in [0, 2 pi).
    bits : list of m + 1 ndarray (H, W)
        Linear images of the Gray planes, most significant first.
    average : ndarray (H, W)
        The fringes' average A (each plane's threshold).
    period : int
        Fringe period T, px.

    Returns
    -------
    ndarray (H, W)
        ``x = Phi T / (2 pi) - 1/2`` with Phi of Zhang et al. 2012 eq. 7 (module step 3).
    """
    g = np.zeros(phi.shape, np.int32)
    j = np.zeros(phi.shape, np.int32)
    for im in bits:  # Gray to binary, most significant bit first: b_i = b_(i-1) XOR g_i
        g ^= (im > average).astype(np.int32)
        j = (j << 1) | g
    k1, k2 = j >> 1, (j + 1) >> 1
    k = np.where(phi <= np.pi / 2, k2, np.where(phi >= 1.5 * np.pi, k2 - 1, k1))
    return (phi + 2 * np.pi * k) * (period / (2 * np.pi)) - 0.5


def decode(capture: StripeCapture, code: PhaseShift) -> tuple[np.ndarray, np.ndarray, dict]:
    """Sub-pixel projector column and row of every camera pixel (module step 3).

    Parameters
    ----------
    capture : StripeCapture
        Grey images in :meth:`PhaseShift.images` order (real or simulated).
    code : PhaseShift

    Returns
    -------
    column, row : ndarray (H, W) float64
        Projector coordinates, px; NaN where the modulation is below ``min_modulation`` in
        either direction or the coordinate falls outside the projector image.
    extra : dict
        ``modulation`` (H, W, 2) (columns, rows) and the wrapped ``phase`` (H, W, 2).
    """
    ims = capture.images
    if len(ims) != code.n_images:
        raise NurbscanError(f"phase shift: {len(ims)} images, the set has {code.n_images}")
    out, mods, phases = [], [], []
    k = 0
    for direction in ("vertical", "horizontal"):
        fr = [_linearise(im, code.camera_gamma) for im in ims[k:k + code.steps]]
        k += code.steps
        nb = code.gray_bits(direction)
        bits = [_linearise(im, code.camera_gamma) for im in ims[k:k + nb]]
        k += nb
        phi, avg, mod = wrapped_phase(fr)
        x = unwrap(phi, bits, avg, code.period).astype(np.float64)
        ok = (mod >= code.min_modulation) & (x >= -0.5) & (x <= code.size(direction) - 0.5)
        out.append(np.where(ok, x, np.nan))
        mods.append(mod)
        phases.append(phi)
    return out[0], out[1], {"modulation": np.stack(mods, -1), "phase": np.stack(phases, -1)}


def triangulate(column: np.ndarray, row: np.ndarray, rig,
                tolerance: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """3-D points of decoded pixels: camera ray x exact light surface of the sub-pixel column.

    The same triangulation as the Gray-code peer (:func:`nurbscan.reconstruct.intersect_exact`,
    Tsai's distortion, Newton on the cubic in the ray parameter) at the decoded fractional
    column; points whose projector row differs from the decoded ``row`` by more than
    ``tolerance`` px are dropped (module step 4).

    Parameters
    ----------
    column, row : ndarray (H, W) float
        Decoded projector coordinates, px (NaN: none).
    rig : nurbscan.camera.Rig
        The (calibrated) rig, rig frame = camera frame.
    tolerance : float
        Projector px.

    Returns
    -------
    points : ndarray (N, 3)
        mm, rig frame.
    pixels : ndarray (N,) int
        Flat pixel index ``y * W + x`` of each point.
    """
    from ..reconstruct import intersect_exact

    H, W = column.shape
    idx = np.flatnonzero((np.isfinite(column) & np.isfinite(row)).ravel())
    pix = np.stack([idx % W, idx // W], axis=1).astype(float)
    origin, dirs = rig.camera.back_project(pix)
    pts, other, _ = intersect_exact(rig.projector, origin, dirs, "vertical",
                                    column.ravel()[idx])
    with np.errstate(invalid="ignore"):
        ok = np.isfinite(pts).all(axis=1) & (np.abs(other - row.ravel()[idx]) <= tolerance)
    return pts[ok], idx[ok]


def scan_view(scene, rig, angle: float = 0.0, *, calibrated_rig=None,
              code: PhaseShift | None = None, settings=None, seed: int = 0, stream: int = 0,
              mode: str = "fast", workers: int | None = None,
              error_sample: int | None = 200_000, base=None) -> dict[str, Any]:
    """Render, decode and triangulate one view; measure it against the truth.

    Parameters
    ----------
    scene, rig, angle, code, settings, seed, stream, mode, workers, base
        As :func:`render_phase_shift` (``rig`` is the true rig that renders).
    calibrated_rig : Rig, optional
        The rig that triangulates (default ``rig``).
    error_sample : int, optional
        Measure the error on this many points drawn at random (seed 0); None: all.

    Returns
    -------
    dict
        As :func:`nurbscan.peers.graycode.scan_view`: ``images``, ``points``, ``coverage``,
        ``error`` (mm), ``decode_s``, ``triangulate_s``, ``time_per_view_s``, ``render_s``,
        ``points_rig`` (N, 3), ``pixels`` (N,), the ``capture`` and the decoded ``column``
        and ``row`` (H, W).
    """
    code = code or PhaseShift.for_projector(rig.projector)
    cap = render_phase_shift(scene, rig, code, angle, settings, seed, stream, mode, workers,
                             base)
    t0 = time.perf_counter()
    col, row, _ = decode(cap, code)
    t1 = time.perf_counter()
    pts, pix = triangulate(col, row, calibrated_rig or rig, code.epipolar_tolerance)
    t2 = time.perf_counter()
    return {**view_figures(cap, pts, pix, scene, rig, angle, settings, error_sample),
            "images": code.n_images, "decode_s": t1 - t0, "triangulate_s": t2 - t1,
            "time_per_view_s": t2 - t0, "column": col, "row": row}
