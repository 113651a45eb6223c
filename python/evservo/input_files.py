"""Input files checked before they are read: a path that names something other than a regular file gets
a message saying what is there (a directory, a FIFO, a symlink loop) instead of "no such file"."""

from __future__ import annotations

import os
import stat
from pathlib import Path

__all__ = ["require_regular_file"]


def require_regular_file(path: str | os.PathLike, what: str) -> Path:
    """``path`` if it is a regular file (after symlinks); else ``FileNotFoundError`` when nothing is
    there and ``ValueError`` naming what is there instead (a directory, a FIFO, a symlink loop, ...)."""
    p = Path(path)
    try:
        mode = p.stat().st_mode
    except FileNotFoundError:
        raise FileNotFoundError(f"no such {what}: {p}") from None
    except OSError as e:  # ELOOP, EACCES, ENOTDIR, ...
        raise ValueError(f"{what} {p}: {e.strerror or e}") from None
    if stat.S_ISDIR(mode):
        raise ValueError(f"{what} {p} is a directory, not a file")
    if not stat.S_ISREG(mode):
        raise ValueError(f"{what} {p} is not a regular file (a FIFO, socket or device)")
    return p
