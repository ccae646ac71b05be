"""Option models of the light layer: the environment, its highlight boost and extra lights.

The config's ``target.environment`` section is :class:`EnvironmentOptions`; ``load_environment``,
``from_latlong`` and the synthetic skies validate their arguments with the same models and types, so
the CLI and the Python API refuse the same values with the same one-line message.
"""

from __future__ import annotations

import math
from typing import Annotated, Literal, Optional, Union

from pydantic import Field, model_validator

from ..options import Options

#: A cube face size of the light samples (6 r^2 lights).
Resolution = Annotated[int, Field(ge=2, le=1024, description="cube face size of the light samples")]
Number = float
Colour = Union[Number, list[Number]]


def _finite(x: float) -> bool:
    return math.isfinite(x)


class BoostOptions(Options):
    """Highlight boost of thesis §5.7: pixels above ``threshold`` x the max luminance scaled by ``factor``."""

    threshold: float = Field(0.9, ge=0, le=1)
    factor: float = Field(10.0, gt=0, allow_inf_nan=False)


class LightOptions(Options):
    """An extra light beside the map: directional (a direction and its irradiance) or point (a position
    and an intensity, irradiance = intensity / |position|^2, treated as directional: the environment is
    distant)."""

    type: Literal["directional", "point"] = "directional"
    direction: Optional[list[float]] = Field(None, min_length=3, max_length=3)
    position: Optional[list[float]] = Field(None, min_length=3, max_length=3)
    irradiance: Optional[Colour] = None
    intensity: Optional[Colour] = None

    @model_validator(mode="after")
    def _one_of_each(self):
        if self.direction is not None and self.position is not None:
            raise ValueError("give direction or position, not both")
        if self.direction is None and self.position is None:
            raise ValueError("missing direction")
        if self.irradiance is not None and self.intensity is not None:
            raise ValueError("give irradiance or intensity, not both")
        if self.type == "directional" and (self.position is not None or self.intensity is not None):
            raise ValueError("a directional light takes direction and irradiance (position and intensity are for point lights)")
        vec = self.direction if self.direction is not None else self.position
        if not all(_finite(x) for x in vec) or sum(x * x for x in vec) < 1e-24:
            raise ValueError(f"the light direction must be a non-zero finite [x, y, z], got {vec}")
        for name in ("irradiance", "intensity"):
            c = getattr(self, name)
            vals = c if isinstance(c, list) else ([] if c is None else [c])
            if c is not None and (len(vals) not in (1, 3) or not all(_finite(x) and x >= 0 for x in vals)):
                raise ValueError(f"light {name} must be a finite non-negative number or [r, g, b], got {c}")
        return self


class EnvironmentOptions(Options):
    """``target.environment``: a map (file or bundled name), its light resolution, boost, lights, culling."""

    file: str = "forest"
    resolution: Resolution = 32
    boost: Optional[BoostOptions] = None
    lights: list[LightOptions] = Field(default_factory=list)
    #: drop the weakest lights holding at most this fraction of the total power (light.cull_lights)
    cull: Optional[float] = Field(None, ge=0, lt=1)


__all__ = ["BoostOptions", "Colour", "EnvironmentOptions", "LightOptions", "Resolution"]
