"""Reading input files with one-line errors naming the file: `.npz` archives (empty, not an archive,
unreadable) and text files (binary or not UTF-8)."""

from __future__ import annotations

import os
import zipfile
from pathlib import Path

import numpy as np

__all__ = ["read_npz", "read_text"]


def read_npz(path: str | os.PathLike, what: str = "file") -> dict[str, np.ndarray]:
    """Every array of the `.npz` at `path` (no pickled objects). `what` names the file in errors
    ("log", "scans", ...): FileNotFoundError if it is missing, ValueError if it is empty, not a zip
    archive (e.g. a text file named .npz) or not readable as NumPy arrays."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{what} file not found: {path}")
    with open(path, "rb") as f:
        head = f.read(4)
    if not head:
        raise ValueError(f"{what} {path}: the file is empty")
    if head != b"PK\x03\x04":  # every .npz is a zip archive
        raise ValueError(f"{what} {path}: not an .npz archive (written by numpy.savez)")
    try:
        with np.load(path, allow_pickle=False) as f:
            return {k: f[k] for k in f.files}
    except (OSError, EOFError, zipfile.BadZipFile, ValueError) as e:
        raise ValueError(f"{what} {path}: not a readable .npz ({type(e).__name__}: {e})") from None


def read_text(path: str | os.PathLike, what: str = "file") -> str:
    """The text of the UTF-8 file at `path` (a byte-order mark dropped); FileNotFoundError if it is
    missing, ValueError naming the file if it is binary or in another encoding."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{what} file not found: {path}")
    try:
        return path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError as e:
        raise ValueError(f"{what} {path}: not a UTF-8 text file (byte {e.start} is {e.object[e.start]:#04x})") from None
