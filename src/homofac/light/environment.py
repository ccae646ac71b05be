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
import numpy as np
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


#: Angular radius (degrees) of the cap :func:`brightest_direction` sums power over.
PEAK_CAP_DEGREES = 8.0


def brightest_directions(env: Environment, count: int = 1, cap_degrees: float = PEAK_CAP_DEGREES) -> np.ndarray:
    """The directions ``(count, 3)`` of the brightest lights, brightest first: the power-weighted mean
    direction of the texels within ``cap_degrees`` of the texel whose cap holds the most power (``e_k``
    of :func:`dominant_direction`); then the same with those texels left out, ``count`` times.

    Eq. 66's mean direction lies between the sun and the sky that surrounds it (9 degrees off the sun
    under the bundled city sky, 43 degrees off the brightest lamp of the interior); a highlight term of
    one light (projection ``nh_dom``) needs the light itself. The bundled interior's three brightest
    caps hold 22, 13 and 6 % of its power. Float32 NumPy; a one-line refusal when the environment
    holds no power.
    """
    d = np.asarray(env.directions, np.float64)
    e = np.maximum(np.asarray(luminance(env.radiance), np.float64), 0.0) * np.asarray(env.solid_angle, np.float64)
    if not np.sum(e) > 0:
        raise HomofacError(f"{env.info.get('source', 'environment')}: no light to find the brightest direction of")
    cos_cap = np.cos(np.radians(cap_degrees))
    out = []
    for _ in range(int(count)):  # a few lights: each pass one vectorised cap sum over the lit texels
        lit = np.flatnonzero(e >= 1e-3 * e.max())  # candidate centres: the texels that could hold a peak
        power = np.concatenate([((d[c] @ d.T) >= cos_cap) @ e for c in np.array_split(lit, max(1, len(lit) // 512))])
        near = (d @ d[lit[np.argmax(power)]]) >= cos_cap
        s = (e[near, None] * d[near]).sum(0)
        out.append(s / np.linalg.norm(s))
        e = np.where(near, 0.0, e)
        if not np.any(e > 0):
            out += [out[-1]] * (int(count) - len(out))
            break
    return np.asarray(out, np.float32)


def brightest_direction(env: Environment, cap_degrees: float = PEAK_CAP_DEGREES) -> np.ndarray:
    """The direction ``(3,)`` of the brightest light (:func:`brightest_directions`)."""
    return brightest_directions(env, 1, cap_degrees)[0]


def light_radii(env: Environment, directions, cap_degrees: float = PEAK_CAP_DEGREES) -> np.ndarray:
    """The sine of the angular radius of the light around each of ``directions`` ``(J, 3)``: ``sqrt 2``
    times the power-weighted median angle from the direction of the texels within ``cap_degrees`` of it
    (a uniform disc of radius rho has its median at ``rho / sqrt 2``; the median, unlike a mean, leaves
    the sky around a sun out). What the highlight coordinate of a light with a disc reads (projection
    ``nhs_dom``, context ``radius``): 0.023 for the bundled city sun at light resolution 64 (1.3
    degrees), 0.046 at 16, where its texels are 4.9 degrees wide. Float32 NumPy ``(J,)``; 0 for a
    direction without power in its cap."""
    d = np.asarray(env.directions, np.float64)
    e = np.maximum(np.asarray(luminance(env.radiance), np.float64), 0.0) * np.asarray(env.solid_angle, np.float64)
    ang = np.arccos(np.clip(np.asarray(directions, np.float64).reshape(-1, 3) @ d.T, -1.0, 1.0))  # (J, L)
    w = np.where(ang <= np.radians(cap_degrees), e[None, :], 0.0)
    order = np.argsort(ang, axis=1)
    cum = np.cumsum(np.take_along_axis(w, order, axis=1), axis=1)
    total = cum[:, -1:]
    k = np.argmax(cum >= 0.5 * np.maximum(total, 1e-300), axis=1)  # the first texel past half the cap's power
    median = np.take_along_axis(np.take_along_axis(ang, order, axis=1), k[:, None], axis=1)[:, 0]
    return np.where(total[:, 0] > 0, np.sin(np.minimum(np.sqrt(2.0) * median, np.pi / 6)), 0.0).astype(np.float32)


__all__ = ["Environment", "LUMINANCE", "PEAK_CAP_DEGREES", "brightest_direction", "brightest_directions", "light_radii",
           "dominant_direction", "luminance",
           "total_power"]
