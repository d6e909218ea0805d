"""``nurbscan export``: write a model as glb, obj, ply, stl, 3dm, igs or step."""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

FORMATS = ("glb", "obj", "ply", "stl", "3dm", "igs", "step")


def register(sub) -> None:
    """Add the ``export`` sub-command."""
    p = sub.add_parser(
        "export", help="Write a model as glb, obj, ply, stl, 3dm, igs or step",
        description=(
            "Export a model folder. NURBS for CAD: 3dm (Rhino, rhino3dm), igs (IGES 5.3, "
            "entities 126/128) and step (OpenCASCADE, pip install 'nurbscan[cad]'), in mm, "
            "holding the model's CAD surface set (every part of the covered surface on exactly "
            "one surface, cut back to the data; step sewn into shells); --patches: the "
            "per-view curves and surfaces of --kinds instead. Meshes for VR: "
            "the model's fused mesh (fused. py; fused now when the folder has none), one "
            "surface of the object with vertex colours from the white-light images, at most "
            "--max-triangles; --patches: the per-view Gordon patches tessellated instead. glb "
            "in metres, y up (glTF), obj/ply/stl in mm. The file is written atomically."))
    p.add_argument("model", type=Path, help="model folder (with model.json)")
    p.add_argument("--format", choices=FORMATS, default=None,
                   help="output format (default: from the output file's extension)")
    p.add_argument("-o", "--output", type=Path, required=True, help="output file")
    p.add_argument("--kinds", default="horizontal_line,vertical_line,gordon",
                   help="NURBS formats with --patches: comma-separated kinds to write, or "
                        "'all' (default horizontal_line,vertical_line,gordon)")
    p.add_argument("--no-colour", action="store_true",
                   help="mesh formats: neutral grey instead of the white-light colours")
    p.add_argument("--points", action="store_true",
                   help="ply only: the merged point cloud (points.npz) with normals and "
                        "colours instead of the mesh")
    p.add_argument("--patches", action="store_true",
                   help="the per-view Gordon patches (and curves) instead of the fused mesh "
                        "or the CAD set")
    p.add_argument("--max-triangles", type=int, default=300_000,
                   help="mesh formats: triangle budget of the fused mesh (300000)")
    p.add_argument("--per-span", type=int, default=4,
                   help="mesh formats with --patches: grid intervals per knot span (4)")
    p.add_argument("--memory-budget", type=float, default=8.0, metavar="GIB",
                   help="mesh formats with --patches: refuse a tessellation estimated to need "
                        "more memory than this, GiB (default 8; the estimate, from the "
                        "patches' knot spans and --per-span, is in the message)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress lines")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Export ``args.model`` to ``args.output``."""
    from ..errors import NurbscanError
    from ..export import ALL_KINDS, MESH_FORMATS, export_model, load_model

    fmt = args.format or args.output.suffix.lstrip(".").lower()
    fmt = {"stp": "step", "iges": "igs"}.get(fmt, fmt)
    if fmt not in FORMATS:
        raise NurbscanError(f"{args.output}: unknown format {fmt!r}; give --format, one of "
                            f"{', '.join(FORMATS)}")
    suffix = args.output.suffix.lstrip(".").lower()
    if fmt == "stp":
        fmt = "step"
    if args.format and suffix != fmt and not (fmt == "igs" and suffix == "iges") \
            and not (fmt == "step" and suffix == "stp"):
        raise NurbscanError(f"{args.output}: the name says {suffix or 'no format'!r} but "
                            f"--format is {fmt!r}; name the file .{fmt}")
    if args.points and fmt != "ply":
        raise NurbscanError(f"--points: the point cloud is written as ply only, not {fmt!r} "
                            f"({args.output})")
    if args.per_span < 1:
        raise NurbscanError(f"--per-span {args.per_span}: must be at least 1")
    if args.max_triangles < 100:
        raise NurbscanError(f"--max-triangles {args.max_triangles}: must be at least 100")
    if not (math.isfinite(args.memory_budget) and args.memory_budget > 0):
        raise NurbscanError(f"--memory-budget {args.memory_budget}: must be a positive number "
                            "of GiB")
    budget = args.memory_budget * 2**30
    model = load_model(args.model)
    if args.patches and fmt in MESH_FORMATS and not args.points:
        from ..export.mesh import _patches, check_memory

        # before anything is allocated, named by the option (--per-span 2000 took 21 GB)
        check_memory([e["surface"] for e in _patches(model)], args.per_span, budget,
                     what="--per-span")
    kinds = ALL_KINDS if args.kinds == "all" else tuple(
        k.strip() for k in args.kinds.split(",") if k.strip())
    unknown = [k for k in kinds if k not in ALL_KINDS]
    if unknown or not kinds:
        raise NurbscanError(f"--kinds {args.kinds}: {', '.join(unknown) or 'none given'}; "
                            f"expected 'all' or of {', '.join(ALL_KINDS)}")
    t0 = time.perf_counter()

    def say(msg: str) -> None:
        if not args.quiet:
            print(f"[{time.perf_counter() - t0:6.1f} s] {msg}", file=sys.stderr, flush=True)

    out = export_model(model, args.output, fmt, kinds=kinds, colour=not args.no_colour,
                       per_span=args.per_span, points=args.points, patches=args.patches,
                       max_triangles=args.max_triangles, progress=say,
                       memory_budget=budget)
    print(f"wrote {out} ({fmt}, {out.stat().st_size} bytes)")
    return 0
