"""Tests for nurbscan.pattern.lines: LineFamily, LinePattern, window_length, load_pattern."""

from __future__ import annotations

import itertools
import json

import numpy as np
import pytest

from nurbscan.errors import NurbscanError
from nurbscan.io import read_image
from nurbscan.pattern import (
    LINE_PATTERN_TYPE,
    LineFamily,
    LinePattern,
    Pattern,
    load_pattern,
    window_length,
)

# ---------------------------------------------------------------- independent oracles


def brute_window_length(seqs, max_n=6):
    """Smallest n with all runs of n codes distinct in every sequence, by Python sets."""
    for n in range(1, max_n + 1):
        if all(len({tuple(s[i:i + n]) for i in range(len(s) - n + 1)}) == max(len(s) - n + 1, 0)
               for s in seqs):
            return n
    return None


def brute_lookup(codes, window):
    """First line of the only run equal to ``window``, -1 if none or several."""
    n = len(window)
    hits = [i for i in range(len(codes) - n + 1) if tuple(codes[i:i + n]) == tuple(window)]
    return hits[0] if len(hits) == 1 else -1


PALETTE8 = (("red", (255, 0, 0)), ("yellow", (255, 191, 0)), ("lime", (128, 255, 0)),
            ("green", (0, 255, 128)), ("cyan", (0, 255, 255)), ("blue", (0, 64, 255)),
            ("purple", (191, 0, 255)), ("magenta", (255, 0, 191)))


def foreign(crossing="horizontal-over"):
    """A small foreign grid: 3 px lines, 4 colours per direction, per-direction pitch."""
    hcodes = (0, 0, 2, 4, 6, 2, 2, 6, 0, 4, 4, 0, 2)  # pairs repeat (0, 2), triples do not
    vcodes = (1, 3, 5, 7, 1, 1, 5, 3, 3, 7, 5, 5, 3, 5)
    hc = 11 + 21 * np.arange(len(hcodes))
    vc = 11 + 29 * np.arange(len(vcodes))
    return LinePattern(
        width=400, height=280, colours=PALETTE8, window=window_length([hcodes, vcodes]),
        vertical=LineFamily("vertical", vcodes, tuple(vc - 1.5), tuple(vc + 1.5)),
        horizontal=LineFamily("y", hcodes, tuple(hc - 1.5), tuple(hc + 1.5)),
        crossing=crossing,
    )


# ---------------------------------------------------------------- window length and look-up


def test_window_length_against_brute_force():
    rng = np.random.default_rng(31)
    for _ in range(300):
        k = int(rng.integers(2, 9))
        seqs = [rng.integers(0, k, int(rng.integers(1, 40))).tolist() for _ in range(2)]
        want = brute_window_length(seqs)
        if want is None:
            with pytest.raises(NurbscanError, match="repeats a window"):
                window_length(seqs)
        else:
            assert window_length(seqs) == want
    assert window_length({"horizontal": [0, 1, 2, 3]}) == 1
    assert window_length([[0, 0, 1, 1, 0]]) == 2 and window_length([[0, 0, 1, 0, 0, 1]]) == 4
    with pytest.raises(NurbscanError, match="vertical colour sequence repeats.*6") as exc:
        window_length({"vertical": [0, 1] * 10}, source="grid.png")
    assert str(exc.value).startswith("grid.png:") and "\n" not in str(exc.value)


def test_lookup_against_brute_force():
    rng = np.random.default_rng(7)
    for _ in range(20):
        codes = rng.integers(0, 4, int(rng.integers(3, 30))).tolist()
        fam = LineFamily("x", tuple(codes), tuple(10.0 * np.arange(len(codes)) - 0.5),
                         tuple(10.0 * np.arange(len(codes)) + 2.5))
        for n in (1, 2, 3):
            allw = np.array(list(itertools.product(range(-1, 5), repeat=n)))
            want = np.array([brute_lookup(codes, w) for w in allw.tolist()])
            got = fam.lookup(allw)
            assert got.shape == (len(allw),) and np.array_equal(got, want)
            # batch shape kept
            assert np.array_equal(fam.lookup(allw.reshape(-1, 1, n))[:, 0], want)


def test_family_derived_values_and_refusals():
    fam = LineFamily("horizontal", (2, 0, 1), (9.5, 30.5, 51.5), (12.5, 33.5, 54.5))
    assert fam.count == 3 and fam.direction == "horizontal"
    assert fam.centres.tolist() == [11.0, 32.0, 53.0] and fam.widths.tolist() == [3.0] * 3
    assert fam.edges.shape == (3, 2) and fam.edges[1].tolist() == [30.5, 33.5]
    lit = fam.lit(60)
    assert np.flatnonzero(lit == 1).tolist() == [31, 32, 33] and (lit >= 0).sum() == 9
    for args, what in [
        (("diagonal", (0,), (0.5,), (2.5,)), "direction"),
        (("x", (), (), ()), "no lines"),
        (("x", (0, 1), (0.5,), (2.5, 4.5)), "1 lower"),
        (("x", (0, -1), (0.5, 5.5), (2.5, 7.5)), "codes"),
        (("x", (0, 1), (0.5, 5.5), (0.5, 7.5)), "line 0 has upper edge"),
        (("x", (0, 1), (0.5, 1.5), (2.5, 7.5)), "line 1 .* starts before line 0"),
        (("x", (0, 1), (0.5, float("nan")), (2.5, 7.5)), "finite"),
    ]:
        with pytest.raises(NurbscanError, match=what):
            LineFamily(*args)


def test_line_pattern_checks():
    good = foreign()
    assert good.window == 3 and good.codes_used("horizontal") == (0, 2, 4, 6)
    assert good.codes_used(0) == (1, 3, 5, 7) and good.family("y") is good.horizontal
    assert good.rgb.shape == (8, 3) and good.rgb.dtype == np.uint8
    kw = dict(width=good.width, height=good.height, colours=good.colours, window=3,
              vertical=good.vertical, horizontal=good.horizontal, crossing=good.crossing)
    for change, what in [
        (dict(window=4), "smallest window length .* is 3"),
        (dict(window=2), "smallest window length .* is 3"),
        (dict(vertical=None, horizontal=None), "no lines"),
        (dict(width=380), "leave the image"),
        (dict(colours=good.colours[:7]), "code 7 has no colour"),
        (dict(colours=good.colours[:7] + (("black", (0, 0, 0)),)), "not black"),
        (dict(colours=good.colours[:7] + (("x", (255, 0, 0)),)), "same RGB"),
        (dict(crossing="over"), "crossing"),
        (dict(vertical=good.horizontal), "holds horizontal lines"),
    ]:
        with pytest.raises(NurbscanError, match=what):
            LinePattern(**{**kw, **change})
    one = LinePattern(**{**kw, "vertical": None})
    assert one.families == (good.horizontal,)
    with pytest.raises(NurbscanError, match="no vertical lines"):
        one.family("vertical")
    rep = LineFamily("x", (0, 1) * 6, tuple(20.0 * np.arange(12)), tuple(20.0 * np.arange(12) + 3))
    with pytest.raises(NurbscanError, match="vertical colour sequence repeats"):
        LinePattern(**{**kw, "vertical": rep})


# ---------------------------------------------------------------- image and sidecar


@pytest.mark.parametrize("crossing", ["horizontal-over", "vertical-over", "max", "unknown"])
def test_render_from_edges(crossing):
    pat = foreign(crossing)
    img = pat.render()
    assert img.shape == (280, 400, 3) and img.dtype == np.uint8
    # oracle: paint each line's pixels (centres between the edges), one line at a time
    cols = np.full(400, -1)
    rows = np.full(280, -1)
    for fam, lit in ((pat.vertical, cols), (pat.horizontal, rows)):
        for c, lo, hi in zip(fam.codes, fam.lower, fam.upper, strict=True):
            lit[int(np.ceil(lo)):int(np.floor(hi)) + 1] = c
    rgb = pat.rgb.astype(int)
    want = np.zeros((280, 400, 3), int)
    for y, x in itertools.product(range(280), range(400)):
        v, h = cols[x], rows[y]
        if v >= 0 and h >= 0:
            want[y, x] = {"horizontal-over": rgb[h], "vertical-over": rgb[v]}.get(
                crossing, np.maximum(rgb[v], rgb[h]))
        elif v >= 0 or h >= 0:
            want[y, x] = rgb[max(v, h)]
    assert np.array_equal(img, want)
    assert (cols >= 0).sum() == 3 * 14 and (rows >= 0).sum() == 3 * 13


def test_round_trip_and_load_pattern(tmp_path):
    pat = foreign()
    d = json.loads(json.dumps(pat.to_dict()))
    assert d["type"] == LINE_PATTERN_TYPE and d["counts"] == {"vertical": 14, "horizontal": 13}
    assert d["lines"]["horizontal"][1] == {"index": 1, "code": 0, "lower": 30.5, "upper": 33.5}
    assert LinePattern.from_dict(d) == pat
    png, side = pat.save(tmp_path / "foreign.png")
    assert side == tmp_path / "foreign.json"
    assert np.array_equal(read_image(png, as_float=False), pat.render())
    assert load_pattern(side) == pat
    one = LinePattern(width=360, height=240, colours=PALETTE8[:2], window=1, vertical=None,
                      horizontal=LineFamily("h", (0, 1), (4.5, 9.5), (6.5, 11.5)))
    assert LinePattern.from_dict(json.loads(json.dumps(one.to_dict()))) == one
    with pytest.raises(NurbscanError, match=r"\.jpg"):
        pat.save(tmp_path / "p.jpg")
    assert "14 vertical lines 3 px wide" in pat.summary() and "\n" not in pat.summary()


def test_bad_line_pattern_sidecars(tmp_path):
    _, side = foreign().save(tmp_path / "p.png")
    for mutate, what in [
        (lambda d: d.pop("window"), "missing key 'window'"),
        (lambda d: d.update(width="360"), "'width' must be an integer"),
        (lambda d: d.update(window=2), "smallest window length"),
        (lambda d: d.update(version=2), "newer"),
        (lambda d: d.update(crossing="on top"), "crossing"),
        (lambda d: d.update(colours="rgb"), "'colours' must be"),
        (lambda d: d["colours"].reverse(), "code order"),
        (lambda d: d.pop("lines"), "missing key 'lines'"),
        (lambda d: d["lines"].pop("vertical"), "missing key lines.'vertical'"),
        (lambda d: d["lines"]["vertical"][2].pop("upper"), r"lines.vertical\[2\].'upper'"),
        (lambda d: d["lines"]["vertical"][2].update(lower="a"), "must be a number"),
        (lambda d: d["lines"]["vertical"][2].update(index=5), "index 5, expected 2"),
        (lambda d: d["lines"]["vertical"][2].update(lower=30.0), "starts before line 1"),
        (lambda d: [e.update(code=0) for e in d["lines"]["horizontal"]],
         "horizontal colour sequence repeats a window"),
        (lambda d: d["lines"]["horizontal"][3].update(code=2), "smallest window length .* 4"),
        (lambda d: d["counts"].update(vertical=3), "'counts' disagree"),
        (lambda d: d.update(type="nurbscan.linepattern"), "type"),
    ]:
        bad = json.loads(side.read_text())
        mutate(bad)
        path = tmp_path / "bad.json"
        path.write_text(json.dumps(bad))
        with pytest.raises(NurbscanError, match=what) as exc:
            load_pattern(path)
        assert str(exc.value).startswith(str(path)) and "\n" not in str(exc.value)
    path.write_text("[1, 2]")
    with pytest.raises(NurbscanError, match="expected a JSON object"):
        load_pattern(path)
    path.write_text("{")
    with pytest.raises(NurbscanError, match="not valid JSON"):
        load_pattern(path)


# ---------------------------------------------------------------- nurbscan's own grid


@pytest.mark.parametrize("kw", [dict(), dict(width=800, height=600, pitch=12, band=4),
                                dict(width=640, height=480, pitch=8, band=3, q=3, n=4),
                                dict(width=200, height=120, pitch=20, band=9)])
def test_to_line_pattern_matches_pattern(kw, tmp_path):
    pat = Pattern.create(**kw)
    lp = pat.to_line_pattern()
    assert lp.width == pat.width and lp.height == pat.height and lp.colours == pat.colours
    assert lp.crossing == "max"
    assert np.array_equal(lp.vertical.edges, pat.vertical_edges)
    assert np.array_equal(lp.horizontal.edges, pat.horizontal_edges)
    assert np.array_equal(lp.vertical.code_array, pat.band_codes("vertical"))
    assert np.array_equal(lp.horizontal.code_array, pat.band_codes("horizontal"))
    assert lp.window == brute_window_length([pat.band_codes("x").tolist(),
                                             pat.band_codes("y").tolist()], max_n=pat.n)
    assert np.array_equal(lp.render(), pat.render())
    # the windows name the same bands as the PRMVS look-up
    codes = pat.band_codes("x")
    win = np.lib.stride_tricks.sliding_window_view(codes, pat.n)
    assert np.array_equal(lp.vertical.lookup(win), pat.lookup(win, "x"))
    _, side = lp.save(tmp_path / "lp.png")
    assert load_pattern(side) == lp


def test_default_pattern_window_is_three():
    assert Pattern.create().to_line_pattern().window == 3
    small = Pattern.create(width=200, height=120, pitch=20, band=9)  # 10 + 6 bands
    assert small.to_line_pattern().window == brute_window_length(
        [small.band_codes("x").tolist(), small.band_codes("y").tolist()])
