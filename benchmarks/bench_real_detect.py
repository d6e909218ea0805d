"""Benchmark of :func:`nurbscan.detect.detect_lines` on the shared real photographs.

The set ``../shared/real/procam-colour-grid`` (README there; ``NURBSCAN_REAL_DIR`` overrides):
a real projector's thin-line colour grid on a calibration board in 8 poses and two scenes.
Per shot it prints the lines visible on the board's white area (outside the checkerboard), the
decoded ones, the wrong ones, the decoded share, the coverage (share of the visible lines'
rows / columns on the white area that hold a correctly decoded centre) and the detection
time; the labels are checked by the oracles of ``tests/_real_oracle.py`` (the board's RANSAC
homography and the source's calibration for the poses; the source's epipolar geometry on the
object masks for the scenes).
``bench()`` returns the figures as a dict (``{"skipped": reason}`` when the set is absent).

Run ``python benchmarks/bench_real_detect.py [--overlays DIR]`` (prints a table, then JSON;
with ``--overlays`` the decoded lines are drawn on each photograph into DIR).
"""

from __future__ import annotations

import json
import sys
import time
import warnings
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "tests"))


def bench(overlays: Path | None = None, echo: bool = False) -> dict:
    from _real_oracle import (
        check_labels,
        check_scene,
        pose_oracle,
        read_rgb,
        real_dir,
        real_pattern,
        shift_ok,
    )
    from nurbscan.detect import detect_lines, draw_line_overlay

    root = real_dir()
    if not (root / "images" / "colorGrid01.png").is_file():
        reason = f"shared real set not found at {root}"
        if echo:
            print(f"skipped: {reason}")
        return {"skipped": reason}
    pat = real_pattern()
    out: dict = {"poses": {}, "scenes": {}}
    if echo:
        print(f"{'shot':>4} {'visible':>7} {'decoded':>7} {'wrong':>5} {'share':>6} "
              f"{'cover':>6} {'lines':>5} {'cross':>5} {'seconds':>7}")
    tot_v = tot_d = tot_w = 0
    for n in range(1, 11):
        img = read_rgb(root / "images" / f"colorGrid{n:02d}.png")
        white = read_rgb(root / "images" / f"lightGrid{n:02d}.png")
        detect_lines(img, pat, white)  # warm (imports, OpenCV's first calls)
        t0 = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            r = detect_lines(img, pat, white)
        dt = time.perf_counter() - t0
        if overlays is not None:
            import cv2

            overlays.mkdir(parents=True, exist_ok=True)
            cv2.imwrite(str(overlays / f"colorGrid{n:02d}_lines.png"),
                        draw_line_overlay(img, r, pat, scale=2)[:, :, ::-1])
        if n <= 8:
            oracle = pose_oracle(root, n)
            chk = check_labels(r, pat, oracle)
            nv, nd = len(chk.visible), len(chk.decoded)
            nw = len(chk.wrong) + (0 if shift_ok(chk, pat) else nd)
            tot_v, tot_d, tot_w = tot_v + nv, tot_d + nd, tot_w + nw
            share = nd / nv if nv else float("nan")
            out["poses"][f"{n:02d}"] = {"visible": nv, "decoded": nd, "wrong": nw,
                                        "share": round(share, 4),
                                        "coverage": round(chk.coverage, 4), "lines": r.nlines,
                                        "intersections": len(r.cam), "seconds": round(dt, 3)}
            if echo:
                print(f"{n:>4} {nv:>7} {nd:>7} {nw:>5} {share:>6.3f} {chk.coverage:>6.3f} "
                      f"{r.nlines:>5} "
                      f"{len(r.cam):>5} {dt:>7.2f}")
        else:
            chk = check_scene(r, pat, root, n, flat=n == 9)
            out["scenes"][f"{n:02d}"] = {
                "lines_on_object": chk.lines, "intersections_on_object": chk.crossings,
                "wrong": len(chk.wrong), "epipolar_p50_px": round(chk.epipolar_p50, 3),
                "epipolar_p95_px": round(chk.epipolar_p95, 3),
                "off_by_one_p5_px": round(chk.shifted_p5, 3), "seconds": round(dt, 3)}
            if echo:
                print(f"{n:>4} {'-':>7} {chk.lines:>7} {len(chk.wrong):>5} {'-':>6} {'-':>6} "
                      f"{r.nlines:>5} {len(r.cam):>5} {dt:>7.2f}   (scene: lines on the "
                      f"object; epipolar p95 {chk.epipolar_p95:.2f} px, off-by-one would be "
                      f">= {chk.shifted_p5:.1f})")
    out["poses_total"] = {"visible": tot_v, "decoded": tot_d, "wrong": tot_w,
                          "share": round(tot_d / tot_v, 4) if tot_v else None,
                          "min_share": min(p["share"] for p in out["poses"].values())}
    if echo:
        print(f"all poses: {tot_d}/{tot_v} decoded ({tot_d / tot_v:.3f}), {tot_w} wrong; "
              f"lowest pose share {out['poses_total']['min_share']:.3f}")
    return out


if __name__ == "__main__":
    ov = None
    if "--overlays" in sys.argv:
        ov = Path(sys.argv[sys.argv.index("--overlays") + 1])
    print(json.dumps(bench(ov, echo=True), indent=1))
