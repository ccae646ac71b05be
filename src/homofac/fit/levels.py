"""The validation lighting's values on grouped pairs at one light level, each pair's value computed once.

At the fit's own light resolution the values are the target's grouped lighting
(:func:`~homofac.fit.samples.evaluate_grouped`: the program with the environment's own bound on visible
lights, half the cube texels); at a refined level (:func:`homofac.fit.validation.lighting_at`) the sum over
light blocks (:func:`~homofac.fit.samples.evaluate_blocked`: one program for every level). At light
resolution 32 on forest the grouped program is 7x faster than the blocks (20 000 pairs: 1.4 s against
10.8 s CPU), which see every light of a block as visible (docs/notes/speed.md, "A fit's fixed overhead").

The plan's decision (:func:`homofac.fit.validation.decide`) evaluates the first normals of the validation
pairs at every level it measures; :func:`remember` keeps the decided level's values, and :func:`values`
(the validation values of :func:`homofac.fit.draw.draw_samples`) reuses them for those normals and
evaluates only the rest.
"""

from __future__ import annotations

import numpy as np

from ..target import Target
from . import cache
from .sampling import Grouped
from .samples import evaluate_blocked, evaluate_grouped

#: Values kept per process (the decisions of the last few targets: a notebook or a test module).
KEEP = 4

#: (target key, refined) -> (normals, views, mask, values) of the decision's rows at the decided level.
_ROWS: dict[tuple[str, bool], tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = {}


def _key(target: Target) -> str | None:
    # the lighting's arrays (the projection context, which the values do not read, is not in the key)
    return cache.key(target, {"levels": 1}, "")


def evaluate(target: Target, grouped: Grouped, refined: bool) -> np.ndarray:
    """``target``'s values at the valid pairs of ``grouped`` (flattened order, float64): grouped at the
    fit's own light level, in light blocks at a ``refined`` one (module docstring)."""
    if refined:
        return evaluate_blocked(target, grouped)
    return np.asarray(evaluate_grouped(target, grouped), np.float64)


def remember(target: Target, grouped: Grouped, refined: bool, y: np.ndarray) -> None:
    """Keep ``y``, ``target``'s values at ``grouped`` (:func:`evaluate`), for :func:`values`."""
    k = _key(target)
    if k is None:
        return
    while len(_ROWS) >= KEEP:
        _ROWS.pop(next(iter(_ROWS)))
    _ROWS[k, bool(refined)] = (np.asarray(grouped.normals), np.asarray(grouped.views), np.asarray(grouped.mask),
                               np.asarray(y))


def values(target: Target, grouped: Grouped, refined: bool) -> np.ndarray:
    """:func:`evaluate` of ``target`` at ``grouped``, the leading normals whose values :func:`remember`
    kept (the same normals, views and mask) taken from there, only the others evaluated."""
    k = _key(target)
    hit = _ROWS.get((k, bool(refined))) if k is not None else None
    rows = 0
    if hit is not None:
        normals, views, mask, _ = hit
        n = len(normals)
        if (n <= len(grouped.normals) and np.array_equal(normals, np.asarray(grouped.normals)[:n])
                and np.array_equal(views, np.asarray(grouped.views)[:n])
                and np.array_equal(mask, np.asarray(grouped.mask)[:n])):
            rows = n
    if rows == 0:
        return evaluate(target, grouped, refined)
    rest = Grouped(np.asarray(grouped.normals)[rows:], np.asarray(grouped.views)[rows:],
                   np.asarray(grouped.mask)[rows:])
    y = hit[3]
    if not rest.mask.any():
        return y
    return np.concatenate([y, evaluate(target, rest, refined)])


__all__ = ["KEEP", "evaluate", "remember", "values"]
