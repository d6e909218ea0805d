"""File formats and safe writing: images, JSON, atomic output."""

from .atomic import (
    atomic_folder,
    atomic_path,
    atomic_paths,
    folder_lock,
    read_bytes,
    read_json,
    write_bytes,
    write_json,
    write_text,
)
from .images import chroma_subsampled, read_image, write_image
from .scan import Scan, load_scan

__all__ = [
    "atomic_folder",
    "atomic_path",
    "atomic_paths",
    "folder_lock",
    "read_bytes",
    "Scan",
    "chroma_subsampled",
    "load_scan",
    "read_image",
    "read_json",
    "write_bytes",
    "write_image",
    "write_json",
    "write_text",
]
