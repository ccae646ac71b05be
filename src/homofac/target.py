"""Targets: the function of two directions (a, b) that a factorization approximates (layer L3: plain data
and pure functions; the lighting computation of :mod:`homofac.light` is one such function).

A target is a pytree (an equinox module) so its parameters -- BRDF parameters, environment pixels --
can be differentiated. ``kind`` decides the domain of (a, b) (docs/conventions.md):

* ``brdf``: a = wi, b = wo in the local frame; the value is f(wi, wo) (``quantity="brdf"``, as McCool
  does) or f(wi, wo) cos(theta_i) (``quantity="brdf_cos"``). Metrics are always computed on
  f cos(theta_i), what a renderer shows for a unit light.
* ``lighting``: a = n, b = v in the world frame; the value is the lighting computation L(v, n).
"""

from __future__ import annotations

from typing import Any, Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .errors import HomofacError

QUANTITIES = ("brdf", "brdf_cos")


class Target(eqx.Module):
    """A target function of direction pairs: ``target(a, b) -> (N, 3)`` values to factor."""

    kind: str = eqx.field(static=True)
    fn: Any  # a callable pytree: BRDF (wi, wo) -> (..., 3), or a lighting computation (n, v) -> (..., 3)
    quantity: str = eqx.field(static=True, default="brdf")
    context: dict = eqx.field(default_factory=dict)  # e.g. {"dominant": (3,)} for NRHD

    def __call__(self, a: Float[Array, "N 3"], b: Float[Array, "N 3"]) -> Float[Array, "N 3"]:
        v = self.fn(a, b)
        if self.kind == "brdf" and self.quantity == "brdf_cos":
            v = v * jnp.maximum(a[..., 2:3], 0.0)
        return v

    def shown(self, a, values: Float[Array, "N 3"]) -> Float[Array, "N 3"]:
        """Turn factorized values into what the metrics compare: f cos(theta_i) for BRDF targets (in numpy
        for numpy arrays, so host metrics compile nothing)."""
        if self.kind == "brdf" and self.quantity == "brdf":
            xp = np if isinstance(values, np.ndarray) and isinstance(a, np.ndarray) else jnp
            return values * xp.maximum(a[..., 2:3], 0.0)
        return values


def brdf_target(brdf: Callable, quantity: str = "brdf") -> Target:
    """Target of a BRDF factorization (McCool et al. 2001): f itself, or f cos(theta_i)."""
    if quantity not in QUANTITIES:
        raise HomofacError(f"target.quantity must be one of {', '.join(QUANTITIES)}, got {quantity!r}")
    return Target("brdf", brdf, quantity)


@eqx.filter_jit
def _eval_chunks(fn, a, b):
    return jax.lax.map(lambda ab: fn(ab[0], ab[1]), (a, b))


def evaluate(fn: Callable, a, b, chunk: int = 4096) -> Float[Array, "N 3"]:
    """Evaluate ``fn(a, b)`` on N pairs in chunks of ``chunk`` rows (bounded memory, one compile)."""
    a = jnp.asarray(a)
    b = jnp.asarray(b)
    n = a.shape[0]
    if n == 0:
        return jnp.zeros((0, 3), a.dtype)
    chunk = max(1, min(chunk, n))
    pad = (-n) % chunk
    if pad:
        a = jnp.concatenate([a, jnp.broadcast_to(a[:1], (pad, 3))])
        b = jnp.concatenate([b, jnp.broadcast_to(b[:1], (pad, 3))])
    out = _eval_chunks(fn, a.reshape(-1, chunk, 3), b.reshape(-1, chunk, 3))
    return out.reshape(-1, 3)[:n]


__all__ = ["QUANTITIES", "Target", "brdf_target", "evaluate"]
