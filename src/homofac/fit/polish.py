"""Off-grid polish of a grid ALS sum of products (issue 13, item 6: where the error lives).

The grid design (``sampling.kind: grid``) puts every training pair at the centres of the n and r
texels, which is what makes block ALS exact and fast (:mod:`homofac.fit.als`); but at a texel centre
a bilinear lookup returns that texel, so the fit never sees the model *between* texel centres, where a
renderer mostly reads it. Where the lighting has detail at the texel scale (a near-mirror, small lamps)
the grid fit is good at the centres and poor between them: on the 16-case accuracy benchmark the
near-mirror under small lamps had a training nrmse of 0.27 against 0.56 on uniform (n, v) pairs.

``linear: {polish: N}`` follows the ALS fit with N Levenberg-Marquardt steps (:mod:`homofac.fit.refine`,
matrix-free, bilinear footprints) on the grid pairs *and* texel-sampled pairs between them
(``sampling.kind: texels`` at ``polish_size``, the sampling's seed; their values cost one more lighting
evaluation), warm-started from the ALS textures, with the same smoothing. The grid pairs stay: on the
off-grid pairs alone the fit lost the sun's glints (gold under the city sun 0.277 -> 0.297 with texel
pairs, 0.325 with 300 000 random ones, 0.275 with both sets), while the near-mirror under small lamps
gained either way (0.586 -> 0.500 alone, 0.527 with both). It minimises the objective of the ALS fit:
with ``nv_balance``, the n.v-bin weights of the union of both sets of pairs. Refits polish again on the
same pairs (deterministic), so a refit equals its full run.

``linear.ridge: M`` runs a second stage of as many steps with M pairs on the grazing ridge of the
brightest light(s) added (:mod:`homofac.fit.ridge`), weighted as the share of uniform pairs they stand
for; the polish's own pairs on the ridge get weight 0. The objective stays the one of uniform pairs;
its sampled estimate now sees the ridge, which the grid and texel pairs all but miss (plastic under the
city sun, 16 lookups: 0.118 nrmse on 270 000 uniform pairs after the first stage, 0.064 after the
second; docs/notes/sums-research.md, "The grazing ridge of the sun"). The lights are those of the structure's
highlight terms, else the brightest one (:func:`ridge_lights`); the pairs are seeded by the sampling
seed. :func:`ridge_validation` and :func:`ridge_nrmse` give the validation estimate the same stratum.
The chooser also tries the ridge stage straight from the ALS fit (``direct``), which is what the gold
under the city sun needs, and keeps the stage of lowest validation error (:func:`polish_stages`).
"""

from __future__ import annotations

import time
from typing import Callable, NamedTuple

import jax.numpy as jnp
import numpy as np

from ..errors import HomofacError
from ..factorization import Factorization, evaluate_by_factor
from ..light import brightest_directions
from ..param import projections as pj
from ..target import Target
from ..options import validate
from .draw import draw_pairs, draw_samples
from .metrics import CHUNK, _chunks
from .options import LinearOptions, SamplingOptions
from .result import Result
from .ridge import RidgePairs, in_any_ridge, ridge_pairs, stratified_nrmse
from .samples import Samples, evaluate, evaluate_grouped, row_width, row_work
from .sampling import Grouped
from .structures import Structure
from .sums import SumFit, fit_sum, line_size_of, with_highlight_context


#: How much more grouped-lighting work (:func:`homofac.fit.samples.row_work`) the polish's off-grid pairs may take in
#: rows of the training grid's width than in their own, to run the grid's compiled program instead of compiling one:
#: on gold / forest ``balanced``'s 100 352 pairs cost 1.25x in rows of 64 (the grid's) and saved 3.4 s CPU of 6.8
#: (the compile of a program of their own width, 112); docs/notes/speed.md, "balanced, twenty-second session".
SHARED_WIDTH_WORK = 1.5


def shared_width(mask: np.ndarray, width: int | None) -> int | None:
    """``width`` (the training grid's rows) where the groups of valid views ``mask`` cost at most
    :data:`SHARED_WIDTH_WORK` times their own packing's work in rows of it, else None (their own width)."""
    counts = np.asarray(mask).sum(axis=1)
    if width is None or counts.size == 0 or not counts.any():
        return None
    own = min(row_width(counts), int(np.asarray(mask).shape[1]))
    return int(width) if row_work(counts, width) <= SHARED_WIDTH_WORK * row_work(counts, own) else None


def polish_pairs(target: Target, parametrization: str, lin: LinearOptions, seed: int, cache: bool,
                 log: Callable[[str], None], stride: int = 1, width: int | None = None) -> Samples:
    """The off-grid training pairs of the polish (texel sampling at ``lin.polish_size``, no validation);
    with ``stride`` k > 1 every k-th view of each normal of them (about 1/k of the pairs: a strided polish,
    the plan's ``polish_stride``), only those evaluated, in rows of ``width`` views where given and not
    much costlier (:func:`shared_width`; :func:`homofac.fit.samples.packed`: the training grid's width,
    :func:`homofac.fit.samples.row_width_of`, so that they run the grid's compiled lighting program instead of
    compiling one of their own)."""
    settings = {"kind": "texels", "size": int(lin.polish_size), "validation": 0, "seed": int(seed),
                "cache": bool(cache)}
    if stride <= 1 or target.kind != "lighting":
        return draw_samples(target, parametrization, settings, log)
    _, _, groups, _ = draw_pairs(target.kind, parametrization, validate(SamplingOptions, settings, "sampling"),
                                 target.context)
    part = Grouped(groups.normals, groups.views[:, ::stride], groups.mask[:, ::stride])
    pairs = part.flatten()
    log(f"sampling {len(pairs.a)} training pairs (every {stride}th of the polish's {int(groups.mask.sum())})")
    y = np.asarray(evaluate_grouped(target, part, shared_width(part.mask, width)), np.float32)
    none = np.zeros((0, 3), np.float32)
    return Samples(pairs.a, pairs.b, y, none, none, none)


class OffGridFigures(NamedTuple):
    """The residual of a fit on the polish's two sets of pairs (:func:`off_grid_figures`)."""

    grid: float  # mean squared residual (per pair and channel) on the grid pairs the polish fits
    off: float  # ... on its off-grid pairs
    ratio: float  # off / grid: what the off-grid pairs add to the polish's objective, per pair
    validation: float  # ... on the validation pairs (uniform: another distribution than the grid's), for comparison


def off_grid_figures(model, samples: Samples, pairs: Samples, stride: int = 1, chunk: int = CHUNK) -> OffGridFigures:
    """The mean squared residual of ``model`` on every ``stride``-th grid pair of ``samples``, on the off-grid
    ``pairs`` (:func:`polish_pairs`) and on the validation pairs of ``samples``, and the first two's ratio: the
    polish minimises the sum over both sets (from the fit, which minimised the grid's alone), so where the off-grid
    residual is not above the grid's there is little between the texel centres for it to lower. Evaluated in calls of ``chunk`` pairs (the program shape of the
    candidates' metrics)."""
    def mse(a, b, y) -> float:
        got = _chunks(model.evaluate, jnp.asarray(a, jnp.float32), jnp.asarray(b, jnp.float32), int(chunk))
        return float(np.mean((np.asarray(got, np.float64) - np.asarray(y, np.float64)) ** 2))

    k = max(1, int(stride))
    grid = mse(np.asarray(samples.a)[::k], np.asarray(samples.b)[::k], np.asarray(samples.y)[::k])
    off = mse(pairs.a, pairs.b, pairs.y)
    val = mse(samples.val_a, samples.val_b, samples.val_y) if len(samples.val_a) else float("nan")
    return OffGridFigures(grid, off, off / grid if grid > 0 else float("inf"), val)


#: Why ``linear.ridge`` is refused for a target without an environment (its lights are the ridge's).
RIDGE_NEEDS_ENVIRONMENT = "linear.ridge draws pairs on the grazing ridge of an environment's brightest lights: a lighting target of an environment"


def ridge_lights(target: Target, structure: Structure) -> np.ndarray:
    """The lights whose ridges the polish samples: those of the structure's highlight terms (the target's
    context), else the environment's brightest one."""
    if target.kind != "lighting" or getattr(target.fn, "env", None) is None:
        raise HomofacError(RIDGE_NEEDS_ENVIRONMENT)
    if structure.highlights.terms > 0:
        tgt = with_highlight_context(target, structure)
        return np.asarray([tgt.context[key] for _, key in pj.HIGHLIGHTS[:structure.highlights.terms]], np.float64)
    return np.asarray(brightest_directions(target.fn.env, 1), np.float64)


#: The brightest lights whose ridges :func:`ridge_validation` stratifies (as many as the quality mode's
#: candidates give highlight terms).
VALIDATION_RIDGE_LIGHTS = 2


class RidgeValidation(NamedTuple):
    """Ridge pairs beside a sample set's validation pairs, for :func:`ridge_nrmse`."""

    pairs: RidgePairs
    y: np.ndarray  # the target at the ridge pairs (M, 3)
    inside: np.ndarray  # which validation pairs lie on the ridges (N,)
    lights: np.ndarray  # (L, 3)


def ridge_validation(target: Target, samples: Samples, count: int, seed: int) -> RidgeValidation:
    """``count`` ridge pairs (seeded) of the environment's :data:`VALIDATION_RIDGE_LIGHTS` brightest lights
    and the target there, with the validation pairs of ``samples`` that lie on those ridges: the ridge
    stratum of the validation estimate (:func:`ridge_nrmse`)."""
    if target.kind != "lighting" or getattr(target.fn, "env", None) is None:
        raise HomofacError(RIDGE_NEEDS_ENVIRONMENT)
    lights = np.asarray(brightest_directions(target.fn.env, VALIDATION_RIDGE_LIGHTS), np.float64)
    rp = ridge_pairs(lights, int(count), int(seed))
    y = np.asarray(evaluate(target, rp.a, rp.b), np.float64)
    inside = in_any_ridge(np.asarray(samples.val_a), np.asarray(samples.val_b), lights)
    return RidgeValidation(rp, y, inside, lights)


def ridge_nrmse(model: Result | Factorization, samples: Samples, rv: RidgeValidation, chunk: int = CHUNK) -> float:
    """The validation nrmse of ``model`` (float textures; a result or its factorization) with the ridge as
    its own stratum (:func:`homofac.fit.ridge.stratified_nrmse`): under a sun the 30-80 validation pairs on
    the ridge decide the plain figure (gold under the city sun at 16 lookups: 0.062 plain, 0.128 stratified,
    0.148 on 270 000 uniform pairs). The model is evaluated factor by factor
    (:func:`homofac.factorization.evaluate_by_factor`: the lookup programs the candidates' metrics compiled,
    one per projection, mapper and texture shape, not one per structure) in calls of ``chunk`` pairs, the
    last padded (:data:`homofac.fit.metrics.CHUNK`: the program shape of those metrics)."""
    fac = model.model if isinstance(model, Result) else model

    def values(a, b) -> np.ndarray:
        if len(a) == 0:
            return np.zeros((0, 3))
        return np.asarray(_chunks(lambda x, z: evaluate_by_factor(fac, x, z), np.asarray(a, np.float32),
                                  np.asarray(b, np.float32), int(chunk)), np.float64)

    approx = values(np.asarray(samples.val_a), np.asarray(samples.val_b))
    ridge = values(np.asarray(rv.pairs.a), np.asarray(rv.pairs.b))
    return stratified_nrmse(approx, np.asarray(samples.val_y, np.float64), rv.inside, ridge, rv.y, rv.pairs.weight)


#: Where each stage of :func:`polish_stages` (with ``direct``) starts: the ALS fit, the first stage, the
#: ALS fit (the chooser records it as ``selection.polish.stages[i].start``).
STAGE_STARTS = ("als", "polish", "als")


def polish(target: Target, structure: Structure, mapper: str, size: int, fit: SumFit, samples: Samples,
           pairs: Samples, lin: LinearOptions, log: Callable[[str], None], seed: int = 0,
           direct: bool = False, stride: int = 1) -> SumFit:
    """The polished fit: the last stage of :func:`polish_stages` without ``direct``; with it (and
    ``lin.ridge`` > 0) the ridge stage straight from ``fit``, the third candidate of the chooser's vote.
    A refit passes :func:`recorded_direct` and :func:`recorded_stride` of the record it repeats."""
    lin = lin.resolved()
    if direct and lin.ridge > 0:
        return polish_stage(target, structure, mapper, size, fit, samples, pairs, lin, log, seed, stride=stride)
    return polish_stages(target, structure, mapper, size, fit, samples, pairs, lin, log, seed, stride=stride)[-1]


def polish_stages(target: Target, structure: Structure, mapper: str, size: int, fit: SumFit, samples: Samples,
                  pairs: Samples, lin: LinearOptions, log: Callable[[str], None], seed: int = 0,
                  direct: bool = False, stride: int = 1) -> list[SumFit]:
    """``lin.polish`` Levenberg-Marquardt steps on the grid ``samples`` (every ``stride``-th, whose off-grid
    ``pairs`` are then :func:`polish_pairs` with the same stride) and the off-grid ``pairs`` together,
    from the textures of ``fit`` (see the module doc); with ``lin.ridge`` > 0, ``lin.polish`` more from
    there with ``lin.ridge`` ridge pairs added (seeded by ``seed``), and with ``direct`` a third stage of
    ``lin.polish`` steps with the ridge pairs straight from ``fit``. Returns each stage's fit.

    The ridge pairs come second: from the ALS fit, eight steps with them left the plastic under the city
    sun at 0.072 nrmse on 270 000 uniform pairs and sixteen at 0.068, eight without them and then eight
    with them at 0.064 (the first stage: 0.118). The gold under the same sun goes the other way: its
    first stage raised the validation error with the ridge stratum from 0.140 to 0.223 and the second,
    from there, ended at 0.164, while eight steps with the ridge pairs straight from the ALS fit reached
    0.135 (on 270 000 uniform pairs: the ALS fit 0.164, the direct stage 0.139; docs/notes/sums-research.md, "A third
    polish stage"). Hence the three candidates the chooser votes between
    (the plan's polish vote, :mod:`homofac.fit.plan`).

    Each record keeps the ALS fit's entries and adds ``polish`` (steps, samples, objectives, seconds; a
    stage with the ridge pairs also ``ridge``: pairs, lights, the probability of each light's ridge; the
    second stage ``first``: the first stage's record, which the direct stage lacks)."""
    lin = lin.resolved()
    first = polish_stage(target, structure, mapper, size, fit, samples, pairs, lin.model_copy(update={"ridge": 0}),
                         log, seed, stride=stride)
    if lin.ridge <= 0:
        return [first]
    ridge = ridge_samples(target, structure, int(lin.ridge), int(seed))  # the same pairs in both ridge stages
    second = polish_stage(target, structure, mapper, size, first, samples, pairs, lin, log, seed, ridge=ridge,
                          stride=stride)
    if not direct:
        return [first, second]
    return [first, second, polish_stage(target, structure, mapper, size, fit, samples, pairs, lin, log, seed,
                                        ridge=ridge, stride=stride)]


class RidgeSamples(NamedTuple):
    """The ridge pairs of a polish stage (:func:`homofac.fit.ridge.ridge_pairs`), their lights and the
    target's values there."""

    pairs: RidgePairs
    lights: np.ndarray  # (L, 3)
    y: np.ndarray  # (M, 3) float32


def ridge_samples(target: Target, structure: Structure, count: int, seed: int) -> RidgeSamples:
    """``count`` ridge pairs (seeded) of ``structure``'s lights (:func:`ridge_lights`) and the target there:
    what every ridge stage of one polish reads (evaluated once for all of them)."""
    lights = ridge_lights(target, structure)
    rp = ridge_pairs(lights, int(count), int(seed))
    return RidgeSamples(rp, lights, np.asarray(evaluate(target, rp.a, rp.b), np.float32))


#: Levenberg-Marquardt steps per compiled call of a polish stage (:func:`homofac.fit.refine.solve`'s
#: ``chunk``): a polish of any even number of steps on the same pairs runs one program.
POLISH_CHUNK = 2


def polish_stage(target: Target, structure: Structure, mapper: str, size: int, fit: SumFit, samples: Samples,
                 pairs: Samples, lin: LinearOptions, log: Callable[[str], None], seed: int = 0,
                 ridge: RidgeSamples | None = None, stride: int = 1) -> SumFit:
    """One stage of :func:`polish_stages`: ``lin.polish`` Levenberg-Marquardt steps from ``fit`` on every
    ``stride``-th grid pair of ``samples`` (``stride`` recorded, for a refit: :func:`recorded_stride`) and the
    off-grid ``pairs`` (in calls of :data:`POLISH_CHUNK` steps), with ``lin.ridge``
    ridge pairs (seeded by ``seed``; ``ridge``: those already drawn and evaluated, :func:`ridge_samples`)
    where it is above 0. ``fit``'s own polish record, if any, becomes the new one's ``first``."""
    lin = lin.resolved()
    t0 = time.perf_counter()
    k = max(1, int(stride))
    a, b, y = (np.concatenate([np.asarray(u)[::k], np.asarray(v)]) for u, v in
               ((samples.a, pairs.a), (samples.b, pairs.b), (samples.y, pairs.y)))
    weights, ridge_note = None, None
    if lin.ridge > 0:
        if ridge is None or len(ridge.pairs.a) != int(lin.ridge):
            ridge = ridge_samples(target, structure, int(lin.ridge), int(seed))
        lights, rp, ry = ridge.lights, ridge.pairs, ridge.y
        log(f"ridge: {len(rp.a)} pairs on the grazing ridge of {len(lights)} light(s), probability "
            f"{sum(rp.probability):.3g} of the validation distribution")
        inside = in_any_ridge(a, b, lights)  # counted by the ridge pairs instead
        weights = np.concatenate([np.where(inside, 0.0, 1.0), len(a) * rp.weight])
        a, b, y = np.concatenate([a, rp.a]), np.concatenate([b, rp.b]), np.concatenate([y, ry])
        ridge_note = {"pairs": int(len(rp.a)), "lights": lights.tolist(), "probability": list(rp.probability),
                      "replaced": int(inside.sum())}
    union = Samples(a, b, y, samples.val_a, samples.val_b, samples.val_y)
    lm = lin.model_copy(update={"method": "levenberg_marquardt", "iterations": int(lin.polish), "polish": 0})
    log(f"polishing {structure.label()} off the grid: {lin.polish} Levenberg-Marquardt steps on {len(a)} pairs")
    out = fit_sum(target, structure, mapper, size, union, lm, log, previous=fit.model, line_size=line_size_of(fit.model),
                  sample_weights=weights, chunk=POLISH_CHUNK)
    record = {**fit.solver, "polish": {"steps": int(lin.polish), "method": out.solver["method"],
                                       "backend": out.solver["backend"],
                                       "iterations": out.solver["iterations"], "converged": out.solver["converged"],
                                       "samples": int(len(a)), "size": int(lin.polish_size), "stride": k,
                                       "objective_start": out.solver["objective_start"],
                                       "objective": out.solver["objective"], "seconds": time.perf_counter() - t0,
                                       **({"ridge": ridge_note} if ridge_note else {}),
                                       **({"first": fit.solver["polish"]} if "polish" in fit.solver else {})}}
    return SumFit(out.model, record, fit.assemble_s + out.assemble_s, fit.solve_s + out.solve_s,
                  tuple(fit.warnings) + tuple(out.warnings), out.unknowns)


def recorded_direct(solver: dict | None) -> bool:
    """Whether a sum's solver record is a ridge stage straight from the ALS fit (``polish.ridge`` and no
    ``polish.first``: the third stage of :func:`polish_stages`), which a refit repeats with
    ``polish(..., direct=True)``."""
    pol = (solver or {}).get("polish")
    return isinstance(pol, dict) and isinstance(pol.get("ridge"), dict) and "first" not in pol


def recorded_stride(solver: dict | None) -> int:
    """The stride of a sum's recorded polish (its grid pairs and off-grid views every k-th:
    :func:`polish_stage`), which a refit repeats; 1 where none is recorded."""
    pol = (solver or {}).get("polish")
    return int(pol.get("stride", 1)) if isinstance(pol, dict) else 1


def recorded_linear(lin: LinearOptions, solver: dict | None) -> LinearOptions:
    """``lin`` with the ``nv_balance`` and polish (steps, size) a sum's solver record says its fit used.

    A chooser (a preset, ``max_lookups``, ``target_error``) fits with settings the options may not hold
    (the preset's, :mod:`homofac.fit.plan`); a refit
    of its result repeats them so that it equals the full run.
    """
    lin = lin.resolved()
    if not solver:
        return lin
    update: dict = {}
    if "nv_balance" in solver:
        update["nv_balance"] = float(solver["nv_balance"])
    pol = solver.get("polish")
    update["polish"] = int(pol.get("steps", pol.get("iterations", 0))) if isinstance(pol, dict) else 0
    if isinstance(pol, dict) and "size" in pol:
        update["polish_size"] = int(pol["size"])
    update["ridge"] = int(pol["ridge"]["pairs"]) if isinstance(pol, dict) and isinstance(pol.get("ridge"), dict) else 0
    return lin.model_copy(update=update)


__all__ = ["OffGridFigures", "POLISH_CHUNK", "RIDGE_NEEDS_ENVIRONMENT", "RidgeSamples", "RidgeValidation", "SHARED_WIDTH_WORK", "STAGE_STARTS",
           "VALIDATION_RIDGE_LIGHTS", "off_grid_figures", "polish", "shared_width",
           "polish_pairs", "polish_stage", "polish_stages", "recorded_direct", "recorded_linear", "recorded_stride", "ridge_lights",
           "ridge_nrmse", "ridge_samples", "ridge_validation"]
