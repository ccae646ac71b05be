"""Isotropic filtering of an environment by tabulated kernels (the matmul form of every bake texel).

``F_j(d) = sum_k L_k dw_k kappa_j(q(d.l_k))`` with q = sqrt((1 - d.l) / 2) and kappa_j tabulated uniformly
in q (:mod:`.kernels`): cosines as one (B, 3) @ (3, L) matmul per chunk, the J tables read by linear
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
        pos = jnp.sqrt(jnp.clip((1.0 - c) * 0.5, 0.0, 1.0)) * (g - 1)
        i0 = jnp.minimum(jnp.floor(pos).astype(jnp.int32), g - 2)
        f = pos - i0
        return jnp.stack([((1.0 - f) * t[i0] + f * t[i0 + 1]) @ power for t in tables], axis=1)  # (B, J, 3)

    out = jax.lax.map(one, d.reshape(-1, chunk, 3))
    return out.reshape(-1, j_count, 3)[:count]


def prefilter(tables: np.ndarray, dirs: np.ndarray, env: Environment, chunk: int = CHUNK) -> np.ndarray:
    """``(N, J, 3)``: the J kernels ``tables`` (J, G) applied to ``env`` at directions ``dirs`` (N, 3) (float32)."""
    power = env.radiance.astype(jnp.float32) * env.solid_angle.astype(jnp.float32)[:, None]
    out = _filter(jnp.asarray(tables, jnp.float32), jnp.asarray(dirs, jnp.float32),
                  env.directions.astype(jnp.float32), power, int(min(chunk, max(1, len(dirs)))))
    return np.asarray(out, np.float64)


__all__ = ["prefilter"]
