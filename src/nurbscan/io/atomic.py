"""Atomic output: write to a temporary file (or folder) beside the target, then rename.

A failed or interrupted write never leaves a half-written file under the target's name. A
failure of the file system (a read-only folder, a full disk, a target that is a folder) is a
one-line :class:`~nurbscan.errors.NurbscanError` naming the target.

:func:`read_json` reads only regular files of at most :data:`MAX_JSON_BYTES` (a named pipe would
hang, ``/dev/zero`` would fill the memory).
"""

from __future__ import annotations

import contextlib
import glob
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
    suffix = path.suffix if suffix is None else suffix
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        _remove_dead_temporaries(path, suffix)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.{os.getpid()}-", suffix=suffix,
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
        from ..errors import NurbscanError

        if isinstance(exc, NurbscanError) and str(tmp) in str(exc):  # a writer of ``tmp``
            raise NurbscanError(str(exc).replace(str(tmp), str(path))) from None
        raise


@contextlib.contextmanager
def atomic_paths(*paths: str | os.PathLike) -> Iterator[tuple[Path, ...]]:
    """:func:`atomic_path` for files that belong together (an image and its sidecar, a
    table and its Markdown): yield one temporary path per target; only when all are
    written are they renamed onto the targets, one after the other.

    A failure while writing any of them (a full disk, a read-only folder, a target that is
    a folder) leaves every target as it was: never a new image beside an old sidecar. Each
    target is checked before anything is written.
    """
    with contextlib.ExitStack() as stack:
        tmps = tuple(stack.enter_context(atomic_path(p)) for p in paths)
        yield tmps


def _remove_dead_temporaries(path: Path, suffix: str) -> None:
    """Remove the temporaries of ``path`` that a killed :func:`atomic_path` left
    (``.NAME.PID-XXXX.SUFFIX`` of a process no longer alive)."""
    for p in path.parent.glob(f".{glob.escape(path.name)}.*-*{glob.escape(suffix)}"):
        pid = p.name[len(path.name) + 2:].split("-", 1)[0]
        if pid.isdigit() and int(pid) != os.getpid() and not _pid_alive(int(pid)):
            with contextlib.suppress(OSError):
                p.unlink()


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


def read_bytes(path: str | os.PathLike, limit: int, what: str = "file") -> bytes:
    """The bytes of a regular file of at most ``limit`` bytes, else a one-line
    :class:`~nurbscan.errors.NurbscanError` (missing, not a regular file, too large,
    unreadable)."""
    from ..errors import NurbscanError

    path = Path(path)
    if not path.exists():
        raise NurbscanError(f"{path}: file not found")
    if not path.is_file():
        raise NurbscanError(f"{path}: not a regular file")
    size = path.stat().st_size
    if size > limit:
        raise NurbscanError(f"{path}: {size} bytes, more than a {what} here may have ({limit})")
    try:
        return path.read_bytes()
    except OSError as exc:
        raise NurbscanError(f"{path}: cannot read ({exc.strerror or exc})") from None


def read_json(path: str | os.PathLike) -> Any:
    """Read a JSON file, raising :class:`~nurbscan.errors.NurbscanError` with a one-line message."""
    from ..errors import NurbscanError

    path = Path(path)
    data = read_bytes(path, MAX_JSON_BYTES, "JSON file")
    try:
        return json.loads(data.decode("utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise NurbscanError(f"{path}: not valid JSON ({exc})") from None
    except RecursionError:
        raise NurbscanError(f"{path}: not valid JSON (nested too deeply)") from None


# ------------------------------------------------------------------------------ folders
def lock_path(path: str | os.PathLike) -> Path:
    """The lock file of an output folder: ``.NAME.lock`` beside it."""
    path = Path(path)
    return path.parent / f".{path.name}.lock"


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # alive, someone else's
        return True
    return True


@contextlib.contextmanager
def folder_lock(path: str | os.PathLike) -> Iterator[Path]:
    """Hold the lock of output folder ``path`` (``.NAME.lock`` beside it, holding the pid).

    The lock is an exclusive :func:`fcntl.flock` on the lock file, which the kernel releases
    when the holder dies however it dies (``kill -9``): a lock file left by a dead process is
    taken over. A second writer while the holder lives is refused with a one-line
    :class:`~nurbscan.errors.NurbscanError` naming the folder and the holder's pid. The lock
    file is removed on release.
    """
    import fcntl

    from ..errors import NurbscanError

    path = Path(path)
    lock = lock_path(path)
    try:
        lock.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise _cannot_write(path, exc) from None
    for _ in range(100):
        try:
            fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as exc:
            raise _cannot_write(path, exc) from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            try:
                holder = os.read(fd, 32).decode("ascii", "replace").strip()
            finally:
                os.close(fd)
            who = f"pid {holder}" if holder.isdigit() and _pid_alive(int(holder)) \
                else "another process"
            raise NurbscanError(f"{path}: {who} is writing this folder (lock {lock}); wait "
                                "for it to finish or choose another output") from None
        # the file may have been removed by the holder releasing it between open and flock
        try:
            same = os.path.samestat(os.fstat(fd), os.stat(lock))
        except FileNotFoundError:
            same = False
        if same:
            break
        os.close(fd)
    else:  # pragma: no cover - a lock file replaced 100 times in a row
        raise NurbscanError(f"{path}: cannot take the lock {lock}")
    try:
        try:
            os.ftruncate(fd, 0)
            os.write(fd, f"{os.getpid()}\n".encode())
        except OSError as exc:  # a full disk: not even the lock's pid fits
            raise _cannot_write(path, exc) from None
        yield lock
    finally:
        with contextlib.suppress(OSError):
            lock.unlink()
        os.close(fd)


def stale_temporaries(path: str | os.PathLike) -> list[Path]:
    """Temporary siblings that :func:`atomic_folder` and :func:`atomic_path` leave when killed:
    ``.NAME.tmp-*`` and ``.NAME.old-*`` beside folder ``path``."""
    path = Path(path)
    if not path.parent.is_dir():
        return []
    name = glob.escape(path.name)
    return sorted(p for pat in (f".{name}.tmp-*", f".{name}.old-*")
                  for p in path.parent.glob(pat))


def _remove(p: Path) -> None:
    import shutil

    if p.is_dir() and not p.is_symlink():
        shutil.rmtree(p, ignore_errors=True)
    else:
        with contextlib.suppress(OSError):
            p.unlink()


def _exchange(a: Path, b: Path) -> bool:
    """Swap two paths atomically (Linux ``renameat2(RENAME_EXCHANGE)``); False if the system
    cannot."""
    import ctypes
    import ctypes.util
    import sys

    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        fn = libc.renameat2
    except (OSError, AttributeError):
        return False
    at_fdcwd, rename_exchange = -100, 2
    fn.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p,
                   ctypes.c_uint]
    rc = fn(at_fdcwd, os.fsencode(a), at_fdcwd, os.fsencode(b), rename_exchange)
    return rc == 0


def _replace_folder(tmp: Path, path: Path) -> None:
    """Put folder ``tmp`` in the place of ``path`` (absent or a folder) as one step."""
    if not path.exists() and not path.is_symlink():
        os.rename(tmp, path)
        return
    if _exchange(tmp, path):  # tmp now holds the old folder
        _remove(tmp)
        return
    old = path.parent / f".{path.name}.old-{os.getpid()}"
    os.rename(path, old)  # a kill between the two renames leaves no folder, never a mixed one
    os.rename(tmp, path)
    _remove(old)


@contextlib.contextmanager
def atomic_folder(path: str | os.PathLike,
                  replaceable: frozenset[str] | None = None) -> Iterator[Path]:
    """Yield an empty temporary folder beside ``path``; on success it replaces ``path`` whole.

    The folder is written under ``.NAME.tmp-PID`` and renamed into place (an existing folder
    is swapped for it in one ``renameat2(RENAME_EXCHANGE)`` on Linux), so a reader never sees
    a mix of old and new files, and a failed or killed run leaves the old folder as it was.
    While the folder is written its lock is held (:func:`folder_lock`): a second writer is
    refused. Temporaries left by a killed earlier run are removed first
    (:func:`stale_temporaries`).

    Parameters
    ----------
    path : path-like
        The folder to (re)write.
    replaceable : frozenset of str, optional
        Names an existing folder may hold to be replaced; one holding anything else (a folder
        that is not this kind of output) is refused, so that ``-o ~/Documents`` never
        deletes a user's files. None: any folder is replaced.
    """
    from ..errors import NurbscanError

    path = Path(path)
    if path.exists() and not path.is_dir():
        raise NurbscanError(f"{path}: cannot write a folder there (it is a file)")
    with folder_lock(path):
        for p in stale_temporaries(path):
            _remove(p)
        if replaceable is not None and path.is_dir():
            other = sorted(p.name for p in path.iterdir() if p.name not in replaceable)
            if other:
                raise NurbscanError(
                    f"{path}: the folder holds {other[0]!r}"
                    f"{f' and {len(other) - 1} more' if len(other) > 1 else ''}, which this "
                    "command does not write; it would be replaced with the folder: move it "
                    "or choose another output")
        tmp = path.parent / f".{path.name}.tmp-{os.getpid()}"
        try:
            tmp.mkdir()
        except OSError as exc:
            raise _cannot_write(path, exc) from None
        try:
            yield tmp
            _replace_folder(tmp, path)
        except BaseException as exc:
            _remove(tmp)
            if isinstance(exc, OSError):
                raise _cannot_write(path, exc) from None
            raise


@contextlib.contextmanager
def atomic_path_fixed(path: str | os.PathLike) -> Iterator[Path]:
    """:func:`atomic_path` with a temporary name that depends only on the target
    (``.NAME.tmp.SUFFIX``), under the target's lock (:func:`folder_lock`).

    For writers that record the name they write to inside the file (OpenNURBS stores it in a
    ``.3dm``): two runs writing the same target then give the same bytes. A temporary left
    by a killed run has the same name and is overwritten by the next.
    """
    path = Path(path)
    with folder_lock(path):
        tmp = path.parent / f".{path.name}.tmp{path.suffix}"
        try:
            if path.is_dir():
                from ..errors import NurbscanError

                raise NurbscanError(f"{path}: cannot write (it is a folder)")
            with contextlib.suppress(FileNotFoundError):
                tmp.unlink()
            yield tmp
            os.replace(tmp, path)
        except BaseException as exc:
            with contextlib.suppress(OSError):
                tmp.unlink()
            if isinstance(exc, OSError):
                raise _cannot_write(path, exc) from None
            raise
