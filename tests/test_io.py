"""Image reading/writing in every supported format, and atomic output."""

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
