"""The bake's three integrals of an environment (docs/format.md "The bake directory", pinned):

    I_d(n, v)    = sum_k (1 - s5)/pi  L_i(l_k) w_k(n)
    I_A(n, v, r) = sum_k (1 - s5) S   L_i(l_k) w_k(n)
    I_B(n, v, r) = sum_k s5 S         L_i(l_k) w_k(n)

with the lobes of the glTF BRDF (:mod:`homofac.brdf.gltf`) and the pinned lighting sum over light texels
(w_k(n) the exact clamped-cosine texel integral, the BRDF at the visible centroid of texels straddling
the horizon, as :mod:`.lighting`). Then for any material
``L(n, v; c, m, r) = (1 - m) 0.96 c I_d + f0_eff I_A + I_B`` exactly (:func:`material_radiance`).

Computed as :mod:`.lighting` does: the three lobes are evaluated once per (pair, light) on structure-of-
arrays components and reduced with one (B, L) @ (L, 3) matmul each; pairs go through ``lax.map`` in
chunks, so nothing of size pairs x lights x 3 exists. Roughness is per pair (an array), so a benchmark's
random materials and a bake's layers go through the same call. float64 when the inputs are float64.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from .. import sphere
from ..brdf.gltf import DIELECTRIC_F0, gltf_lobes_at
from .environment import Environment
from .geometry import cosine_weights, light_geometry
from .lights import light_corners, light_moments

#: Pairs per lax.map step: 64 pairs x 6 r^2 lights x a few temporaries stays well inside the caches' reach.
CHUNK = 64


def _chunk_integrals(dirs, rad, geom, n, v, rough):
    """(B, 3 lobes, 3 channels) for one chunk of pairs n, v (B, 3), roughness (B,)."""
    w, (sidx, cent) = cosine_weights(n, geom, select=True, centroids=True)
    t, b, nn = sphere.frame(n)
    wi = (t @ dirs.T, b @ dirs.T, nn @ dirs.T)  # (B, L) each: local light directions by matmuls
    rows = jnp.arange(n.shape[0])[:, None]
    wi = tuple(c.at[rows, sidx].set(jnp.einsum("bkx,bx->bk", cent, axis), mode="drop")
               for c, axis in zip(wi, (t, b, nn)))
    wo = sphere.to_local(v, t, b, nn)
    above = wi[2] > 0
    safe = (jnp.where(above, wi[0], 0.0), jnp.where(above, wi[1], 0.0), jnp.where(above, wi[2], 1.0))
    lobes = gltf_lobes_at(rough[:, None], safe, tuple(wo[:, None, c] for c in range(3)))
    ww = jnp.where(above, w, 0.0)
    out = jnp.stack([(g * ww) @ rad for g in lobes], axis=1)  # (B, 3, 3)
    valid = jnp.sum(n * v, axis=-1) > 0
    return jnp.where(valid[:, None, None], out, 0.0)


@eqx.filter_jit
def _integrals(dirs, rad, geom, n, v, rough, chunk: int):
    count = n.shape[0]
    pad = (-count) % chunk
    if pad:
        n = jnp.concatenate([n, jnp.broadcast_to(n[:1], (pad, 3))])
        v = jnp.concatenate([v, jnp.broadcast_to(v[:1], (pad, 3))])
        rough = jnp.concatenate([rough, jnp.broadcast_to(rough[:1], (pad,))])
    out = jax.lax.map(lambda a: _chunk_integrals(dirs, rad, geom, *a),
                      (n.reshape(-1, chunk, 3), v.reshape(-1, chunk, 3), rough.reshape(-1, chunk)))
    return out.reshape(-1, 3, 3)[:count]


def integrals(env: Environment, n: Float[Array, "N 3"], v: Float[Array, "N 3"], roughness, *,
              chunk: int = CHUNK) -> Float[Array, "N 3 3"]:
    """``(I_d, I_A, I_B)`` stacked on axis 1, RGB on axis 2: (N, 3, 3), for pairs (n, v) with a roughness
    each (scalar or (N,)). Pairs with n.v <= 0 give 0. The dtype follows ``n`` (float64 for references)."""
    n = jnp.asarray(n)
    dtype = n.dtype
    v = jnp.asarray(v, dtype)
    rough = jnp.broadcast_to(jnp.asarray(roughness, dtype), n.shape[:1])
    dirs = env.directions.astype(dtype)
    geom = light_geometry(dirs, env.solid_angle.astype(dtype), light_corners(env).astype(dtype),
                          int(env.info.get("resolution", 0)), moments=light_moments(env))
    c = max(1, min(chunk, n.shape[0]))
    return _integrals(dirs, env.radiance.astype(dtype), geom, n, v, rough, c)


def material_radiance(parts: Float[Array, "N 3 3"], base_color, metallic) -> Float[Array, "N 3"]:
    """``L = (1 - m) 0.96 c I_d + f0_eff I_A + I_B`` with ``f0_eff = (1 - m) 0.04 + m c`` (pinned), from
    :func:`integrals` (or a bake's approximation of them): base_color (N, 3) or (3,), metallic (N,) or ()."""
    c = jnp.asarray(base_color, parts.dtype)
    m = jnp.asarray(metallic, parts.dtype)
    m = m[..., None] if m.ndim else m
    f0 = (1.0 - m) * DIELECTRIC_F0 + m * c
    return (1.0 - m) * (1.0 - DIELECTRIC_F0) * c * parts[:, 0] + f0 * parts[:, 1] + parts[:, 2]


__all__ = ["integrals", "material_radiance"]
