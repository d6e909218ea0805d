"""Hashes of :func:`nurbscan.detect.detect_grid`'s results, to show a restructuring keeps them.

Runs the detector on the 7.1 MP teapot view 0 at 1x noise (``bench_detect.render``, cached)
with the default options and with the option sets of ``nurbscan reconstruct``
(:data:`nurbscan.reconstruct.pipeline.DETECT_OPTIONS`, the true rig's epipolar constraint) and
of ``nurbscan calibrate`` (:data:`nurbscan.calibrate.pipeline.DETECT_OPTIONS`), and on the
views of ``tests/test_detect.py`` (the warped synthetic view with and without its white
image, the 1280 x 960 teapot, the oblique and the sheared views, a 640 x 480 view with bands
too narrow for the strict rules) with the options those tests set. Prints one line per run:
the run's name, a hash over all arrays of the result, and a hash per array; then the option
sets that reconstruct and calibrate change (by name) and their hash. Two versions of the code
behave the same on these inputs when every line is the same.

Usage: ``PYTHONPATH=src python benchmarks/detect_hash.py [--quick] [--options]``
(``--quick``: without the 7.1 MP view; ``--options``: the option sets only).
"""

from __future__ import annotations

import hashlib
import importlib.util
import json
import sys
import warnings
from dataclasses import fields
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent


def array_hash(a: np.ndarray) -> str:
    """First 8 hex digits of the SHA-1 of an array's dtype, shape and bytes."""
    a = np.ascontiguousarray(a)
    h = hashlib.sha1(f"{a.dtype.str}{a.shape}".encode())
    h.update(a.tobytes())
    return h.hexdigest()[:8]


def result_hashes(r) -> tuple[str, dict[str, str]]:
    """(hash over every array, {name: hash}) of a DetectionResult."""
    per = {f.name: array_hash(getattr(r, f.name)) for f in fields(r)
           if isinstance(getattr(r, f.name), np.ndarray)}
    total = hashlib.sha1(json.dumps(per, sort_keys=True).encode()).hexdigest()[:8]
    return total, per


def detect(image, pattern, white=None, epipolar=None, **changes):
    """detect_grid with the named options changed (the options object where the code has one,
    else keywords)."""
    import nurbscan.detect as det

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        if hasattr(det, "DetectOptions"):
            opts = det.DetectOptions().replace(**changes)
            return det.detect_grid(image, pattern, white, opts, epipolar=epipolar)
        if epipolar is not None:
            changes["epipolar"] = epipolar
        return det.detect_grid(image, pattern, white, **changes)


def option_sets() -> dict[str, dict]:
    """The detect options that reconstruct and calibrate change, by name (no callables, and
    none set to its default)."""
    import inspect

    import nurbscan.detect as det
    from nurbscan.calibrate import pipeline as cal
    from nurbscan.reconstruct import pipeline as rec
    from nurbscan.simulate.rig import default_rig

    rec_opts = (rec.DETECT_OPTIONS if hasattr(rec, "DETECT_OPTIONS")
                else rec.detect_options(default_rig()))
    out = {}
    for name, opts in (("reconstruct", rec_opts), ("calibrate", cal.DETECT_OPTIONS)):
        if hasattr(opts, "changes"):
            out[name] = opts.changes()
        else:  # keyword options of the single-function detector
            default = {k: p.default for k, p in
                       inspect.signature(det.detect_grid).parameters.items()}
            out[name] = {k: v for k, v in opts.items() if not callable(v) and v != default[k]}
    return out


def _bench_module():
    spec = importlib.util.spec_from_file_location("bench_detect", HERE / "bench_detect.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def runs(quick: bool = False):
    """(name, callable returning a DetectionResult) of every run."""
    from nurbscan.detect._synth import synth_view
    from nurbscan.pattern import Pattern
    from nurbscan.simulate import make_scene
    from nurbscan.simulate.render import RenderSettings, render_view
    from nurbscan.simulate.rig import default_rig, scale_camera
    from nurbscan.simulate.scan import default_pattern

    out = []
    sets = option_sets()
    if not quick:
        from functools import partial

        from nurbscan.reconstruct.light import other_coordinate

        bd = _bench_module()
        z = np.load(bd.render(1.0))
        g, w = z["grid"], z["white"]
        bp = bd._pattern()
        rig = default_rig()
        epi = partial(other_coordinate, rig)
        out += [("bench0", lambda: detect(g, bp, w)),
                ("bench0_reconstruct", lambda: detect(g, bp, w, epipolar=epi,
                                                      **sets["reconstruct"])),
                ("bench0_calibrate", lambda: detect(g, bp, w, **sets["calibrate"]))]
    pat = Pattern.create()
    sg, sw, _, _ = synth_view(pat, 1024, 768, noise=0.01, seed=3)
    out += [("synth", lambda: detect(sg, pat, sw)),
            ("synth_no_white", lambda: detect(sg, pat)),
            ("synth_calibrate", lambda: detect(sg, pat, sw, **sets["calibrate"]))]
    ng, nw, _, _ = synth_view(pat, 640, 480, noise=0.01, seed=0)
    out += [("narrow", lambda: detect(ng, pat, nw)),
            ("narrow_calibrate", lambda: detect(ng, pat, nw, **sets["calibrate"]))]
    trig = scale_camera(default_rig(), 1280, 960)
    tpat = default_pattern(trig.projector)
    v = render_view(make_scene("teapot"), trig, tpat, 0.0, RenderSettings(), seed=0, stream=0)
    tg, tw = v.grid, v.white
    for name, ch in (("", {}), ("_min_paired0", {"min_paired": 0}),
                     ("_smooth0", {"smooth_reach": 0}), ("_corner1", {"corner_dominance": 1.0}),
                     ("_end0", {"end_residual": 0}),
                     ("_dominance", {"dominance": 0.5, "corner_keep": 1.0,
                                     "refit_residual": 0.15}),
                     ("_chroma", {"chroma_subsampled": True}),
                     ("_partner_all", {"partner_drops": "all"}),
                     ("_fit_reach0", {"fit_reach": 0.0}), ("_plane0", {"plane_radius": 0.0})):
        out.append(("teapot" + name, lambda ch=ch: detect(tg, tpat, tw, **ch)))
    from functools import partial

    from nurbscan.reconstruct.light import other_coordinate

    epi_t = partial(other_coordinate, trig)
    out.append(("teapot_reconstruct", lambda: detect(tg, tpat, tw, epipolar=epi_t,
                                                     **sets["reconstruct"])))

    def field(av_deg, ah_deg, scale):
        av, ah = np.radians(av_deg), np.radians(ah_deg)
        return lambda xc, yc, w, h, pw, ph: (
            scale * (np.cos(av) * xc + np.sin(av) * yc) + 100.0 + 0 * yc,
            scale * (np.cos(ah) * xc + np.sin(ah) * yc) + 150.0 + 0 * xc)

    og, ow, _, _ = synth_view(pat, 480, 360, noise=0.01, seed=1, field=field(50.0, 92.0, 0.5))
    for name, ch in (("", {}), ("_colour_only", {"fit_rounds": 0, "read_along": "pixels"}),
                     ("_families0", {"families": False}), ("_row", {"fit_line": "row"}),
                     ("_pixels", {"read_along": "pixels"})):
        out.append(("oblique" + name, lambda ch=ch: detect(og, pat, ow, **ch)))
    hg, hw, _, _ = synth_view(pat, 480, 360, noise=0.01, seed=1, field=field(20.0, 60.0, 0.5))
    for name, ch in (("", {}), ("_pixels", {"read_along": "pixels"}),
                     ("_fit0", {"fit_rounds": 0}), ("_checked", {"min_checked_length": 0.5}),
                     ("_oblique0", {"oblique": False})):
        out.append(("sheared" + name, lambda ch=ch: detect(hg, pat, hw, **ch)))
    return out


def main(argv: list[str]) -> None:
    quick = "--quick" in argv
    for name, fn in ([] if "--options" in argv else runs(quick)):
        total, per = result_hashes(fn())
        print(f"{name:22s} {total}  " + " ".join(f"{k}={v}" for k, v in per.items()),
              flush=True)
    for name, opts in option_sets().items():
        text = json.dumps(opts, sort_keys=True)
        print(f"options {name:14s} {hashlib.sha1(text.encode()).hexdigest()[:8]}  {text}")


if __name__ == "__main__":
    main(sys.argv[1:])
