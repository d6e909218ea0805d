"""``nurbscan pattern``: write the projector's colour-grid image and its JSON sidecar."""

from __future__ import annotations

import argparse

from ..pattern import Pattern


def register(sub) -> argparse.ArgumentParser:
    """Add the ``pattern`` sub-command."""
    p = sub.add_parser(
        "pattern",
        help="Write the projected colour-grid image (PNG) and its JSON sidecar",
        description=(
            "Write the projector image of the colour grid (vertical and horizontal bands "
            "coloured by a de Bruijn sequence over GF(q), on black) to OUTPUT, and beside it a "
            "JSON sidecar with the same name and suffix .json holding everything a decoder "
            "needs: the sequence, polynomial, colour table, geometry, and the exact projector "
            "coordinate of both edges of every band. Colours: magenta 0, red 1, green 2, "
            "yellow 3, cyan 4 (then blue 5, white 6); where bands cross the pixel is the "
            "channel-wise max of the two colours."
        ),
    )
    p.add_argument("-o", "--output", required=True, metavar="OUTPUT",
                   help="pattern image to write, .png or .tif (the sidecar is OUTPUT with .json)")
    p.add_argument("--width", type=int, default=1920, help="projector width, px (default 1920)")
    p.add_argument("--height", type=int, default=1080, help="projector height, px (default 1080)")
    p.add_argument("--pitch", type=int, default=16, help="band pitch, px (default 16)")
    p.add_argument("--band", type=int, default=6, help="band width, px (default 6)")
    p.add_argument("--base", type=int, default=5,
                   help="number of colours q, a prime (default 5)")
    p.add_argument("--window", type=int, default=3,
                   help="window length n: n consecutive bands identify one (default 3)")
    p.add_argument("--poly", default=None,
                   help="primitive polynomial over GF(q), coefficients from the highest degree "
                        "down, monic: '1403' = x^3+4x^2+3 (the default for q=5, n=3) or a comma "
                        "list '1,4,0,3'; default: the first primitive one found")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    """Build the pattern, save image and sidecar, print one summary line."""
    pat = Pattern.create(width=args.width, height=args.height, pitch=args.pitch, band=args.band,
                         q=args.base, n=args.window, poly=args.poly)
    image, sidecar = pat.save(args.output)
    print(f"nurbscan pattern: wrote {image} and {sidecar} ({pat.summary()})")
    return 0
