"""Image reading/writing in every supported format, and atomic output."""

from pathlib import Path

import cv2
import numpy as np
import pytest

from nurbscan.errors import NurbscanError
from nurbscan.io import atomic_path, chroma_subsampled, read_image, write_image, write_json
from nurbscan.io.atomic import read_json


@pytest.fixture
def rgb16():
    rng = np.random.default_rng(1)
    return rng.integers(0, 65536, size=(37, 53, 3), dtype=np.uint16)


@pytest.mark.parametrize("ext", [".png", ".tif", ".tiff"])
def test_16bit_round_trip_is_exact(tmp_path, rgb16, ext):
    path = write_image(tmp_path / f"img{ext}", rgb16)
    back = read_image(path, as_float=False)
    assert back.dtype == np.uint16
    np.testing.assert_array_equal(back, rgb16)
    f = read_image(path)
    assert f.dtype == np.float32
    np.testing.assert_allclose(f, rgb16 / 65535.0, atol=1e-7)


def test_channel_order_is_rgb(tmp_path):
    img = np.zeros((4, 5, 3), np.uint8)
    img[..., 0] = 200  # red
    path = write_image(tmp_path / "red.png", img)
    raw = cv2.imread(str(path))  # OpenCV's own BGR reader
    assert raw[0, 0, 2] == 200 and raw[0, 0, 0] == 0
    assert read_image(path, as_float=False)[0, 0].tolist() == [200, 0, 0]


def test_grey_and_jpeg(tmp_path):
    grey = np.tile(np.arange(0, 250, 10, dtype=np.uint8), (8, 1))
    path = tmp_path / "grey.png"
    assert cv2.imwrite(str(path), grey)
    img = read_image(path, as_float=False)
    assert img.shape == (8, 25, 3)
    np.testing.assert_array_equal(img[..., 1], grey)
    jpg = write_image(tmp_path / "a.jpg", np.full((16, 16, 3), 128, np.uint8))
    assert abs(read_image(jpg)[8, 8, 0] - 128 / 255) < 2 / 255


def test_chroma_subsampling_is_read_from_the_jpeg_frame_header(tmp_path):
    """JPEG 4:2:0, 4:2:2 and 4:1:1 (baseline or progressive) store colour below the luma
    resolution; 4:4:4, grey JPEG, PNG and TIFF do not; a truncated file is not subsampled
    and a missing one is an error."""
    img = np.random.default_rng(0).integers(0, 256, (24, 40, 3), dtype=np.uint8)
    cases = {"420": cv2.IMWRITE_JPEG_SAMPLING_FACTOR_420,
             "422": cv2.IMWRITE_JPEG_SAMPLING_FACTOR_422,
             "411": cv2.IMWRITE_JPEG_SAMPLING_FACTOR_411,
             "444": cv2.IMWRITE_JPEG_SAMPLING_FACTOR_444}
    for name, factor in cases.items():
        path = tmp_path / f"{name}.jpg"
        assert cv2.imwrite(str(path), img, [cv2.IMWRITE_JPEG_SAMPLING_FACTOR, factor])
        assert chroma_subsampled(path) == (name != "444"), name
    prog = tmp_path / "progressive.jpg"
    assert cv2.imwrite(str(prog), img, [cv2.IMWRITE_JPEG_PROGRESSIVE, 1])  # 4:2:0 default
    assert chroma_subsampled(prog)
    assert cv2.imwrite(str(tmp_path / "grey.jpg"), img[..., 0])
    assert not chroma_subsampled(tmp_path / "grey.jpg")
    for ext in (".png", ".tif"):
        assert cv2.imwrite(str(tmp_path / f"a{ext}"), img)
        assert not chroma_subsampled(tmp_path / f"a{ext}")
    (tmp_path / "cut.jpg").write_bytes((tmp_path / "420.jpg").read_bytes()[:40])
    assert not chroma_subsampled(tmp_path / "cut.jpg")
    with pytest.raises(NurbscanError, match="nope.jpg"):
        chroma_subsampled(tmp_path / "nope.jpg")


def test_missing_and_corrupt_files_raise_one_line(tmp_path):
    with pytest.raises(NurbscanError, match="not found"):
        read_image(tmp_path / "nope.png")
    bad = tmp_path / "bad.png"
    bad.write_bytes(b"\x89PNG\r\n\x1a\n this is not a png")
    with pytest.raises(NurbscanError, match="bad.png") as info:
        read_image(bad)
    assert "\n" not in str(info.value)
    (tmp_path / "bad.json").write_text("{not json")
    with pytest.raises(NurbscanError, match="not valid JSON"):
        read_json(tmp_path / "bad.json")


def test_atomic_write_leaves_nothing_on_failure(tmp_path):
    target = tmp_path / "out.json"
    write_json(target, {"a": 1})
    with pytest.raises(RuntimeError), atomic_path(target) as tmp:
        tmp.write_text("half")
        raise RuntimeError("boom")
    assert read_json(target) == {"a": 1}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.json"]


# ---------------------------------------------------------------- bounded, regular-file reads
def test_read_image_refuses_a_huge_header_before_decoding(tmp_path):
    """A PNG whose header claims 32000 x 32000 px is refused from its header (decoding it
    took 9 GB before failing)."""
    from nurbscan.io.images import MAX_IMAGE_PIXELS, image_size

    p = tmp_path / "huge.png"
    cv2.imwrite(str(p), np.zeros((4, 4, 3), np.uint8))
    data = bytearray(p.read_bytes())
    data[16:24] = (32000).to_bytes(4, "big") * 2
    p.write_bytes(bytes(data))
    assert image_size(p) == (32000, 32000) and 32000 ** 2 > MAX_IMAGE_PIXELS
    with pytest.raises(NurbscanError, match=r"32000 x 32000 px, more than"):
        read_image(p)


@pytest.mark.parametrize("ext", [".png", ".jpg", ".tif"])
def test_image_size_from_the_header(tmp_path, ext):
    from nurbscan.io.images import image_size

    p = tmp_path / f"a{ext}"
    cv2.imwrite(str(p), np.zeros((37, 53, 3), np.uint8))
    assert image_size(p) == (53, 37)


def test_reads_refuse_what_is_not_a_regular_file(tmp_path):
    """A named pipe (would hang) and /dev/zero (would fill the memory) are refused at once."""
    import os

    fifo = tmp_path / "pipe.json"
    os.mkfifo(fifo)
    for reader in (read_json, read_image):
        with pytest.raises(NurbscanError, match="not a regular file"):
            reader(fifo)
        if Path("/dev/zero").exists():
            with pytest.raises(NurbscanError, match="not a regular file"):
                reader("/dev/zero")


def test_read_json_deeply_nested(tmp_path):
    p = tmp_path / "deep.json"
    p.write_text("[" * 100000 + "]" * 100000)
    with pytest.raises(NurbscanError, match="nested too deeply"):
        read_json(p)


def test_atomic_write_onto_a_folder_is_a_one_line_error(tmp_path):
    (tmp_path / "out.json").mkdir()
    with pytest.raises(NurbscanError, match=r"out.json: cannot write \(it is a folder\)"):
        write_json(tmp_path / "out.json", {"a": 1})
    assert [p.name for p in tmp_path.iterdir()] == ["out.json"]  # no temporary left
