"""Material libraries: one layout, many right-hand sides (issue 15).

:func:`factorize_many` factors a list of targets (materials under one environment, or one material
under several environments) on one layout: the same sample directions, the same system matrix.

1. The directions are drawn once (:func:`homofac.fit.draw.draw_pairs`). The values of lighting targets
   of a BRDF in lobe form that share an environment come from one evaluation: the per-lobe sums of
   :func:`homofac.fit.transport.lobe_sums` are computed once per distinct lobe *shape* (roughness,
   exponent), vmapped over the shapes so the geometry of every normal is shared, and each material is
   a linear combination of them with its colours (kd, ks, F0). Other targets are sampled one by one.
2. Products: the system rows (thesis eq. 37) are built once, and every target is solved by the
   ``lsmr`` solver from its own §3.1.2 start in one LSMR run: the targets' RGB channels are the
   columns of one block-diagonal least-squares problem (as the three channels of one product already
   are), so one Krylov iteration serves all of them (each result is what a full run of that target
   gives, tested within 1%). Sums of products, baselines and fits that choose their structure or size
   (``target_error``, ``max_lookups``) are fitted per target on the shared samples (after the first
   target's choice, which fixes the layout of the others).
3. The metrics are measured per target from shared footprints.

Every result is a normal :class:`~homofac.fit.result.Result` with a state (refits work on each).
"""

from __future__ import annotations

import functools
import hashlib
import json
import time
from typing import Callable, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from ..errors import HomofacError
from ..light import Lighting, with_context
from ..target import Target, evaluate
from ..param import parametrizations as pz
from . import cache, programs, scene, transport
from .draw import cache_settings, default_mapper, draw_pairs
from .options import FitOptions
from .pipeline import factorize, options, quality_warnings, resolve_sampling
from .product import zeros_rule
from .result import Result
from .samples import Samples, check_values, evaluate_grouped
from .refit import layout_of, measure_all, product_models, refit, system_rows
from .solvers.lsmr import _lsmr as lsmr_solve
from .start import starting_solution
from .state import from_layout
from .system import adjoint_plan, apply, augmented_rhs, log_transform, sample_mean

#: Keywords of factorize that are not fit options (they describe one target's run).
RUN_KEYWORDS = ("samples", "config", "target_info", "log", "keep_samples")


def _environment_key(fn: Lighting) -> tuple:
    h = hashlib.sha256(transport.geometry_key(fn.env).encode())
    h.update(np.ascontiguousarray(np.asarray(fn.env.radiance, np.float32)).tobytes())
    return (h.hexdigest(), fn.clamp, fn.horizon, fn.brdf.model)


def library_values(targets: Sequence[Target], groups, val_groups, pairs, val_pairs,
                   log: Callable[[str], None]) -> list[tuple[np.ndarray, np.ndarray]]:
    """Every target's values at the shared training and validation pairs (see the module doc, 1.)."""
    out: list = [None] * len(targets)
    shared: dict = {}
    for i, t in enumerate(targets):
        if groups is not None and transport.supported(t.fn):
            shared.setdefault(_environment_key(t.fn), []).append(i)
    for members in shared.values():
        shapes: dict = {}
        for i in members:
            shapes.setdefault(transport.shape_key(targets[i].fn.brdf), []).append(i)
        first = [targets[idx[0]].fn.brdf for idx in shapes.values()]
        fn0 = targets[members[0]].fn
        log(f"sampling {len(members)} materials ({len(first)} lobe shapes) at {len(pairs)} training pairs")
        parts = []
        for g in (groups, val_groups):
            if g.mask.any():
                parts.append((g, transport.lobe_sums(first, fn0.env, g.normals, g.views, horizon=fn0.horizon)))
            else:
                parts.append((g, None))
        order = [i for idx in shapes.values() for i in idx]
        shape_of = [s for s, idx in enumerate(shapes.values()) for _ in idx]
        ys = [np.asarray(transport.combine_many([targets[i].fn.brdf for i in order], sums, shape_of, g.normals,
                                                g.views, fn0.clamp))[:, g.mask]
              if sums is not None else np.zeros((len(order), 0, 3), np.float32) for g, sums in parts]
        for j, i in enumerate(order):
            out[i] = (ys[0][j], ys[1][j])
    for i, t in enumerate(targets):
        if out[i] is not None:
            continue
        log(f"sampling material {i + 1} of {len(targets)}")
        if groups is not None:
            y = np.asarray(evaluate_grouped(t, groups))
            v = np.asarray(evaluate_grouped(t, val_groups)) if len(val_pairs) else np.zeros((0, 3), np.float32)
        else:
            y = np.asarray(evaluate(t, pairs.a, pairs.b))
            v = np.asarray(evaluate(t, val_pairs.a, val_pairs.b)) if len(val_pairs) else np.zeros((0, 3), np.float32)
        out[i] = (y, v)
    return out


def _samples(targets, parametrization, s, log) -> tuple[list[Samples], object]:
    """The shared directions and every target's samples (from the sample cache where it has them)."""
    kind = targets[0].kind
    pairs, val, groups, vgroups = draw_pairs(kind, parametrization, s, targets[0].context)
    if len(pairs) == 0:
        raise HomofacError("sampling produced no valid direction pairs; increase sampling.size")
    settings = cache_settings(s, kind, parametrization, targets[0].context)
    keys = [cache.key(t, settings, parametrization) if s.cache else None for t in targets]
    hits = [cache.load(k, validation=s.validation) if k is not None else None for k in keys]
    todo = [i for i, h in enumerate(hits) if h is None]
    values = library_values([targets[i] for i in todo], groups, vgroups, pairs, val, log) if todo else []
    out = list(hits)
    for i, (y, v) in zip(todo, values):
        smp = Samples(pairs.a, pairs.b, np.ascontiguousarray(y, np.float32), val.a, val.b,
                      np.ascontiguousarray(v, np.float32))
        out[i] = smp
        if keys[i] is not None:
            cache.store(keys[i], smp)
    return out, groups


def factorize_many(targets: Sequence[Target], parametrization: str | None = None, *, configs: Sequence[dict] | None = None,
                   target_infos: Sequence[dict] | None = None, log: Callable[[str], None] | None = None,
                   keep_samples: bool = False, **keywords) -> list[Result]:
    """Factor every target on one layout (see the module docstring); one :class:`Result` per target.

    ``keywords`` are those of :func:`homofac.fit.factorize` (``mapper``, ``texture_size``, ``sampling``,
    ``solver``, ``terms``, ...), validated once; ``configs`` and ``target_infos`` are recorded per
    result. All targets must be of one kind.
    """
    log = log or (lambda msg: None)
    programs.bound_compiled_programs()
    programs.enable_compilation_cache()
    t_start = time.perf_counter()
    targets = list(targets)
    if not targets:
        raise HomofacError("factorize_many needs at least one target")
    bad = [i for i, t in enumerate(targets) if not isinstance(t, Target)]
    if bad:
        raise HomofacError(f"factorize_many: target {bad[0]} is a {type(targets[bad[0]]).__name__}, not a homofac Target")
    kinds = {t.kind for t in targets}
    if len(kinds) > 1:
        raise HomofacError(f"factorize_many: all targets must be of one kind, got {', '.join(sorted(kinds))}")
    for name in RUN_KEYWORDS:
        if name in keywords:
            raise HomofacError(f"factorize_many: {name} is per target; use configs=, target_infos=, log=, keep_samples=")
    for what, seq in (("configs", configs), ("target_infos", target_infos)):
        if seq is not None and len(seq) != len(targets):
            raise HomofacError(f"factorize_many: {len(seq)} {what} for {len(targets)} targets")
    opts = options(parametrization, **keywords)
    kind = targets[0].kind
    if kind == "lighting" and opts.parametrization in pz.PARAMETRIZATIONS:
        targets = [with_context(t, opts.parametrization) for t in targets]  # NRHD's dominant light, NRO's shift
    mapper = opts.mapper or default_mapper(kind)
    t0 = time.perf_counter()
    resolved = resolve_sampling(opts, kind, mapper)
    grids = {json.dumps(cache_settings(resolved, kind, opts.parametrization, t.context).get("grid_projection"))
             for t in targets}  # one entry unless the grid lies on r_off with different shifts
    if len(grids) > 1:
        raise HomofacError(f"{opts.parametrization} on grid samples: the materials' off-specular shifts differ, so "
                           f"they share no training pairs; fit them one by one or give them one shift (lighting_target(..., shift=))")
    samples, _ = _samples(targets, opts.parametrization, resolved, log)
    sc = scene.load(resolved) if resolved.kind == "scene" else None  # image-space metrics of every target
    sample_s = time.perf_counter() - t0
    for smp in samples:
        check_values(np.asarray(smp.y), "training")
    configs = list(configs) if configs is not None else [None] * len(targets)
    infos = list(target_infos) if target_infos is not None else [None] * len(targets)
    contexts = {tuple(sorted((k, np.asarray(v).tobytes()) for k, v in t.context.items())) for t in targets}
    batched = (opts.target_error is None and not opts.is_sum and opts.parametrization in pz.PARAMETRIZATIONS
               and opts.solver.method == "lsmr" and int(opts.solver.levels) == 1 and len(contexts) == 1
               and all(zeros_rule(t, opts.solver) == "bias" for t in targets))
    if batched:
        state = from_layout(opts, kind, samples[0], mapper, scene=sc)
        p, layout = layout_of(state)
    if not batched:
        return _one_by_one(targets, opts, samples, configs, infos, keep_samples, log, sample_s, t_start)
    t1 = time.perf_counter()
    sys = system_rows(state, targets[0])
    eps = float(opts.solver.epsilon)
    lam = float(opts.solver.laplacian)
    alphas, rhs, side, bnorm2 = (np.asarray(a) for a in _log_sides(jnp.asarray(np.stack([s.y for s in samples])),
                                                                     jnp.float32(eps)))
    x0 = np.asarray(starting_solution(sys._replace(rhs=jnp.asarray(side)), layout, p.J))
    x0 = x0.reshape(layout.n_unknowns, len(rhs), 3).transpose(1, 0, 2)
    xs, steps, ok, objs = _solve_all(sys, adjoint_plan(sys), jnp.asarray(rhs), jnp.asarray(x0), jnp.float32(lam),
                                     rtol=float(opts.solver.tolerance), max_steps=int(opts.solver.max_iterations))
    xs, steps, ok, objs = np.asarray(xs, np.float64), np.asarray(steps), np.asarray(ok), np.asarray(objs, np.float64)
    method = opts.solver.method
    log(f"solved {len(targets)} right-hand sides of one system ({layout.n_unknowns} unknowns), "
        + f"{int(steps.max())} LSMR iterations")
    built = []
    models = product_models(targets[0], p, layout, xs, alphas)  # one context (checked above)
    for i, (t, smp) in enumerate(zip(targets, samples)):
        model = models[i]
        obj = float(objs[i])
        bn = float(bnorm2[i])
        solver = {"method": method, "iterations": int(steps[i]), "converged": bool(ok[i]),
                  "tolerance": float(opts.solver.tolerance), "max_iterations": int(opts.solver.max_iterations),
                  "laplacian": lam, "epsilon": eps, "objective": obj,
                  "residual": float(np.sqrt(obj / bn)) if bn > 0 else float(np.sqrt(obj)), "library": len(targets)}
        built.append(Result(model, solver=solver, config=configs[i] or {}, target_info=infos[i] or {}, state=state,
                            target=t, samples=smp if keep_samples else None))
    solve_s = time.perf_counter() - t1
    t2 = time.perf_counter()
    every = measure_all(state, built, targets, samples, eps)  # one program for all targets
    n = len(targets)
    total = time.perf_counter() - t_start
    results = []
    for res, t, smp, mets in zip(built, targets, samples, every):
        if sc is not None:
            mets = {**mets, "scene": sc.metrics(res, t, eps)}
        res = res.replace(metrics=mets, warnings=tuple(quality_warnings(mets)))
        measure_s = (time.perf_counter() - t2) / n
        results.append(res.replace(
            timings={"sample_s": sample_s / n, "solve_s": solve_s / n, "measure_s": measure_s,
                     "total_s": total / n + measure_s, "library_sample_s": sample_s,
                     "library_solve_s": solve_s},
            counts={"train": int(len(smp.a)), "validation": int(len(smp.val_a)), "unknowns": int(layout.n_unknowns),
                    "lights": int(getattr(t.fn, "n_lights", 0)), "library": n,
                    **({"scene_pixels": len(sc)} if sc is not None else {})}))
    return results


@jax.jit
def _log_sides(ys, eps):
    """Every target's alpha (T, 3) and log right-hand side (T, m, 3) of eq. 26 as a single fit builds them
    (:func:`homofac.fit.system.sample_mean`, :func:`~homofac.fit.system.log_transform`), the sides next to
    each other (m, 3 T) for the start (its columns are independent in §3.1.2), and their squared norms."""
    alphas = jax.vmap(sample_mean)(ys)
    rhs = jax.vmap(log_transform, in_axes=(0, 0, None))(ys, alphas, eps)
    side = jnp.transpose(rhs, (1, 0, 2)).reshape(rhs.shape[1], -1)
    return alphas, rhs, side, jnp.sum(rhs.astype(jnp.float32) ** 2, axis=(1, 2))


@functools.partial(jax.jit, static_argnames=("rtol", "max_steps"))
def _solve_all(sys, plan, rhs, x0, lam, *, rtol: float, max_steps: int):
    """LSMR (the ``lsmr`` solver: column-scaled, from each target's §3.1.2 start) on the targets' right-hand
    sides of one system side by side: the T targets' RGB channels are the 3T columns of one block-diagonal
    least-squares problem ``min sum_c ||A x_c - b_c||^2`` (the channels of one product already are), whose
    minimiser is every target's own. One Krylov iteration serves every column (the operator's gathers are
    shared; the transposed products gather by ``plan``, :func:`~homofac.fit.system.adjoint_plan`: their
    scatter was 3/4 of an iteration at 48 columns), where a vmap ran T LSMRs with their own scalars.
    Returns x (T, n, 3), steps and success (one value for all, broadcast per target) and each target's objective ``||A x - b||^2 + ||lambda L x||^2``
    (:func:`homofac.fit.system.objective` per target, from the same program)."""
    t, m, c = rhs.shape
    n = x0.shape[1]
    wide = sys._replace(rhs=jnp.transpose(rhs, (1, 0, 2)).reshape(m, t * c))
    x, steps, ok = lsmr_solve(wide, lam, jnp.transpose(x0, (1, 0, 2)).reshape(n, t * c), rtol=rtol, max_steps=max_steps,
                              plan=plan)
    r = apply(wide, lam, x) - augmented_rhs(wide)
    objs = jnp.sum(jnp.sum(r * r, axis=0).reshape(t, c), axis=1)
    return (jnp.transpose(x.reshape(n, t, c), (1, 0, 2)), jnp.broadcast_to(steps, (t,)), jnp.broadcast_to(ok, (t,)),
            objs)


def _one_by_one(targets, opts: FitOptions, samples, configs, infos, keep_samples, log, sample_s, t_start):
    """Per-target fits on the shared samples: the first one fixes the layout (its choice, when it chooses)."""
    kw = {k: v for k, v in opts.model_dump().items() if v is not None}
    name = kw.pop("parametrization")
    results = []
    n = len(targets)
    first = None
    for i, (t, smp) in enumerate(zip(targets, samples)):
        log(f"fitting material {i + 1} of {n}")
        if first is None or not (opts.target_error is not None or opts.max_lookups is not None
                                 or opts.preset is not None):
            res = factorize(t, name, samples=smp, config=configs[i], target_info=infos[i], log=log,
                            keep_samples=keep_samples, **kw)
            first = first or res
        else:  # the first target's choice fixes the layout of the others
            res = refit(first, target=t, samples=smp, start="fresh", config=configs[i] or {},
                                  target_info=infos[i] or {}, keep_samples=keep_samples, log=log)
        results.append(res.replace(timings={**res.timings, "sample_s": sample_s / n, "library_sample_s": sample_s}))
    return results


__all__ = ["factorize_many", "library_values"]
