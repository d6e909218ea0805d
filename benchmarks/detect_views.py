"""Detection figures of every view of a simulated scan against its truth.

Usage: ``python benchmarks/detect_views.py SCAN_DIR ['{"option": value}']`` where SCAN_DIR
holds ``pattern.json``, ``views/view_KK_grid.png`` / ``_white.png`` and
``truth/view_KK.npz`` (what ``nurbscan demo`` or ``nurbscan simulate`` writes). Prints, per
view and on average, :func:`nurbscan.detect.evaluate_detection`'s coverage, RMS, label rate
and wrong lines over 20 px; the optional JSON names the options to change
(:meth:`nurbscan.detect.DetectOptions.replace`, e.g. ``{"fit_rounds": 0}``).
"""

from __future__ import annotations

import json
import sys
import warnings
from pathlib import Path

import numpy as np


def main(scan: Path, options: dict) -> None:
    from nurbscan.detect import DetectOptions, detect_grid, evaluate_detection
    from nurbscan.io import read_image
    from nurbscan.pattern import load_pattern

    pattern = load_pattern(scan / "pattern.json")
    rows = []
    for truth in sorted((scan / "truth").glob("view_*.npz")):
        stem = truth.stem
        grid = read_image(scan / "views" / f"{stem}_grid.png")
        white = read_image(scan / "views" / f"{stem}_white.png")
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            r = detect_grid(grid, pattern, white, DetectOptions().replace(**options))
        ev = evaluate_detection(r, truth, pattern)
        rows.append((ev["coverage"], ev["rms_px"], ev["label_rate"],
                     ev["wrong_lines_over_20px"]))
        print(f"{stem}: coverage {rows[-1][0]:.4f} rms {rows[-1][1]:.4f} px "
              f"labels {rows[-1][2]:.5f} wrong lines > 20 px {rows[-1][3]:.0f}", flush=True)
    t = np.array(rows)
    print(f"mean: coverage {t[:, 0].mean():.4f} rms {t[:, 1].mean():.4f} px "
          f"labels {t[:, 2].mean():.5f} wrong lines > 20 px (total) {t[:, 3].sum():.0f}")


if __name__ == "__main__":
    main(Path(sys.argv[1]), json.loads(sys.argv[2]) if len(sys.argv) > 2 else {})
