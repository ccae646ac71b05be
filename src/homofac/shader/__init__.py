"""homofac.shader: shader code generated from the records (GLSL, GLSL ES, HLSL, MSL, WGSL)."""

from __future__ import annotations

from . import generate, languages, symbolic
from .generate import source
from .languages import LANGUAGES

__all__ = ["LANGUAGES", "generate", "languages", "source", "symbolic"]
