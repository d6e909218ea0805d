"""Atomic output: write to a temporary file beside the target, then rename.

A failed or interrupted write never leaves a half-written file under the target's name. A
failure of the file system (a read-only folder, a full disk, a target that is a folder) is a
one-line :class:`~nurbscan.errors.NurbscanError` naming the target.

:func:`read_json` reads only regular files of at most :data:`MAX_JSON_BYTES` (a named pipe would
hang, ``/dev/zero`` would fill the memory).
"""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

#: Largest JSON file read, bytes: nurbscan's own JSON files (scan, rig, model, lines) stay far
#: below; a larger one is refused before it is read.
MAX_JSON_BYTES = 512 << 20


def _cannot_write(path: Path, exc: OSError):
    from ..errors import NurbscanError

    return NurbscanError(f"{path}: cannot write ({exc.strerror or exc})")


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path in the target's folder; rename it onto ``path`` on success.

    Parameters
    ----------
    path : path-like
        The final file name. Its folder is created if needed.
    suffix : str, optional
        Suffix of the temporary file (defaults to the target's, so that writers that choose
        a format from the extension, such as OpenCV's, still work).

    On an exception the temporary file is removed and the target is left untouched.
    """
    path = Path(path)
    if path.is_dir():
        from ..errors import NurbscanError

        raise NurbscanError(f"{path}: cannot write (it is a folder)")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(
            prefix=f".{path.name}.", suffix=path.suffix if suffix is None else suffix,
            dir=path.parent)
    except OSError as exc:
        raise _cannot_write(path, exc) from None
    os.close(fd)
    tmp = Path(tmp)
    try:
        yield tmp
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)  # mkstemp creates 0600; give the file the usual mode
        os.replace(tmp, path)
    except BaseException as exc:
        with contextlib.suppress(OSError):
            tmp.unlink()
        if isinstance(exc, OSError):
            raise _cannot_write(path, exc) from None
        raise


def write_bytes(path: str | os.PathLike, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically and return the path."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return Path(path)


def write_text(path: str | os.PathLike, text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically and return the path."""
    return write_bytes(path, text.encode("utf-8"))


def write_json(path: str | os.PathLike, obj: Any, indent: int | None = 1) -> Path:
    """Write ``obj`` as JSON to ``path`` atomically and return the path."""
    return write_text(path, json.dumps(obj, indent=indent) + "\n")


def read_json(path: str | os.PathLike) -> Any:
    """Read a JSON file, raising :class:`~nurbscan.errors.NurbscanError` with a one-line message."""
    from ..errors import NurbscanError

    path = Path(path)
    if not path.exists():
        raise NurbscanError(f"{path}: file not found")
    if not path.is_file():
        raise NurbscanError(f"{path}: not a regular file")
    size = path.stat().st_size
    if size > MAX_JSON_BYTES:
        raise NurbscanError(f"{path}: {size} bytes, more than a JSON file here may have "
                            f"({MAX_JSON_BYTES})")
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise NurbscanError(f"{path}: cannot read ({exc.strerror or exc})") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise NurbscanError(f"{path}: not valid JSON ({exc})") from None
    except RecursionError:
        raise NurbscanError(f"{path}: not valid JSON (nested too deeply)") from None
