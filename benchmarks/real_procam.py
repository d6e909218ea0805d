"""Lay the shared real projector-camera set out as nurbscan scan folders (issue 31).

The set (``../shared/real/procam-colour-grid/``, read its README; academic licence: its images
are never copied into the repository) holds 640 x 480 photographs of a real camera under a
real projector's thin-line colour grid: a checkerboard (6 x 9 inner corners, 24 mm squares)
glued on a larger white board in 8 poses, and two scenes (09 a flat sheet, 10 a curved band)
with the source's object masks. :func:`lay_out` writes, under a scratch folder (never the
repository), scan folders (docs/scan-format.md) whose images are symbolic links into the set:

* ``calib/``: a calibration scan, poses 1-8 as ``free`` poses (``calibration/pose_NN_white.png``
  -> ``lightGridNN.png``, ``pose_NN_grid.png`` -> ``colorGridNN.png``), the target as people
  print it (``inner_corners`` and ``square_mm`` only), no views;
* ``scene09/``, ``scene10/``: one view each (``views/view_00_grid.png``, ``_white.png`` and
  ``_mask.png`` -> ``objectROINN.png``, 255 inside the object), table angle 0;

each with ``pattern.png`` (-> the set's ``pattern.png``) and ``pattern.json``, the
:class:`nurbscan.pattern.LinePattern` read from that image by :func:`line_pattern` (line
positions from the README's rules, each line's colour code from the image).

Run ``python benchmarks/real_procam.py OUT`` to write the folders; then e.g.
``nurbscan calibrate OUT/calib/calibration -o calib.json``.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import numpy as np

#: The shared set, relative to the repository root (``../shared/real/...``); the environment
#: variable ``NURBSCAN_REAL_PROCAM`` overrides it.
REL_PATH = Path("..") / "shared" / "real" / "procam-colour-grid"
ENV = "NURBSCAN_REAL_PROCAM"
CALIB_POSES = tuple(range(1, 9))
SCENES = (9, 10)
INNER_CORNERS = (6, 9)
SQUARE_MM = 24.0
#: The README's palette (RGB in [0, 1] there): horizontal lines r, l, c, p; vertical y, g, b, m.
PALETTE = (("r", (1.0, 0.0, 0.0)), ("y", (1.0, 0.75, 0.0)), ("l", (0.5, 1.0, 0.0)),
           ("g", (0.0, 1.0, 0.5)), ("c", (0.0, 1.0, 1.0)), ("b", (0.0, 0.25, 1.0)),
           ("p", (0.75, 0.0, 1.0)), ("m", (1.0, 0.0, 0.75)))


def data_dir(repo: Path | None = None) -> Path | None:
    """The shared set's folder, or None when it is absent (``$NURBSCAN_REAL_PROCAM`` first)."""
    env = os.environ.get(ENV)
    if env:
        p = Path(env)
    else:
        repo = Path(__file__).resolve().parents[1] if repo is None else Path(repo)
        p = (repo / REL_PATH).resolve()
    return p if (p / "images" / "colorGrid01.png").is_file() else None


def line_pattern(pattern_png: Path):
    """The :class:`~nurbscan.pattern.LinePattern` of the set's ``pattern.png``.

    Line positions from the README's rules: 3 px wide lines, line k's centre (0-based px) at
    ``11 + 29 k`` (vertical, columns) and ``11 + 21 k`` (horizontal, rows): 28 vertical and 29
    horizontal lines in the 800 x 600 image (the 29th, centre row 599, cut by the image's
    edge to its rows 598-599), so ``lower = centre - 1.5`` and ``upper = centre + 1.5``
    within the image. Each line's
    colour code: the palette colour nearest (RGB distance) to the median colour of its lit
    pixels away from the crossings. The positions are checked against the image (every pixel
    of a line lit, the pixels beside it black away from crossings); the crossing rule is read
    from the crossings (``"horizontal-over"`` when they show the horizontal line's colour).
    """
    from nurbscan.errors import NurbscanError
    from nurbscan.io import read_image
    from nurbscan.pattern import LineFamily, LinePattern, window_length

    img = read_image(pattern_png, as_float=False).astype(np.int64)
    h, w = img.shape[:2]
    cx = 11 + 29 * np.arange(40)
    cy = 11 + 21 * np.arange(40)
    cx, cy = cx[cx - 1 < w], cy[cy - 1 < h]  # a line cut by the image's edge included
    pal = np.array([c for _, c in PALETTE]) * 255.0
    lit = img.max(axis=2) > 40
    xon = np.zeros(w + 2, bool)
    yon = np.zeros(h + 2, bool)
    for d in (-1, 0, 1):
        xon[cx + d] = True
        yon[cy + d] = True
    xon, yon = xon[:w], yon[:h]
    # away from crossings: a vertical line's pixels on rows of no horizontal line
    if not (lit[~yon][:, xon].all() and lit[yon][:, ~xon].all()
            and not lit[~yon][:, ~xon].any()):
        raise NurbscanError(f"{pattern_png}: lines are not where the README's rules put them")

    def codes(samples):  # samples (n_lines, k, 3)
        med = np.median(samples, axis=1)
        return tuple(int(i) for i in np.argmin(((med[:, None] - pal[None])**2).sum(-1), axis=1))

    vcodes = codes(np.stack([img[~yon][:, c] for c in cx]))
    hcodes = codes(np.stack([img[r][~xon] for r in cy]))
    cross = img[cy][:, cx]  # (nh, nv, 3)
    on_h = np.all(np.abs(cross - pal[np.array(hcodes)][:, None]) < 2, axis=-1).mean()
    on_v = np.all(np.abs(cross - pal[np.array(vcodes)][None]) < 2, axis=-1).mean()
    crossing = "horizontal-over" if on_h > 0.99 else "vertical-over" if on_v > 0.99 \
        else "unknown"
    colours = tuple((n, tuple(int(round(255 * v)) for v in rgb)) for n, rgb in PALETTE)
    # lit pixels c - 1 .. c + 1 within the image: lower = first - 0.5, upper = last + 0.5
    fam_v = LineFamily("vertical", vcodes, tuple(max(c - 1.5, -0.5) for c in map(float, cx)),
                       tuple(min(c + 1.5, w - 0.5) for c in map(float, cx)))
    fam_h = LineFamily("horizontal", hcodes, tuple(max(c - 1.5, -0.5) for c in map(float, cy)),
                       tuple(min(c + 1.5, h - 0.5) for c in map(float, cy)))
    return LinePattern(width=w, height=h, colours=colours,
                       window=window_length([vcodes, hcodes]), vertical=fam_v,
                       horizontal=fam_h, crossing=crossing)


def _link(src: Path, dst: Path) -> None:
    dst.parent.mkdir(parents=True, exist_ok=True)
    if dst.is_symlink() or dst.exists():
        dst.unlink()
    dst.symlink_to(src)


def _scan_doc(pattern, source: dict) -> dict:
    return {"type": "nurbscan.scan", "version": 1, "image_size": [640, 480], "bit_depth": 8,
            "pattern": {"image": "pattern.png", "sidecar": "pattern.json"},
            "angle_unit": "radians", "views": [], "source": source}


def lay_out(out: str | os.PathLike, data: Path | None = None) -> dict[str, Path]:
    """Write the scan folders under ``out`` (module notes); returns ``{"calib": ...,
    "scene09": ..., "scene10": ...}``. Images are symbolic links into the set."""
    from nurbscan.errors import NurbscanError
    from nurbscan.io import write_json

    data = data_dir() if data is None else Path(data)
    if data is None:
        raise NurbscanError(f"real procam set not found (../shared/real/procam-colour-grid or "
                            f"${ENV})")
    out = Path(out)
    repo = Path(__file__).resolve().parents[1]
    if out.resolve().is_relative_to(repo):
        raise NurbscanError(f"{out}: inside the repository; the set's images (academic "
                            "licence) must stay out of it: use a scratch folder")
    img = data / "images"
    pattern = line_pattern(data / "pattern.png")
    source = {"kind": "real", "set": "procam-colour-grid",
              "origin": "BingyaoHuang/single-shot-pro-cam-calib@cd7fda6b, "
                        "data/calibration-04-01-19_16-02-01 (academic licence)",
              "camera": "640 x 480, 8-bit RGB", "projector": "800 x 600"}
    folders = {}

    def common(folder: Path) -> None:
        _link(data / "pattern.png", folder / "pattern.png")
        write_json(folder / "pattern.json", pattern.to_dict())

    calib = out / "calib"
    common(calib)
    doc = _scan_doc(pattern, source)
    poses = []
    for k in CALIB_POSES:
        w, g = f"calibration/pose_{k:02d}_white.png", f"calibration/pose_{k:02d}_grid.png"
        _link(img / f"lightGrid{k:02d}.png", calib / w)
        _link(img / f"colorGrid{k:02d}.png", calib / g)
        poses.append({"index": k, "kind": "free", "white": w, "grid": g})
    doc["calibration"] = {"target": {"inner_corners": list(INNER_CORNERS),
                                     "square_mm": SQUARE_MM},
                          "poses": poses}
    write_json(calib / "scan.json", doc)
    folders["calib"] = calib
    for k in SCENES:
        scene = out / f"scene{k:02d}"
        common(scene)
        _link(img / f"colorGrid{k:02d}.png", scene / "views/view_00_grid.png")
        _link(img / f"lightGrid{k:02d}.png", scene / "views/view_00_white.png")
        _link(img / f"objectROI{k:02d}.png", scene / "views/view_00_mask.png")
        doc = _scan_doc(pattern, source | {"shot": k})
        doc["views"] = [{"index": 0, "table_angle": 0.0, "grid": "views/view_00_grid.png",
                         "white": "views/view_00_white.png",
                         "mask": "views/view_00_mask.png"}]
        write_json(scene / "scan.json", doc)
        folders[f"scene{k:02d}"] = scene
    return folders


if __name__ == "__main__":
    if len(sys.argv) != 2:
        print("usage: python benchmarks/real_procam.py OUT_FOLDER", file=sys.stderr)
        raise SystemExit(2)
    for name, path in lay_out(sys.argv[1]).items():
        print(f"{name}: {path}")
