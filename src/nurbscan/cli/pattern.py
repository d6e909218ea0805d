"""``nurbscan pattern``: write the projector's colour-grid image and its JSON sidecar, or read
the sidecar of any projector image of straight coloured lines (``--from-image``)."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..errors import NurbscanError
from ..io import write_json
from ..pattern import Pattern, read_line_pattern

#: Options that shape a generated grid, with their defaults (not used with --from-image).
_GENERATE = {"width": 1920, "height": 1080, "pitch": 16, "band": 6, "base": 5, "window": 3,
             "poly": None}


def register(sub) -> argparse.ArgumentParser:
    """Add the ``pattern`` sub-command."""
    p = sub.add_parser(
        "pattern",
        help="Write the projected colour-grid image (PNG) and its JSON sidecar, or read the "
             "sidecar of a given projector image (--from-image)",
        description=(
            "Write the projector image of the colour grid (vertical and horizontal bands "
            "coloured by a de Bruijn sequence over GF(q), on black) to OUTPUT, and beside it a "
            "JSON sidecar with the same name and suffix .json holding everything a decoder "
            "needs: the sequence, polynomial, colour table, geometry, and the exact projector "
            "coordinate of both edges of every band. Colours: magenta 0, red 1, green 2, "
            "yellow 3, cyan 4 (then blue 5, white 6); where bands cross the pixel is the "
            "channel-wise max of the two colours. "
            "With --from-image PROJECTED, read instead any projector image made of straight "
            "coloured lines or bands on black in one or both directions (nurbscan's own grid "
            "or another project's) and write its sidecar to OUTPUT (.json): each line's "
            "direction, index, colour code and exact edges in projector px, the palette found "
            "in the image, the crossing rule and the window length n (the smallest n <= 6 for "
            "which every run of n consecutive colours along a direction is unique). See "
            "docs/patterns.md."
        ),
    )
    p.add_argument("-o", "--output", required=True, metavar="OUTPUT",
                   help="pattern image to write, .png or .tif (the sidecar is OUTPUT with "
                        ".json); with --from-image, the sidecar to write (.json)")
    p.add_argument("--from-image", metavar="PROJECTED", default=None,
                   help="read this projector image (PNG/TIFF of straight coloured lines on "
                        "black) and write its sidecar to OUTPUT instead of generating a grid")
    p.add_argument("--width", type=int, default=None, help="projector width, px (default 1920)")
    p.add_argument("--height", type=int, default=None,
                   help="projector height, px (default 1080)")
    p.add_argument("--pitch", type=int, default=None, help="band pitch, px (default 16)")
    p.add_argument("--band", type=int, default=None, help="band width, px (default 6)")
    p.add_argument("--base", type=int, default=None,
                   help="number of colours q, a prime (default 5)")
    p.add_argument("--window", type=int, default=None,
                   help="window length n: n consecutive bands identify one (default 3)")
    p.add_argument("--poly", default=None,
                   help="primitive polynomial over GF(q), coefficients from the highest degree "
                        "down, monic: '1403' = x^3+4x^2+3 (the default for q=5, n=3) or a comma "
                        "list '1,4,0,3'; default: the first primitive one found")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    """Generate (image + sidecar) or read a projector image (sidecar); print one summary line."""
    if args.from_image is not None:
        return _from_image(args)
    kw = {k: (d if getattr(args, k) is None else getattr(args, k)) for k, d in _GENERATE.items()}
    pat = Pattern.create(width=kw["width"], height=kw["height"], pitch=kw["pitch"],
                         band=kw["band"], q=kw["base"], n=kw["window"], poly=kw["poly"])
    image, sidecar = pat.save(args.output)
    print(f"nurbscan pattern: wrote {image} and {sidecar} ({pat.summary()})")
    return 0


def _from_image(args: argparse.Namespace) -> int:
    """Read the projector image, write its line-pattern sidecar atomically."""
    given = [f"--{k}" for k in _GENERATE if getattr(args, k) is not None]
    if given:
        raise NurbscanError(
            f"{' '.join(given)}: generating options do not apply with --from-image "
            "(the pattern is read from the image)"
        )
    out = Path(args.output)
    if out.suffix.lower() != ".json":
        raise NurbscanError(
            f"{out}: with --from-image OUTPUT is the JSON sidecar and must end in .json"
        )
    pattern = read_line_pattern(args.from_image)
    write_json(out, pattern.to_dict())
    print(f"nurbscan pattern: read {args.from_image}, wrote {out} ({pattern.summary()})")
    return 0
