"""homofac.light: environments (light lists) and the lighting computation L(v, n)."""

from __future__ import annotations

from .environment import (
    BUNDLED,
    Environment,
    bundled,
    dominant_direction,
    from_cube,
    from_latlong,
    gradient_sky,
    load_environment,
    painted_lights,
    sun_sky,
    to_cube_image,
    total_power,
    uniform,
    with_lights,
)
from .lighting import Lighting, cull_lights, irradiance, lighting, lighting_target

__all__ = [
    "BUNDLED", "Environment", "Lighting", "bundled", "cull_lights", "dominant_direction", "from_cube",
    "from_latlong", "gradient_sky", "irradiance", "lighting", "lighting_target", "load_environment",
    "painted_lights", "sun_sky", "to_cube_image", "total_power", "uniform", "with_lights",
]
