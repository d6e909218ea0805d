"""Image files: PNG, TIFF or JPEG, 8 or 16 bit, grey or colour, any size.

OpenCV does the decoding and encoding (``cv2.imread`` / ``cv2.imencode``); this module fixes
the channel order to RGB and the sample type to float in [0, 1] on request, and turns every
failure into a one-line :class:`~nurbscan.errors.NurbscanError` naming the file.

:func:`chroma_subsampled` reads a JPEG's frame header by hand: OpenCV decodes the colour
to full resolution and does not report the sampling factors, and the one library that does
(Pillow's ``JpegImagePlugin.get_sampling``) would be a dependency for a few bytes of header.
:func:`image_size` reads the size from the header of a PNG, JPEG or TIFF file for the same
reason, so that :func:`read_image` refuses an image larger than :data:`MAX_IMAGE_PIXELS` before
decoding it (a 32000 x 32000 PNG would take 9 GB before failing).
"""

from __future__ import annotations

import contextlib
import os
from pathlib import Path

import cv2
import numpy as np

from ..errors import NurbscanError
from .atomic import write_bytes

#: Largest image read, pixels: above the largest camera sensors (about 150 Mpx); an image this
#: size takes 2.4 GB as float RGB.
MAX_IMAGE_PIXELS = 200_000_000


def read_image(path: str | os.PathLike, as_float: bool = True) -> np.ndarray:
    """Read an image file as RGB.

    Parameters
    ----------
    path : path-like
        PNG, TIFF or JPEG file; 8 or 16 bit; grey, RGB or RGBA (alpha is dropped).
    as_float : bool
        If true return float32 in [0, 1]; otherwise the file's own integer type.

    Returns
    -------
    image : ndarray, shape (H, W, 3)
        Row 0 is the top of the picture (y down), column 0 the left (x right).
    """
    path = Path(path)
    if not path.exists():
        raise NurbscanError(f"{path}: image file not found")
    if not path.is_file():
        raise NurbscanError(f"{path}: not a regular file")
    size = image_size(path)
    if size is not None and size[0] * size[1] > MAX_IMAGE_PIXELS:
        raise NurbscanError(f"{path}: {size[0]} x {size[1]} px, more than the "
                            f"{MAX_IMAGE_PIXELS / 1e6:.0f} Mpx an image may have here")
    with _codec_messages_silenced():  # libpng's "Read Error": the one line below says it
        img = cv2.imread(str(path),
                         cv2.IMREAD_UNCHANGED | cv2.IMREAD_ANYDEPTH | cv2.IMREAD_ANYCOLOR)
    if img is None or img.size == 0:
        raise NurbscanError(f"{path}: not a readable image (corrupt or unsupported format)")
    if img.ndim == 2:
        img = np.repeat(img[:, :, None], 3, axis=2)
    elif img.shape[2] == 4:
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2RGB)
    elif img.shape[2] == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
    else:
        raise NurbscanError(f"{path}: unsupported channel count {img.shape[2]}")
    if not as_float:
        return img
    if img.dtype == np.uint8:
        return img.astype(np.float32) / 255.0
    if img.dtype == np.uint16:
        return img.astype(np.float32) / 65535.0
    if np.issubdtype(img.dtype, np.floating):
        return img.astype(np.float32)
    raise NurbscanError(f"{path}: unsupported sample type {img.dtype}")


@contextlib.contextmanager
def _codec_messages_silenced():
    """Send file descriptor 2 to ``/dev/null`` while OpenCV decodes: libpng and libtiff print
    their own messages on a corrupt file (``libpng error: Read Error``) before OpenCV returns
    None, which :func:`read_image` reports as one line naming the file."""
    import sys

    try:
        sys.stderr.flush()
        saved = os.dup(2)
        null = os.open(os.devnull, os.O_WRONLY)
    except OSError:
        yield
        return
    try:
        os.dup2(null, 2)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)
        os.close(null)


def write_image(path: str | os.PathLike, image: np.ndarray) -> Path:
    """Write an RGB (H, W, 3) or grey (H, W) uint8 or uint16 image atomically.

    The format follows the file name's extension (.png, .tif/.tiff, .jpg). The image is
    encoded in memory (``cv2.imencode``) and the bytes written atomically
    (:func:`~nurbscan.io.write_bytes`): a full disk is a one-line error naming ``path``,
    not a codec's message.
    """
    path = Path(path)
    image = np.asarray(image)
    if image.dtype not in (np.uint8, np.uint16):
        raise TypeError(f"write_image wants uint8 or uint16, got {image.dtype}")
    if image.ndim == 3:
        image = cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_RGB2BGR)
    try:
        ok, buf = cv2.imencode(path.suffix.lower() or ".png", image)
    except cv2.error:
        ok = False
    if not ok:
        raise NurbscanError(f"{path}: could not encode the image as {path.suffix or 'PNG'!r}")
    return write_bytes(path, buf.tobytes())


#: JPEG start-of-frame markers (baseline, extended, progressive, lossless; Huffman and
#: arithmetic coding), which carry the components' sampling factors (ITU-T T.81, B.2.2).
_SOF_MARKERS = frozenset((0xC0, 0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD,
                          0xCE, 0xCF))


def chroma_subsampled(path: str | os.PathLike) -> bool:
    """Whether an image file stores its colour at a lower resolution than its brightness.

    True for a JPEG whose frame header (ITU-T T.81, B.2.2) gives its colour components
    smaller sampling factors than its first (luma) component: 4:2:2 and 4:2:0, what most
    cameras write; False for JPEG 4:4:4, grey JPEG and any other format (PNG, TIFF). Such a
    file's colour channels have blurred, displaced edges (:func:`nurbscan.detect.detect_grid`'s
    ``chroma_subsampled``). Only a JPEG's header is read (up to 1 MB); of other files, two
    bytes.

    Parameters
    ----------
    path : path-like

    Returns
    -------
    bool
    """
    seg = _jpeg_frame(_head(path))
    if seg is None or len(seg) < 6:
        return False
    n = seg[5]
    comps = [seg[6 + 3 * k + 1] for k in range(n) if 6 + 3 * k + 1 < len(seg)]
    if n < 3 or len(comps) < 3:
        return False
    luma = (comps[0] >> 4, comps[0] & 15)
    return any((c >> 4, c & 15) != luma for c in comps[1:3])


def _head(path, limit: int = 1 << 20) -> bytes:
    """The first ``limit`` bytes of a file (one-line error when it cannot be read)."""
    try:
        with open(path, "rb") as f:
            return f.read(limit)
    except OSError as exc:
        raise NurbscanError(f"{path}: cannot read ({exc.strerror})") from None


def _jpeg_frame(data: bytes) -> bytes | None:
    """The frame header segment (ITU-T T.81, B.2.2) of a JPEG file's first bytes, or None."""
    if data[:2] != b"\xff\xd8":  # not a JPEG
        return None
    i = 2
    while i + 4 <= len(data):
        if data[i] != 0xFF:
            return None  # not a marker: corrupt header (decoding will report it)
        marker = data[i + 1]
        if marker == 0xFF:  # fill byte
            i += 1
            continue
        if marker in (0xD8, 0x01) or 0xD0 <= marker <= 0xD7:  # no length field
            i += 2
            continue
        length = int.from_bytes(data[i + 2:i + 4], "big")
        if marker in _SOF_MARKERS:
            return data[i + 4:i + 2 + length]
        if marker == 0xDA:  # start of scan before any frame header
            return None
        i += 2 + length
    return None


def image_size(path: str | os.PathLike) -> tuple[int, int] | None:
    """(width, height) from a PNG (IHDR), JPEG (frame header) or TIFF (first IFD) header.

    None for another format or a header this does not understand (decoding then decides).
    """
    data = _head(path)
    if data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) >= 24:
        return int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")
    seg = _jpeg_frame(data)
    if seg is not None:
        if len(seg) < 5:
            return None
        return int.from_bytes(seg[3:5], "big"), int.from_bytes(seg[1:3], "big")
    if data[:4] in (b"II*\x00", b"MM\x00*") and len(data) >= 8:
        order = "little" if data[:2] == b"II" else "big"
        off = int.from_bytes(data[4:8], order)
        if off + 2 > len(data):
            return None
        n = int.from_bytes(data[off:off + 2], order)
        tags = {}
        for k in range(n):
            e = data[off + 2 + 12 * k: off + 14 + 12 * k]
            if len(e) < 12:
                break
            tag, typ = int.from_bytes(e[:2], order), int.from_bytes(e[2:4], order)
            value = int.from_bytes(e[8:10] if typ == 3 else e[8:12], order)
            tags[tag] = value
        if 256 in tags and 257 in tags:
            return tags[256], tags[257]
    return None
