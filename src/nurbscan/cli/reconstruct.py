"""``nurbscan reconstruct``: build 3-D NURBS curves and surfaces from a scan."""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

#: Exit status of a model written without some of its views (no grid line decoded in them).
PARTIAL = 3


def register(sub) -> None:
    """Add the ``reconstruct`` sub-command."""
    p = sub.add_parser(
        "reconstruct", help="Build 3-D NURBS curves, surfaces and one fused mesh from a scan",
        description=(
            "Detect the grid in every view of a scan folder, triangulate its labelled edge "
            "lines with the calibrated rig, build the curve network, skins and Gordon "
            "surfaces, merge the views in the turntable frame (the table left out, the "
            "views' poses registered against each other), fuse them into one coloured "
            "triangle mesh (a rig whose turntable is not calibrated: one view, in the rig "
            "frame, not fused) and write the model folder (model.json, points.npz, "
            "model.png, fused.ply, overlays/view_KK_overlay.png with the detected lines of "
            "each view; docs/model-format.md). Several scan folders of one object "
            "(turntable passes, the object turned over between them): each reconstructed "
            "into OUTPUT-passK, then merged into OUTPUT as 'nurbscan merge' does. Never "
            "reads truth/. Exit status: 0 every view decoded; 2 bad input, nothing written "
            "(also when no view shows a grid); "
            f"{PARTIAL} partial result: the model is written without the views in which no "
            "grid line was decoded, named in a warning on stderr."))
    p.add_argument("scan", type=Path, nargs="+",
                   help="scan folder (with scan.json); several: passes of one object")
    p.add_argument("--calib", type=Path, required=True, nargs="+",
                   help="calibrated rig (calib.json from 'nurbscan calibrate'); with several "
                        "scans one for all or one per scan")
    p.add_argument("-o", "--output", type=Path, default=Path("model"),
                   help="model folder (model/); with several scans the merged model, each "
                        "pass's model beside it in OUTPUT-pass1, OUTPUT-pass2, ...")
    p.add_argument("--views", type=int, nargs="+", default=None,
                   help="only these view indices (default all)")
    p.add_argument("--min-curves", type=int, default=3,
                   help="smallest Gordon patch, curves per direction (3)")
    p.add_argument("--workers", type=int, default=2,
                   help="processes reconstructing views side by side, at most one per CPU "
                        "(default 2; 0 = one per CPU); the model does not depend on it")
    p.add_argument("--no-register", action="store_true",
                   help="keep every view where the turntable and its table angle put it")
    p.add_argument("--keep-table", action="store_true",
                   help="keep what lies on the table top or outside the table's cylinder")
    p.add_argument("--table-margin", type=float, default=0.5, metavar="MM",
                   help="height above the table plane up to which points are the table's "
                        "(default 0.5 mm)")
    p.add_argument("--table-radius", type=float, default=150.0, metavar="MM",
                   help="radius of the table's cylinder about the axis (default 150 mm)")
    p.add_argument("--max-triangles", type=int, default=300_000,
                   help="triangle budget of the fused mesh (300000)")
    p.add_argument("--no-fuse", action="store_true",
                   help="no fused mesh (fused.ply): the per-view patches only")
    p.add_argument("--allow-outside-paths", action="store_true",
                   help="accept image paths in scan.json that are absolute or leave the scan "
                        "folder (refused by default)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress lines")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Reconstruct ``args.scan`` with the rig ``args.calib`` into ``args.output``; several
    scans: each into its pass folder, then merged (:func:`run_passes`)."""
    from ..errors import NurbscanError

    scans, calibs = list(args.scan), list(args.calib)
    if len(calibs) not in (1, len(scans)):
        raise NurbscanError(f"--calib: {len(calibs)} files for {len(scans)} scans (one for "
                            "all, or one per scan)")
    if len(scans) > 1:
        return run_passes(args, scans, calibs)
    return _run_one(argparse.Namespace(**{**vars(args), "scan": scans[0],
                                          "calib": calibs[0]}))


def run_passes(args: argparse.Namespace, scans: list, calibs: list) -> int:
    """Reconstruct every scan folder into ``OUTPUT-passK`` (K = 1, 2, ...), then merge the
    passes into ``OUTPUT`` (:func:`nurbscan.cli.merge.run` with its default settings, the
    colours from the scans' white images). Each pass's fused mesh is only its alignment
    surface (:func:`nurbscan.merge.fusion.alignment_fusion`: not subdivided, grey): the merge
    fuses every pass's views again into the model's mesh."""
    from ..errors import NurbscanError
    from . import build_parser
    from . import merge as merge_cli

    if args.no_fuse:
        raise NurbscanError("--no-fuse: several passes are aligned by their fused meshes")
    if args.views is not None:
        raise NurbscanError("--views: not with several scans (every pass needs its views)")
    out = Path(args.output)
    folders = [out.parent / f"{out.name}-pass{k + 1}" for k in range(len(scans))]
    partial = False
    for k, (scan, folder) in enumerate(zip(scans, folders, strict=True)):
        calib = calibs[k if len(calibs) == len(scans) else 0]
        if not args.quiet:
            print(f"nurbscan reconstruct: pass {k + 1} of {len(scans)}: {scan} -> {folder}",
                  file=sys.stderr, flush=True)
        partial = _run_one(argparse.Namespace(**{**vars(args), "scan": scan, "calib": calib,
                                                 "output": folder, "for_merge": True})
                           ) == PARTIAL or partial
    argv = ["merge", *map(str, folders), "-o", str(out),
            "--max-triangles", str(args.max_triangles)]
    for k, scan in enumerate(scans):
        argv += ["--scan", str(scan),
                 "--calib", str(calibs[k if len(calibs) == len(scans) else 0])]
    if args.quiet:
        argv.append("-q")
    rc = merge_cli.run(build_parser().parse_args(argv))
    return PARTIAL if rc == 0 and partial else rc


def _run_one(args: argparse.Namespace) -> int:
    """One scan folder into one model folder."""
    from ..calibrate import turntable_calibrated
    from ..camera import load_rig
    from ..errors import NurbscanError
    from ..io import load_scan
    from ..io.atomic import atomic_folder, read_json
    from ..merge import MergeOptions, MergeWarning, RegistrationOptions, TableOptions
    from ..merge.fusion import FusionOptions, alignment_fusion
    from ..reconstruct import reconstruct_scan
    from ..reconstruct.model import MODEL_FILES

    if args.workers < 0:
        raise NurbscanError(f"--workers {args.workers}: must be >= 0")
    if args.min_curves < 2:
        raise NurbscanError(f"--min-curves {args.min_curves}: must be at least 2")
    if args.max_triangles < 100:  # as export's
        raise NurbscanError(f"--max-triangles {args.max_triangles}: must be at least 100")
    merge = MergeOptions(
        table=None if args.keep_table else TableOptions(margin=args.table_margin,
                                                        radius=args.table_radius),
        registration=None if args.no_register else RegistrationOptions())
    fusion = None if args.no_fuse else FusionOptions(max_triangles=args.max_triangles)
    if fusion is not None and getattr(args, "for_merge", False):
        fusion = alignment_fusion(fusion)  # the merge fuses all passes' views again
    t0 = time.perf_counter()
    rig = load_rig(args.calib)
    tt_ok = turntable_calibrated(read_json(args.calib))
    scan = load_scan(args.scan, allow_outside=args.allow_outside_paths)
    cam = (int(rig.camera.width), int(rig.camera.height))
    if scan.image_size != cam:  # named by both files here (the library knows the rig only)
        raise NurbscanError(f"{args.calib}: camera {cam[0]} x {cam[1]} px does not match the "
                            f"images of {scan.folder / 'scan.json'} ({scan.image_size[0]} x "
                            f"{scan.image_size[1]})")
    unknown = sorted(set(args.views or ()) - {v.index for v in scan.views})
    if unknown:
        raise NurbscanError(f"--views {' '.join(map(str, unknown))}: no such view in "
                            f"{scan.folder / 'scan.json'} (views "
                            f"{', '.join(str(v.index) for v in scan.views)})")

    def say(msg: str) -> None:
        if not args.quiet:
            print(f"[{time.perf_counter() - t0:6.1f} s] {msg}", file=sys.stderr, flush=True)

    # the model folder is written whole under a temporary name, under its lock: a killed run
    # leaves the old folder (or none), a second run into the same folder is refused
    with atomic_folder(args.output, MODEL_FILES) as tmp:
        with warnings.catch_warnings():  # printed below, also with --quiet
            warnings.simplefilter("ignore", MergeWarning)
            model = reconstruct_scan(args.scan, rig, progress=say, views=args.views,
                                     min_curves=args.min_curves, workers=args.workers,
                                     overlays=tmp / "overlays", merge=merge,
                                     fusion=fusion, turntable_calibrated=tt_ok,
                                     allow_outside=args.allow_outside_paths)
        if args.quiet:
            for w in model.meta.get("merge", {}).get("warnings", []):
                print(f"nurbscan reconstruct: warning: {w}", file=sys.stderr, flush=True)
        model.meta["calibration"] = str(args.calib)
        model.write_files(tmp)
    blind = [v for v in model.views if not v.get("lines")]
    if blind:
        names = ", ".join(str(v["index"]) for v in blind)
        print(f"nurbscan reconstruct: warning: no grid line decoded in view(s) {names} of "
              f"{args.scan / 'scan.json'}; the model holds the other "
              f"{len(model.views) - len(blind)} view(s) (exit status {PARTIAL})",
              file=sys.stderr, flush=True)
    path = Path(args.output) / "model.json"
    n = {k: v for k, v in model.to_dict()["counts"].items()}
    print(f"wrote {path}: {n['gordon']} Gordon patches, "
          f"{n['horizontal_line'] + n['vertical_line']} curves, {len(model.points)} points"
          + ("" if model.fused is None else
             f", fused mesh of {len(model.fused.faces)} triangles (fused.ply)"))
    return PARTIAL if blind else 0
