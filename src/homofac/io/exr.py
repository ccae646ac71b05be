"""OpenEXR read and write (OpenEXR 3.x python bindings), RGB float32.

``read_exr`` returns an ``(H, W, 3)`` float32 array whatever the file stores: an interleaved
``"RGB"``/``"RGBA"`` group, separate ``"R"``, ``"G"``, ``"B"`` channels, or a single grey ``"Y"``
channel (copied to the three channels). Half and uint channels are converted to float32
(``native=True`` keeps half pixels as float16, for a bit-exact half round trip).
``read_exr_with_header`` also returns the header dict, e.g. to read the ``envmap`` attribute
(``OpenEXR.ENVMAP_LATLONG`` or ``OpenEXR.ENVMAP_CUBE``); :func:`envmap_kind` turns it into a string.

``write_exr`` writes float32 (or half) RGB into a temporary file in the target directory and renames
it at the end, so a failure never leaves a partial file. A float32 round trip is bit-exact.

Every problem (missing file, not an EXR, truncated or corrupt file, no colour channels, bad array)
raises :class:`~homofac.errors.HomofacError` with one line naming the path and the problem.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import HomofacError
from .files import one_line as _one_line
from .files import read_head, write_atomically

#: The four magic bytes every OpenEXR file starts with.
EXR_MAGIC = b"\x76\x2f\x31\x01"

__all__ = ["read_exr", "read_exr_with_header", "write_exr", "envmap_kind", "is_exr", "EXR_MAGIC"]




def is_exr(path: str | os.PathLike) -> bool:
    """True if ``path`` is a readable file that starts with the OpenEXR magic number."""
    try:
        with open(path, "rb") as f:
            return f.read(4) == EXR_MAGIC
    except OSError:
        return False


def _check_file(path: Path) -> None:
    if read_head(path, "an EXR", 4) != EXR_MAGIC:
        raise HomofacError(f"{path}: not an OpenEXR file (bad magic number)")


def _rgb_from_channels(path: Path, channels: dict[str, Any], native: bool = False) -> np.ndarray:
    pix = {name: np.asarray(ch.pixels) for name, ch in channels.items()}
    if "RGB" in pix or "RGBA" in pix:
        a = pix["RGB"] if "RGB" in pix else pix["RGBA"]
        if a.ndim != 3 or a.shape[2] < 3:
            raise HomofacError(f"{path}: RGB channel group has unexpected shape {a.shape}")
        rgb = a[..., :3]
    elif all(c in pix for c in "RGB"):
        rgb = np.stack([pix["R"], pix["G"], pix["B"]], axis=-1)
    elif "Y" in pix:
        y = pix["Y"]
        rgb = np.repeat(y[..., None], 3, axis=-1)
    else:
        names = ", ".join(sorted(pix)) or "none"
        raise HomofacError(f"{path}: no RGB, RGBA or Y channels (has: {names})")
    if rgb.ndim != 3 or rgb.shape[0] == 0 or rgb.shape[1] == 0:
        raise HomofacError(f"{path}: empty image (shape {rgb.shape})")
    if native and rgb.dtype in (np.float16, np.float32):
        return np.ascontiguousarray(rgb)
    return np.ascontiguousarray(rgb, dtype=np.float32)


def read_exr_with_header(path: str | os.PathLike, *, native: bool = False) -> tuple[np.ndarray, dict]:
    """``(rgb (H, W, 3) float32, header dict)`` of the first part of an OpenEXR file.

    ``native=True`` keeps half channels as float16 (float32 stays float32; uint becomes float32).
    """
    import OpenEXR

    p = Path(path)
    _check_file(p)
    try:
        f = OpenEXR.File(str(p))
        header = dict(f.header())
        channels = f.channels()
    except HomofacError:
        raise
    except Exception as e:  # OpenEXR raises RuntimeError / ValueError on corrupt or truncated data
        raise HomofacError(f"{p}: cannot read EXR (corrupt or truncated?): {_one_line(e)}") from None
    if not channels:
        raise HomofacError(f"{p}: cannot read EXR pixel data (corrupt or truncated?)")
    return _rgb_from_channels(p, channels, native), header


def read_exr(path: str | os.PathLike, *, native: bool = False) -> np.ndarray:
    """RGB pixels of an OpenEXR file as an ``(H, W, 3)`` float32 array (row 0 is the top row).

    ``native=True`` returns half files as float16 arrays (bit-exact half round trip).
    """
    return read_exr_with_header(path, native=native)[0]


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
) -> Path:
    """Write an ``(H, W, 3)`` (or ``(H, W)`` grey) image as an RGB OpenEXR file; returns the path.

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
    a = np.ascontiguousarray(a[..., :3], dtype=np.float16 if half else np.float32)
    hdr: dict = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    if compression is not None:
        name = compression.upper().removesuffix("_COMPRESSION") + "_COMPRESSION"
        if not hasattr(OpenEXR, name):
            raise HomofacError(f"{p}: unknown EXR compression {compression!r}")
        hdr["compression"] = getattr(OpenEXR, name)
    if header:
        hdr.update(header)
    return write_atomically(p, "EXR", lambda tmp: OpenEXR.File(hdr, {"RGB": a}).write(tmp), suffix=".tmp.exr")
