"""8-bit RGBA PNG textures (pillow), the files of the thesis' alpha precision trick (§4.3.2).

``write_png`` stores an ``(H, W, 4)`` uint8 array (row 0 is the top row, as in the float textures)
through a temporary file in the target directory that is renamed at the end, so a failure never leaves
a partial file. The values are *linear* codes (``value = code / 255``, no sRGB transfer); optional text
chunks (``text``) can carry a short description. ``read_png`` returns the uint8 RGBA array again (an RGB
or grey PNG gets an opaque alpha). A round trip is exact.

Every problem (missing file, not a PNG, truncated or corrupt data, wrong array) raises
:class:`~homofac.errors.HomofacError` with one line naming the path and the problem.
"""

from __future__ import annotations

import os
import warnings
from pathlib import Path

import numpy as np
from jaxtyping import UInt8

from ..errors import HomofacError
from .files import one_line as _one_line
from .files import read_head, write_atomically

__all__ = ["read_png", "write_png", "PNG_MAGIC"]

#: The eight bytes every PNG file starts with.
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"




def write_png(path: str | os.PathLike, rgba: UInt8[np.ndarray, "H W 4"], *, text: dict | None = None) -> Path:
    """Write an ``(H, W, 4)`` uint8 array as an 8-bit RGBA PNG (atomically); returns the path."""
    from PIL import Image, PngImagePlugin

    p = Path(path)
    a = np.asarray(rgba)
    if a.dtype != np.uint8 or a.ndim != 3 or a.shape[2] != 4 or a.shape[0] == 0 or a.shape[1] == 0:
        raise HomofacError(f"{p}: cannot write PNG: expected an (H, W, 4) uint8 array, got {a.dtype} {a.shape}")
    info = PngImagePlugin.PngInfo()
    for k, v in (text or {}).items():
        info.add_text(str(k), str(v))
    img = Image.fromarray(np.ascontiguousarray(a))
    return write_atomically(p, "PNG", lambda tmp: img.save(tmp, format="PNG", pnginfo=info), suffix=".tmp.png")


def read_png(path: str | os.PathLike) -> UInt8[np.ndarray, "H W 4"]:
    """The pixels of a PNG file as an ``(H, W, 4)`` uint8 RGBA array (row 0 is the top row)."""
    from PIL import Image

    p = Path(path)
    if read_head(p, "a PNG", 8) != PNG_MAGIC:
        raise HomofacError(f"{p}: not a PNG file (bad signature)")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            with Image.open(p) as im:
                im.load()  # decode now: truncated data raises here, not later
                if im.mode not in ("RGBA", "RGB", "L", "LA"):
                    raise HomofacError(f"{p}: unsupported PNG mode {im.mode} (expected 8-bit RGBA)")
                a = np.asarray(im.convert("RGBA"), dtype=np.uint8)
    except HomofacError:
        raise
    except MemoryError:
        raise  # not a corrupt file: the caller reports running out of memory
    except Exception as e:  # pillow raises OSError / SyntaxError / ValueError on corrupt data
        raise HomofacError(f"{p}: cannot read PNG (corrupt or truncated?): {_one_line(e)}") from None
    return np.ascontiguousarray(a)
