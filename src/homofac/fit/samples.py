"""Samples: training and validation pairs with the target's exact values, and how they are evaluated.

:class:`Samples` is what sampling produces and what every later stage (system, solve, metrics,
refits) consumes. :func:`evaluate_grouped` evaluates a target on lighting pairs grouped by normal
with the target's per-normal fast path (:meth:`homofac.light.Lighting.grouped`), over all devices when
there are several (:mod:`homofac.fit.shard`).
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..compiling import jit
from ..errors import HomofacError
from ..light.refine import blocks
from ..target import Target, evaluate
from .sampling import Grouped
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


@jit(kind="lighting grid", filter=True)
def _eval_groups(fn, normals, views):
    return fn.grouped(normals, views)


#: Row widths up to this run the grouped lighting compiled by :func:`_eval_groups_quick` (a plan's decision,
#: the validation values: the ``lighting rows`` programs of :mod:`homofac.compiling`); wider rows (the training
#: grid's) run :func:`_eval_groups` (``lighting grid``).
QUICK_WIDTH = 8


@jit(kind="lighting rows", filter=True)
def _eval_groups_quick(fn, normals, views):
    return fn.grouped(normals, views)


def evaluate_grouped(target: Target, grouped) -> np.ndarray:
    """Values at the valid pairs of a :class:`~homofac.fit.sampling.Grouped` set, in flattened order (float32
    numpy, (M, 3)).

    Uses the target's per-normal fast path (``target.fn.grouped``) when it has one, with the normals
    split over all devices when there are several (:mod:`homofac.fit.shard`). The rows' packing, blocks and
    the selection of the valid pairs are numpy on the host: as JAX operations outside a compiled program each
    would compile a program of its own per shape (``concatenate``, ``dynamic_slice``, ``gather``, ...).
    """
    if grouped.mask.size == 0 or not grouped.mask.any():
        return np.zeros((0, 3), np.float32)
    if hasattr(target.fn, "grouped"):
        grouped = packed(grouped)
        mask = np.asarray(grouped.mask)
        if getattr(target.fn, "culls_lobes", False):
            out = _culled(target.fn, jnp.asarray(grouped.normals), jnp.asarray(grouped.views))
        elif jax.device_count() > 1:
            out = grouped_sharded(target.fn, jnp.asarray(grouped.normals), jnp.asarray(grouped.views))
        else:
            out = _blocks(target.fn, np.asarray(grouped.normals), np.asarray(grouped.views))
        return np.asarray(out)[mask]
    pairs = grouped.flatten()
    return np.asarray(evaluate(target, pairs.a, pairs.b))


def evaluate_blocked(target: Target, grouped) -> np.ndarray:
    """:func:`evaluate_grouped` of a lighting target as the sum over its lights in blocks
    (:func:`homofac.light.refine.blocks`; its clamp applied to the sum), float64: one compiled program
    for every environment, whatever its light count (the validation lighting's levels,
    :mod:`homofac.fit.validation`). A target summed by a two-level light tree (``fn.tree``,
    :mod:`homofac.light.tree`) is evaluated at once: the tree reads every light of the environment."""
    fn = target.fn
    if getattr(fn, "tree", None) is not None:  # a two-level light tree sums every light of the environment at once
        return np.asarray(evaluate_grouped(target, grouped), np.float64)
    out = None
    for env in blocks(fn.env):
        part = np.asarray(evaluate_grouped(Target(target.kind, dataclasses.replace(fn, env=env, clamp=None),
                                                  target.quantity, target.context), grouped), np.float64)
        out = part if out is None else out + part
    return out if fn.clamp is None else np.minimum(out, fn.clamp)


#: Rows (normals) per call of the compiled grouped lighting (:func:`_blocks`).
BLOCK_ROWS = 256


def _blocks(fn, normals: np.ndarray, views: np.ndarray) -> np.ndarray:
    """``fn.grouped`` over blocks of :data:`BLOCK_ROWS` rows (the last padded with copies of the first
    row), so that one compiled program of shape (BLOCK_ROWS, W) serves every sample set of row width W
    (the training grids of both directions, the polish pairs, ...), whatever its number of rows; rows of
    at most :data:`QUICK_WIDTH` views by :func:`_eval_groups_quick`. The padding and
    the blocks are numpy (no program of their own)."""
    g = int(normals.shape[0])
    pad = (-g) % BLOCK_ROWS
    if pad:
        normals = np.concatenate([normals, np.broadcast_to(normals[:1], (pad, 3))])
        views = np.concatenate([views, np.broadcast_to(views[:1], (pad,) + views.shape[1:])])
    program = _eval_groups_quick if views.shape[1] <= QUICK_WIDTH else _eval_groups
    out = [program(fn, normals[i:i + BLOCK_ROWS], views[i:i + BLOCK_ROWS]) for i in range(0, g + pad, BLOCK_ROWS)]
    return np.concatenate([np.asarray(o) for o in out])[:g]


#: The per-normal work of the grouped lighting (the texel weights of every light, the local frame) in
#: views' worth of work: what one more row of :func:`packed` costs beside its views.
ROW_COST = 16


def packed(grouped: Grouped) -> Grouped:
    """The same valid pairs in the same flattened order, regrouped into rows of at most W views (a
    normal with more views gets several rows), W the power of 2 from 8 that minimises the work
    ``rows x (W + ROW_COST)``. The grid design's groups hold 1 to about 2.2x the mean count of views, so
    padding every normal to the largest evaluated the BRDF at 2.2 slots per pair (0.45 of them valid);
    the values are those of the unpacked groups (each pair is computed alike)."""
    mask = np.asarray(grouped.mask)
    counts = mask.sum(axis=1)
    if counts.size == 0 or counts.max() <= 8:
        return grouped
    widths = 8 * 2 ** np.arange(int(np.ceil(np.log2(max(counts.max() / 8, 1)))) + 1)  # 8, 16, ...: few programs
    rows = -(-counts[None, :] // widths[:, None])  # (widths, G)
    width = int(widths[np.argmin(rows.sum(axis=1) * (widths + ROW_COST))])
    if width >= mask.shape[1]:
        return grouped
    per = -(-counts // width)
    first_row = np.concatenate([[0], np.cumsum(per)[:-1]])
    group = np.repeat(np.arange(len(counts)), counts)  # group of each valid pair, flattened order
    rank = np.arange(int(counts.sum())) - np.repeat(np.cumsum(counts) - counts, counts)
    row, col = first_row[group] + rank // width, rank % width
    normals = np.repeat(np.asarray(grouped.normals), per, axis=0)
    views = np.broadcast_to(normals[:, None, :], (len(normals), width, 3)).copy()  # padding v = n (valid, unread)
    views[row, col] = np.asarray(grouped.views)[mask]
    out = np.zeros((len(normals), width), bool)
    out[row, col] = True
    return Grouped(normals, views, out)


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



__all__ = ["FIELDS", "QUICK_WIDTH", "ROW_COST", "Samples", "check_values", "evaluate", "evaluate_blocked", "evaluate_grouped", "packed"]
