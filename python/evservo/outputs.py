"""Where runs write: output locations checked before any work starts, and files replaced atomically.

A command calls :func:`prepare_out_dir` (or :func:`check_out_file`) first, so that a bad ``--out``
fails in a second instead of after the run (or, with a real arm, after the arm moved). Files are
written with :func:`atomic_path` / :func:`write_text_atomic`: to a temporary name in the same
directory, renamed over the target only once complete, so an interrupted writer never leaves a
half-written file nor destroys the previous one.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import tempfile
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

__all__ = [
    "OutputError",
    "atomic_path",
    "check_out_file",
    "json_text",
    "make_out_dir",
    "prepare_out_dir",
    "read_json",
    "write_text_atomic",
]

#: Non-finite floats as JSON strings: bare ``NaN``/``Infinity`` are not JSON (JavaScript's parser
#: rejects them, jq reads ``Infinity`` as 1.8e308), and ``null`` would lose "never" (an infinite
#: re-lock time) against "did not apply" (None).
_NON_FINITE = {"NaN": math.nan, "Infinity": math.inf, "-Infinity": -math.inf}


class OutputError(ValueError):
    """An output location that cannot be written (the CLI reports it as ``evservo: error: …``, exit 2)."""


def _probe_writable(directory: Path, what: str) -> None:
    """Create and remove a file in ``directory``: the only check that also holds for root and for
    read-only file systems (``os.access`` answers yes to root)."""
    try:
        fd, name = tempfile.mkstemp(dir=directory, prefix=".evservo-probe-")
    except OSError as e:
        raise OutputError(f"{what} {directory} is not writable: {e.strerror or e}") from None
    os.close(fd)
    os.unlink(name)


def prepare_out_dir(path: str | os.PathLike, stale: Iterable[str] = (), option: str = "--out") -> Path:
    """Check that ``path`` can be the output directory and remove the files named in ``stale`` from an
    earlier run in it, so that an interrupted run never leaves an old ``summary.json`` behind that reads
    as its own. Raises :class:`OutputError` when ``path`` is an existing file, lies under a file, or
    the directory that would hold it is not writable. A missing directory is not created here (a run
    whose inputs turn out bad leaves nothing behind); writers call :func:`make_out_dir`."""
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise OutputError(f"{option} {p} exists and is not a directory")
    absolute = p.absolute()
    existing = next(q for q in (absolute, *absolute.parents) if q.exists())
    if not existing.is_dir():
        raise OutputError(f"{option} {p}: {existing} is a file, not a directory")
    _probe_writable(existing, option)
    for name in stale:
        target = p / name
        if target.is_file() or target.is_symlink():
            target.unlink()
    return p


def make_out_dir(path: str | os.PathLike, stale: Iterable[str] = (), option: str = "--out") -> Path:
    """:func:`prepare_out_dir`, then create the directory."""
    p = prepare_out_dir(path, stale, option)
    p.mkdir(parents=True, exist_ok=True)
    return p


def check_out_file(path: str | os.PathLike, suffixes: tuple[str, ...] = (), option: str = "--out") -> Path:
    """Make sure a file can be written at ``path``: the suffix is one of ``suffixes`` (if given), the
    path is not a directory, and its directory exists and is writable. The file itself is not
    touched (an existing one is replaced only when the new one is complete)."""
    p = Path(path)
    if p.is_dir():
        raise OutputError(f"{option} {p} is a directory; give a file name")
    if suffixes and p.suffix.lower() not in suffixes:
        raise OutputError(f"{option} {p}: want a {'/'.join(suffixes)} file name")
    parent = p.parent
    if not parent.is_dir():
        raise OutputError(f"{option} {p}: the directory {parent} does not exist")
    _probe_writable(parent, option)
    return p


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """A temporary path in ``path``'s directory to write to; renamed to ``path`` when the block ends
    normally, removed when it raises (also on KeyboardInterrupt). The temporary name keeps the
    target's suffix out of its end (``.NAME.XXXX.part``) so no reader mistakes it for the real file."""
    p = Path(path)
    fd, name = tempfile.mkstemp(dir=p.parent, prefix=f".{p.name}.", suffix=".part")
    os.close(fd)
    tmp = Path(name)
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o666 & ~umask)  # mkstemp's 0600 would otherwise become the file's mode
    try:
        yield tmp
        os.replace(tmp, p)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
        raise


def write_text_atomic(path: str | os.PathLike, text: str) -> None:
    """Write ``text`` to ``path`` through :func:`atomic_path`."""
    with atomic_path(path) as tmp:
        tmp.write_text(text)


def _finite_or_text(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {k: _finite_or_text(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_finite_or_text(v) for v in obj]
    if isinstance(obj, float) and not math.isfinite(obj):
        return "NaN" if math.isnan(obj) else ("Infinity" if obj > 0 else "-Infinity")
    return obj


def _numpy_scalar(obj: Any) -> Any:
    item = getattr(obj, "item", None)  # numpy scalars (not imported here: this module stays light)
    if item is None:
        raise TypeError(f"{type(obj).__name__} is not JSON serialisable")
    return _finite_or_text(item())


def json_text(obj: Any) -> str:
    """``obj`` as indented, strict JSON (numpy scalars as numbers, non-finite floats as the strings
    ``"NaN"``, ``"Infinity"``, ``"-Infinity"``, which :func:`read_json` turns back into floats)."""
    return json.dumps(_finite_or_text(obj), indent=2, default=_numpy_scalar, allow_nan=False) + "\n"


def read_json(path: str | os.PathLike) -> Any:
    """A file :func:`json_text` wrote (or any JSON), the non-finite floats restored."""

    def back(v: Any) -> Any:
        if isinstance(v, str):
            return _NON_FINITE.get(v, v)
        return [back(x) for x in v] if isinstance(v, list) else v  # dicts were restored on the way up

    return back(json.loads(Path(path).read_text(), object_hook=lambda d: {k: back(v) for k, v in d.items()}))
