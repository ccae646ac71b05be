"""What the baselines share: their record, and the pieces they are built from.

A baseline is one record (:class:`Baseline`): its name (a value of the config's ``parametrization``),
its option model, the function that *computes* its textures (no solve) and its doc. It produces the
same schema-2 model a fit produces (:class:`homofac.factorization.Factorization`), so evaluation,
metrics, export, preview and shaders apply to it unchanged.

The pieces: the lighting target's BRDF and environment (:func:`lighting_parts`), texel-centre
directions of a mapper (:func:`centres`), the exact irradiance map E(n) (:func:`irradiance_map`), and
a chunked weighted sum over the lights (:func:`light_sums`), the common core of every prefiltering.
"""

from __future__ import annotations

from typing import Callable, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..brdf import albedo, make
from ..brdf.core import BRDF
from ..errors import HomofacError
from ..light import Environment, Lighting, irradiance
from ..options import Options
from ..param import mappers
from ..target import Target


class Baseline(NamedTuple):
    """A registered baseline: ``build(target, mapper, texture_size, options) -> Factorization``."""

    name: str
    options: type[Options]
    build: Callable
    doc: str


def lighting_parts(target: Target, name: str) -> tuple[BRDF, Environment]:
    """The BRDF and environment of a lighting target (one-line refusal for anything else)."""
    fn = getattr(target, "fn", None)
    if getattr(target, "kind", None) != "lighting" or not isinstance(fn, Lighting):
        raise HomofacError(f"{name} is a baseline of lighting factorizations (target.kind lighting); got a "
                           f"{getattr(target, 'kind', type(target).__name__)} target")
    if not isinstance(fn.brdf, BRDF):
        raise HomofacError(f"{name} needs a registered BRDF model, got {type(fn.brdf).__name__}")
    if fn.clamp is not None:
        raise HomofacError(f"{name} computes the unclamped lighting; remove target.clamp")
    return fn.brdf, fn.env


def centres(mapper: str, size: int) -> np.ndarray:
    """Texel-centre directions ``(H*W, 3)`` (float32) of every texel of a mapper's texture."""
    d = mappers.texel_directions(mapper, size)
    return np.ascontiguousarray(d.reshape(-1, d.shape[-1]) if d.ndim == 3 else d.reshape(-1))


def irradiance_map(env: Environment, mapper: str, size: int) -> np.ndarray:
    """E(n) at the texel centres, exactly (the clamped-cosine texel integrals of light.geometry): (H, W, 3)."""
    d = centres(mapper, size)
    e = np.asarray(irradiance(env, jnp.asarray(d)))
    return e.reshape(mappers.texture_shape(mapper, size) + (3,))


@eqx.filter_jit
def _sums(weight, params, dirs, light_dirs, power, solid, chunk: int):
    """``(num (J, 3), den (J,))``: ``sum_k w(d_j, l_k) L_k dw_k`` and ``sum_k w dw_k`` in chunks of directions."""
    j = dirs.shape[0]
    pad = (-j) % chunk
    d = jnp.concatenate([dirs, jnp.broadcast_to(dirs[:1], (pad, 3))]) if pad else dirs

    def one(block):
        c = block @ light_dirs.T  # (chunk, L) cosines between the direction and every light
        w = weight(params, c)
        return (w * solid[None]) @ power, (w * solid[None]).sum(axis=1)

    num, den = jax.lax.map(one, d.reshape(-1, chunk, 3))
    return num.reshape(-1, 3)[:j], den.reshape(-1)[:j]


def light_sums(weight: Callable, params, dirs: np.ndarray, env: Environment, chunk: int = 128):
    """For directions ``d_j`` and a weight ``w(params, cos(d_j, l_k))`` (a pure jnp function of the cosine),
    ``sum_k w L_k dw_k`` (J, 3) and ``sum_k w dw_k`` (J,): the matmul form of every prefilter here."""
    return _sums(weight, params, jnp.asarray(dirs, jnp.float32), env.directions.astype(jnp.float32),
                 env.radiance.astype(jnp.float32), env.solid_angle.astype(jnp.float32), chunk)


def view_directions(x: np.ndarray) -> np.ndarray:
    """Local view directions ``(sqrt(1 - x^2), 0, x)`` of view cosines ``x`` (the plane of incidence is xz)."""
    x = np.clip(np.asarray(x, np.float64), 1e-6, 1.0)
    return np.stack([np.sqrt(1.0 - x * x), np.zeros_like(x), x], axis=-1)


def directional_albedo(brdf: BRDF, x: np.ndarray, n: int = 128, **params) -> np.ndarray:
    """Directional albedo (RGB) of ``brdf`` with some parameters replaced (e.g. ``kd=0``), at view
    cosines ``x``: the integral of f cos(theta_i) over the hemisphere (:func:`homofac.brdf.albedo`)."""
    b = make(brdf.model, **{**{k: np.asarray(v) for k, v in brdf.params.items()}, **params})
    return np.asarray(albedo(b, jnp.asarray(view_directions(x), jnp.float32), n=n), np.float64)


__all__ = ["Baseline", "centres", "directional_albedo", "irradiance_map", "light_sums", "lighting_parts", "view_directions"]
