"""homofac.param: direction mappers (texture maps) and parametrizations (factors -> textures)."""

from __future__ import annotations

from . import mappers, parametrizations
from .parametrizations import PARAMETRIZATIONS, Factor, Parametrization

__all__ = ["PARAMETRIZATIONS", "Factor", "Parametrization", "mappers", "parametrizations"]
