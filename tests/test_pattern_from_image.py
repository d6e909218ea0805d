"""Tests for nurbscan.pattern.read_line_pattern and ``nurbscan pattern --from-image``."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from _line_synth import de_bruijn
from nurbscan.cli import main
from nurbscan.errors import NurbscanError
from nurbscan.io import write_image
from nurbscan.pattern import LinePattern, Pattern, load_pattern, read_line_pattern

REAL = Path(os.environ.get("NURBSCAN_REAL_DATA",
                           Path(__file__).resolve().parents[2] / "shared" / "real"))
REAL_PATTERN = REAL / "procam-colour-grid" / "pattern.png"

# ---------------------------------------------------------------- independent oracles


def brute_window_length(seqs, max_n=6):
    """Smallest n with all runs of n codes distinct in every sequence, by Python sets."""
    for n in range(1, max_n + 1):
        if all(len({tuple(s[i:i + n]) for i in range(len(s) - n + 1)}) == max(len(s) - n + 1, 0)
               for s in seqs):
            return n
    return None


def procam_sequence():
    """The README's recursive De Bruijn rule (order 3 over symbols 1..4, 66 long)."""
    seq = []
    d1, d2 = 3, 4
    for h in range(1, 5):
        for a in range(1, d1 + 1):
            for b in range(1, d2 + 1):
                seq += [4 - (a - 1), 4 - (b - 1), h]
        if h < 4:
            seq.append(h)
        d1, d2 = d1 - 1, d2 - 1
    return seq + [4, 4, 4]


#: The README's 8 colours, RGB in [0, 1], in its order r, y, l, g, c, b, p, m.
PROCAM = {"r": (1, 0, 0), "y": (1, .75, 0), "l": (.5, 1, 0), "g": (0, 1, .5), "c": (0, 1, 1),
          "b": (0, .25, 1), "p": (.75, 0, 1), "m": (1, 0, .75)}


def foreign_image(over="horizontal", width=400, height=300):
    """A foreign grid painted line by line: 3 px lines, 8 colours (4 per direction),
    vertical pitch 29 and horizontal pitch 21, one direction drawn over the other."""
    rgb = {k: np.round(255 * np.array(v)).astype(np.uint8) for k, v in PROCAM.items()}
    seq = de_bruijn(4, 3)
    vsym, hsym = "ygbm", "rlcp"
    vcentres = list(range(14, width - 2, 29))
    hcentres = list(range(9, height - 2, 21))
    vnames = [vsym[s] for s in seq[:len(vcentres)]]
    hnames = [hsym[s] for s in seq[5:5 + len(hcentres)]]
    img = np.zeros((height, width, 3), np.uint8)
    strokes = ([("v", c, n) for c, n in zip(vcentres, vnames, strict=True)],
               [("h", c, n) for c, n in zip(hcentres, hnames, strict=True)])
    for group in (strokes if over == "horizontal" else strokes[::-1]):
        for d, c, n in group:
            if d == "v":
                img[:, c - 1:c + 2] = rgb[n]
            else:
                img[c - 1:c + 2, :] = rgb[n]
    return img, vcentres, vnames, hcentres, hnames, rgb


def line_colours(lp, direction):
    fam = lp.family(direction)
    return [lp.colours[c] for c in fam.codes]


# ---------------------------------------------------------------- nurbscan's own grid


@pytest.mark.parametrize("kw", [
    dict(width=800, height=600, pitch=16, band=6),
    dict(width=1920, height=1080),
    dict(width=640, height=480, pitch=8, band=3, q=3, n=4),
    dict(width=330, height=250, pitch=11, band=2),
    dict(width=200, height=120, pitch=20, band=9),  # only 4 of the 5 colours appear
    dict(width=86, height=120, pitch=16, band=6),  # offset 0: bands touch the border
])
def test_own_pattern_reads_back_as_its_sidecar(kw, tmp_path):
    pat = Pattern.create(**kw)
    png, side = pat.save(tmp_path / "own.png")
    d = json.loads(side.read_text())
    colour = {c["code"]: (c["name"], tuple(c["rgb"])) for c in d["colours"]}
    for image in (png, pat.render()):
        lp = read_line_pattern(image)
        assert (lp.width, lp.height) == (d["width"], d["height"]) and lp.crossing == "max"
        for name in ("vertical", "horizontal"):
            bands = d["bands"][name]
            fam = lp.family(name)
            assert fam.direction == name and fam.count == len(bands)
            assert list(fam.lower) == [b["rising"] for b in bands]
            assert list(fam.upper) == [b["falling"] for b in bands]
            assert line_colours(lp, name) == [colour[b["code"]] for b in bands]
        assert lp.window == brute_window_length(
            [[b["code"] for b in d["bands"][k]] for k in ("vertical", "horizontal")])
        if len(lp.colours) == pat.q:  # every colour shows: the very same codes and palette
            assert lp == pat.to_line_pattern()


# ---------------------------------------------------------------- a foreign grid


@pytest.mark.parametrize("over", ["horizontal", "vertical"])
def test_foreign_thin_line_grid(over, tmp_path):
    img, vc, vn, hc, hn, rgb = foreign_image(over)
    path = tmp_path / "foreign.png"
    write_image(path, img)
    lp = read_line_pattern(path)
    assert lp.crossing == f"{over}-over"
    assert lp.vertical.centres.tolist() == vc and lp.horizontal.centres.tolist() == hc
    assert lp.vertical.widths.tolist() == [3.0] * len(vc)
    assert lp.horizontal.lower[0] == hc[0] - 1.5 and lp.horizontal.upper[0] == hc[0] + 1.5
    assert [rgb_ for _, rgb_ in line_colours(lp, "x")] == [tuple(rgb[n].tolist()) for n in vn]
    assert [rgb_ for _, rgb_ in line_colours(lp, "y")] == [tuple(rgb[n].tolist()) for n in hn]
    names = {"r": "red", "y": "yellow", "l": "lime", "g": "green", "c": "cyan", "b": "blue",
             "p": "purple", "m": "magenta"}
    assert [n for n, _ in line_colours(lp, "x")] == [names[n] for n in vn]
    assert [n for n, _ in line_colours(lp, "y")] == [names[n] for n in hn]
    assert len(lp.colours) == 8 and len(lp.codes_used("x")) == len(lp.codes_used("y")) == 4
    codes = [list(f.codes) for f in lp.families]
    assert lp.window == brute_window_length(codes) == 3
    # it renders back to the painted image and survives its sidecar
    assert np.array_equal(lp.render(), img)
    _, side = lp.save(tmp_path / "again.png")
    assert load_pattern(side) == lp


def test_one_direction_and_16_bit(tmp_path):
    img, vc, *_ = foreign_image()
    only_v = img.copy()
    only_v[:] = img[150:151]  # replicate a row without horizontal lines: vertical lines only
    assert not any(150 in range(c - 1, c + 2) for c in foreign_image()[3])
    path = tmp_path / "v16.tif"
    cv2.imwrite(str(path), cv2.cvtColor(only_v.astype(np.uint16) * 257, cv2.COLOR_RGB2BGR))
    lp = read_line_pattern(path)
    assert lp.horizontal is None and lp.vertical.centres.tolist() == vc
    assert np.array_equal(lp.render(), only_v) and lp.crossing == "max"


# ---------------------------------------------------------------- the real set's pattern


@pytest.mark.skipif(not REAL_PATTERN.is_file(), reason=f"{REAL_PATTERN} not present")
def test_real_procam_pattern():
    lp = read_line_pattern(REAL_PATTERN)
    assert (lp.width, lp.height) == (800, 600)
    assert lp.horizontal.count == 28 and lp.vertical.count == 28
    k = np.arange(28)
    assert np.array_equal(lp.horizontal.centres, 11 + 21 * k)
    assert np.array_equal(lp.vertical.centres, 11 + 29 * k)
    assert (lp.horizontal.widths == 3).all() and (lp.vertical.widths == 3).all()
    assert lp.window == 3 and lp.crossing == "horizontal-over"
    # the README's 8 colours (RGB within 1 of 255 x its [0, 1] values), 4 per direction
    want = {k: np.array(v) * 255 for k, v in PROCAM.items()}
    assert len(lp.colours) == 8

    def letters(direction):
        out = []
        for _, c in line_colours(lp, direction):
            d = {k: np.abs(np.array(c) - v).max() for k, v in want.items()}
            best = min(d, key=d.get)
            assert d[best] <= 1
            out.append(best)
        return out

    hl, vl = letters("horizontal"), letters("vertical")
    assert set(hl) == set("rlcp") and set(vl) == set("ygbm")
    # the README's rule: symbol s (1..4) of its De Bruijn sequence -> colour 2s-1 horizontal
    # (r, l, c, p), 2s vertical (y, g, b, m), in the order r, y, l, g, c, b, p, m
    order = "rylgcbpm"
    seq = procam_sequence()
    assert len(seq) == 66 and brute_window_length([seq]) == 3
    assert [order[2 * s - 2] for s in seq[:28]] == hl
    assert [order[2 * s - 1] for s in seq[:28]] == vl
    assert [n for n, _ in lp.colours] == ["red", "yellow", "lime", "green", "cyan", "blue",
                                          "purple", "magenta"]


# ---------------------------------------------------------------- bad input


def _bad_images():
    img, *_ = foreign_image()
    black = np.zeros_like(img)
    diagonal = np.zeros((200, 200, 3), np.uint8)
    i = np.arange(200)
    diagonal[i, i] = 255
    diagonal[:, 50:53] = (255, 0, 0)
    partial = img.copy()
    partial[:120, 200:203] = (0, 255, 0)  # a vertical stroke over 40 % of the height
    bent = img.copy()
    bent[100:103, 50:150] = (255, 0, 0)  # a horizontal stroke that does not span the width
    repeating = np.zeros((100, 400, 3), np.uint8)
    for j in range(20):  # red, green, red, green, ...: every window repeats
        repeating[:, 10 + 19 * j:13 + 19 * j] = (255, 0, 0) if j % 2 else (0, 255, 0)
    white = np.full((50, 60, 3), 255, np.uint8)
    return [(black, "no lines"), (diagonal, "not straight"), (partial, "not straight"),
            (bent, "not straight"), (repeating, "repeats a window"), (white, "no dark gaps")]


@pytest.mark.parametrize("case", range(6))
def test_bad_images_refused(case, tmp_path):
    img, what = _bad_images()[case]
    path = tmp_path / f"bad{case}.png"
    write_image(path, img)
    with pytest.raises(NurbscanError, match=what) as exc:
        read_line_pattern(path)
    msg = str(exc.value)
    assert msg.startswith(str(path)) and "\n" not in msg
    with pytest.raises(NurbscanError, match=what):
        read_line_pattern(img, source="projector")


def test_unreadable_files(tmp_path):
    junk = tmp_path / "junk.png"
    junk.write_bytes(b"not a png at all")
    for path, what in [(junk, "not a readable image"), (tmp_path / "none.png", "not found")]:
        with pytest.raises(NurbscanError, match=what) as exc:
            read_line_pattern(path)
        assert str(path) in str(exc.value) and "\n" not in str(exc.value)
    with pytest.raises(NurbscanError, match="shape"):
        read_line_pattern(np.zeros((4, 4, 2)))
    # a JPEG of a good pattern: its compression noise makes hundreds of colours
    jpeg = tmp_path / "own.jpg"
    cv2.imwrite(str(jpeg), cv2.cvtColor(Pattern.create(width=320, height=240).render(),
                                        cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 95])
    with pytest.raises(NurbscanError, match="not a clean projector image") as exc:
        read_line_pattern(jpeg)
    assert str(exc.value).startswith(str(jpeg))


# ---------------------------------------------------------------- command line


def test_cli_from_image_writes_the_sidecar(tmp_path, capsys):
    img, vc, *_ = foreign_image()
    src = tmp_path / "projected.png"
    write_image(src, img)
    out = tmp_path / "sub" / "pattern.json"
    assert main(["pattern", "--from-image", str(src), "-o", str(out)]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert len(lines) == 1 and str(out) in lines[0] and "horizontal-over" in lines[0]
    lp = load_pattern(out)
    assert isinstance(lp, LinePattern) and lp == read_line_pattern(src)
    assert lp.vertical.centres.tolist() == vc
    assert sorted(p.name for p in out.parent.iterdir()) == ["pattern.json"]


def test_cli_from_image_own_pattern(tmp_path, capsys):
    png = tmp_path / "own.png"
    assert main(["pattern", "-o", str(png), "--width", "640", "--height", "480"]) == 0
    out = tmp_path / "read.json"
    assert main(["pattern", "--from-image", str(png), "-o", str(out)]) == 0
    capsys.readouterr()
    assert load_pattern(out) == load_pattern(png.with_suffix(".json")).to_line_pattern()


def test_cli_from_image_bad_input_exit_2(tmp_path, capsys):
    img, what = _bad_images()[4]
    src = tmp_path / "repeating.png"
    write_image(src, img)
    out = tmp_path / "pattern.json"
    for args in (["--from-image", str(src), "-o", str(out)],
                 ["--from-image", str(tmp_path / "missing.png"), "-o", str(out)]):
        assert main(["pattern", *args]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and args[1] in err[0]
        assert not out.exists() and list(tmp_path.glob(".pattern.json*")) == []
    assert "repeats a window" in (main(["pattern", "--from-image", str(src), "-o", str(out)])
                                  and capsys.readouterr().err)
    # the sidecar must be .json; generating options do not mix with --from-image
    good = tmp_path / "good.png"
    write_image(good, foreign_image()[0])
    assert main(["pattern", "--from-image", str(good), "-o", str(tmp_path / "p.png")]) == 2
    assert ".json" in capsys.readouterr().err and not (tmp_path / "p.png").exists()
    assert main(["pattern", "--from-image", str(good), "-o", str(out), "--pitch", "8"]) == 2
    assert "--pitch" in capsys.readouterr().err and not out.exists()


def test_cli_from_image_as_a_process(tmp_path):
    src = tmp_path / "projected.png"
    write_image(src, foreign_image()[0])
    out = tmp_path / "pattern.json"
    cmd = [sys.executable, "-m", "nurbscan", "pattern", "--from-image"]
    ok = subprocess.run([*cmd, str(src), "-o", str(out)], capture_output=True, text=True)
    assert ok.returncode == 0 and ok.stderr == "" and load_pattern(out).window == 3
    junk = tmp_path / "junk.png"
    junk.write_bytes(b"\x89PNG broken")
    out2 = tmp_path / "other.json"
    bad = subprocess.run([*cmd, str(junk), "-o", str(out2)], capture_output=True, text=True)
    assert bad.returncode == 2 and bad.stdout == "" and not out2.exists()
    assert len(bad.stderr.strip().splitlines()) == 1 and str(junk) in bad.stderr
