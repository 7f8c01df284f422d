"""Atomic, permission-uniform file output: every file jaxquad writes goes through here.

A file is written to a hidden temporary name in its destination folder and renamed into place, so a
stopped run never leaves half a file; a folder is built beside its destination and swapped in whole.
Files get the usual 0666 & ~umask mode (mkstemp alone would leave 0600).
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import IO

__all__ = [
    "atomic_dir",
    "atomic_open",
    "atomic_path",
    "atomic_write_bytes",
    "atomic_write_text",
    "check_output_dir",
    "check_output_file",
]


def _umask_mode(base: int) -> int:
    mask = os.umask(0)
    os.umask(mask)
    return base & ~mask


@contextlib.contextmanager
def atomic_open(path: str | os.PathLike, mode: str = "wb") -> Iterator[IO]:
    """Open a temporary file beside `path`; on a clean exit it is renamed to `path`, else removed."""
    if mode not in ("w", "wb"):
        raise ValueError(f"atomic_open writes only ('w' or 'wb'), got {mode!r}")
    path = Path(path)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        os.chmod(tmp, _umask_mode(0o666))
        with os.fdopen(fd, mode) as f:
            yield f
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> Path:
    with atomic_open(path, "wb") as f:
        f.write(data)
    return Path(path)


def atomic_write_text(path: str | os.PathLike, text: str) -> Path:
    with atomic_open(path, "w") as f:
        f.write(text)
    return Path(path)


@contextlib.contextmanager
def atomic_dir(out: str | os.PathLike) -> Iterator[Path]:
    """Yield an empty temporary folder beside `out`; on a clean exit it replaces `out` whole.

    An existing `out` is renamed away first and removed only after the new folder is in place.
    """
    out = Path(out).resolve()
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(dir=out.parent, prefix=f".{out.name}.tmp."))
    os.chmod(tmp, _umask_mode(0o777))
    try:
        yield tmp
        old = None
        if out.exists():
            old = out.with_name(f".{out.name}.old.{os.getpid()}")
            os.replace(out, old)
        os.replace(tmp, out)
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def _probe_dir(folder: Path, what: str) -> None:
    """Create and remove a file in `folder` (its nearest existing ancestor if it does not exist yet)."""
    probe = folder
    while not probe.exists():
        if probe.parent == probe:
            break
        probe = probe.parent
    if not probe.is_dir():
        raise ValueError(f"{what}: {probe} is not a folder")
    try:
        fd, tmp = tempfile.mkstemp(dir=probe, prefix=".jaxquad-probe.")
        os.close(fd)
        os.unlink(tmp)
    except OSError as e:
        raise ValueError(f"{what}: cannot write in {probe} ({e.strerror or e})") from None


def check_output_file(path: str | os.PathLike, what: str = "output") -> Path:
    """Fail now, in one line, if `path` cannot be written (a folder in the way, a read-only place)."""
    path = Path(path)
    if path.is_dir():
        raise ValueError(f"{what} {path} is a folder, not a file")
    _probe_dir(path.parent if str(path.parent) else Path("."), f"{what} {path}")
    return path


def check_output_dir(out: str | os.PathLike, what: str = "--out", kind: str | None = None) -> Path:
    """Fail now, in one line, if folder `out` cannot be created or replaced: a file in the way, a
    read-only place, or a non-empty folder that does not hold an earlier output of `kind` (its
    summary.json names the kind), whose contents a run would replace."""
    import json

    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"{what} {out} exists and is not a folder")
    if kind is not None and out.is_dir() and any(out.iterdir()):
        try:
            earlier = json.loads((out / "summary.json").read_text()).get("kind") == kind
        except (OSError, ValueError, AttributeError):
            earlier = False
        if not earlier:
            raise ValueError(f"{what} {out} is a non-empty folder that holds no earlier {kind} output; choose another")
    # atomic_dir builds beside `out`, so its parent must be writable too.
    _probe_dir(out.resolve().parent, f"{what} {out}")
    return out


@contextlib.contextmanager
def atomic_path(out: str | os.PathLike) -> Iterator[Path]:
    """Yield a path that does not exist yet and has `out`'s name (for writers that create their own file
    or folder and record its name inside, as ROS 2 bags do); on a clean exit it replaces `out`."""
    out = Path(out).resolve()
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(dir=out.parent, prefix=f".{out.name}.tmp."))
    try:
        yield tmp / out.name
        made = tmp / out.name
        if made.is_dir():
            os.chmod(made, _umask_mode(0o777))
        old = None
        if out.exists():
            old = out.with_name(f".{out.name}.old.{os.getpid()}")
            os.replace(out, old)
        os.replace(made, out)
        if old is not None:
            shutil.rmtree(old, ignore_errors=True) if old.is_dir() else old.unlink()
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
