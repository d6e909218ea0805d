"""Reading ``.npz`` array files (truth maps, point sets) with one-line errors."""

from __future__ import annotations

import io
import os
import zipfile
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ..errors import NurbscanError
from .atomic import read_bytes

#: Largest ``.npz`` file read, bytes.
MAX_NPZ_BYTES = 8 << 30


def read_npz(path: str | os.PathLike, keys: Sequence[str], what: str = "array file"
             ) -> dict[str, np.ndarray]:
    """The arrays ``keys`` of an ``.npz`` file (no pickles).

    Raises :class:`~nurbscan.errors.NurbscanError` with one line naming the file: missing, not
    a regular file, over :data:`MAX_NPZ_BYTES`, not an ``.npz`` archive, or without one of
    ``keys`` (``what`` names the kind of file in the message).
    """
    path = Path(path)
    data = read_bytes(path, MAX_NPZ_BYTES, what)
    try:
        with np.load(io.BytesIO(data), allow_pickle=False) as z:
            missing = [k for k in keys if k not in z.files]
            if missing:
                raise NurbscanError(f"{path}: not a {what} (no {', '.join(missing)})")
            return {k: np.asarray(z[k]) for k in keys}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
        msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise NurbscanError(f"{path}: not a {what} ({msg})") from None
