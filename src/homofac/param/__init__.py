"""homofac.param: direction mappers, projections and parametrizations (records: math written once)."""

from __future__ import annotations

from . import mappers, parametrizations, projections
from .parametrizations import PARAMETRIZATIONS, Factor, Parametrization
from .projections import PROJECTIONS, Projection

__all__ = ["PARAMETRIZATIONS", "PROJECTIONS", "Factor", "Parametrization", "Projection", "mappers",
           "parametrizations", "projections"]
