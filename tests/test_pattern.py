"""Tests for nurbscan.pattern (sequences, grid, sidecar) and the ``nurbscan pattern`` command."""

from __future__ import annotations

import itertools
import json

import numpy as np
import pytest

from nurbscan.cli import main
from nurbscan.errors import NurbscanError
from nurbscan.io import read_image
from nurbscan.pattern import (
    Pattern,
    de_bruijn,
    default_poly,
    find_primitive,
    is_primitive,
    load_pattern,
    m_sequence,
    parse_poly,
)

# ---------------------------------------------------------------- independent oracles


def companion_order(coeffs, q):
    """Multiplicative order of the companion matrix of a monic polynomial (0 if singular).

    Independent of the library's LFSR: repeated matrix products until the identity returns.
    p is primitive over GF(q) iff this order is q^n - 1.
    """
    n = len(coeffs) - 1
    if coeffs[-1] % q == 0:
        return 0
    m = np.zeros((n, n), dtype=np.int64)
    m[1:, :-1] = np.eye(n - 1, dtype=np.int64)
    m[:, -1] = [(-c) % q for c in reversed(coeffs[1:])]  # last column: -c0, -c1, ...
    eye = np.eye(n, dtype=np.int64)
    p = m.copy()
    for k in range(1, q**n):
        if np.array_equal(p, eye):
            return k
        p = (p @ m) % q
    return 0


def window_ints(seq, n, q, cyclic):
    seq = np.asarray(seq)
    ext = np.concatenate([seq, seq[: n - 1]]) if cyclic else seq
    count = len(seq) if cyclic else len(seq) - n + 1
    return np.array([int("".join(map(str, ext[i:i + n])), q) if q <= 10 else
                     sum(int(ext[i + k]) * q ** (n - 1 - k) for k in range(n))
                     for i in range(count)])


def follows_recurrence(seq, coeffs, q):
    """a[k+n] + c[n-1] a[k+n-1] + ... + c[0] a[k] = 0 (mod q) for every k, cyclically."""
    n = len(coeffs) - 1
    s = np.asarray(seq)
    total = sum(c * np.roll(s, -(n - d)) for d, c in enumerate(coeffs))
    return bool(np.all(total % q == 0))


# ---------------------------------------------------------------- sequences


def test_default_m_sequence_q5_n3():
    m = m_sequence(5, 3)
    assert m.shape == (124,)
    # the recurrence a[k+3] = a[k+2] + 2 a[k] (mod 5) of "1403", cyclically
    assert np.array_equal(np.roll(m, -3), (np.roll(m, -2) + 2 * m) % 5)
    keys = window_ints(m, 3, 5, cyclic=True)
    assert sorted(keys.tolist()) == list(range(1, 125))  # every non-zero window once, 000 never
    assert not any(np.array_equal(np.roll(m, s), m) for s in range(1, 124))  # period exactly 124
    assert companion_order(parse_poly("1403", 5, 3), 5) == 124


@pytest.mark.parametrize("q, n", [(5, 3), (3, 4), (7, 2), (5, 4)])
def test_m_sequence_and_de_bruijn(q, n):
    poly = default_poly(q, n)
    coeffs = parse_poly(poly, q, n)
    assert companion_order(coeffs, q) == q**n - 1  # oracle: really primitive
    m = m_sequence(q, n, poly)
    assert m.shape == (q**n - 1,)
    assert follows_recurrence(m, coeffs, q)
    assert sorted(window_ints(m, n, q, cyclic=True).tolist()) == list(range(1, q**n))
    db = de_bruijn(q, n, poly)
    assert db.shape == (q**n,)
    assert sorted(window_ints(db, n, q, cyclic=True).tolist()) == list(range(q**n))
    assert np.array_equal(db[1:], m) and db[0] == 0


def test_primitive_check_agrees_with_oracle_for_all_cubics_over_gf5():
    found = set()
    for c2, c1, c0 in itertools.product(range(5), repeat=3):
        poly = f"1{c2}{c1}{c0}"
        oracle = companion_order((1, c2, c1, c0), 5) == 124
        assert is_primitive(poly, 5, 3) == oracle, poly
        if oracle:
            found.add(poly)
    assert len(found) == 20  # phi(124) / 3
    assert "1403" in found and find_primitive(5, 3) == min(found, key=lambda s: s[1:])


def _irreducible_non_primitive_cubic_gf5():
    for c2, c1, c0 in itertools.product(range(5), repeat=3):
        coeffs = (1, c2, c1, c0)
        no_root = all((x**3 + c2 * x * x + c1 * x + c0) % 5 for x in range(5))
        if no_root and 0 < companion_order(coeffs, 5) < 124:
            return f"1{c2}{c1}{c0}"
    raise AssertionError("no irreducible non-primitive cubic found")


@pytest.mark.parametrize("poly", ["1000", "1001", "irreducible"])
def test_non_primitive_refused(poly):
    if poly == "irreducible":
        poly = _irreducible_non_primitive_cubic_gf5()
    assert companion_order(parse_poly(poly, 5, 3), 5) != 124
    with pytest.raises(NurbscanError, match=f"polynomial '{poly}'.*not primitive"):
        m_sequence(5, 3, poly)
    with pytest.raises(NurbscanError, match=poly):
        Pattern.create(poly=poly)


def test_poly_notation():
    assert parse_poly("1403", 5, 3) == parse_poly("1,4,0,3", 5, 3) == parse_poly([1, 4, 0, 3], 5, 3)
    assert parse_poly("1403", 5, 3) == (1, 4, 0, 3)
    for bad, what in [("2403", "monic"), ("14031", "coefficients"), ("1503", "0..4"),
                      ("x^3+1", "digits"), ("1,4,,3", "digits")]:
        with pytest.raises(NurbscanError, match=what):
            parse_poly(bad, 5, 3)
    with pytest.raises(NurbscanError, match="prime"):
        parse_poly("1403", 4, 3)
    # q > 10 needs the comma list; the search returns it in that form
    poly = find_primitive(11, 2)
    assert "," in poly and companion_order(parse_poly(poly, 11, 2), 11) == 120
    assert sorted(window_ints(de_bruijn(11, 2, poly), 2, 11, cyclic=True).tolist()) == list(
        range(121))


# ---------------------------------------------------------------- grid geometry and look-up


@pytest.fixture(scope="module")
def pat():
    return Pattern.create()


def test_default_geometry(pat):
    assert pat.counts == (120, 68)  # (1920 - 6) // 16 + 1, (1080 - 6) // 16 + 1
    assert pat.offsets == (5, 1)  # centred: 1920 - (119*16 + 6) = 10, 1080 - (67*16 + 6) = 2
    ve = pat.vertical_edges
    assert ve.shape == (120, 2) and pat.horizontal_edges.shape == (68, 2)
    assert ve[0].tolist() == [4.5, 10.5] and ve[119].tolist() == [1908.5, 1914.5]
    assert pat.horizontal_edges[67].tolist() == [1072.5, 1078.5]
    assert np.array_equal(pat.band_codes("x"), de_bruijn(5, 3)[:120])


def test_lookup_recovers_every_band(pat):
    for direction in ("vertical", "horizontal"):
        codes = pat.band_codes(direction)
        count = len(codes)
        windows = np.lib.stride_tricks.sliding_window_view(codes, 3)  # (count - 2, 3)
        assert np.array_equal(pat.lookup(windows, direction), np.arange(count - 2))
        assert np.array_equal(pat.lookup(windows[::-1][None], direction),
                              np.arange(count - 2)[::-1][None])
    # windows that exist only in the longer (vertical) direction
    w = np.asarray(pat.sequence[66:69])
    assert pat.lookup(w, "horizontal") == -1 and pat.lookup(w, "vertical") == 66
    # unread or impossible codes
    assert pat.lookup([[-1, 0, 1], [0, 5, 1], [0, 0, 7]], "x").tolist() == [-1, -1, -1]
    # every possible window: a hit points at a band whose window is that one
    allw = np.array(list(itertools.product(range(5), repeat=3)))
    idx = pat.lookup(allw, "vertical")
    seq = np.asarray(pat.sequence)
    hit = idx >= 0
    assert hit.sum() == 118
    assert np.array_equal(seq[idx[hit, None] + np.arange(3)], allw[hit])


def test_edge_coordinate_and_stripe_field(pat):
    i = np.arange(120)
    ve = pat.vertical_edges
    assert np.array_equal(pat.edge_coordinate("vertical", i, "rising"), ve[:, 0])
    assert np.array_equal(pat.edge_coordinate("vertical", i, 1), ve[:, 1])
    both = pat.edge_coordinate("horizontal", np.array([[0], [3]]), np.array(["rising", "falling"]))
    assert both.tolist() == [[0.5, 6.5], [48.5, 54.5]]
    assert np.isnan(pat.edge_coordinate("y", [-1, 68], 0)).all()
    eps = 1e-9
    sf = pat.stripe_field
    assert np.array_equal(sf(ve[:, 0], "x"), i) and np.array_equal(sf(ve[:, 1] - eps, "x"), i)
    assert (sf(ve[:, 0] - eps, "x") == -1).all() and (sf(ve[:, 1], "x") == -1).all()
    assert sf([np.nan, -100.0, 5000.0], "y").tolist() == [-1, -1, -1]
    with pytest.raises(NurbscanError, match="direction"):
        sf([1.0], "diagonal")


def test_small_q3_n4_grid():
    p = Pattern.create(width=640, height=480, pitch=8, band=3, q=3, n=4)
    assert p.counts == (80, 60) and len(p.sequence) == 81
    codes = p.band_codes("x")
    win = np.lib.stride_tricks.sliding_window_view(codes, 4)
    assert np.array_equal(p.lookup(win, "x"), np.arange(77))
    # black, the 3 colours, and the crossings magenta|green = white, red|green = yellow
    found = {tuple(c) for c in np.unique(p.render().reshape(-1, 3), axis=0).tolist()}
    assert found == {(0, 0, 0), (255, 0, 255), (255, 0, 0), (0, 255, 0), (255, 255, 255),
                     (255, 255, 0)}


def test_refusals():
    with pytest.raises(NurbscanError, match="240 vertical bands.*125"):
        Pattern.create(pitch=8, band=3)
    with pytest.raises(NurbscanError, match="narrower"):
        Pattern.create(pitch=6, band=6)
    with pytest.raises(NurbscanError, match="colour"):
        Pattern.create(width=1000, height=1000, pitch=100, band=6, q=11, n=2)


# ---------------------------------------------------------------- image and sidecar


def test_rendered_png_agrees_with_sidecar(pat, tmp_path):
    png, side = pat.save(tmp_path / "grid.png")
    assert side == tmp_path / "grid.json" and png.is_file() and side.is_file()
    img = read_image(png, as_float=False)
    d = json.loads(side.read_text())
    assert img.shape == (d["height"], d["width"], 3) and img.dtype == np.uint8
    rgb = {c["code"]: np.array(c["rgb"], np.uint8) for c in d["colours"]}
    assert [c["name"] for c in d["colours"]] == ["magenta", "red", "green", "yellow", "cyan"]
    assert rgb[0].tolist() == [255, 0, 255] and rgb[3].tolist() == [255, 255, 0]
    assert d["sequence"][:len(d["bands"]["vertical"])] == [b["code"] for b in d["bands"][
        "vertical"]]

    # expected image from the sidecar's edges alone: lit pixels have centres between the edges
    cols = np.zeros((d["width"], 3), np.uint8)
    rows = np.zeros((d["height"], 3), np.uint8)
    for lines, b in [(cols, "vertical"), (rows, "horizontal")]:
        for e in d["bands"][b]:
            lo, hi = int(np.ceil(e["rising"])), int(np.floor(e["falling"]))
            assert hi - lo + 1 == d["band"]
            lines[lo:hi + 1] = rgb[e["code"]]
    expected = np.maximum(cols[None], rows[:, None])
    assert np.array_equal(img, expected)

    # away from crossings: band interior lit with its colour, the pixels just outside dark
    free_row = int(d["bands"]["horizontal"][0]["falling"] + 1.5)  # a dark row
    assert not rows[free_row].any()
    for e in d["bands"]["vertical"]:
        a, b = int(e["rising"] + 0.5), int(e["falling"] - 0.5)
        assert (img[free_row, a:b + 1] == rgb[e["code"]]).all()
        assert not img[free_row, a - 1].any() and not img[free_row, b + 1].any()
    free_col = int(d["bands"]["vertical"][0]["falling"] + 1.5)
    for e in d["bands"]["horizontal"]:
        a, b = int(e["rising"] + 0.5), int(e["falling"] - 0.5)
        assert (img[a:b + 1, free_col] == rgb[e["code"]]).all()
        assert not img[a - 1, free_col].any() and not img[b + 1, free_col].any()
    # a crossing of red (1) and green (2) is yellow
    v = next(e for e in d["bands"]["vertical"] if e["code"] == 1)
    h = next(e for e in d["bands"]["horizontal"] if e["code"] == 2)
    assert img[int(h["rising"] + 0.5), int(v["rising"] + 0.5)].tolist() == [255, 255, 0]
    assert d["crossing"] == "max" and d["type"] == "nurbscan.pattern"


def test_dict_and_file_round_trip(pat, tmp_path):
    d = json.loads(json.dumps(pat.to_dict()))
    assert Pattern.from_dict(d) == pat
    _, side = pat.save(tmp_path / "p.png")
    assert load_pattern(side) == pat
    with pytest.raises(NurbscanError, match="not found"):
        load_pattern(tmp_path / "missing.json")
    for mutate, what in [
        (lambda d: d.pop("pitch"), "missing key 'pitch'"),
        (lambda d: d.update(pitch="16"), "'pitch' must be an integer"),
        (lambda d: d.update(sequence="012"), "'sequence' must be a list"),
        (lambda d: d.update(type="something"), "type"),
        (lambda d: d["bands"]["vertical"][3].update(rising=52.0), "bands"),
        (lambda d: d.update(poly="1000"), "not primitive"),
    ]:
        bad = json.loads(side.read_text())
        mutate(bad)
        path = tmp_path / "bad.json"
        path.write_text(json.dumps(bad))
        with pytest.raises(NurbscanError, match=what) as exc:
            load_pattern(path)
        assert str(path) in str(exc.value) and "\n" not in str(exc.value)


# ---------------------------------------------------------------- command line


def test_cli_writes_both_files(tmp_path, capsys):
    out = tmp_path / "sub" / "pattern.png"
    assert main(["pattern", "-o", str(out), "--width", "800", "--height", "600"]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert len(lines) == 1 and "pattern.json" in lines[0]
    p = load_pattern(out.with_suffix(".json"))
    assert p == Pattern.create(width=800, height=600)
    assert np.array_equal(read_image(out, as_float=False), p.render())


def test_cli_bad_poly_exits_2(tmp_path, capsys):
    out = tmp_path / "pattern.png"
    assert main(["pattern", "-o", str(out), "--poly", "1000"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "'1000'" in err[0] and "not primitive" in err[0]
    assert not out.exists() and not out.with_suffix(".json").exists()


def test_cli_help_says_what_it_writes(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["pattern", "--help"])
    assert exc.value.code == 0
    assert ".json" in capsys.readouterr().out
