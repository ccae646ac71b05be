"""Texture range and precision: exponentiation, normalization with a correction colour, 8-bit.

* :func:`exponentiate` undoes the log transform of eq. 26-27: each factor receives alpha^(1/J) so the
  product of the J factors carries alpha (thesis §3.1.2, end of "Basic Approach"); the tiny
  ``- eps alpha`` of eq. 27 is neglected as the thesis does.
* :func:`normalize` scales every texture channel to a maximum of 1 and moves the scale into a
  correction colour, so ``correction * prod_j t_k(j)`` is unchanged (thesis §4.3, Latta-Kolb §3.4).
* :func:`quantize` rounds normalized textures to 8 bits (what an RGBA8 texture stores).
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from ..param.parametrizations import Parametrization


def exponentiate(x_textures: list, alpha, n_factors: int) -> list:
    """Linear textures ``exp(x_k) alpha^(1/J)`` from log textures (eq. 27 with the alpha^(1/J) split)."""
    s = jnp.asarray(alpha) ** (1.0 / n_factors)
    return [jnp.exp(x) * s for x in x_textures]


def normalize(param: Parametrization, textures: list, valid: np.ndarray | None = None):
    """Scale each texture channel to max 1; returns (textures, correction (3,)).

    The correction colour is prod_j max(t_k(j)) per channel, so the evaluated product is unchanged.
    ``valid`` (H, W) restricts the maximum to texels that hold data.
    """
    out, corr = [], jnp.ones((3,), textures[0].dtype)
    for k, t in enumerate(textures):
        tv = t if valid is None else jnp.where(jnp.asarray(valid)[..., None], t, 0.0)
        mx = jnp.max(tv.reshape(-1, 3), axis=0)
        mx = jnp.where(mx > 0, mx, 1.0)
        out.append(tv / mx)
        corr = corr * mx ** len(param.uses(k))
    return out, corr


def quantize(textures: list, bits: int = 8) -> list:
    """Round textures in [0, 1] to ``bits`` bits per channel (unsigned normalized integers)."""
    q = float(2**bits - 1)
    return [jnp.round(jnp.clip(t, 0.0, 1.0) * q) / q for t in textures]
