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
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np

from ..errors import HomofacError
from .files import read_head, write_atomically

__all__ = ["read_hdr", "read_hdr_with_header", "write_hdr", "rgbe_to_float", "float_to_rgbe"]

_RES_RE = re.compile(rb"^([-+])Y\s+(\d+)\s+([-+])X\s+(\d+)\s*$")


def rgbe_to_float(rgbe: np.ndarray) -> np.ndarray:
    """``(..., 4)`` uint8 RGBE -> ``(..., 3)`` float32 (Radiance ``colr_color``: (m + 0.5) 2^(e-136))."""
    rgbe = np.asarray(rgbe, np.uint8)
    e = rgbe[..., 3].astype(np.int32)
    scale = np.where(e > 0, np.ldexp(1.0, e - 136), 0.0)
    return ((rgbe[..., :3].astype(np.float64) + 0.5) * scale[..., None]).astype(np.float32)


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


def _parse_header(path: Path, data: bytes) -> tuple[dict, int, int, bool, int]:
    """``(header dict, H, W, flip_y, offset of pixel data)``."""
    if not data.startswith(b"#?"):  # "#?RADIANCE", "#?RGBE" or another program name
        raise HomofacError(f"{path}: not a Radiance HDR file (missing '#?RADIANCE' signature)")
    header: dict = {}
    pos = 0
    # header lines up to an empty line
    while True:
        nl = data.find(b"\n", pos)
        if nl < 0:
            raise HomofacError(f"{path}: truncated Radiance HDR header")
        line = data[pos:nl].rstrip(b"\r")
        pos = nl + 1
        if not line:
            break
        if b"=" in line and not line.startswith(b"#"):
            k, v = line.split(b"=", 1)
            header[k.strip().decode("latin-1")] = v.strip().decode("latin-1")
        if pos > 65536:
            raise HomofacError(f"{path}: Radiance HDR header too long (no blank line found)")
    fmt = header.get("FORMAT", "32-bit_rle_rgbe")
    if fmt != "32-bit_rle_rgbe":
        raise HomofacError(f"{path}: unsupported Radiance pixel format {fmt!r} (only 32-bit_rle_rgbe)")
    nl = data.find(b"\n", pos)
    if nl < 0:
        raise HomofacError(f"{path}: truncated Radiance HDR file (no resolution line)")
    m = _RES_RE.match(data[pos:nl].rstrip(b"\r"))
    if not m:
        raise HomofacError(f"{path}: unsupported or bad resolution line {data[pos:nl][:40]!r} (expected '-Y H +X W')")
    if m.group(3) != b"+":
        raise HomofacError(f"{path}: unsupported orientation (-X, mirrored image)")
    h, w = int(m.group(2)), int(m.group(4))
    if h <= 0 or w <= 0 or h * w > 1 << 28:
        raise HomofacError(f"{path}: bad image size {w}x{h}")
    return header, h, w, m.group(1) == b"+", nl + 1


def _decode_rle_channel(path: Path, buf: np.ndarray, pos: int, w: int, y: int) -> tuple[np.ndarray, int]:
    """One component of a new-style RLE scanline: returns (w bytes, new position)."""
    out = np.empty(w, np.uint8)
    x = 0
    n = buf.shape[0]
    while x < w:
        if pos >= n:
            raise HomofacError(f"{path}: truncated RLE data in scanline {y}")
        count = int(buf[pos])
        if count > 128:
            count -= 128
            if pos + 1 >= n:
                raise HomofacError(f"{path}: truncated RLE data in scanline {y}")
            if x + count > w:
                raise HomofacError(f"{path}: bad RLE run in scanline {y} (overruns the width)")
            out[x : x + count] = buf[pos + 1]
            pos += 2
        else:
            if count == 0 or x + count > w:
                raise HomofacError(f"{path}: bad RLE literal in scanline {y}")
            if pos + 1 + count > n:
                raise HomofacError(f"{path}: truncated RLE data in scanline {y}")
            out[x : x + count] = buf[pos + 1 : pos + 1 + count]
            pos += 1 + count
        x += count
    return out, pos


def read_hdr_with_header(path: str | os.PathLike) -> tuple[np.ndarray, dict]:
    """``(rgb (H, W, 3) float32, header dict)`` of a Radiance RGBE file (row 0 is the top row)."""
    p = Path(path)
    read_head(p, "an HDR", 0)  # exists, not a directory
    try:
        data = p.read_bytes()
    except OSError as e:
        raise HomofacError(f"{p}: cannot read: {' '.join(str(e).split())}") from None
    header, h, w, flip, off = _parse_header(p, data)
    buf = np.frombuffer(data, np.uint8, offset=off) if off < len(data) else np.zeros(0, np.uint8)
    rgbe = np.empty((h, w, 4), np.uint8)
    pos = 0
    n = buf.shape[0]
    for y in range(h):
        if pos + 4 <= n and 8 <= w < 32768 and buf[pos] == 2 and buf[pos + 1] == 2 and not (buf[pos + 2] & 0x80):
            sw = (int(buf[pos + 2]) << 8) | int(buf[pos + 3])
            if sw != w:
                raise HomofacError(f"{p}: RLE scanline {y} has width {sw}, expected {w}")
            pos += 4
            for c in range(4):
                rgbe[y, :, c], pos = _decode_rle_channel(p, buf, pos, w, y)
        else:
            if pos + 4 * w > n:
                raise HomofacError(f"{p}: truncated pixel data at scanline {y} of {h}")
            row = buf[pos : pos + 4 * w].reshape(w, 4)
            if np.any((row[:, 0] == 1) & (row[:, 1] == 1) & (row[:, 2] == 1)):
                raise HomofacError(f"{p}: old-style RLE (1 1 1 n repeat pixels) is not supported")
            rgbe[y] = row
            pos += 4 * w
    rgb = rgbe_to_float(rgbe)
    if flip:
        rgb = rgb[::-1].copy()
    header["width"], header["height"] = w, h
    return rgb, header


def read_hdr(path: str | os.PathLike) -> np.ndarray:
    """RGB pixels of a Radiance ``.hdr`` file as an ``(H, W, 3)`` float32 array."""
    return read_hdr_with_header(path)[0]


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
