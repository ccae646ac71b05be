"""The environment type: a list of lights for the lighting computation, and what derives from it.

An :class:`Environment` is the light list of the pinned lighting computation (docs/conventions.md,
Latta & Kolb 2002 eq. 10): unit directions ``l_k``, RGB radiance ``L_k`` and the exact solid angle ``dw_k`` of each
light, so that ``radiance * solid_angle`` is the power term of ``L(v, n) = sum_k f L_k max(n.l_k, 0) dw_k``.
The lights are the texels of a cube map of face size ``resolution`` (``6 r^2`` lights, pinned cube
layout of :mod:`homofac.param.mappers`: texel ``k`` is the row-major index into the ``(r, 6r)``
texture), optionally followed by extra directional lights (``solid_angle`` 1, ``radiance`` = their
irradiance). It is an equinox module: ``jax.grad`` with respect to ``radiance`` works.

Where environments come from: :mod:`.sources` (files, bundled maps), :mod:`.resample` (lat-long and
cube images in memory), :mod:`.synthetic` (analytic skies), :mod:`.lights` (extra lights, culling).
"""

from __future__ import annotations

from typing import Optional

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from ..errors import HomofacError

#: Rec. 709 luminance weights (linear RGB).
LUMINANCE = (0.2126, 0.7152, 0.0722)


class Environment(eqx.Module):
    """Light list of the lighting computation; a pytree whose arrays are leaves.

    ``radiance * solid_angle[:, None]`` is the power term of the pinned sum (for an extra directional
    light ``solid_angle`` is 1 and ``radiance`` its irradiance). ``info`` (static, JSON-friendly) holds the
    provenance: source, kind, resolution, n_texels, clamped_negative, nonfinite, energy_before,
    energy_after, boost, lights, ...
    """

    directions: Float[Array, "L 3"]
    radiance: Float[Array, "L 3"]
    solid_angle: Float[Array, "L"]
    info: dict = eqx.field(static=True)
    #: Corners (L, 4, 3) of each light texel, counter-clockwise from outside (all zero for delta
    #: lights); they let the lighting integrate max(n.l, 0) exactly over each texel (light.geometry).
    corners: Optional[Float[Array, "L 4 3"]] = None
    #: (moment (L, 3), sin_radius (L,)) of the lights, precomputed from the corners (light.geometry).
    moments: Optional[tuple] = None

    @property
    def num_lights(self) -> int:
        return int(self.directions.shape[0])


def luminance(rgb):
    """Rec. 709 luminance of linear RGB ``(..., 3) -> (...)`` (numpy or jax)."""
    return rgb[..., 0] * LUMINANCE[0] + rgb[..., 1] * LUMINANCE[1] + rgb[..., 2] * LUMINANCE[2]


def total_power(env: Environment) -> Float[Array, "3"]:
    """``sum_k radiance_k * solid_angle_k`` per channel (for uniform radiance 1: 4 pi)."""
    return jnp.sum(env.radiance * env.solid_angle[:, None], axis=0)


def dominant_direction(env: Environment) -> Float[Array, "3"]:
    """Dominant light direction, thesis eq. 66: ``normalize(sum_k e_k l_k)``.

    ``e_k = luminance(radiance_k) * solid_angle_k`` (weighted by solid angle because cube texels are
    not equal). Raises :class:`HomofacError` when the sum vanishes (isotropic lighting has no dominant
    direction; give one explicitly). Differentiable when traced (the check is then skipped).
    """
    e = luminance(env.radiance) * env.solid_angle
    s = e @ env.directions
    n = jnp.linalg.norm(s)
    total = jnp.sum(jnp.abs(e))
    if not isinstance(n, jax.core.Tracer) and not isinstance(total, jax.core.Tracer):
        if not float(n) > 1e-5 * float(total):
            src = env.info.get("source", "environment")
            raise HomofacError(
                f"{src}: no dominant light direction (sum of e_k l_k vanishes: isotropic lighting); give one explicitly"
            )
    return s / n


__all__ = ["Environment", "LUMINANCE", "dominant_direction", "luminance", "total_power"]
