"""homofac.io: image formats only (layer L1): OpenEXR, Radiance HDR, PNG, checked reads and atomic writes.

The pinned output directory is :mod:`homofac.output` (a higher layer).
"""

from __future__ import annotations

from .exr import read_exr, write_exr
from .hdr import read_hdr, write_hdr
from .limits import image_info, iter_strips, read_downsampled
from .png import read_png, write_png

__all__ = ["image_info", "iter_strips", "read_downsampled", "read_exr", "read_hdr", "read_png", "write_exr",
           "write_hdr", "write_png"]
