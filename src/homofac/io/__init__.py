"""homofac.io: EXR / HDR / PNG images and the pinned output directory."""

from __future__ import annotations

from .output import load, save
from .png import read_png, write_png

__all__ = ["load", "save", "read_png", "write_png"]
