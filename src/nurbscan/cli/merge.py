"""``nurbscan merge``: several turntable passes of one object into one model (issue 33)."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path


def register(sub) -> None:
    """Add the ``merge`` sub-command."""
    p = sub.add_parser(
        "merge", help="Merge turntable passes of one object (turned over) into one model",
        description=(
            "Align two or more model folders of one object, each a turntable pass with the "
            "object in another resting pose, with no prior: the passes' fused surfaces (the "
            "table and what lies below the object's base left out) are registered globally "
            "(FPFH features, RANSAC, point-to-plane ICP), then all views of all passes are "
            "refined jointly (pairwise ICP, pose graph) and fused into one mesh. Writes a "
            "model folder in the first pass's frame (view v of pass k is view 100 k + v) "
            "that export, evaluate and report read, with alignment.json (the transforms, "
            "RMS over the overlap, overlap shares, warnings). Passes of different objects "
            "or with too little overlap: an error, nothing written."))
    p.add_argument("models", type=Path, nargs="+", metavar="MODEL",
                   help="model folders (with model.json and fused.ply), the first fixes the "
                        "frame")
    p.add_argument("-o", "--output", type=Path, required=True, help="merged model folder")
    p.add_argument("--base-margin", type=float, default=2.0, metavar="MM",
                   help="height above each pass's table plane below which its surface is left "
                        "out of the alignment (default 2 mm)")
    p.add_argument("--trials", type=int, default=6,
                   help="RANSAC runs of the global registration, each a candidate alignment "
                        "(default 6)")
    p.add_argument("--no-refine", action="store_true",
                   help="keep the global alignment (no joint refinement of all views)")
    p.add_argument("--max-misclosure", type=float, default=0.5, metavar="DEG",
                   help="largest angle by which the jointly optimised poses may differ from a "
                        "pair of views' own ICP result before the joint refinement is refused "
                        "and the global alignment kept (default 0.5 degrees)")
    p.add_argument("--max-triangles", type=int, default=300_000,
                   help="triangle budget of the fused mesh (300000)")
    p.add_argument("--no-fuse", action="store_true", help="no fused mesh of the merged model")
    p.add_argument("--scan", type=Path, action="append", default=None, metavar="SCAN",
                   help="a pass's scan folder, for the fused mesh's colours from its "
                        "white-light images: once per model, in the same order (default: "
                        "each model's recorded source, where it exists)")
    p.add_argument("--calib", type=Path, action="append", default=None, metavar="CALIB",
                   help="a pass's calibrated rig (calib.json), once per model or once for "
                        "all (default: each model's recorded calibration, where it exists)")
    p.add_argument("--no-colour", action="store_true",
                   help="a grey fused mesh (do not read the passes' white images)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress lines")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Merge ``args.models`` into ``args.output``; print the alignment."""
    from ..errors import NurbscanError
    from ..merge import RegistrationOptions
    from ..merge.fusion import FusionOptions
    from ..merge.global_registration import GlobalOptions
    from ..merge.passes import PassOptions, merge_passes
    from ..reconstruct import load_model

    if len(args.models) < 2:
        raise NurbscanError("at least two model folders are needed")
    if not args.max_misclosure > 0:
        raise NurbscanError(f"--max-misclosure {args.max_misclosure}: must be > 0 degrees")
    if not args.base_margin >= 0:
        raise NurbscanError(f"--base-margin {args.base_margin}: must be >= 0 mm")
    out = Path(args.output)
    for m in args.models:
        if m.resolve() == out.resolve():
            raise NurbscanError(f"{out}: the output must not be one of the input models")
    t0 = time.perf_counter()

    def say(msg: str) -> None:
        if not args.quiet:
            print(f"[{time.perf_counter() - t0:6.1f} s] {msg}", file=sys.stderr, flush=True)

    models = []
    for m in args.models:
        say(f"load {m}")
        model = load_model(m)
        model.meta["_folder"] = str(m)
        models.append(model)
    if args.trials < 1:
        raise NurbscanError(f"--trials {args.trials}: must be at least 1")
    opt = PassOptions(base_margin=args.base_margin,
                      alignment=GlobalOptions(trials=args.trials),
                      registration=None if args.no_refine else RegistrationOptions(
                          max_misclosure=args.max_misclosure),
                      fusion=None if args.no_fuse else FusionOptions(
                          max_triangles=args.max_triangles, loose_edges=0.5))
    rigs = pass_rigs(args, models, say)
    colour = (None if args.no_fuse or args.no_colour
              else pass_colours(args, models, say, rigs))
    merged, report = merge_passes(models, [str(m) for m in args.models], opt, progress=say,
                                  colour=colour, rigs=rigs)
    for m in models:
        m.meta.pop("_folder", None)
    merged.meta.pop("_folder", None)
    _save_folder(merged, report, out)
    if args.quiet:
        for w in report["warnings"]:
            print(f"nurbscan merge: warning: {w}", file=sys.stderr)
    for p in report["passes"][1:]:
        g = p["global"]
        print(f"{p['name']} -> {report['passes'][0]['name']}: rotation {g['rotation_deg']:.4f} "
              f"degrees about {g['rotation_axis']}, translation {g['translation_mm']} mm; "
              f"overlap {100 * p['overlap']:.1f} %, RMS {p['rms_mm']:.4f} mm over the overlap"
              + ("" if g.get("free_space") is None else
                 f", free-space violation {100 * g['free_space']:.2f} % (chosen by "
                 f"{g['chosen_by']}; candidates "
                 + ", ".join(f"{100 * c['free_space']:.2f}" for c in g["candidates"]) + " %)")
              + (" (AMBIGUOUS)" if g["ambiguous"] else ""))
        print("  transform (after the joint refinement): "
              + json.dumps([[round(x, 6) for x in r] for r in p["refined_matrix"]]))
    n = merged.to_dict()["counts"]
    print(f"wrote {out}: {len(merged.views)} views of {len(models)} passes, {n['gordon']} "
          f"Gordon patches" + ("" if merged.fused is None else
                              f", fused mesh of {len(merged.fused.faces)} triangles")
          + f", alignment in {out / 'alignment.json'}")
    return 0


def _check_counts(args: argparse.Namespace, n: int) -> None:
    """``--scan`` once per model, ``--calib`` once per model or once for all."""
    from ..errors import NurbscanError

    for opt, name in ((args.scan, "--scan"), (args.calib, "--calib")):
        if opt is not None and len(opt) not in ((1, n) if name == "--calib" else (n,)):
            raise NurbscanError(f"{name}: given {len(opt)} times for {n} models "
                                + ("(once per model, or once for all)" if name == "--calib"
                                   else "(once per model)"))


def pass_rigs(args: argparse.Namespace, models: list, say) -> list:
    """Per pass, its calibrated rig (``--calib``, else the model's recorded calibration), or
    None when not found (then said: the alignment is chosen without the pass's free space;
    given explicitly and unreadable: an error)."""
    from ..camera import load_rig

    n = len(models)
    _check_counts(args, n)
    out = []
    for k, (folder, m) in enumerate(zip(args.models, models, strict=True)):
        calib = (args.calib[k if len(args.calib) == n else 0] if args.calib
                 else _recorded(m.meta.get("calibration"), folder))
        if calib is None:
            say(f"rig: {folder}: its calibration is not found: its views' free space does "
                "not check the alignment, nor do they colour the merged mesh (give --calib)")
        out.append(None if calib is None else load_rig(calib))
    return out


def pass_colours(args: argparse.Namespace, models: list, say, rigs: list | None = None) -> list:
    """Per pass, ``(rig, {view: white image path})`` for the merged mesh's colours, or None
    when its scan folder or calibration is not found (then said, not an error; given
    explicitly with ``--scan``/``--calib`` and unreadable: an error). ``rigs``: the passes'
    rigs (:func:`pass_rigs`), loaded here when not given."""
    from ..io import load_scan

    rigs = pass_rigs(args, models, say) if rigs is None else rigs
    out = []
    for k, (folder, m) in enumerate(zip(args.models, models, strict=True)):
        scan = args.scan[k] if args.scan else _recorded(m.meta.get("source"), folder)
        if scan is None or rigs[k] is None:
            say(f"colour: {folder}: its scan folder or calibration is not found; its views "
                "do not colour the merged mesh (give --scan and --calib)")
            out.append(None)
            continue
        views = load_scan(scan).views
        out.append((rigs[k], {int(v.index): v.white for v in views if v.white is not None}))
    return out


def _recorded(path, model_folder: Path):
    """A path recorded in a model (relative to where it was made): as it stands, else
    relative to the model folder's parent; None when neither exists."""
    if not path:
        return None
    for cand in (Path(path), Path(model_folder).resolve().parent / path):
        if cand.exists():
            return cand
    return None


def _save_folder(model, report: dict, out: Path) -> None:
    """Write the model and ``alignment.json`` as one folder (:func:`nurbscan.io.atomic_folder`:
    under a temporary name, renamed into place, under the folder's lock; an existing ``out``
    is replaced only once the new one is complete, a file or a folder of other files is
    refused)."""
    from ..io import atomic_folder, write_json
    from ..reconstruct.model import MODEL_FILES

    with atomic_folder(out, MODEL_FILES | {"alignment.json"}) as tmp:
        model.write_files(tmp)
        write_json(tmp / "alignment.json", {"type": "nurbscan.alignment", "version": 1,
                                            **report})
