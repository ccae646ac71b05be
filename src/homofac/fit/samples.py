"""Samples: training and validation pairs with the target's exact values, and how they are evaluated.

:class:`Samples` is what sampling produces and what every later stage (system, solve, metrics,
refits) consumes. :func:`evaluate_grouped` evaluates a target on lighting pairs grouped by normal
with the target's per-normal fast path (:meth:`homofac.light.Lighting.grouped`), over all devices when
there are several (:mod:`homofac.fit.shard`).
"""

from __future__ import annotations

from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..errors import HomofacError
from ..target import Target, evaluate
from .shard import grouped_sharded

#: Array names of a sample set, in order (also the keys of samples.npz and of cache entries).
FIELDS = ("a", "b", "y", "val_a", "val_b", "val_y")


class Samples(NamedTuple):
    """Training and validation pairs with their exact target values (float32 numpy)."""

    a: np.ndarray
    b: np.ndarray
    y: np.ndarray
    val_a: np.ndarray
    val_b: np.ndarray
    val_y: np.ndarray


def check_values(y: np.ndarray, what: str) -> None:
    """Refuse non-finite target values, and a target that is zero everywhere."""
    if not np.all(np.isfinite(y)):
        bad = int(np.sum(~np.isfinite(y)))
        raise HomofacError(f"the target gave {bad} non-finite values on the {what} samples")
    if not np.any(y > 0):
        raise HomofacError(f"the target is zero on every {what} sample: nothing to factor")


@eqx.filter_jit
def _eval_groups(fn, normals, views):
    return fn.grouped(normals, views)


def evaluate_grouped(target: Target, grouped) -> Float[Array, "M 3"]:
    """Values at the valid pairs of a :class:`~homofac.fit.sampling.Grouped` set, in flattened order.

    Uses the target's per-normal fast path (``target.fn.grouped``) when it has one, with the normals
    split over all devices when there are several (:mod:`homofac.fit.shard`).
    """
    if grouped.mask.size == 0 or not grouped.mask.any():
        return jnp.zeros((0, 3))
    if hasattr(target.fn, "grouped"):
        normals, views = jnp.asarray(grouped.normals), jnp.asarray(grouped.views)
        if getattr(target.fn, "culls_lobes", False):
            return _culled(target.fn, normals, views)[jnp.asarray(grouped.mask)]
        if jax.device_count() > 1:
            out = grouped_sharded(target.fn, normals, views)
        else:
            out = _eval_groups(target.fn, normals, views)
        return out[jnp.asarray(grouped.mask)]
    pairs = grouped.flatten()
    return evaluate(target, pairs.a, pairs.b)


@eqx.filter_jit
def _eval_groups_culled(fn, normals, views, slots):
    return fn.grouped_culled(normals, views, slots)


def _culled(fn, normals, views):
    """Lobe-culled values: start from ``fn.lobe_slots()`` lights per cone; when a cone held more, rerun
    with enough slots (the next multiple of 64), so no light inside a cone is ever left out."""
    slots = fn.lobe_slots()
    while True:
        out, count = _eval_groups_culled(fn, normals, views, slots)
        count = int(count)
        if count <= slots:
            return out
        slots = 64 * -(-count // 64)



__all__ = ["FIELDS", "Samples", "check_values", "evaluate", "evaluate_grouped"]
