"""Radiance RGBE (``.hdr`` / ``.pic``) read and write.

Supported: the standard orientation ``-Y H +X W`` (row 0 is the top row) and ``+Y H +X W``
(flipped on read), pixel data as flat 4-byte RGBE pixels or as new-style run-length encoded
scanlines (``2 2 hi lo`` scanline header, one RLE stream per component). The old-style RLE
(``1 1 1 n`` repeat pixels, from the 1980s) and rotated orientations (``+X``/``-X`` first) are
rejected with a :class:`~homofac.errors.HomofacError`; ``FORMAT=32-bit_rle_xyze`` is rejected too.

Decoding uses Radiance's own rule ``c = (m + 0.5) 2^(e - 136)`` (0 when e = 0); encoding its
``setcolr``, so a round trip is exact to the 8-bit mantissa of the brightest component: the error
of each component is at most ``2^(e-136)/2``, i.e. at most 1/256 of the pixel's largest component.
Files are written with new-style RLE (``rle=True``, widths 8..32767) or flat.

Nothing on disk is trusted: :func:`hdr_info` reads the text header and the resolution line only, and
absurd sizes (zero, more than :data:`~homofac.io.files.MAX_PIXELS` pixels) are refused. Reading
streams the file (never holding it whole): :func:`iter_hdr_strips` yields float32 strips of rows
in file order (top to bottom; bottom to top for ``+Y`` files, each strip with its image row ``y0``) in
bounded memory; ``read_hdr`` fills the float32 image strip by strip (about 12 bytes per pixel in all)
and refuses, before allocating it, an image whose estimate exceeds ``max_bytes`` (default
:data:`~homofac.io.files.DEFAULT_MAX_BYTES`, 1 GiB; None: no cap).
"""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Iterator

import numpy as np

from ..errors import HomofacError
from .files import DEFAULT_MAX_BYTES, ImageInfo, check_image_size, check_strip, check_whole_read, open_regular, read_head
from .files import one_line as _one_line
from .files import strip_rows as _strip_rows
from .files import write_atomically

__all__ = [
    "read_hdr", "read_hdr_with_header", "write_hdr", "rgbe_to_float", "float_to_rgbe", "hdr_info", "iter_hdr_strips",
]

#: Longest text header accepted (bytes before the blank line).
_HEADER_LIMIT = 65536
#: Bytes read from the file at a time while decoding.
_READ_BYTES = 1 << 20

_RES_RE = re.compile(rb"^([-+])Y\s+(\d+)\s+([-+])X\s+(\d+)\s*$")


def rgbe_to_float(rgbe: np.ndarray) -> np.ndarray:
    """``(..., 4)`` uint8 RGBE -> ``(..., 3)`` float32 (Radiance ``colr_color``: (m + 0.5) 2^(e-136))."""
    rgbe = np.asarray(rgbe, np.uint8)
    # (m + 0.5) has 9 significant bits and 2^(e-136) >= 2^-136: the float32 result is exact (no rounding)
    out = np.ldexp(rgbe[..., :3].astype(np.float32) + np.float32(0.5), rgbe[..., 3:4].astype(np.int32) - 136)
    out[rgbe[..., 3] == 0] = 0.0
    return out


def float_to_rgbe(rgb: np.ndarray) -> np.ndarray:
    """``(..., 3)`` float -> ``(..., 4)`` uint8 RGBE (Radiance ``setcolr``); negatives clamp to 0."""
    rgb = np.maximum(np.nan_to_num(np.asarray(rgb, np.float64), nan=0.0, posinf=0.0), 0.0)
    mx = rgb.max(axis=-1)
    mant, ex = np.frexp(mx)  # mx = mant * 2^ex, mant in [0.5, 1)
    ok = mx > 1e-32
    too_big = ex > 127
    safe = np.where(ok, mx, 1.0)
    d = np.where(ok, mant * 255.9999 / safe, 0.0)
    out = np.zeros(rgb.shape[:-1] + (4,), np.uint8)
    out[..., :3] = np.clip(np.floor(rgb * d[..., None]), 0, 255).astype(np.uint8)
    out[..., 3] = np.where(ok, np.clip(ex + 128, 0, 255), 0).astype(np.uint8)
    out[too_big] = (255, 255, 255, 255)
    return out


def _parse_header(path: Path, data: bytes, at_eof: bool = True) -> tuple[dict, int, int, bool, int]:
    """``(header dict, H, W, flip_y, offset of pixel data)`` from the first bytes of the file.

    ``at_eof``: ``data`` holds the whole file (else a missing line means the header is too long).
    """
    if not data.startswith(b"#?"):  # "#?RADIANCE", "#?RGBE" or another program name
        raise HomofacError(f"{path}: not a Radiance HDR file (missing '#?RADIANCE' signature)")
    header: dict = {}
    pos = 0
    # header lines up to an empty line
    while True:
        nl = data.find(b"\n", pos)
        if nl < 0:
            if at_eof:
                raise HomofacError(f"{path}: truncated Radiance HDR header")
            raise HomofacError(f"{path}: Radiance HDR header too long (no blank line found)")
        line = data[pos:nl].rstrip(b"\r")
        pos = nl + 1
        if not line:
            break
        if b"=" in line and not line.startswith(b"#"):
            k, v = line.split(b"=", 1)
            header[k.strip().decode("latin-1")] = v.strip().decode("latin-1")
        if pos > _HEADER_LIMIT:
            raise HomofacError(f"{path}: Radiance HDR header too long (no blank line found)")
    fmt = header.get("FORMAT", "32-bit_rle_rgbe")
    if fmt != "32-bit_rle_rgbe":
        raise HomofacError(f"{path}: unsupported Radiance pixel format {fmt!r} (only 32-bit_rle_rgbe)")
    nl = data.find(b"\n", pos)
    if nl < 0:
        if at_eof:
            raise HomofacError(f"{path}: truncated Radiance HDR file (no resolution line)")
        nl = min(len(data), pos + 40)
    m = _RES_RE.match(data[pos:nl].rstrip(b"\r"))
    if not m:
        raise HomofacError(f"{path}: unsupported or bad resolution line {data[pos:nl][:40]!r} (expected '-Y H +X W')")
    if m.group(3) != b"+":
        raise HomofacError(f"{path}: unsupported orientation (-X, mirrored image)")
    if len(m.group(2)) > 12 or len(m.group(4)) > 12:
        raise HomofacError(f"{path}: bad image size in the resolution line {data[pos:nl][:40]!r} (corrupt file?)")
    h, w = int(m.group(2)), int(m.group(4))
    check_image_size(path, w, h, 16)
    return header, h, w, m.group(1) == b"+", nl + 1


def _open(path: Path, f) -> tuple[dict, int, int, bool, bytes]:
    """Parse the header from the open file ``f``: ``(header, H, W, flip_y, first pixel bytes)``."""
    try:
        data = f.read(_HEADER_LIMIT + 4096)
        at_eof = len(data) < _HEADER_LIMIT + 4096
    except OSError as e:
        raise HomofacError(f"{path}: cannot read: {_one_line(e)}") from None
    header, h, w, flip, off = _parse_header(path, data, at_eof)
    return header, h, w, flip, data[off:]


def _info(path: Path, h: int, w: int, first: bytes) -> ImageInfo:
    rle = len(first) >= 4 and 8 <= w < 32768 and first[0] == 2 and first[1] == 2 and not (first[2] & 0x80)
    rows = min(h, 64)
    return ImageInfo(
        path=path, kind="hdr", width=w, height=h, channels=("R", "G", "B"), pixel_type="rgbe",
        bytes_per_channel=1, stored_bytes_per_pixel=4, compression="rle" if rle else "flat", block_rows=1,
        # the float32 result, one strip of RGBE rows and its float conversion, the read buffer
        whole_read_bytes=w * h * 12 + rows * w * (4 + 12 + 12) + 2 * _READ_BYTES + 8 * w,
    )


def hdr_info(path: str | os.PathLike) -> ImageInfo:
    """Size of a Radiance HDR file (and whether its first scanline is RLE) from its header alone."""
    p = Path(path)
    read_head(p, "an HDR", 0)  # exists, not a directory
    try:
        with open_regular(p, "an HDR") as f:
            _, h, w, _, first = _open(p, f)
    except OSError as e:
        raise HomofacError(f"{p}: cannot read: {_one_line(e)}") from None
    return _info(p, h, w, first)


def _decode_rle_row(path: Path, data: bytes, pos: int, w: int, y: int) -> tuple[bytearray, int]:
    """The four components of a new-style RLE scanline (planar, 4 x w bytes) and the new position."""
    out = bytearray(4 * w)
    n = len(data)
    for c in range(4):
        x, end = c * w, (c + 1) * w
        while x < end:
            if pos >= n:
                raise HomofacError(f"{path}: truncated RLE data in scanline {y}")
            count = data[pos]
            if count > 128:
                count -= 128
                if pos + 1 >= n:
                    raise HomofacError(f"{path}: truncated RLE data in scanline {y}")
                if x + count > end:
                    raise HomofacError(f"{path}: bad RLE run in scanline {y} (overruns the width)")
                out[x : x + count] = data[pos + 1 : pos + 2] * count
                pos += 2
            else:
                if count == 0 or x + count > end:
                    raise HomofacError(f"{path}: bad RLE literal in scanline {y}")
                if pos + 1 + count > n:
                    raise HomofacError(f"{path}: truncated RLE data in scanline {y}")
                out[x : x + count] = data[pos + 1 : pos + 1 + count]
                pos += 1 + count
            x += count
    return out, pos


def _rgbe_rows(path: Path, f, h: int, w: int, data: bytes, out: np.ndarray) -> Iterator[tuple[int, int]]:
    """Decode the scanlines in file order into ``out`` (``(rows, W, 4)`` uint8), reading ``f`` as needed.

    Yields ``(first file row, count)`` each time ``out`` is full and at the end; then ``out[:count]``
    holds those rows.
    """
    need = 8 * w + 4  # longest possible RLE scanline (every pixel a 2-byte run): never a false "truncated"
    eof = False
    pos = 0
    i = 0
    for y in range(h):
        while len(data) - pos < need and not eof:
            try:
                more = f.read(max(_READ_BYTES, need))
            except OSError as e:
                raise HomofacError(f"{path}: cannot read: {_one_line(e)}") from None
            eof = not more
            data = data[pos:] + more
            pos = 0
        n = len(data)
        if pos + 4 <= n and 8 <= w < 32768 and data[pos] == 2 and data[pos + 1] == 2 and not (data[pos + 2] & 0x80):
            sw = (data[pos + 2] << 8) | data[pos + 3]
            if sw != w:
                raise HomofacError(f"{path}: RLE scanline {y} has width {sw}, expected {w}")
            planes, pos = _decode_rle_row(path, data, pos + 4, w, y)
            out[i] = np.frombuffer(planes, np.uint8).reshape(4, w).T
        else:
            if pos + 4 * w > n:
                raise HomofacError(f"{path}: truncated pixel data at scanline {y} of {h}")
            row = np.frombuffer(data, np.uint8, 4 * w, pos).reshape(w, 4)
            if np.any((row[:, 0] == 1) & (row[:, 1] == 1) & (row[:, 2] == 1)):
                raise HomofacError(f"{path}: old-style RLE (1 1 1 n repeat pixels) is not supported")
            out[i] = row
            pos += 4 * w
        i += 1
        if i == out.shape[0] or y == h - 1:
            yield y + 1 - i, i
            i = 0


def _strips(path: Path, f, h: int, w: int, flip: bool, data: bytes, rows: int) -> Iterator[tuple[int, np.ndarray]]:
    buf = np.empty((min(rows, h), w, 4), np.uint8)
    for fy0, n in _rgbe_rows(path, f, h, w, data, buf):
        rgb = rgbe_to_float(buf[:n])
        if flip:  # file rows fy0 .. fy0+n-1 are image rows h-1-fy0 down to h-fy0-n
            yield h - fy0 - n, np.ascontiguousarray(rgb[::-1])
        else:
            yield fy0, rgb


def iter_hdr_strips(
    path: str | os.PathLike, rows: int | None = None, *, max_bytes: int | None = DEFAULT_MAX_BYTES
) -> Iterator[tuple[int, np.ndarray]]:
    """Yield ``(y0, strip)`` pairs covering a Radiance HDR image, decoding the file sequentially.

    ``strip`` is a fresh ``(n, W, 3)`` float32 array of image rows ``y0 .. y0 + n - 1`` (top to
    bottom within the strip). Strips come in file order: top to bottom for ``-Y`` files, bottom to
    top for ``+Y`` ones (place them by ``y0``); strips hold ``rows`` rows, counted from the start of
    the file (the last one shorter). ``rows`` defaults to about 8 MiB of float32 rows; ``max_bytes``
    caps the strips' memory. The header is checked before the first strip is read.
    """
    p = Path(path)
    info = hdr_info(p)
    rows = _strip_rows(info) if rows is None else int(rows)
    if rows < 1:
        raise HomofacError(f"{p}: strip rows must be >= 1, got {rows}")
    check_strip(info, rows, max_bytes)

    def gen():
        try:
            with open_regular(p, "an HDR") as f:
                _, h, w, flip, data = _open(p, f)
                yield from _strips(p, f, h, w, flip, data, rows)
        except OSError as e:
            raise HomofacError(f"{p}: cannot read: {_one_line(e)}") from None

    return gen()


def read_hdr_with_header(
    path: str | os.PathLike, *, max_bytes: int | None = DEFAULT_MAX_BYTES
) -> tuple[np.ndarray, dict]:
    """``(rgb (H, W, 3) float32, header dict)`` of a Radiance RGBE file (row 0 is the top row).

    An image whose read would need more than ``max_bytes`` (default 1 GiB; None: no cap) is refused
    before any pixel is allocated, with the estimate.
    """
    p = Path(path)
    read_head(p, "an HDR", 0)  # exists, not a directory
    try:
        with open_regular(p, "an HDR") as f:
            header, h, w, flip, data = _open(p, f)
            check_whole_read(_info(p, h, w, data[:4]), max_bytes)
            rgb = np.empty((h, w, 3), np.float32)
            for y0, strip in _strips(p, f, h, w, flip, data, 64):
                rgb[y0 : y0 + strip.shape[0]] = strip
    except OSError as e:
        raise HomofacError(f"{p}: cannot read: {_one_line(e)}") from None
    header["width"], header["height"] = w, h
    return rgb, header


def read_hdr(path: str | os.PathLike, *, max_bytes: int | None = DEFAULT_MAX_BYTES) -> np.ndarray:
    """RGB pixels of a Radiance ``.hdr`` file as an ``(H, W, 3)`` float32 array (see ``max_bytes`` above)."""
    return read_hdr_with_header(path, max_bytes=max_bytes)[0]


def _encode_rle_channel(row: np.ndarray) -> bytes:
    """New-style RLE of one component of one scanline (runs of >= 4 equal bytes become runs)."""
    w = row.shape[0]
    change = np.flatnonzero(np.diff(row.astype(np.int16)) != 0) + 1
    starts = np.concatenate([[0], change])
    lengths = np.diff(np.concatenate([starts, [w]]))
    out = bytearray()
    lit_start = 0  # start of the pending literal block
    for s, ln in zip(starts.tolist(), lengths.tolist()):
        if ln >= 4:
            # flush pending literals [lit_start, s)
            i = lit_start
            while i < s:
                k = min(128, s - i)
                out.append(k)
                out += row[i : i + k].tobytes()
                i += k
            v = int(row[s])
            left = ln
            while left > 0:
                k = min(127, left)
                out += bytes((128 + k, v))
                left -= k
            lit_start = s + ln
    i = lit_start
    while i < w:
        k = min(128, w - i)
        out.append(k)
        out += row[i : i + k].tobytes()
        i += k
    return bytes(out)


def write_hdr(path: str | os.PathLike, rgb, *, rle: bool = True) -> Path:
    """Write an ``(H, W, 3)`` float image as a Radiance RGBE file (``-Y H +X W``); returns the path.

    New-style RLE when ``rle`` and 8 <= W < 32768, flat pixels otherwise. Written to a temporary file
    in the same directory and renamed, so a failure leaves no partial file.
    """
    p = Path(path)
    a = np.asarray(rgb, np.float32)
    if a.ndim != 3 or a.shape[2] != 3 or a.shape[0] == 0 or a.shape[1] == 0:
        raise HomofacError(f"{p}: cannot write HDR: expected an (H, W, 3) image, got shape {a.shape}")
    h, w, _ = a.shape
    rgbe = float_to_rgbe(a)
    parts = [b"#?RADIANCE\n# written by homofac\nFORMAT=32-bit_rle_rgbe\n\n", f"-Y {h} +X {w}\n".encode()]
    if rle and 8 <= w < 32768:
        head = bytes((2, 2, w >> 8, w & 0xFF))
        for y in range(h):
            parts.append(head)
            for c in range(4):
                parts.append(_encode_rle_channel(rgbe[y, :, c]))
    else:
        parts.append(rgbe.tobytes())
    return write_atomically(p, "HDR", lambda tmp: Path(tmp).write_bytes(b"".join(parts)))
