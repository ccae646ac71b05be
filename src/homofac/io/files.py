"""File plumbing shared by the readers and writers: checked reads and atomic writes.

Reads: :func:`read_head` refuses a missing path or a directory and returns the first bytes (the
format's magic number) with one-line errors that name the file.

Writes: every file homofac writes appears whole or not at all.

The data goes to a temporary file in the destination's directory (same filesystem), gets the mode
the old file had (or 0644), and is renamed over the destination with :func:`os.replace`. On any
failure the temporary file is removed and a one-line :class:`~homofac.errors.HomofacError` names the
file; an existing file at the destination is left as it was.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import Callable

from ..errors import HomofacError


def one_line(e: BaseException) -> str:
    """An exception's message on one line (its type name when it has none)."""
    return " ".join(str(e).split()) or type(e).__name__


def read_head(path: str | os.PathLike, kind: str, n: int) -> bytes:
    """The first ``n`` bytes of the file at ``path``, after checking it exists and is not a directory.

    ``kind`` names the expected format with its article (``an EXR``, ``a PNG``) for the messages.
    """
    p = Path(path)
    if not p.exists():
        raise HomofacError(f"{p}: no such file")
    if p.is_dir():
        raise HomofacError(f"{p}: is a directory, not {kind} file")
    try:
        with open(p, "rb") as f:
            return f.read(n)
    except OSError as e:
        raise HomofacError(f"{p}: cannot read: {one_line(e)}") from None


def write_atomically(path: str | os.PathLike, kind: str, write: Callable[[str], None], suffix: str = ".tmp") -> Path:
    """Call ``write(tmp)`` to fill a temporary file, then rename it onto ``path``; returns the path.

    Args:
        path: destination file.
        kind: what is written (``EXR``, ``PNG`` ...), for the error message.
        write: writes the whole file at the temporary path it is given.
        suffix: suffix of the temporary file (some writers pick the format from it).
    """
    p = Path(path)
    directory = p.parent if str(p.parent) else Path(".")
    if not directory.is_dir():
        raise HomofacError(f"{p}: cannot write {kind}: directory {directory} does not exist")
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", suffix=suffix, dir=directory)
    except OSError as e:
        raise HomofacError(f"{p}: cannot write {kind}: {one_line(e)}") from None
    os.close(fd)
    try:
        write(tmp)
        os.chmod(tmp, (p.stat().st_mode & 0o777) if p.exists() else 0o644)
        os.replace(tmp, p)
    except BaseException as e:
        Path(tmp).unlink(missing_ok=True)
        if isinstance(e, HomofacError) or not isinstance(e, Exception):
            raise
        raise HomofacError(f"{p}: cannot write {kind}: {one_line(e)}") from None
    return p


__all__ = ["one_line", "read_head", "write_atomically"]
