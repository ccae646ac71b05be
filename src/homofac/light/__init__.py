"""homofac.light: environments (light lists) and the lighting computation L(v, n).

* :mod:`.environment`: the :class:`Environment` type (lights with exact solid angles);
* :mod:`.sources` (files, bundled maps), :mod:`.resample` (lat-long and cube images), :mod:`.synthetic`
  (analytic skies), :mod:`.sky` (the Preetham daylight sky and a moving sun), :mod:`.lights` (extra lights, culling), built on :mod:`.latlong`, :mod:`.cubemap`,
  :mod:`.clean` (checks, bad pixels, boost) and :mod:`.geometry` (exact clamped-cosine texel weights);
* :mod:`.lighting`: L(v, n) of a BRDF under an environment, the target of a lighting factorization;
* :mod:`.sh`: the 9 spherical-harmonic coefficients of the irradiance (``sh9.json``, Filament's ``sh.txt``).
"""

from __future__ import annotations

from .cubemap import FACE_NAMES, to_cube_image
from .environment import (Environment, brightest_direction, brightest_directions, dominant_direction, light_radii, luminance,
                          total_power)
from .lighting import Lighting, irradiance, lighting, lighting_target, off_specular_shift, with_context
from .lights import cull_lights, with_lights
from .options import BoostOptions, EnvironmentOptions, LightOptions
from .resample import from_cube, from_latlong
from .sources import BUNDLED, bundled, environment_from_options, load_environment
from .synthetic import gradient_sky, painted_lights, sun_sky, uniform
from .sh import SH9, sh9
from .sky import preetham_sky, sun_direction, time_of_day

__all__ = [
    "BUNDLED", "BoostOptions", "FACE_NAMES", "Environment", "EnvironmentOptions", "LightOptions", "Lighting", "bundled",
    "brightest_direction", "brightest_directions", "cull_lights", "dominant_direction", "environment_from_options", "from_cube", "from_latlong", "gradient_sky",
    "light_radii",
    "irradiance", "lighting", "lighting_target", "load_environment", "luminance", "off_specular_shift", "painted_lights",
    "preetham_sky", "SH9", "sh9", "sun_direction", "sun_sky", "time_of_day", "to_cube_image", "total_power", "uniform", "with_context",
    "with_lights",
]
