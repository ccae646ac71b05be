"""homofac.io: EXR / HDR images and the pinned output directory."""

from __future__ import annotations

from .output import load, save

__all__ = ["load", "save"]
