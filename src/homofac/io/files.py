"""File plumbing shared by the readers and writers: checked reads and atomic writes.

Reads: only regular files are opened. :func:`check_regular` refuses a missing path, a directory, a FIFO,
a device or a socket in one line naming the path and what it is; :func:`open_regular` opens with
``O_NONBLOCK`` and checks the open descriptor again (a FIFO swapped in after the check cannot block);
:func:`read_bounded` reads a whole file up to a stated byte limit; :func:`read_head` returns the first
bytes (the format's magic number).

Writes: every file homofac writes appears whole or not at all.

The data goes to a temporary file in the destination's directory (same filesystem), gets the mode
the old file had (or 0644), and is renamed over the destination with :func:`os.replace`. On any
failure the temporary file is removed and a one-line :class:`~homofac.errors.HomofacError` names the
file; an existing file at the destination is left as it was.

Sizes ("trust nothing on disk"): a header's declared size is checked before any pixel is allocated.
:func:`check_image_size` refuses absurd sizes (zero, negative, more than :data:`MAX_PIXELS` pixels);
:func:`check_whole_read` refuses a whole-image read whose estimated memory
(:attr:`ImageInfo.whole_read_bytes`: the decoded float32 pixels plus the reader's own temporaries)
exceeds the caller's ``max_bytes``, by default :data:`DEFAULT_MAX_BYTES` (1 GiB). :class:`ImageInfo` is
what the header-only probes (``homofac.io.exr.exr_info``, ``homofac.io.hdr.hdr_info``,
``homofac.io.limits.image_info``) return.
"""

from __future__ import annotations

import contextlib
import math
import os
import stat
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO, Callable, Iterator

from ..errors import HomofacError


def one_line(e: BaseException) -> str:
    """An exception's message on one line (its type name when it has none)."""
    return " ".join(str(e).split()) or type(e).__name__


def what_is(mode: int) -> str:
    """What a file of ``st_mode`` is, with its article: ``a regular file``, ``a FIFO``, ``a directory`` ..."""
    for test, name in ((stat.S_ISREG, "a regular file"), (stat.S_ISDIR, "a directory"), (stat.S_ISFIFO, "a FIFO"),
                       (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
                       (stat.S_ISSOCK, "a socket"), (stat.S_ISLNK, "a symbolic link")):
        if test(mode):
            return name
    return "not a regular file"


def check_regular(path: str | os.PathLike, kind: str = "a") -> os.stat_result:
    """``os.stat`` of ``path`` after checking it is a regular file (symlinks followed).

    A missing path, a directory, a FIFO, a device or a socket is refused in one line naming the path and
    what it is (``kind`` names the expected file with its article: ``an EXR``, ``a mesh``), so nothing
    blocks on a FIFO or reads a device without end.
    """
    p = Path(path)
    try:
        st = os.stat(p)
    except FileNotFoundError:
        raise HomofacError(f"{p}: no such file") from None
    except (OSError, ValueError) as e:
        raise HomofacError(f"{p}: cannot read: {one_line(e)}") from None
    if not stat.S_ISREG(st.st_mode):
        raise HomofacError(f"{p}: is {what_is(st.st_mode)}, not {kind} file")
    return st


@contextlib.contextmanager
def open_regular(path: str | os.PathLike, kind: str = "a", max_bytes: int | None = None) -> Iterator[BinaryIO]:
    """A binary file object of the regular file at ``path`` (see :func:`check_regular`).

    The file is opened with ``O_NONBLOCK`` (a FIFO swapped in after the check cannot block the open) and
    checked again on the open descriptor (``fstat``), so what is read is the regular file that was
    checked. ``max_bytes`` refuses a larger file (its size stated in the message); callers that read
    it whole should use :func:`read_bounded`, which also stops at the limit if the file grows.
    """
    p = Path(path)
    check_regular(p, kind)
    try:
        fd = os.open(p, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    except OSError as e:
        raise HomofacError(f"{p}: cannot read: {one_line(e)}") from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise HomofacError(f"{p}: is {what_is(st.st_mode)}, not {kind} file")
        if max_bytes is not None and st.st_size > max_bytes:
            raise HomofacError(f"{p}: {kind} file of {format_bytes(st.st_size)}, more than the limit of "
                               f"{format_bytes(max_bytes)}")
        os.set_blocking(fd, True)
        f = os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise
    with f:
        yield f


def read_bounded(path: str | os.PathLike, kind: str = "a", max_bytes: int = 64 << 20) -> bytes:
    """The whole content of the regular file at ``path``, at most ``max_bytes`` bytes (a larger file, or
    one that grows past the limit while it is read, is refused in one line)."""
    p = Path(path)
    with open_regular(p, kind, max_bytes) as f:
        try:
            data = f.read(max_bytes + 1)
        except OSError as e:
            raise HomofacError(f"{p}: cannot read: {one_line(e)}") from None
    if len(data) > max_bytes:
        raise HomofacError(f"{p}: {kind} file of more than {format_bytes(max_bytes)}, the limit")
    return data


def read_head(path: str | os.PathLike, kind: str, n: int) -> bytes:
    """The first ``n`` bytes of the file at ``path``, after checking it is a regular file (not missing, a
    directory, a FIFO, a device or a socket: :func:`check_regular`).

    ``kind`` names the expected format with its article (``an EXR``, ``a PNG``) for the messages.
    """
    p = Path(path)
    with open_regular(p, kind) as f:
        try:
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


#: Default cap on the memory of a whole-image read (decoded pixels plus the reader's temporaries): 1 GiB.
#: An 8192 x 4096 half RGB EXR needs about 0.6 GiB and passes; a 16384 x 8192 one (2.3 GiB) is refused
#: with the estimate and can be read downsampled in strips (``homofac.io.limits.read_downsampled``).
DEFAULT_MAX_BYTES = 1 << 30

#: Images declaring more pixels than this (46341 x 46341) are refused as corrupt, whatever the cap.
MAX_PIXELS = 1 << 31


@dataclass(frozen=True)
class ImageInfo:
    """What an image file's header declares, read without decoding any pixel.

    Attributes:
        path: the file.
        kind: ``"exr"`` or ``"hdr"``.
        width, height: image size in pixels (EXR: of the data window).
        channels: the channel names stored (EXR: all of them, alphabetical; HDR: ``("R", "G", "B")``).
        pixel_type: type of the colour channels read: ``"half"``, ``"float"`` or ``"uint"`` (EXR; the
            widest of R, G, B or Y), ``"rgbe"`` (HDR: three 8-bit mantissas and a shared exponent).
        bytes_per_channel: bytes of one stored colour sample (2 or 4; 1 for RGBE).
        stored_bytes_per_pixel: bytes of one pixel as stored, all channels (RGBE: 4).
        envmap: the EXR ``envmap`` attribute as ``"latlong"`` / ``"cube"``, else None.
        compression: EXR compression name (``"zip"``, ``"piz"`` ...); HDR ``"rle"`` or ``"flat"``
            (from the first scanline).
        tiled: EXR tiled image.
        block_rows: rows the format decodes at once (EXR chunk lines or tile height; HDR 1): strips
            that are multiples of it decode each block once.
        whole_read_bytes: estimated peak memory of reading the whole image with ``read_exr`` /
            ``read_hdr`` (float32 RGB result plus the reader's temporaries).
    """

    path: Path
    kind: str
    width: int
    height: int
    channels: tuple[str, ...]
    pixel_type: str
    bytes_per_channel: int
    stored_bytes_per_pixel: int
    envmap: str | None = None
    compression: str | None = None
    tiled: bool = False
    block_rows: int = 1
    whole_read_bytes: int = 0

    @property
    def pixels(self) -> int:
        """``width * height``."""
        return self.width * self.height

    @property
    def float32_bytes(self) -> int:
        """Bytes of the decoded ``(H, W, 3)`` float32 image."""
        return self.width * self.height * 12


def format_bytes(n: float) -> str:
    """``1.5 GiB``, ``12.0 MiB``, ``512 B``: a byte count for messages."""
    for unit, k in (("TiB", 1 << 40), ("GiB", 1 << 30), ("MiB", 1 << 20), ("KiB", 1 << 10)):
        if n >= k:
            return f"{n / k:.1f} {unit}"
    return f"{int(n)} B"


def check_image_size(path: str | os.PathLike, width: int, height: int, bytes_per_pixel: int = 12) -> None:
    """Refuse a header's absurd size before anything is allocated (one line naming the file).

    Zero or negative sizes, more than :data:`MAX_PIXELS` pixels, and sizes whose decoded bytes
    (``bytes_per_pixel`` per pixel) would overflow a 64-bit size are refused.
    """
    if width <= 0 or height <= 0:
        raise HomofacError(f"{path}: bad image size {width} x {height} in the header (corrupt file?)")
    if width * height > MAX_PIXELS:
        raise HomofacError(
            f"{path}: bad image size {width} x {height} in the header ({width * height:.3g} pixels, more than "
            f"the {MAX_PIXELS:.3g} accepted; corrupt file?)"
        )
    if width * height * max(int(bytes_per_pixel), 1) >= 1 << 63:
        raise HomofacError(f"{path}: bad image size {width} x {height} in the header (decoded size overflows)")


def check_whole_read(info: ImageInfo, max_bytes: int | None) -> None:
    """Refuse reading ``info``'s image whole when its estimated memory exceeds ``max_bytes``.

    ``max_bytes=None`` means no cap. The message states the estimate and the limit.
    """
    if max_bytes is None or info.whole_read_bytes <= max_bytes:
        return
    raise HomofacError(
        f"{info.path}: {info.width} x {info.height} pixels need {format_bytes(info.whole_read_bytes)} to read whole; "
        f"limit {format_bytes(max_bytes)} (read it downsampled in strips with homofac.io.limits.read_downsampled, "
        f"or pass a larger max_bytes)"
    )


#: Target size of one strip of float32 RGB rows in the strip readers (a few strips are alive at once).
STRIP_BYTES = 8 << 20


def strip_rows(info: ImageInfo, factor: int = 1, target_bytes: int = STRIP_BYTES) -> int:
    """Rows per strip for ``info``'s image: about ``target_bytes`` of float32 RGB rows, a multiple of
    ``factor`` (and of ``info.block_rows`` when that keeps the strip near the target, so each block of
    the file is decoded once), at least ``factor`` rows and not more than the image (rounded up).
    """
    f = max(1, int(factor))
    row = max(1, info.width * 12)
    unit = math.lcm(f, max(1, info.block_rows))
    if unit * row > target_bytes:
        unit = f
    n = unit * max(1, target_bytes // (unit * row))
    return min(n, -(-info.height // unit) * unit)


def check_strip(info: ImageInfo, rows: int, max_bytes: int | None) -> None:
    """Refuse strips of ``rows`` full-width rows whose memory (the float32 strip and the decoder's
    temporaries, about 4 strips) exceeds ``max_bytes`` (None: no cap)."""
    need = 4 * rows * info.width * 12
    if max_bytes is not None and need > max_bytes:
        raise HomofacError(
            f"{info.path}: strips of {rows} rows of {info.width} pixels need {format_bytes(need)}; "
            f"limit {format_bytes(max_bytes)}"
        )


__all__ = [
    "STRIP_BYTES", "strip_rows", "check_strip",
    "one_line", "read_head", "check_regular", "open_regular", "read_bounded", "what_is", "write_atomically", "ImageInfo", "DEFAULT_MAX_BYTES", "MAX_PIXELS",
    "format_bytes", "check_image_size", "check_whole_read",
]
