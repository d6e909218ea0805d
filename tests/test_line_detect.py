"""Thin-line grid detection (nurbscan.detect.line_grid, ridges, colour_model)."""

from __future__ import annotations

import numpy as np
import pytest

from _real_oracle import read_rgb, real_dir, real_pattern
from nurbscan.detect import DetectionResult, detect_lines

REAL = real_dir()
HAVE_REAL = (REAL / "images" / "colorGrid01.png").is_file()
NEED_REAL = pytest.mark.skipif(not HAVE_REAL, reason=f"shared real set not found at {REAL}")


@NEED_REAL
def test_real_pattern_helper_renders_the_projected_image():
    """The test helper's LinePattern (README rules) renders pattern.png exactly."""
    pat = real_pattern()
    ref = read_rgb(REAL / "pattern.png")
    assert pat.render().shape == ref.shape
    assert int((pat.render() != ref).any(axis=2).sum()) == 0


def test_blank_and_noise_images_give_an_empty_result_with_warnings():
    pat = real_pattern()
    for img in (np.zeros((120, 160, 3), np.uint8),
                np.random.default_rng(1).integers(0, 255, (120, 160, 3)).astype(np.uint8)):
        with pytest.warns(UserWarning, match="no grid found"):
            r = detect_lines(img, pat)
        assert isinstance(r, DetectionResult)
        assert r.nlines == 0 and len(r.cam) == 0
        assert r.warnings and r.warnings[0].startswith("no grid found")
