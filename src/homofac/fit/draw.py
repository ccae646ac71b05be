"""Drawing samples: the target evaluated on the training pairs and on a seeded validation set.

Sampling (thesis §4.2 / §5.6) dominates a lighting fit; :func:`draw_samples` reads the result from the
on-disk cache of :mod:`homofac.fit.cache` when the same target was sampled the same way before.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from ..errors import HomofacError
from ..options import validate
from ..param import parametrizations as pz
from ..param import projections as pj
from ..target import Target
from . import cache, levels, sampling, scene
from .options import DEFAULT_VALIDATION, SamplingOptions
from .samples import Samples, evaluate, evaluate_grouped

#: Views per normal of the lighting validation pairs (``count / VALIDATION_VIEWS`` random normals). Under a
#: sun the squared error sits on the few pairs whose view grazes and reflects it, so the figure depends on
#: whether some normal lands there: on sqrt(count) normals (141 for 20000 pairs) one plastic / city fit read
#: 0.239 nrmse where 3000 normals read 0.067, and the chooser ranked the candidates by that noise
#: (docs/notes/sums-research.md). 2500 normals cost 1.2 s against 0.25 s at light resolution 32.
VALIDATION_VIEWS = 8


def default_mapper(kind: str) -> str:
    """parabolic for BRDF targets (hemisphere), dual_paraboloid for lighting (sphere)."""
    return "parabolic" if kind == "brdf" else "dual_paraboloid"


def draw_samples(target: Target, parametrization: str, options: SamplingOptions | dict | None = None,
                 log: Callable[[str], None] | None = None, *, validation_target: Target | None = None,
                 validation_light: int | None = None) -> Samples:
    """Sample the target on training pairs (thesis §4.2 / §5.6) and on a seeded validation set.

    ``options``: :class:`~homofac.fit.options.SamplingOptions` or a dict of them. With ``cache`` (the
    default) the samples are read from, or written to, the on-disk cache, keyed by a hash of the target
    and the sampling settings (and, for BRDF targets, the parametrization, whose texel iterator decides
    the pairs). ``validation_target``: the target the validation values are read from (the lighting at
    the plan's validation resolution ``validation_light``, :func:`homofac.fit.validation.lighting_at`;
    default ``target``). With ``validation_light`` the validation values are those of the plan's decision's
    program at that level (:func:`homofac.fit.levels.values`: grouped at the fit's own light resolution,
    in light blocks at a refined one), the decision's pairs not evaluated again.
    """
    log = log or (lambda msg: None)
    s = counted(validate(SamplingOptions, options, "sampling"))
    settings = cache_settings(s, target.kind, parametrization, target.context)
    if validation_target is not None and validation_target is not target:
        settings["validation_light"] = int(validation_light or 0)
        tree = getattr(validation_target.fn, "tree", None)
        if tree is not None:  # the two-level light sum (homofac.fit.validation.light_sum)
            settings["validation_sum"] = [tree.coarse, tree.refine]
    if s.kind == "scene":  # the mesh file's content and the cameras (a bundled scene's own), not only names
        settings["mesh_sha256"] = scene.fingerprint(s)
        settings["cameras"] = [c.model_dump() for c in scene.resolve_cameras(s)]
    k = cache.key(target, settings, parametrization) if s.cache else None
    if k is not None:
        hit = cache.load(k, validation=s.validation)
        if hit is not None:
            log(f"samples from cache {k[:12]} ({len(hit.a)} training pairs)")
            return hit
    samples = _draw(target, parametrization, s, log, validation_target or target, validation_light)
    samples = Samples(*(np.ascontiguousarray(x, np.float32) for x in samples))
    if k is not None:
        cache.store(k, samples)
    return samples


def grid_projection(kind: str, parametrization: str, s: SamplingOptions) -> str:
    """The direction the ``grid`` design puts on texel centres beside ``n``: the parametrization's
    reflection-like projection (``r``, or ``r_off`` for NRO and RO)."""
    if kind != "lighting" or s.kind != "grid" or parametrization not in pz.PARAMETRIZATIONS:
        return "r"
    return pz.reflection_projection(parametrization)


def counted(s: SamplingOptions) -> SamplingOptions:
    """``s`` with its validation count: not given (None), :data:`~homofac.fit.options.DEFAULT_VALIDATION`
    (the plan resolves a preset's count before: :func:`homofac.fit.plan.validation_count`)."""
    return s if s.validation is not None else s.model_copy(update={"validation": DEFAULT_VALIDATION})


def cache_settings(s: SamplingOptions, kind: str, parametrization: str, context: dict) -> dict:
    """The sampling settings that key the sample cache: the options, and for a grid design on another
    projection than ``r`` that projection and its context (``r_off``'s beta)."""
    settings = s.model_dump()
    proj = grid_projection(kind, parametrization, s)
    if proj != "r":
        keys = pj.get(proj).context
        settings["grid_projection"] = {"projection": proj, **{k: np.asarray(context[k]).tolist() for k in keys}}
    return settings


def draw_pairs(kind: str, parametrization: str, s: SamplingOptions, context: dict | None = None):
    """The direction pairs of a sampling, without values: ``(train, validation, groups, val_groups)``
    (:class:`~homofac.fit.sampling.Pairs`; for lighting targets also the pairs grouped by normal, whose
    flattening they are). Deterministic: the same settings give the same pairs (refits rely on it).
    ``context``: the target's projection context (the grid design of NRO reads ``shift``)."""
    s = counted(s)
    smapper = s.mapper or default_mapper(kind)
    if s.kind == "scene":
        if kind != "lighting":
            raise HomofacError("sampling.kind: scene draws the (n, v) pairs of a scene, for lighting targets")
        sc = scene.load(s)  # rendered once per process (homofac.fit.scene)
        groups = sc.pairs(s.count, s.seed)
        vgroups = sc.pairs(s.validation, s.seed + 1) if s.validation else sc.grouped(np.zeros(0, np.int64))
        return groups.flatten(), vgroups.flatten(), groups, vgroups
    if kind == "lighting":
        # grouped by normal: per-normal work (weights, frames, diffuse, horizon culling) done once
        groups = sampling.grouped_pairs(s.kind, s.size, mapper=smapper, count=s.count, seed=s.seed,
                                        view_size=s.view_size, projection=grid_projection(kind, parametrization, s),
                                        context=context)
        vgroups = sampling.grouped_random(s.validation, s.seed + 1, views=VALIDATION_VIEWS)
        return groups.flatten(), vgroups.flatten(), groups, vgroups
    pairs = sampling.sample_pairs(
        kind, s.kind, s.size, mapper=smapper, parametrization=parametrization,
        count=s.count, seed=s.seed, view_size=s.view_size,
    )
    return pairs, sampling.random_pairs(kind, s.validation, s.seed + 1), None, None


def _draw(target: Target, parametrization: str, s: SamplingOptions, log: Callable, vtarget: Target,
          level: int | None = None) -> Samples:
    if s.kind == "scene" and target.kind == "lighting":
        # the exact lighting at every covered pixel, evaluated once (the scene metrics reuse it), then
        # gathered at the drawn pixels: the pairs of draw_pairs, in its order
        sc = scene.load(s)
        train = sc.draw(s.count, s.seed)
        val = sc.draw(s.validation, s.seed + 1) if s.validation else np.zeros(0, np.int64)
        log(f"sampling the scene's {len(sc)} covered pixels ({len(train)} training pairs)")
        y = sc.exact(target)
        val_y = y[val] if vtarget is target or not len(val) else np.asarray(
            evaluate(vtarget, sc.normals[val], sc.views[val]))
        return Samples(sc.normals[train], sc.views[train], y[train], sc.normals[val], sc.views[val], val_y)
    pairs, val, groups, vgroups = draw_pairs(target.kind, parametrization, s, target.context)
    if len(pairs) == 0:
        raise HomofacError("sampling produced no valid direction pairs; increase sampling.size")
    if groups is not None:
        log(f"sampling {len(pairs)} training pairs ({len(groups.normals)} normals)")
        y = np.asarray(evaluate_grouped(target, groups))
        if len(val) and vtarget is not target:
            log(f"validation values of {len(val)} pairs on {vtarget.fn.env.num_lights} lights")
        # at a plan's validation lighting (``level``): its decision's program, its decision's pairs reused
        env = getattr(target.fn, "env", None)
        own = int((env.info.get("resolution") if env is not None else 0) or 0)
        val_y = (np.zeros((0, 3), np.float32) if not len(val) else np.asarray(evaluate_grouped(target, vgroups))
                 if not level and vtarget is target else levels.values(vtarget, vgroups, refined=int(level or 0) != own,
                                                                      start=target))
        return Samples(pairs.a, pairs.b, y, val.a, val.b, val_y)
    log(f"sampling {len(pairs)} training pairs")
    y = np.asarray(evaluate(target, pairs.a, pairs.b))
    val_y = np.asarray(evaluate(vtarget, val.a, val.b)) if len(val) else np.zeros((0, 3), np.float32)
    return Samples(pairs.a, pairs.b, y, val.a, val.b, val_y)


__all__ = ["cache_settings", "counted", "default_mapper", "draw_pairs", "draw_samples", "grid_projection"]
