"""Image files: PNG, TIFF or JPEG, 8 or 16 bit, grey or colour, any size.

OpenCV does the decoding and encoding (``cv2.imread`` / ``cv2.imwrite``); this module fixes
the channel order to RGB and the sample type to float in [0, 1] on request, and turns every
failure into a one-line :class:`~nurbscan.errors.NurbscanError` naming the file.
"""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np

from ..errors import NurbscanError
from .atomic import atomic_path


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
    if not path.is_file():
        raise NurbscanError(f"{path}: image file not found")
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED | cv2.IMREAD_ANYDEPTH | cv2.IMREAD_ANYCOLOR)
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


def write_image(path: str | os.PathLike, image: np.ndarray) -> Path:
    """Write an RGB (H, W, 3) or grey (H, W) uint8 or uint16 image atomically.

    The format follows the file name's extension (.png, .tif/.tiff, .jpg).
    """
    path = Path(path)
    image = np.asarray(image)
    if image.dtype not in (np.uint8, np.uint16):
        raise TypeError(f"write_image wants uint8 or uint16, got {image.dtype}")
    if image.ndim == 3:
        image = cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_RGB2BGR)
    with atomic_path(path) as tmp:
        if not cv2.imwrite(str(tmp), image):
            raise NurbscanError(f"{path}: could not write image")
    return path
