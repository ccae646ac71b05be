"""KTX 2.0 textures (Khronos KTX 2.0 specification): a small writer and reader of uncompressed float data.

Formats: ``half`` = ``VK_FORMAT_R16G16B16A16_SFLOAT`` (97) and ``float`` = ``VK_FORMAT_R32G32B32A32_SFLOAT``
(109), the two float formats three.js' ``KTX2Loader`` uploads (it has no three-channel float format, so RGB
data gets an alpha of 1). Kinds: ``2d`` (levels shaped (H, W, C)), ``array`` (a 2D array, (L, H, W, C)),
``3d`` ((D, H, W, C)) and ``cube`` ((6, S, S, C), faces +X, -X, +Y, -Y, +Z, -Z, each face's first row the
top one as Vulkan/OpenGL read it, i.e. homofac's ``cube`` mapper face for face). Each level halves every
dimension (``max(1, n >> level)``); any number of levels, level 0 the largest.

The file, as the spec lays it out (section 3): the 12-byte identifier, the header (``vkFormat``,
``typeSize``, ``pixelWidth/Height/Depth``, ``layerCount``, ``faceCount``, ``levelCount``,
``supercompressionScheme`` = 0), the index (DFD, key/value data, supercompression global data), the level
index (offset, length, uncompressed length per level), the Data Format Descriptor (one basic block,
colour model RGBSDA, BT.709 primaries, linear transfer, straight alpha; one sample per channel: float and
signed, bounds -1.0 / 1.0 as for every float format), the key/value data (sorted by key, each entry padded
to 4 bytes), and the level data from the smallest level to the largest, each aligned to
``lcm(texel size, 4)``; within a level: layers, faces, depth slices, rows, pixels.

Keys written: ``KTXorientation`` (``rd``; ``rdi`` for 3D), ``KTXwriter`` (homofac and its version), and
whatever the caller adds (homofac writes ``homofac``: a JSON string naming the layout; :func:`write_ktx2`'s
``layout=`` writes it with the container's kind, format and level count). :func:`mip_chain` makes the smaller
levels of a level 0 by 2 x 2 (x 2) box averages. Writes are atomic
(:func:`homofac.io.files.write_atomically`); reads check every offset against the file size and refuse
what they do not support (supercompression, other formats) with a one-line error naming the file.
"""

from __future__ import annotations

import json
import math
import os
import struct
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .._version import __version__
from ..errors import HomofacError
from .files import check_image_size, read_head, write_atomically

IDENTIFIER = b"\xabKTX 20\xbb\r\n\x1a\n"

#: format name -> (vkFormat, numpy dtype of one channel)
FORMATS: dict[str, tuple[int, str]] = {"half": (97, "<f2"), "float": (109, "<f4")}
_BY_VK = {vk: (name, dt) for name, (vk, dt) in FORMATS.items()}

KINDS = ("2d", "array", "3d", "cube")

# Data Format Descriptor constants (Khronos Data Format Specification 1.3, section 5)
_KHR_DF_MODEL_RGBSDA = 1
_KHR_DF_PRIMARIES_BT709 = 1
_KHR_DF_TRANSFER_LINEAR = 1
_KHR_DF_SAMPLE_FLOAT_SIGNED = 0x80 | 0x40
_CHANNEL_IDS = (0, 1, 2, 15)  # R, G, B, A
_FLOAT_ONE, _FLOAT_MINUS_ONE = 0x3F800000, 0xBF800000


@dataclass(frozen=True)
class Ktx2Image:
    """A KTX2 file's content.

    Attributes:
        kind: ``2d``, ``array``, ``3d`` or ``cube``.
        format: ``half`` or ``float``.
        levels: float32 arrays, level 0 first, shaped as the kind says (module docstring), 4 channels.
        key_values: the key/value data (bytes; a trailing NUL of a string value is kept).
        vk_format, width, height, depth, layers, faces: the header's fields.
    """

    kind: str
    format: str
    levels: tuple[np.ndarray, ...]
    key_values: dict[str, bytes] = field(default_factory=dict)
    vk_format: int = 0
    width: int = 0
    height: int = 0
    depth: int = 0
    layers: int = 0
    faces: int = 1

    def text(self, key: str) -> str | None:
        """A key's value as a string (UTF-8, the trailing NUL dropped), None when absent."""
        v = self.key_values.get(key)
        return None if v is None else v.rstrip(b"\0").decode("utf-8", "replace")


def _dims(kind: str, a: np.ndarray) -> tuple[int, int, int, int, int]:
    """``(width, height, depth, layers, faces)`` of one level array of ``kind``."""
    if kind == "2d":
        return a.shape[1], a.shape[0], 0, 0, 1
    if kind == "array":
        return a.shape[2], a.shape[1], 0, a.shape[0], 1
    if kind == "3d":
        return a.shape[2], a.shape[1], a.shape[0], 0, 1
    return a.shape[2], a.shape[1], 0, 0, 6


def _level_shape(kind: str, w: int, h: int, d: int, layers: int, level: int) -> tuple[int, ...]:
    """Array shape (without channels) of ``level`` of a texture of level-0 size ``w, h, d``."""
    lw, lh, ld = max(1, w >> level), max(1, h >> level), max(1, d >> level)
    return {"2d": (lh, lw), "array": (layers, lh, lw), "3d": (ld, lh, lw), "cube": (6, lh, lw)}[kind]


def _dfd(vk_format: int, channel_bytes: int) -> bytes:
    """The Data Format Descriptor of an RGBA float format (one basic descriptor block, 4 samples)."""
    texel = 4 * channel_bytes
    samples = b"".join(
        struct.pack("<HBBBBBBII", i * 8 * channel_bytes, 8 * channel_bytes - 1, _KHR_DF_SAMPLE_FLOAT_SIGNED | cid,
                    0, 0, 0, 0, _FLOAT_MINUS_ONE, _FLOAT_ONE)
        for i, cid in enumerate(_CHANNEL_IDS))
    block_size = 24 + len(samples)
    block = struct.pack("<IHHBBBBBBBB8B", 0, 2, block_size, _KHR_DF_MODEL_RGBSDA, _KHR_DF_PRIMARIES_BT709,
                        _KHR_DF_TRANSFER_LINEAR, 0, 0, 0, 0, 0, texel, 0, 0, 0, 0, 0, 0, 0) + samples
    return struct.pack("<I", 4 + len(block)) + block


def _kvd(keys: dict[str, bytes]) -> bytes:
    """Key/value data: entries sorted by key (byte order), each ``length, key NUL value`` padded to 4 bytes."""
    out = b""
    for k in sorted(keys, key=lambda s: s.encode("utf-8")):
        kv = k.encode("utf-8") + b"\0" + keys[k]
        out += struct.pack("<I", len(kv)) + kv + b"\0" * (-len(kv) % 4)
    return out


def _as_bytes(v: str | bytes) -> bytes:
    return v if isinstance(v, bytes) else v.encode("utf-8") + b"\0"


def encode_ktx2(levels, kind: str = "2d", format: str = "half", keys: dict[str, str | bytes] | None = None) -> bytes:
    """The bytes of a KTX2 file holding ``levels`` (see the module docstring for shapes and layout).

    ``levels``: one array or a list of arrays (level 0 first), float, 3 or 4 channels (RGB gets alpha 1).
    ``keys``: extra key/value entries (str values are written as UTF-8 with a trailing NUL).
    """
    if kind not in KINDS:
        raise HomofacError(f"KTX2: kind must be one of {', '.join(KINDS)}, got {kind!r}")
    if format not in FORMATS:
        raise HomofacError(f"KTX2: format must be one of {', '.join(FORMATS)}, got {format!r}")
    if isinstance(levels, np.ndarray) or not isinstance(levels, (list, tuple)):
        levels = [levels]
    arrs = [np.asarray(a, np.float32) for a in levels]
    if not arrs:
        raise HomofacError("KTX2: no level to write")
    ndim = 3 if kind == "2d" else 4
    a0 = arrs[0]
    if a0.ndim != ndim or a0.shape[-1] not in (3, 4):
        raise HomofacError(f"KTX2: a {kind} level must be shaped {'(H, W, C)' if ndim == 3 else '(N, H, W, C)'} "
                           f"with C = 3 or 4, got {a0.shape}")
    w, h, d, layers, faces = _dims(kind, a0)
    if kind == "cube" and (a0.shape[0] != 6 or w != h):
        raise HomofacError(f"KTX2: a cube level must be shaped (6, S, S, C), got {a0.shape}")
    check_image_size("KTX2", w, h * max(d, 1) * max(layers, 1) * faces, 16)
    vk, dt = FORMATS[format]
    cb = np.dtype(dt).itemsize
    texel = 4 * cb
    align = math.lcm(texel, 4)
    blobs = []
    for i, a in enumerate(arrs):
        want = _level_shape(kind, w, h, d, layers, i)
        if a.shape[:-1] != want or a.shape[-1] != a0.shape[-1]:
            raise HomofacError(f"KTX2: level {i} must be shaped {want + (a0.shape[-1],)}, got {a.shape}")
        if a.shape[-1] == 3:
            a = np.concatenate([a, np.ones(a.shape[:-1] + (1,), np.float32)], axis=-1)
        if not np.all(np.isfinite(a)):
            raise HomofacError(f"KTX2: level {i} holds NaN or infinite values")
        if format == "half" and np.abs(a).max(initial=0.0) > 65504.0:
            raise HomofacError(f"KTX2: level {i} exceeds the half-float range (|x| <= 65504); write format 'float'")
        blobs.append(np.ascontiguousarray(a.astype(dt)).tobytes())
    kv = {"KTXorientation": _as_bytes("rdi" if kind == "3d" else "rd"),
          "KTXwriter": _as_bytes(f"homofac {__version__}")}
    kv.update({k: _as_bytes(v) for k, v in (keys or {}).items()})
    dfd, kvd = _dfd(vk, cb), _kvd(kv)
    n = len(blobs)
    head = 12 + 9 * 4 + 4 * 4 + 2 * 8
    dfd_off = head + n * 24
    kvd_off = dfd_off + len(dfd)
    pos = kvd_off + len(kvd)
    offsets = [0] * n
    for i in reversed(range(n)):  # smallest level first in the file
        pos += -pos % align
        offsets[i] = pos
        pos += len(blobs[i])
    header = IDENTIFIER + struct.pack("<9I", vk, cb, w, h, d, layers, faces, n, 0)
    header += struct.pack("<4I2Q", dfd_off, len(dfd), kvd_off, len(kvd), 0, 0)
    header += b"".join(struct.pack("<3Q", offsets[i], len(blobs[i]), len(blobs[i])) for i in range(n))
    out = bytearray(pos)
    body = header + dfd + kvd
    out[:len(body)] = body
    for off, b in zip(offsets, blobs):
        out[off:off + len(b)] = b
    return bytes(out)


def mip_chain(level0, kind: str = "2d", count: int | None = None) -> list[np.ndarray]:
    """``level0`` and its ``count - 1`` smaller levels (default: down to 1 x 1), each the 2 x 2 box average of
    the one before (2 x 2 x 2 for ``3d``; per layer for ``array``, per face for ``cube``: layers and faces are
    never mixed). Sizes follow the KTX2 rule ``max(1, n >> level)``; an odd size averages its first 2 floor(n/2)
    texels (and a size of 1 is kept as it is). ``level0`` shaped as :func:`encode_ktx2` says."""
    if kind not in KINDS:
        raise HomofacError(f"KTX2: kind must be one of {', '.join(KINDS)}, got {kind!r}")
    a = np.asarray(level0, np.float32)
    spatial = {"2d": (0, 1), "array": (1, 2), "cube": (1, 2), "3d": (0, 1, 2)}[kind]
    if a.ndim != (3 if kind == "2d" else 4):
        raise HomofacError(f"KTX2: a {kind} level must be {'(H, W, C)' if kind == '2d' else '(N, H, W, C)'}, got {a.shape}")
    most = 1 + int(math.floor(math.log2(max(a.shape[i] for i in spatial))))
    count = most if count is None else int(count)
    if not 1 <= count <= most:
        raise HomofacError(f"KTX2: {count} levels asked; a {kind} level of shape {a.shape[:-1]} has 1 ... {most}")
    out = [a]
    for _ in range(count - 1):
        for axis in spatial:
            n = a.shape[axis]
            if n > 1:
                a = np.moveaxis(a, axis, 0)
                a = 0.5 * (a[0:2 * (n // 2):2] + a[1:2 * (n // 2):2])
                a = np.moveaxis(a, 0, axis)
        out.append(np.ascontiguousarray(a))
    return out


def write_ktx2(path: str | os.PathLike, levels, kind: str = "2d", format: str = "half",
               keys: dict[str, str | bytes] | None = None, *, mips: int | None = 1, layout: dict | None = None) -> Path:
    """Write ``levels`` as a KTX2 file at ``path``, atomically (see :func:`encode_ktx2`); returns the path.

    ``levels``: the level arrays (level 0 first), or one array: with ``mips`` > 1 (``None``: the full chain) the
    smaller levels are then made by :func:`mip_chain`. ``kind``: ``2d`` (H, W, C), ``array`` (layers, H, W, C),
    ``3d`` (depth, H, W, C) or ``cube`` (6, S, S, C). ``format``: ``half`` or ``float``. ``layout``: a JSON-able
    dict written as the key ``homofac`` with ``ktx2: {kind, format, levels}`` added, so that a reader knows
    what the file's axes mean (e.g. ``{"texture": "P0", "axes": "layer = roughness layer j"}``).

    Example (a 2D array of roughness layers with its mip chain)::

        write_ktx2("P0.ktx2", layers, "array", "half", mips=None, layout={"texture": "P0", "layer": "roughness"})
    """
    single = isinstance(levels, np.ndarray) or not isinstance(levels, (list, tuple))
    if single and mips != 1:
        levels = mip_chain(levels, kind, mips)
    elif not single and mips not in (1, None, len(levels)):
        raise HomofacError("KTX2: pass one level 0 array to make mips, or the whole list of levels")
    keys = dict(keys or {})
    if layout is not None:
        count = 1 if single and mips == 1 else len(levels)
        keys["homofac"] = json.dumps({**layout, "ktx2": {"kind": kind, "format": format, "levels": count,
                                                         "mip_filter": "2x2 box" if count > 1 else None}})
    data = encode_ktx2(levels, kind, format, keys)
    return write_atomically(path, "KTX2", lambda tmp: Path(tmp).write_bytes(data), suffix=".tmp.ktx2")


def decode_ktx2(data: bytes, name: str = "KTX2") -> Ktx2Image:
    """Parse KTX2 bytes (uncompressed RGBA half or float, no supercompression) into a :class:`Ktx2Image`."""
    def bad(msg: str) -> HomofacError:
        return HomofacError(f"{name}: {msg}")

    if len(data) < 80 or data[:12] != IDENTIFIER:
        raise bad("not a KTX2 file (bad identifier)")
    vk, cb, w, h, d, layers, faces, n, sc = struct.unpack_from("<9I", data, 12)
    dfd_off, dfd_len, kvd_off, kvd_len, sgd_off, sgd_len = struct.unpack_from("<4I2Q", data, 48)
    if sc != 0:
        raise bad(f"supercompression scheme {sc} is not supported (only 0, none)")
    if vk not in _BY_VK:
        raise bad(f"vkFormat {vk} is not supported (only {', '.join(f'{v} ({k})' for k, (v, _) in FORMATS.items())})")
    fmt, dt = _BY_VK[vk]
    if cb != np.dtype(dt).itemsize:
        raise bad(f"typeSize {cb} does not match vkFormat {vk}")
    if faces not in (1, 6) or (faces == 6 and (d or w != h)) or (d and layers):
        raise bad(f"unsupported layout: faces {faces}, depth {d}, layers {layers}")
    kind = "cube" if faces == 6 else ("3d" if d else ("array" if layers else "2d"))
    if kind == "cube" and layers:
        raise bad("cube-map arrays are not supported")
    check_image_size(name, w, max(h, 1) * max(d, 1) * max(layers, 1) * faces, 16)
    n = max(n, 1)
    if 80 + 24 * n > len(data) or kvd_off + kvd_len > len(data) or dfd_off + dfd_len > len(data):
        raise bad("truncated file (index beyond the end)")
    kv: dict[str, bytes] = {}
    p, end = kvd_off, kvd_off + kvd_len
    while p + 4 <= end:
        (ln,) = struct.unpack_from("<I", data, p)
        entry = data[p + 4:p + 4 + ln]
        if len(entry) != ln or b"\0" not in entry:
            raise bad("corrupt key/value data")
        k, v = entry.split(b"\0", 1)
        kv[k.decode("utf-8", "replace")] = v
        p += 4 + ln + (-ln % 4)
    levels = []
    for i in range(n):
        off, ln, _ = struct.unpack_from("<3Q", data, 80 + 24 * i)
        shape = _level_shape(kind, w, h, d, layers, i) + (4,)
        want = int(np.prod(shape)) * cb
        if ln != want or off + ln > len(data):
            raise bad(f"level {i}: {ln} bytes at {off}, expected {want} within the file of {len(data)} bytes")
        levels.append(np.frombuffer(data, dt, count=int(np.prod(shape)), offset=off).reshape(shape).astype(np.float32))
    return Ktx2Image(kind, fmt, tuple(levels), kv, vk, w, h, d, layers, faces)


def read_ktx2(path: str | os.PathLike) -> Ktx2Image:
    """Read a KTX2 file written by :func:`write_ktx2` or another tool (RGBA half/float, uncompressed)."""
    read_head(path, "a KTX2", 12)
    return decode_ktx2(Path(path).read_bytes(), str(path))


__all__ = ["FORMATS", "IDENTIFIER", "KINDS", "Ktx2Image", "decode_ktx2", "encode_ktx2", "mip_chain", "read_ktx2", "write_ktx2"]
