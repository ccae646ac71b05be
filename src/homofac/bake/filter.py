"""Isotropic filtering of an environment by tabulated kernels (the matmul form of every bake texel).

``F_j(d) = sum_k L_k dw_k kappa_j(q(d.l_k))`` with q = sqrt((1 - d.l) / 2) and kappa_j tabulated uniformly
in sqrt(q) (:mod:`.kernels`): cosines as one (B, 3) @ (3, L) matmul per chunk, the J tables read by linear
interpolation at a shared index, the sums as (B, L) @ (L, 3) matmuls; directions go through ``lax.map`` in
chunks, so memory stays B x L per table, never directions x lights x 3.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..light import Environment

#: Directions per lax.map step.
CHUNK = 128


@eqx.filter_jit
def _filter(tables, dirs, light_dirs, power, chunk: int):
    j_count, g = tables.shape
    count = dirs.shape[0]
    pad = (-count) % chunk
    d = jnp.concatenate([dirs, jnp.broadcast_to(dirs[:1], (pad, 3))]) if pad else dirs

    def one(block):
        c = block @ light_dirs.T  # (B, L)
        pos = jnp.sqrt(jnp.sqrt(jnp.clip((1.0 - c) * 0.5, 0.0, 1.0))) * (g - 1)
        i0 = jnp.minimum(jnp.floor(pos).astype(jnp.int32), g - 2)
        f = pos - i0
        return jnp.stack([((1.0 - f) * t[i0] + f * t[i0 + 1]) @ power for t in tables], axis=1)  # (B, J, 4)

    out = jax.lax.map(one, d.reshape(-1, chunk, 3))
    return out.reshape(-1, j_count, power.shape[1])[:count]


def prefilter(tables: np.ndarray, dirs: np.ndarray, env: Environment, chunk: int = CHUNK) -> tuple[np.ndarray, np.ndarray]:
    """The J kernels ``tables`` (J, G) applied to ``env`` at directions ``dirs`` (N, 3): ``(N, J, 3)``, and the
    discrete masses ``sum_k dw_k kappa_j`` (N, J) of the same sums (the quadrature check of :func:`normalized`)."""
    sa = env.solid_angle.astype(jnp.float32)
    power = jnp.concatenate([env.radiance.astype(jnp.float32) * sa[:, None], sa[:, None]], axis=1)
    out = np.asarray(_filter(jnp.asarray(tables, jnp.float32), jnp.asarray(dirs, jnp.float32),
                             env.directions.astype(jnp.float32), power, int(min(chunk, max(1, len(dirs))))), np.float64)
    return out[..., :3], out[..., 3]


def normalized(values: np.ndarray, discrete: np.ndarray, exact) -> np.ndarray:
    """Filtered values scaled by ``exact mass / discrete mass`` (Karis' normalized prefilter): the texel sum of
    a kernel a few light texels wide then reads a constant environment exactly wherever its axis falls
    between texel centres. ``discrete`` (N,) or (N, J), ``exact`` scalar or (J,)."""
    d = np.asarray(discrete, np.float64)
    e = np.broadcast_to(np.asarray(exact, np.float64), d.shape[-1:] if d.ndim > 1 else ())
    scale = np.where(np.abs(d) > 1e-30, e / np.where(np.abs(d) > 1e-30, d, 1.0), 0.0)
    return values * (scale[..., None] if d.ndim == values.ndim - 1 else scale[:, None, None])


__all__ = ["normalized", "prefilter"]
