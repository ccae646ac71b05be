"""OpenEXR read and write (OpenEXR 3.x python bindings), RGB float32.

``read_exr`` returns an ``(H, W, 3)`` float32 array whatever the file stores: an interleaved
``"RGB"``/``"RGBA"`` group, separate ``"R"``, ``"G"``, ``"B"`` channels, or a single grey ``"Y"``
channel (copied to the three channels). Half and uint channels are converted to float32
(``native=True`` keeps half pixels as float16, for a bit-exact half round trip).
``read_exr_with_header`` also returns the header dict, e.g. to read the ``envmap`` attribute
(``OpenEXR.ENVMAP_LATLONG`` or ``OpenEXR.ENVMAP_CUBE``); :func:`envmap_kind` turns it into a string.

Nothing on disk is trusted. Before OpenEXR sees a file, its header is parsed here
(:func:`exr_info`, header only: magic, version, attributes up to the empty name; ``dataWindow`` gives
the size, ``channels`` the types) and absurd values (zero or negative sizes, more than
:data:`~homofac.io.files.MAX_PIXELS` pixels) are refused; a single-part file's chunk offset table must
lie inside the file (a file declaring a huge image over a few bytes of data fails at once). A whole
read is refused up front, before any pixel is allocated, when its estimated memory (the channels
OpenEXR decodes plus the float32 result, :attr:`~homofac.io.files.ImageInfo.whole_read_bytes`) exceeds
``max_bytes`` (default :data:`~homofac.io.files.DEFAULT_MAX_BYTES`, 1 GiB; ``None`` for no cap); the
message states the estimate.

Big images are read in strips of rows by :func:`iter_exr_strips` (see also
:func:`homofac.io.limits.read_downsampled`). Two decoders:

- ``"openexr"``: OpenEXR's own scanline reader (``OpenEXR.InputFile(...).channels(names, FLOAT, y1,
  y2)``, the deprecated but still shipped compatibility class of the 3.x bindings; the new
  ``OpenEXR.File`` API can only read a whole part). Every compression and tiled files, in bounded memory.
- ``"builtin"``: a decoder here, reading chunks through the offset table (zlib for ZIP/ZIPS, run
  lengths for RLE, then the predictor and byte interleave undone): single-part scanline files with
  compression NONE, RLE, ZIPS or ZIP (:data:`BUILTIN_STRIP_COMPRESSIONS`), no subsampled channels.

``"auto"`` (default) uses ``"openexr"`` when the bindings offer ``InputFile``, else ``"builtin"`` when
the file is supported, else a whole read when it fits in ``max_bytes``, else a one-line refusal.

``write_exr`` writes float32 (or half) RGB into a temporary file in the target directory and renames
it at the end, so a failure never leaves a partial file. A float32 round trip is bit-exact.

Every problem (missing file, not an EXR, truncated or corrupt file, absurd header, too big to read
whole, no colour channels, bad array) raises :class:`~homofac.errors.HomofacError` with one line
naming the path and the problem.
"""

from __future__ import annotations

import os
import struct
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from ..errors import HomofacError
from .files import DEFAULT_MAX_BYTES, ImageInfo, check_image_size, check_strip, check_whole_read, open_regular, read_head
from .files import one_line as _one_line
from .files import strip_rows as _strip_rows
from .files import write_atomically

#: The four magic bytes every OpenEXR file starts with.
EXR_MAGIC = b"\x76\x2f\x31\x01"

#: Compressions the builtin strip decoder reads (single-part scanline files).
BUILTIN_STRIP_COMPRESSIONS = ("none", "rle", "zips", "zip")

__all__ = [
    "read_exr", "read_exr_with_header", "write_exr", "envmap_kind", "is_exr", "EXR_MAGIC",
    "exr_info", "iter_exr_strips", "BUILTIN_STRIP_COMPRESSIONS",
]

# compression code -> (name, scanlines per chunk), as written by OpenEXR 3.5
_COMPRESSIONS = {
    0: ("none", 1), 1: ("rle", 1), 2: ("zips", 1), 3: ("zip", 16), 4: ("piz", 32), 5: ("pxr24", 16),
    6: ("b44", 32), 7: ("b44a", 32), 8: ("dwaa", 32), 9: ("dwab", 256), 10: ("htj2k256", 256),
    11: ("htj2k32", 32), 12: ("lj2k", 256), 13: ("zstd", 1),
}
_PIXEL_TYPES = {0: ("uint", 4, "<u4"), 1: ("half", 2, "<f2"), 2: ("float", 4, "<f4")}
_ENVMAPS = {0: "latlong", 1: "cube"}
_TILED, _NON_IMAGE, _MULTIPART = 0x200, 0x800, 0x1000  # version-field flags
# the (name, type) of the attributes read; all others are skipped unread
_WANTED = {
    ("channels", "chlist"), ("compression", "compression"), ("dataWindow", "box2i"), ("lineOrder", "lineOrder"),
    ("envmap", "envmap"), ("tiles", "tiledesc"), ("type", "string"), ("chunkCount", "int"),
}
_FIXED_SIZES = {"compression": 1, "dataWindow": 16, "lineOrder": 1, "envmap": 1, "tiles": 9, "chunkCount": 4}


@dataclass
class _Header:
    """The attributes of the first part this module needs, and where the header ends."""

    flags: int = 0
    channels: list = field(default_factory=list)  # (name, pixel type code, x sampling, y sampling)
    compression: int = 0
    window: tuple | None = None  # (xmin, ymin, xmax, ymax) of dataWindow
    line_order: int = 0
    envmap: int | None = None
    tiles: tuple | None = None  # (x size, y size, level mode)
    type: str | None = None
    chunk_count: int | None = None
    end: int = 0  # file offset just past the header (single part: the chunk offset table)
    file_size: int = 0

    @property
    def width(self) -> int:
        return self.window[2] - self.window[0] + 1

    @property
    def height(self) -> int:
        return self.window[3] - self.window[1] + 1

    @property
    def multipart(self) -> bool:
        return bool(self.flags & _MULTIPART)

    @property
    def tiled(self) -> bool:
        return bool(self.flags & _TILED) or (self.type or "").startswith("tiled") or self.type == "deeptile"

    @property
    def deep(self) -> bool:
        return bool(self.flags & _NON_IMAGE) or (self.type or "").startswith("deep")


def is_exr(path: str | os.PathLike) -> bool:
    """True if ``path`` is a readable file that starts with the OpenEXR magic number."""
    try:
        with open_regular(path, "an EXR") as f:
            return f.read(4) == EXR_MAGIC
    except (OSError, HomofacError):
        return False


def _check_file(path: Path) -> None:
    if read_head(path, "an EXR", 4) != EXR_MAGIC:
        raise HomofacError(f"{path}: not an OpenEXR file (bad magic number)")


def _corrupt(path: Path, what: str) -> HomofacError:
    return HomofacError(f"{path}: cannot read EXR (corrupt or truncated?): {what}")


def _read_exact(path: Path, f, n: int, what: str) -> bytes:
    b = f.read(n)
    if len(b) != n:
        raise _corrupt(path, f"truncated {what}")
    return b


def _read_name(path: Path, f, what: str) -> str:
    """A null-terminated attribute / type / channel name (at most 255 bytes)."""
    out = bytearray()
    while True:
        c = f.read(1)
        if not c:
            raise _corrupt(path, f"truncated header ({what})")
        if c == b"\0":
            return out.decode("latin-1")
        out += c
        if len(out) > 255:
            raise _corrupt(path, f"bad header ({what} longer than 255 bytes)")


def _parse_chlist(path: Path, v: bytes) -> list:
    chans = []
    pos = 0
    while True:
        nul = v.find(b"\0", pos)
        if nul < 0:
            raise _corrupt(path, "bad channels attribute (unterminated)")
        name = v[pos:nul].decode("latin-1")
        pos = nul + 1
        if not name:
            return chans
        if pos + 16 > len(v):
            raise _corrupt(path, f"bad channels attribute (channel {name!r} truncated)")
        ptype, _linear, xs, ys = struct.unpack_from("<iB3xii", v, pos)
        pos += 16
        if ptype not in _PIXEL_TYPES:
            raise _corrupt(path, f"channel {name!r} has unknown pixel type {ptype}")
        if xs < 1 or ys < 1:
            raise _corrupt(path, f"channel {name!r} has bad sampling {xs} x {ys}")
        chans.append((name, ptype, xs, ys))


def _parse_header(path: Path) -> _Header:
    """Parse the first part's header of an OpenEXR file (header only; sizes are checked)."""
    hd = _Header()
    try:
        hd.file_size = path.stat().st_size
        with open_regular(path, "an EXR") as f:
            head = _read_exact(path, f, 8, "header")
            if head[:4] != EXR_MAGIC:
                raise HomofacError(f"{path}: not an OpenEXR file (bad magic number)")
            (hd.flags,) = struct.unpack("<I", head[4:])
            if hd.flags & 0xFF != 2:
                raise HomofacError(f"{path}: unsupported OpenEXR version {hd.flags & 0xFF} (only 2)")
            while True:
                name = _read_name(path, f, "attribute name")
                if not name:
                    break
                typ = _read_name(path, f, f"type of attribute {name!r}")
                (size,) = struct.unpack("<i", _read_exact(path, f, 4, f"header (size of {name!r})"))
                if size < 0 or size > hd.file_size - f.tell():
                    raise _corrupt(path, f"attribute {name!r} declares {size} bytes beyond the end of the file")
                if (name, typ) not in _WANTED:
                    f.seek(size, 1)  # skipped unread: previews and other attributes are never allocated
                    continue
                v = _read_exact(path, f, size, f"header (attribute {name!r})")
                if name in _FIXED_SIZES and size != _FIXED_SIZES[name]:
                    raise _corrupt(path, f"attribute {name!r} has size {size}, expected {_FIXED_SIZES[name]}")
                if name == "channels":
                    hd.channels = _parse_chlist(path, v)
                elif name == "compression":
                    hd.compression = v[0]
                elif name == "dataWindow":
                    hd.window = struct.unpack("<iiii", v)
                elif name == "lineOrder":
                    hd.line_order = v[0]
                elif name == "envmap":
                    hd.envmap = v[0]
                elif name == "tiles":
                    xs, ys, mode = struct.unpack("<IIB", v)
                    if xs < 1 or ys < 1 or xs > 1 << 24 or ys > 1 << 24:
                        raise _corrupt(path, f"bad tile size {xs} x {ys}")
                    hd.tiles = (xs, ys, mode & 0x0F)
                elif name == "type":
                    hd.type = v.split(b"\0", 1)[0].decode("latin-1")
                elif name == "chunkCount":
                    (hd.chunk_count,) = struct.unpack("<i", v)
            hd.end = f.tell()
    except OSError as e:
        raise HomofacError(f"{path}: cannot read: {_one_line(e)}") from None
    if hd.window is None:
        raise _corrupt(path, "no dataWindow attribute in the header")
    if not hd.channels:
        raise _corrupt(path, "no channels in the header")
    xmin, ymin, xmax, ymax = hd.window
    check_image_size(path, xmax - xmin + 1, ymax - ymin + 1, sum(_PIXEL_TYPES[c[1]][1] for c in hd.channels) + 12)
    if not (-(1 << 30) <= xmin and -(1 << 30) <= ymin and xmax < 1 << 30 and ymax < 1 << 30):
        raise HomofacError(f"{path}: bad data window {hd.window} in the header (corrupt file?)")
    return hd


def _colour_names(hd: _Header) -> tuple[str, str, str] | None:
    names = {c[0] for c in hd.channels}
    if {"R", "G", "B"} <= names:
        return ("R", "G", "B")
    if "Y" in names:
        return ("Y", "Y", "Y")
    return None


def _info(path: Path, hd: _Header) -> ImageInfo:
    w, h = hd.width, hd.height
    colour = _colour_names(hd)
    used = [c for c in hd.channels if colour is None or c[0] in colour]
    widest = max(used, key=lambda c: (_PIXEL_TYPES[c[1]][1], c[1]))
    stored = sum(_PIXEL_TYPES[c[1]][1] for c in hd.channels)
    block = hd.tiles[1] if hd.tiled and hd.tiles else _COMPRESSIONS.get(hd.compression, ("", 32))[1]
    return ImageInfo(
        path=path, kind="exr", width=w, height=h, channels=tuple(c[0] for c in hd.channels),
        pixel_type=_PIXEL_TYPES[widest[1]][0], bytes_per_channel=_PIXEL_TYPES[widest[1]][1],
        stored_bytes_per_pixel=stored, envmap=_ENVMAPS.get(hd.envmap) if hd.envmap is not None else None,
        compression=_COMPRESSIONS.get(hd.compression, (f"unknown({hd.compression})",))[0], tiled=hd.tiled,
        block_rows=block,
        # OpenEXR decodes every channel of the part, then the float32 RGB result is made
        whole_read_bytes=w * h * (stored + 12),
    )


def exr_info(path: str | os.PathLike) -> ImageInfo:
    """Size, channels, pixel type, compression and ``envmap`` of an OpenEXR file from its header alone.

    No pixel is read. Absurd header values raise a one-line :class:`~homofac.errors.HomofacError`.
    """
    p = Path(path)
    _check_file(p)
    return _info(p, _parse_header(p))


def _chunk_count(hd: _Header) -> int | None:
    """Number of chunks of a single-part file (None when not computable here)."""
    if hd.multipart or hd.deep:
        return None
    if hd.tiled:
        if hd.tiles is None:
            return hd.chunk_count
        xs, ys, mode = hd.tiles
        if mode == 0:  # ONE_LEVEL
            return -(-hd.width // xs) * -(-hd.height // ys)
        return hd.chunk_count
    if hd.compression not in _COMPRESSIONS:
        return hd.chunk_count
    return -(-hd.height // _COMPRESSIONS[hd.compression][1])


def _chunk_offsets(path: Path, hd: _Header) -> np.ndarray | None:
    """The validated chunk offset table of a single-part file (None when not checked here)."""
    n = _chunk_count(hd)
    if n is None:
        return None
    if hd.chunk_count is not None and hd.chunk_count != n:
        raise _corrupt(path, f"chunkCount {hd.chunk_count} in the header, expected {n}")
    end = hd.end + 8 * n
    if end > hd.file_size:
        raise _corrupt(path, f"the offset table of {n} chunks ends beyond the end of the file")
    try:
        with open_regular(path, "an EXR") as f:
            f.seek(hd.end)
            table = np.frombuffer(_read_exact(path, f, 8 * n, "chunk offset table"), "<u8")
    except OSError as e:
        raise HomofacError(f"{path}: cannot read: {_one_line(e)}") from None
    bad = (table < end) | (table > hd.file_size - 8)
    if bad.any():
        k = int(np.argmax(bad))
        raise _corrupt(path, f"chunk {k} of {n} lies outside the file ({int(bad.sum())} such chunks)")
    return table


def _rgb_from_channels(path: Path, channels: dict[str, Any], native: bool = False, alpha: bool = False) -> np.ndarray:
    pix = {name: np.asarray(ch.pixels) for name, ch in channels.items()}
    if alpha:  # RGB and A (an RGBA group's fourth channel, an "A" channel, or 1)
        rgb = _rgb_from_channels(path, channels, native)
        a = pix["RGBA"][..., 3] if "RGBA" in pix and pix["RGBA"].ndim == 3 and pix["RGBA"].shape[2] >= 4 else pix.get("A")
        if a is None or a.shape != rgb.shape[:2]:
            a = np.ones(rgb.shape[:2], rgb.dtype)
        return np.concatenate([rgb, np.asarray(a, rgb.dtype)[..., None]], axis=-1)
    if "RGB" in pix or "RGBA" in pix:
        a = pix["RGB"] if "RGB" in pix else pix["RGBA"]
        if a.ndim != 3 or a.shape[2] < 3:
            raise HomofacError(f"{path}: RGB channel group has unexpected shape {a.shape}")
        planes = None
        src = a[..., :3]
    elif all(c in pix for c in "RGB"):
        planes = [pix["R"], pix["G"], pix["B"]]
    elif "Y" in pix:
        planes = [pix["Y"]] * 3
    else:
        names = ", ".join(sorted(pix)) or "none"
        raise HomofacError(f"{path}: no RGB, RGBA or Y channels (has: {names})")
    if planes is not None:  # fill the result directly: no stacked temporary
        shapes = {q.shape for q in planes}
        if len(shapes) != 1 or planes[0].ndim != 2:
            raise HomofacError(f"{path}: colour channels have different or unexpected shapes {sorted(shapes)}")
        dt = np.result_type(*planes)
        dt = dt if native and dt in (np.float16, np.float32) else np.float32
        if planes[0].shape[0] == 0 or planes[0].shape[1] == 0:
            raise HomofacError(f"{path}: empty image (shape {planes[0].shape + (3,)})")
        rgb = np.empty(planes[0].shape + (3,), dt)
        for i, q in enumerate(planes):
            rgb[..., i] = q
        return rgb
    if src.shape[0] == 0 or src.shape[1] == 0:
        raise HomofacError(f"{path}: empty image (shape {src.shape})")
    if native and src.dtype in (np.float16, np.float32):
        return np.ascontiguousarray(src)
    return np.ascontiguousarray(src, dtype=np.float32)


def read_exr_with_header(
    path: str | os.PathLike, *, native: bool = False, max_bytes: int | None = DEFAULT_MAX_BYTES, alpha: bool = False
) -> tuple[np.ndarray, dict]:
    """``(rgb (H, W, 3) float32, header dict)`` of the first part of an OpenEXR file.

    ``native=True`` keeps half channels as float16 (float32 stays float32; uint becomes float32).
    ``max_bytes`` caps the estimated memory of the read (see :func:`exr_info`); a bigger image is
    refused before any pixel is allocated, with the estimate (``None``: no cap).
    """
    import OpenEXR

    p = Path(path)
    _check_file(p)
    hd = _parse_header(p)
    check_whole_read(_info(p, hd), max_bytes)
    _chunk_offsets(p, hd)
    try:
        f = OpenEXR.File(str(p))
        header = dict(f.header())
        channels = f.channels()
    except HomofacError:
        raise
    except MemoryError:
        raise  # not a corrupt file: the caller reports running out of memory
    except Exception as e:  # OpenEXR raises RuntimeError / ValueError on corrupt or truncated data
        raise HomofacError(f"{p}: cannot read EXR (corrupt or truncated?): {_one_line(e)}") from None
    if not channels:
        raise HomofacError(f"{p}: cannot read EXR pixel data (corrupt or truncated?)")
    return _rgb_from_channels(p, channels, native, alpha), header


def read_exr(path: str | os.PathLike, *, native: bool = False, max_bytes: int | None = DEFAULT_MAX_BYTES,
             alpha: bool = False) -> np.ndarray:
    """RGB pixels of an OpenEXR file as an ``(H, W, 3)`` float32 array (row 0 is the top row); ``alpha=True``:
    ``(H, W, 4)`` RGBA (alpha 1 when the file has none).

    ``native=True`` returns half files as float16 arrays (bit-exact half round trip). An image whose
    whole read would need more than ``max_bytes`` (default 1 GiB; None: no cap) is refused up front.
    """
    return read_exr_with_header(path, native=native, max_bytes=max_bytes, alpha=alpha)[0]


# ------------------------------------------------------------------------------------------ strips


def _strip_support(hd: _Header) -> str | None:
    """Why the builtin decoder cannot read this file (None: it can)."""
    if hd.multipart:
        return "multi-part file"
    if hd.deep:
        return "deep data"
    if hd.tiled:
        return "tiled file"
    name = _COMPRESSIONS.get(hd.compression, (f"unknown({hd.compression})",))[0]
    if name not in BUILTIN_STRIP_COMPRESSIONS:
        return f"{name.upper()} compression"
    if any(c[2] != 1 or c[3] != 1 for c in hd.channels):
        return "subsampled channels"
    return None


def _undo_predictor(raw: bytes) -> np.ndarray:
    """Undo OpenEXR's ZIP/RLE preprocessing: the byte predictor, then the two-halves interleave."""
    t = np.frombuffer(raw, np.uint8).copy()
    t[1:] -= np.uint8(128)
    np.cumsum(t, dtype=np.uint8, out=t)
    out = np.empty_like(t)
    half = (t.shape[0] + 1) // 2
    out[0::2] = t[:half]
    out[1::2] = t[half:]
    return out


def _rle_decode(path: Path, data: bytes, n: int, k: int) -> bytes:
    """OpenEXR's RLE: a signed count byte c; c < 0: -c literal bytes; c >= 0: the next byte c + 1 times."""
    out = bytearray(n)
    o = i = 0
    size = len(data)
    while i < size:
        c = data[i]
        if c > 127:
            cnt = 256 - c
            if i + 1 + cnt > size or o + cnt > n:
                raise _corrupt(path, f"bad RLE data in chunk {k}")
            out[o : o + cnt] = data[i + 1 : i + 1 + cnt]
            i += 1 + cnt
        else:
            cnt = c + 1
            if i + 1 >= size or o + cnt > n:
                raise _corrupt(path, f"bad RLE data in chunk {k}")
            out[o : o + cnt] = data[i + 1 : i + 2] * cnt
            i += 2
        o += cnt
    if o != n:
        raise _corrupt(path, f"bad RLE data in chunk {k} ({o} bytes, expected {n})")
    return bytes(out)


def _builtin_strips(p: Path, hd: _Header, offsets: np.ndarray, rows: int) -> Iterator[tuple[int, np.ndarray]]:
    """Strips decoded here, chunk by chunk through the offset table (see :data:`BUILTIN_STRIP_COMPRESSIONS`)."""
    w, h, ymin = hd.width, hd.height, hd.window[1]
    block = _COMPRESSIONS[hd.compression][1]
    name = _COMPRESSIONS[hd.compression][0]
    layout = {}
    line = 0
    for cname, ptype, _, _ in hd.channels:  # stored in the header's (alphabetical) order, per line
        nb = _PIXEL_TYPES[ptype][1]
        layout[cname] = (line, nb, _PIXEL_TYPES[ptype][2])
        line += w * nb
    colour = _colour_names(hd)

    def chunk(k: int, f) -> np.ndarray:
        nlines = min(block, h - k * block)
        raw_size = nlines * line
        off = int(offsets[k])
        f.seek(off)
        y, size = struct.unpack("<ii", _read_exact(p, f, 8, f"chunk {k}"))
        if y != ymin + k * block:
            raise _corrupt(p, f"chunk {k} is for line {y}, expected {ymin + k * block}")
        if size <= 0 or size > raw_size or off + 8 + size > hd.file_size or (name == "none" and size != raw_size):
            raise _corrupt(p, f"chunk {k} has a bad size {size} (expected at most {raw_size})")
        data = _read_exact(p, f, size, f"chunk {k}")
        if size == raw_size:  # NONE, or compression did not help: stored as is
            buf = np.frombuffer(data, np.uint8)
        else:
            if name == "rle":
                raw = _rle_decode(p, data, raw_size, k)
            else:
                d = zlib.decompressobj()
                try:
                    raw = d.decompress(data, raw_size)
                except zlib.error as e:
                    raise _corrupt(p, f"bad ZIP data in chunk {k}: {_one_line(e)}") from None
                if len(raw) != raw_size or d.unconsumed_tail:
                    raise _corrupt(p, f"bad ZIP data in chunk {k} (decodes to a wrong size)")
            buf = _undo_predictor(raw)
        a = buf.reshape(nlines, line)
        out = np.empty((nlines, w, 3), np.float32)
        for i, c in enumerate(colour):
            start, nb, dt = layout[c]
            out[..., i] = a[:, start : start + w * nb].view(dt)
        return out

    try:
        with open_regular(p, "an EXR") as f:
            last_k, last = -1, None
            for y0 in range(0, h, rows):
                y1 = min(h, y0 + rows)
                strip = np.empty((y1 - y0, w, 3), np.float32)
                for k in range(y0 // block, (y1 - 1) // block + 1):
                    if k != last_k:
                        last_k, last = k, chunk(k, f)
                    a, b = max(y0, k * block), min(y1, (k + 1) * block)
                    strip[a - y0 : b - y0] = last[a - k * block : b - k * block]
                yield y0, strip
    except OSError as e:
        raise HomofacError(f"{p}: cannot read: {_one_line(e)}") from None


def _openexr_strips(p: Path, hd: _Header, rows: int) -> Iterator[tuple[int, np.ndarray]]:
    """Strips through OpenEXR's scanline reader (``InputFile.channels`` over a row range)."""
    import Imath
    import OpenEXR

    w, h, ymin = hd.width, hd.height, hd.window[1]
    colour = _colour_names(hd)
    names = list(dict.fromkeys(colour))
    float_type = Imath.PixelType(Imath.PixelType.FLOAT)
    try:
        f = OpenEXR.InputFile(str(p))
    except MemoryError:
        raise  # not a corrupt file: the caller reports running out of memory
    except Exception as e:
        raise HomofacError(f"{p}: cannot read EXR (corrupt or truncated?): {_one_line(e)}") from None
    try:
        for y0 in range(0, h, rows):
            y1 = min(h, y0 + rows)
            try:
                planes = f.channels(names, float_type, ymin + y0, ymin + y1 - 1)
            except MemoryError:
                raise  # not a corrupt file: the caller reports running out of memory
            except Exception as e:
                raise HomofacError(
                    f"{p}: cannot read EXR (corrupt or truncated?) rows {y0}..{y1 - 1}: {_one_line(e)}"
                ) from None
            strip = np.empty((y1 - y0, w, 3), np.float32)
            for i, c in enumerate(colour):
                plane = np.frombuffer(planes[names.index(c)], np.float32)
                if plane.shape[0] != (y1 - y0) * w:
                    raise HomofacError(f"{p}: cannot read EXR rows {y0}..{y1 - 1}: unexpected channel {c} size")
                strip[..., i] = plane.reshape(y1 - y0, w)
            yield y0, strip
    finally:
        f.close()


def iter_exr_strips(
    path: str | os.PathLike,
    rows: int | None = None,
    *,
    decoder: str = "auto",
    max_bytes: int | None = DEFAULT_MAX_BYTES,
) -> Iterator[tuple[int, np.ndarray]]:
    """Yield ``(y0, strip)`` pairs covering an OpenEXR image top to bottom, in bounded memory.

    ``strip`` is a fresh ``(n, W, 3)`` float32 array of image rows ``y0 .. y0 + n - 1`` (``n = rows``,
    the last strip shorter); colour channels as in :func:`read_exr` (R, G, B, or Y copied to three).
    ``rows`` defaults to about 8 MiB of float32 rows, a multiple of the file's chunk lines. Only a few
    strips are alive at a time. ``decoder``: ``"auto"``, ``"openexr"`` or ``"builtin"`` (module
    docstring). ``max_bytes`` caps the strips' memory and, for ``"auto"`` without a strip decoder, the
    whole read it falls back to. The header and offset table are checked before the first strip.
    """
    p = Path(path)
    _check_file(p)
    hd = _parse_header(p)
    info = _info(p, hd)
    if _colour_names(hd) is None:
        raise HomofacError(f"{p}: no RGB, RGBA or Y channels (has: {', '.join(sorted(info.channels)) or 'none'})")
    rows = _strip_rows(info) if rows is None else int(rows)
    if rows < 1:
        raise HomofacError(f"{p}: strip rows must be >= 1, got {rows}")
    check_strip(info, rows, max_bytes)
    if decoder not in ("auto", "openexr", "builtin"):
        raise HomofacError(f"{p}: unknown EXR strip decoder {decoder!r} (auto, openexr, builtin)")
    why = _strip_support(hd)
    offsets = _chunk_offsets(p, hd)  # before the first strip: a file declaring more than it holds fails here
    if decoder == "auto":
        import OpenEXR

        decoder = "openexr" if hasattr(OpenEXR, "InputFile") else "builtin" if why is None else "whole"
    if decoder == "openexr":
        if hd.deep:
            raise HomofacError(f"{p}: cannot read EXR in strips: deep data")
        if any(c[2] != 1 or c[3] != 1 for c in hd.channels if c[0] in _colour_names(hd)):
            raise HomofacError(f"{p}: cannot read EXR in strips: subsampled colour channels")
        return _openexr_strips(p, hd, rows)
    if decoder == "builtin":
        if why is not None:
            raise HomofacError(
                f"{p}: cannot read EXR in strips without OpenEXR's scanline reader: {why} (the builtin decoder "
                f"reads single-part scanline files with {', '.join(c.upper() for c in BUILTIN_STRIP_COMPRESSIONS)} compression)"
            )
        return _builtin_strips(p, hd, offsets, rows)
    # no strip decoder for this file: a whole read, if it fits
    if max_bytes is not None and info.whole_read_bytes > max_bytes:
        raise HomofacError(
            f"{p}: cannot read EXR in strips ({why}; this OpenEXR has no scanline reader) and {info.width} x "
            f"{info.height} pixels are too big to read whole (see read_exr's max_bytes)"
        )
    rgb = read_exr(p, max_bytes=max_bytes)
    return ((y0, rgb[y0 : y0 + rows].copy()) for y0 in range(0, rgb.shape[0], rows))


# ------------------------------------------------------------------------------------------- write


def envmap_kind(header: dict) -> str | None:
    """``"latlong"``, ``"cube"`` or None from an EXR header's ``envmap`` attribute."""
    import OpenEXR

    v = header.get("envmap")
    if v is None:
        return None
    if v == OpenEXR.ENVMAP_CUBE or "CUBE" in str(v).upper():
        return "cube"
    if v == OpenEXR.ENVMAP_LATLONG or "LATLONG" in str(v).upper():
        return "latlong"
    return None


def write_exr(
    path: str | os.PathLike,
    rgb,
    *,
    half: bool = False,
    header: dict | None = None,
    compression: str | None = None,
    alpha: bool = False,
) -> Path:
    """Write an ``(H, W, 3)`` (or ``(H, W)`` grey) image as an RGB OpenEXR file; returns the path.
    ``alpha=True`` and an ``(H, W, 4)`` image: an RGBA file (else a fourth channel is dropped).

    float32 by default (bit-exact round trip), half precision with ``half=True``. ``header`` adds or
    overrides attributes (e.g. ``{"envmap": OpenEXR.ENVMAP_CUBE}``); ``compression`` is a name such
    as ``"zip"``, ``"piz"``, ``"none"`` (default ZIP). The file is written to a temporary name in the
    same directory and renamed, so a failure leaves no partial file.
    """
    import OpenEXR

    p = Path(path)
    a = np.asarray(rgb)
    if a.ndim == 2:
        a = np.repeat(a[..., None], 3, axis=-1)
    if a.ndim != 3 or a.shape[2] not in (3, 4) or a.shape[0] == 0 or a.shape[1] == 0:
        raise HomofacError(f"{p}: cannot write EXR: expected an (H, W, 3) image, got shape {a.shape}")
    keep = 4 if alpha and a.shape[2] == 4 else 3
    a = np.ascontiguousarray(a[..., :keep], dtype=np.float16 if half else np.float32)
    hdr: dict = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    if compression is not None:
        name = compression.upper().removesuffix("_COMPRESSION")
        name = ("NO" if name == "NONE" else name) + "_COMPRESSION"  # the documented "none" is OpenEXR's NO_
        if not hasattr(OpenEXR, name):
            raise HomofacError(f"{p}: unknown EXR compression {compression!r}")
        hdr["compression"] = getattr(OpenEXR, name)
    if header:
        hdr.update(header)
    group = "RGBA" if keep == 4 else "RGB"
    return write_atomically(p, "EXR", lambda tmp: OpenEXR.File(hdr, {group: a}).write(tmp), suffix=".tmp.exr")
