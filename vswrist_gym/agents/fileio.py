"""Run files and output folders: files written so that a kill never leaves a half-written one (a temporary file
in the same folder, fsync, rename), and output folders checked before any work (writable; new, empty or of the
same kind)."""

from __future__ import annotations

import io
import os
import tempfile
from pathlib import Path

import numpy as np


class RunDirError(RuntimeError):
    """A run directory, model or statistics file is missing, corrupted, or belongs to another task."""


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write to a temporary file in the same folder, fsync, then rename over `path`."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def atomic_write_text(path: Path, text: str) -> None:
    atomic_write_bytes(path, text.encode())


def atomic_write_npz(path: Path, arrays: dict) -> None:
    """`np.savez` into memory, then an atomic write: a kill never leaves a half-written archive under `path`."""
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    atomic_write_bytes(path, buf.getvalue())


def _nearest_existing(path: Path) -> Path:
    path = Path(os.path.abspath(path))
    while not path.exists() and path != path.parent:
        path = path.parent
    return path


def check_writable(path: str | Path, name: str = "--out") -> None:
    """`path` (a folder, existing or not) can be created and written: a probe file is created and removed in the
    folder itself or, when it does not exist yet, in its nearest existing ancestor. Raises RunDirError otherwise."""
    path = Path(path)
    base = _nearest_existing(path)
    if not base.is_dir():
        what = "is a file" if base == Path(os.path.abspath(path)) else f"lies under {base}, which is a file"
        raise RunDirError(f"{name} {path}: cannot be a folder: it {what}")
    try:
        fd, probe = tempfile.mkstemp(prefix=".vswrist_write_probe_", dir=base)
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        where = "" if base == Path(os.path.abspath(path)) else f" (in {base}, its nearest existing folder)"
        raise RunDirError(f"{name} {path}: not writable{where}: {exc.strerror or exc}") from None


def check_new_out(path: str | Path, allowed: tuple[str, ...], what: str, name: str = "--out") -> None:
    """A folder to write `what` into: writable, and either absent, empty, or holding only names in `allowed`
    (output of the same kind, which the command replaces or continues). A non-empty folder of anything else is
    refused, so that no command writes its files among someone else's."""
    path = Path(path)
    check_writable(path, name)
    if path.is_dir():
        other = sorted(p.name for p in path.iterdir() if p.name not in allowed)
        if other:
            shown = ", ".join(other[:5]) + (f" and {len(other) - 5} more" if len(other) > 5 else "")
            raise RunDirError(f"{name} {path} is a non-empty folder that is not {what} (it holds {shown}); "
                              f"choose a new or empty folder")


def created_root(path: Path) -> Path | None:
    """The top-most folder that `mkdir(parents=True)` of `path` would create (None when `path` exists)."""
    path = Path(os.path.abspath(path))
    if path.exists():
        return None
    while not path.parent.exists():
        path = path.parent
    return path


def folder_bytes(path: Path) -> int:
    """Bytes of the files under `path` (its footprint on disk, up to block rounding)."""
    total = 0
    for root, _, files in os.walk(path):
        for f in files:
            try:
                total += os.lstat(os.path.join(root, f)).st_size
            except OSError:
                pass
    return total
