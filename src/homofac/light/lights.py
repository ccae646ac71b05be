"""Extra lights beside an environment map, and light culling with a stated error bound.

Extra lights: ``lights=[{"type": "directional", "direction": [x, y, z], "irradiance": [r, g, b]}, ...]``.
A ``"point"`` light is treated as directional, because the environment is distant (the lighting does
not depend on the surface position): its ``direction`` (or ``position``, normalised) is the direction
towards it and its ``irradiance`` at the object is given directly, or as ``intensity / |position|^2``.
"""

from __future__ import annotations

from typing import Any, Sequence

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..errors import HomofacError
from ..options import validate
from .clean import check_direction, check_rgb
from .environment import Environment
from .geometry import cube_corners, texel_moments
from .options import LightOptions


def _normalise_light(spec: Any, i: int, source: str) -> dict:
    """One extra light (validated as :class:`~homofac.light.options.LightOptions`) as a directional light."""
    opts = validate(LightOptions, spec, f"{source}: lights[{i}]")
    vec = opts.direction if opts.direction is not None else opts.position
    d = check_direction(vec, "light direction", f"{source}: lights[{i}]")
    if opts.intensity is not None:
        irr = check_rgb(opts.intensity, "light intensity", source) / float(np.sum(np.asarray(vec, np.float64) ** 2))
    else:
        irr = check_rgb(1.0 if opts.irradiance is None else opts.irradiance, "light irradiance", source)
    return {"type": opts.type, "direction": [float(x) for x in d], "irradiance": [float(x) for x in irr]}


def with_lights(env: Environment, lights: Sequence[dict]) -> Environment:
    """``env`` with extra directional lights appended (a point light is treated as directional).

    Each light ``{"type": "directional" | "point", "direction": [x, y, z], "irradiance": c}`` becomes one
    entry with ``solid_angle = 1`` and ``radiance = irradiance`` (so its power term is the irradiance
    it delivers to a surface facing it). A point light may give ``position`` instead of ``direction``
    and ``intensity`` instead of ``irradiance`` (irradiance = intensity / |position|^2).
    """
    source = str(env.info.get("source", "environment"))
    if lights is None:
        lights = ()
    if isinstance(lights, dict):
        lights = [lights]
    specs = [_normalise_light(s, i, source) for i, s in enumerate(lights)]
    if not specs:
        return env
    d = jnp.asarray(np.array([s["direction"] for s in specs], np.float32))
    rad = jnp.asarray(np.array([s["irradiance"] for s in specs], np.float32))
    info = dict(env.info)
    info["lights"] = list(info.get("lights", [])) + specs
    return Environment(
        directions=jnp.concatenate([env.directions, d.astype(env.directions.dtype)]),
        radiance=jnp.concatenate([env.radiance, rad.astype(env.radiance.dtype)]),
        solid_angle=jnp.concatenate([env.solid_angle, jnp.ones(len(specs), env.solid_angle.dtype)]),
        info=info,
        corners=None if env.corners is None else jnp.concatenate(
            [env.corners, jnp.zeros((len(specs), 4, 3), env.corners.dtype)]),
        moments=None if env.moments is None else tuple(
            jnp.concatenate([a, jnp.asarray(b, a.dtype)]) for a, b in zip(
                env.moments, moments_of(np.asarray(d), np.ones(len(specs)), np.zeros((len(specs), 4, 3))))),
    )


def moments_of(directions, solid_angle, corners) -> tuple:
    m, sinr = texel_moments(directions, solid_angle, corners)
    # cast on the host: jnp.asarray(float64, float32) compiles a conversion per shape
    return jnp.asarray(np.asarray(m, np.float32)), jnp.asarray(np.asarray(sinr, np.float32))


def light_corners(env: Environment) -> Float[Array, "L 4 3"]:
    """Texel corners of the lights (zeros for delta lights): ``env.corners`` when the environment has
    them, else the cube texels of ``env.info["resolution"]`` followed by delta lights."""
    c = getattr(env, "corners", None)
    if c is not None:
        return c
    r = int(env.info.get("resolution", 0))
    n_tex = 6 * r * r
    L = env.directions.shape[0]
    if r <= 0 or n_tex > L:
        return jnp.zeros((L, 4, 3), env.directions.dtype)
    return jnp.concatenate([jnp.asarray(cube_corners(r), env.directions.dtype),
                            jnp.zeros((L - n_tex, 4, 3), env.directions.dtype)])


def light_moments(env: Environment):
    """(moment, sin_radius) of the lights: ``env.moments`` or computed from the corners (concrete only)."""
    if getattr(env, "moments", None) is not None:
        return env.moments
    return texel_moments(env.directions, env.solid_angle, light_corners(env))


def cull_lights(env: Environment, tolerance: float) -> tuple[Environment, dict]:
    """Drop the weakest lights whose summed power is at most ``tolerance`` x the total power.

    Error bound (stated and tested): for any BRDF f and any (n, v), the change of L(v, n) per channel is
    at most ``max f * dropped_power`` where dropped_power = sum over dropped lights of L_i dw <=
    tolerance * total power (since max(n.l, 0) <= 1). For a Lambertian BRDF, max f = kd/pi.
    """
    if not 0 <= tolerance < 1:
        raise HomofacError(f"light culling tolerance must be in [0, 1), got {tolerance}")
    power = np.asarray(env.radiance * env.solid_angle[:, None], np.float64)
    lum = power.sum(axis=1)
    order = np.argsort(lum)
    cum = np.cumsum(lum[order])
    total = max(float(lum.sum()), 1e-300)
    n_drop = int(np.searchsorted(cum, tolerance * total, side="right"))
    keep = np.sort(order[n_drop:])
    dropped = power[order[:n_drop]].sum(axis=0) if n_drop else np.zeros(3)
    culled = Environment(
        directions=env.directions[keep], radiance=env.radiance[keep], solid_angle=env.solid_angle[keep],
        info={**env.info, "culled_lights": n_drop}, corners=light_corners(env)[keep],
        moments=tuple(jnp.asarray(a)[keep] for a in light_moments(env)),
    )
    return culled, {"dropped": n_drop, "kept": int(keep.size), "dropped_power": dropped.tolist(),
                    "total_power": power.sum(axis=0).tolist()}


__all__ = ["cull_lights", "light_corners", "light_moments", "moments_of", "with_lights"]
