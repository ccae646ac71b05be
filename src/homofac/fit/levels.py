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

:func:`refined` gives the decision's refined levels without a program of their own: the lighting with
the bright texels refined is the fit's lighting plus the difference of those texels' fine and coarse
lights (the light sum is linear in the lights), evaluated in blocks by the fit's own compiled program.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np

from ..light.environment import Environment
from ..light.geometry import light_geometry
from ..light.lighting import max_visible
from ..light.lights import light_corners, light_moments
from ..light.refine import difference_blocks
from ..light.tree import texel_resolution
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


def evaluate(target: Target, grouped: Grouped, refined: bool, start: Target | None = None) -> np.ndarray:
    """``target``'s values at the valid pairs of ``grouped`` (flattened order, float64): grouped at the
    fit's own light level; at a ``refined`` one summed over every light, as the fit's lighting ``start``
    plus the refined texels' difference in its program where :data:`VALUE_BLOCKS` blocks hold it
    (:func:`refined`), else in light blocks (module docstring), or by its light tree."""
    if refined:
        if start is not None:
            y = refined_values(start, target, grouped, VALUE_BLOCKS)
            if y is not None:
                return y
        return evaluate_blocked(target, grouped)
    return np.asarray(evaluate_grouped(target, grouped), np.float64)


def refined_values(start: Target, fine: Target, grouped: Grouped, max_blocks: int) -> np.ndarray | None:
    """:func:`refined` from ``start``'s own values (evaluated only where it applies), None where it does not."""
    return refined(start, fine, grouped, lambda: np.asarray(evaluate_grouped(start, grouped), np.float64), max_blocks)


#: The most blocks :func:`refined` evaluates: each costs about one evaluation at the fit's own lights, and
#: a refined level's own lighting program about 4.6 s CPU to compile (the light tree at 64 on forest 32,
#: against 0.14-0.3 s per block on the decision's 2048 pairs; docs/notes/speed.md, "fast, sixteenth session").
MAX_BLOCKS = 12
#: The most blocks of :func:`refined` for the validation values (20 000 pairs: about 1.4 s CPU per block,
#: against the light blocks' own program, about 3 s to compile and 5 s per 4096 lights on them).
VALUE_BLOCKS = 4


def _within(block: Environment, normals: np.ndarray, visible: int, straddlers: int) -> bool:
    """Whether, for every normal, ``block``'s lights above or across its horizon (an upper bound of those
    with w_k(n) > 0) fit in ``visible`` slots and those that can cross it in ``straddlers`` (the static
    bounds of the compiled program that evaluates it, :func:`homofac.light.lighting.max_visible`,
    :func:`homofac.light.geometry.light_geometry`)."""
    m, sinr = (np.asarray(a, np.float64) for a in light_moments(block))
    n = np.asarray(normals, np.float64).reshape(-1, 3)
    d = np.asarray(block.directions, np.float64)
    near = (np.abs(n @ d.T) <= sinr[None]) & (sinr[None] >= 0)
    up = (n @ m.T > -1e-6) & (np.abs(m).sum(axis=1) > 0)[None]
    return bool((near.sum(axis=1) <= straddlers).all() and ((up | near).sum(axis=1) <= visible).all())


def refined(target: Target, fine: Target, grouped: Grouped, y: np.ndarray | Callable[[], np.ndarray],
            max_blocks: int = MAX_BLOCKS) -> np.ndarray | None:
    """``fine``'s values at ``grouped``, where ``fine`` is ``target`` with its brightest texels refined (the
    mixture of :func:`homofac.fit.validation.lighting_at`, summed over every light), from ``y``, ``target``'s
    values there (:func:`evaluate`; or a function giving them, called only where this applies): ``y`` plus
    the lighting of :func:`homofac.light.refine.difference_blocks`, each block evaluated by ``target``'s own
    compiled program. The blocks are made small enough that every
    normal of ``grouped`` finds its lights within that program's static bounds; None where that takes more
    than ``max_blocks`` blocks, or the lighting is clamped or summed by a light tree (not a sum over lights)."""
    fn = target.fn
    if any(getattr(f, "clamp", None) is not None or getattr(f, "tree", None) is not None for f in (fn, fine.fn)):
        return None
    env = fn.env
    visible = max_visible(env)
    straddlers = light_geometry(env.directions, env.solid_angle, light_corners(env), texel_resolution(env),
                                moments=light_moments(env)).max_straddlers
    size = visible
    while True:
        blocks = difference_blocks(env, fine.fn.env, size)
        if len(blocks) > max_blocks:
            return None
        if all(_within(b, grouped.normals, visible, straddlers) for b in blocks):
            break
        size //= 2
    out = np.asarray(y() if callable(y) else y, np.float64)
    for b in blocks:
        out = out + np.asarray(evaluate_grouped(Target(target.kind, dataclasses.replace(fn, env=b), target.quantity,
                                                       target.context), grouped), np.float64)
    return out


def remember(target: Target, grouped: Grouped, refined: bool, y: np.ndarray) -> None:
    """Keep ``y``, ``target``'s values at ``grouped`` (:func:`evaluate`), for :func:`values`."""
    k = _key(target)
    if k is None:
        return
    while len(_ROWS) >= KEEP:
        _ROWS.pop(next(iter(_ROWS)))
    _ROWS[k, bool(refined)] = (np.asarray(grouped.normals), np.asarray(grouped.views), np.asarray(grouped.mask),
                               np.asarray(y))


def values(target: Target, grouped: Grouped, refined: bool, start: Target | None = None) -> np.ndarray:
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
        return evaluate(target, grouped, refined, start)
    rest = Grouped(np.asarray(grouped.normals)[rows:], np.asarray(grouped.views)[rows:],
                   np.asarray(grouped.mask)[rows:])
    y = hit[3]
    if not rest.mask.any():
        return y
    return np.concatenate([y, evaluate(target, rest, refined, start)])


__all__ = ["KEEP", "MAX_BLOCKS", "VALUE_BLOCKS", "evaluate", "refined", "refined_values", "remember", "values"]
