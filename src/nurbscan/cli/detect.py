"""``nurbscan detect``: find, trace and decode the grid's edge lines in a photograph."""

from __future__ import annotations

import argparse
import sys


def register(sub) -> None:
    """Add the ``detect`` sub-command."""
    p = sub.add_parser(
        "detect", help="Find, trace and decode the grid's edge lines in a photograph",
        description=(
            "Find the sub-pixel edges of the projected colour grid in IMAGE, chain them into "
            "lines, label each line with its band index and edge by decoding the PRMVS colour "
            "windows, and write the lines and grid intersections to a JSON file. With a "
            "pattern of thin coloured lines (a sidecar from 'nurbscan pattern --from-image') "
            "the lines' sub-pixel centres are found and decoded instead (colours learned from "
            "the photograph). An image in which no grid line can be decoded is an error "
            "(exit status 2)."
        ),
    )
    p.add_argument("image", help="photograph of the object under the grid (PNG, TIFF, JPEG)")
    p.add_argument("--pattern", required=True, help="the pattern's JSON file (pattern.json)")
    p.add_argument("--white", help="the same view under white light (recommended)")
    p.add_argument("-o", "--output", required=True, help="output file (lines.json)")
    p.add_argument("--overlay", help="also write an overlay picture (PNG) of the decoded lines")
    p.add_argument("--gamma", type=float, default=2.2,
                   help="encoding gamma of the images (default 2.2; 1 for linear data)")
    p.add_argument("--sigma", type=float, default=None,
                   help="edge filter scale across the edges, camera px (default: automatic)")
    p.add_argument("--calib", help="the calibrated rig (calib.json): lines the colour windows "
                   "leave undecoded are also decoded with its epipolar constraint, as "
                   "nurbscan reconstruct does (the image must be of the rig's camera size)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Detect the grid in one image; returns the exit status."""
    import warnings

    from ..detect import (
        DetectOptions,
        detect_grid,
        detect_lines,
        draw_line_overlay,
        draw_overlay,
    )
    from ..errors import NurbscanError
    from ..io import atomic_paths, chroma_subsampled, read_image, write_image
    from ..pattern import LinePattern, load_pattern

    pattern = load_pattern(args.pattern)
    thin = isinstance(pattern, LinePattern)
    if thin and args.calib:
        raise NurbscanError(f"{args.pattern}: --calib (epipolar decoding) is only for nurbscan's "
                            "own band grids, not for a pattern of thin lines")
    image = read_image(args.image, as_float=False)
    # an edge filter wider than the image finds nothing, and its kernel (8 sigma) would not
    # fit in memory (--sigma 1e9: 59.6 GiB)
    max_sigma = max(image.shape[:2]) / 8.0
    if args.sigma is not None and args.sigma > max_sigma:
        raise NurbscanError(f"--sigma {args.sigma:g}: wider than {args.image} allows (at most "
                            f"{max_sigma:g} px, an eighth of its larger side)")
    epipolar = None
    if args.calib:
        from functools import partial

        from ..camera import load_rig
        from ..reconstruct.light import other_coordinate

        rig = load_rig(args.calib)
        size = (rig.camera.width, rig.camera.height)
        if (image.shape[1], image.shape[0]) != size:
            raise NurbscanError(f"{args.image}: size {image.shape[1]}x{image.shape[0]} does "
                                f"not match the camera of {args.calib} ({size[0]}x{size[1]})")
        epipolar = partial(other_coordinate, rig)
    white = read_image(args.white, as_float=False) if args.white else None
    if white is not None and white.shape != image.shape:
        raise NurbscanError(f"{args.white}: size {white.shape[1]}x{white.shape[0]} does not "
                            f"match {args.image} ({image.shape[1]}x{image.shape[0]})")
    subsampled = chroma_subsampled(args.image)
    if subsampled:
        print(f"{args.image}: JPEG with subsampled colour (4:2:2 / 4:2:0): edges measured in "
              "its luma, not re-measured in the colour channels (PNG, TIFF or JPEG 4:4:4 give "
              "more accurate edges)", file=sys.stderr)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        if thin:
            result = detect_lines(image, pattern, white)
        else:
            options = DetectOptions().replace(gamma=args.gamma, sigma=args.sigma,
                                              chroma_subsampled=subsampled)
            result = detect_grid(image, pattern, white, options, epipolar=epipolar)
    if result.nlines == 0:
        raise NurbscanError(f"{args.image}: " + (result.warnings[0] if result.warnings
                                                  else "no grid line decoded"))
    outputs = (args.output,) + ((args.overlay,) if args.overlay else ())
    with atomic_paths(*outputs) as tmps:  # the lines and their overlay, both or neither
        result.save(tmps[0])
        if args.overlay:
            draw = draw_line_overlay if thin else draw_overlay
            write_image(tmps[1], draw(image, result, pattern))
    nv = int((result.direction == 0).sum())
    kind = "centre" if thin else "edge"
    print(f"{args.output}: {nv} vertical and {result.nlines - nv} horizontal {kind} lines, "
          f"{len(result.x)} {kind} points, {len(result.cam)} grid intersections", file=sys.stderr)
    return 0
