"""Big images in bounded memory: a header-only probe, a memory cap on whole reads, strip reads.

Nothing on disk is trusted ("a 0.8 MB EXR may declare 8192 x 16384 pixels"):

- :func:`image_info` reads only the header of an OpenEXR or Radiance HDR file and returns an
  :class:`~homofac.io.files.ImageInfo` (size, channels, pixel type, compression, EXR ``envmap``, and
  ``whole_read_bytes``, the estimated memory of a whole read). Absurd header values (zero or negative
  sizes, more than :data:`MAX_PIXELS` pixels) raise a one-line :class:`~homofac.errors.HomofacError`.
- ``read_exr`` / ``read_hdr`` refuse a whole read, before any pixel is allocated, when that estimate
  exceeds their ``max_bytes`` (default :data:`DEFAULT_MAX_BYTES` = 1 GiB: an 8192 x 4096 half EXR,
  0.6 GiB, is read; a 16384 x 8192 one, 2.3 GiB, is refused with the estimate).
- :func:`iter_strips` yields the image as float32 strips of full-width rows and :func:`read_downsampled`
  box-averages it by an integer factor strip by strip, so a 16K map is read holding only a few strips
  (about 8 MiB each) and the small result. Weighting rows (e.g. by solid angle for a lat-long map)
  is the caller's business: iterate the strips. EXR strips use OpenEXR's scanline reader (every
  compression, tiled files) or, without it, a builtin decoder for scanline NONE / RLE / ZIPS / ZIP
  files (:mod:`homofac.io.exr`); HDR scanlines are decoded sequentially (:mod:`homofac.io.hdr`).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Iterator

import numpy as np

from ..errors import HomofacError
from .exr import EXR_MAGIC, exr_info, iter_exr_strips
from .files import DEFAULT_MAX_BYTES, MAX_PIXELS, STRIP_BYTES, ImageInfo, format_bytes, read_head, strip_rows
from .hdr import hdr_info, iter_hdr_strips

__all__ = [
    "ImageInfo", "DEFAULT_MAX_BYTES", "MAX_PIXELS", "STRIP_BYTES", "image_info", "iter_strips",
    "read_downsampled", "box_downsample", "strip_rows", "format_bytes",
]


def _kind(path: Path) -> str:
    magic = read_head(path, "an image", 4)
    if magic == EXR_MAGIC:
        return "exr"
    if magic.startswith(b"#?"):
        return "hdr"
    raise HomofacError(f"{path}: not an OpenEXR or Radiance HDR file")


def image_info(path: str | os.PathLike) -> ImageInfo:
    """The header of an OpenEXR or Radiance HDR file (chosen by its magic bytes), no pixel read."""
    p = Path(path)
    return exr_info(p) if _kind(p) == "exr" else hdr_info(p)


def iter_strips(
    path: str | os.PathLike, rows: int | None = None, *, max_bytes: int | None = DEFAULT_MAX_BYTES
) -> Iterator[tuple[int, np.ndarray]]:
    """``(y0, strip)`` pairs covering an EXR or HDR image: ``strip`` is ``(n, W, 3)`` float32, image rows
    ``y0 .. y0 + n - 1``.

    Strips hold ``rows`` rows (default :func:`strip_rows`, about 8 MiB; the last one shorter) and
    come in file order (top to bottom, except ``+Y`` HDR files: bottom to top), so place them by
    ``y0``. Header problems are raised by this call, before the first strip.
    """
    p = Path(path)
    if _kind(p) == "exr":
        return iter_exr_strips(p, rows, max_bytes=max_bytes)
    return iter_hdr_strips(p, rows, max_bytes=max_bytes)


def box_downsample(a, factor: int) -> np.ndarray:
    """Plain ``factor x factor`` box average of an ``(H, W, C)`` array whose H and W divide by ``factor``.

    Summed in float64, returned as float32 (the same arithmetic :func:`read_downsampled` applies per strip).
    """
    a = np.asarray(a)
    f = int(factor)
    h, w = a.shape[:2]
    if f < 1 or h % f or w % f:
        raise HomofacError(f"box_downsample: {w} x {h} pixels do not divide by the factor {factor}")
    if f == 1:
        return np.asarray(a, np.float32).copy()
    return a.reshape(h // f, f, w // f, f, *a.shape[2:]).mean(axis=(1, 3), dtype=np.float64).astype(np.float32)


def read_downsampled(
    path: str | os.PathLike, factor: int, *, rows: int | None = None, max_bytes: int | None = DEFAULT_MAX_BYTES
) -> np.ndarray:
    """An EXR or HDR image box-averaged by ``factor``: ``(H / factor, W / factor, 3)`` float32.

    The file is decoded in strips of ``rows`` full-resolution rows (a multiple of ``factor``; default
    about 8 MiB), each averaged at once, so the memory is a few strips plus the result however big
    the image. Each output pixel is the plain mean of its ``factor x factor`` block (no solid-angle
    weighting). W and H must divide by ``factor``; the result must fit in ``max_bytes``.
    """
    p = Path(path)
    info = image_info(p)
    try:
        f = int(factor)
    except (TypeError, ValueError):
        raise HomofacError(f"{p}: downsampling factor must be an integer >= 1, got {factor!r}") from None
    if f < 1 or f != factor:
        raise HomofacError(f"{p}: downsampling factor must be an integer >= 1, got {factor!r}")
    if info.width % f or info.height % f:
        raise HomofacError(
            f"{p}: {info.width} x {info.height} pixels do not divide by the downsampling factor {f}"
        )
    rows = strip_rows(info, f) if rows is None else int(rows)
    if rows < 1 or rows % f:
        raise HomofacError(f"{p}: strip rows must be a positive multiple of the factor {f}, got {rows}")
    hs, ws = info.height // f, info.width // f
    if max_bytes is not None and hs * ws * 12 > max_bytes:
        raise HomofacError(
            f"{p}: the {ws} x {hs} result needs {format_bytes(hs * ws * 12)}; limit {format_bytes(max_bytes)}"
        )
    out = np.empty((hs, ws, 3), np.float32)
    seen = np.zeros(hs, bool)
    for y0, strip in iter_strips(p, rows, max_bytes=max_bytes):
        n = strip.shape[0]
        if y0 % f or n % f or strip.shape[1] != info.width:
            raise HomofacError(f"{p}: internal error: strip at row {y0} of {n} rows is not aligned to the factor {f}")
        out[y0 // f : (y0 + n) // f] = box_downsample(strip, f)
        seen[y0 // f : (y0 + n) // f] = True
    if not seen.all():
        raise HomofacError(f"{p}: internal error: rows missing after the strip read")
    return out
