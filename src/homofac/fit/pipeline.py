"""``factorize``: target -> samples -> system -> solve -> factorization -> metrics (docs/architecture.md).

Each stage is a pure function in its own module (:mod:`.draw`, :mod:`.system`, :mod:`.start`,
:mod:`.solvers`, :mod:`.precision`, :mod:`.metrics`); this composes them, validates the keywords once
(:class:`~homofac.fit.options.FitOptions`, the model the YAML config extends) and records timings, so
a notebook can call the stages one by one and the CLI is just this function driven by a config.
"""

from __future__ import annotations

import math
import time
from typing import Callable

import numpy as np

from .. import baselines
from ..errors import HomofacError
from ..light import with_context
from ..options import validate
from ..param import parametrizations as pz
from ..param import projections as pj
from ..target import Target
from . import auto, polish, programs, scene, sums
from .draw import default_mapper, draw_samples, grid_projection
from .metrics import measure
from .options import AdvancedOptions, AnalysisOptions, FitOptions, SamplingOptions
from .plan import Plan, build_plan, grid_count, validation_count
from .product import fit_product
from .result import Result
from .samples import Samples, check_values, row_width_of
from .sampling import GRID_COUNT
from .state import from_fit
from .structures import Structure
from .validation import lighting_at


#: Why ``advanced.line_size`` is refused for a single log-space product.
LINE_SIZE_NEEDS_SUM = ("advanced.line_size sizes the line textures of a sum of products; a single product's "
                       "scalar factor has texture_size texels")


def quality_warnings(metrics: dict) -> list[str]:
    """Warnings for a result that does not approximate its target: a non-finite metric, or a validation
    (else training) nrmse above 1 (worse than predicting 0 everywhere), with the figure."""
    out = []
    split = "validation" if "validation" in metrics else "train"
    for kind, m in metrics.get(split, {}).items():
        bad = [k for k, x in m.items() if not math.isfinite(x)]
        if bad:
            out.append(f"{split} {kind} metrics {', '.join(bad)} are not finite: the factorization does not "
                       "approximate this target (try a larger solver.laplacian, another parametrization or sampling)")
    nrmse = metrics.get(split, {}).get("float", {}).get("nrmse")
    if nrmse is not None and math.isfinite(nrmse) and nrmse > 1.0:
        out.append(f"{split} nrmse {nrmse:.3g} > 1: the factorization is worse than predicting 0 everywhere and "
                   "does not approximate this target (try another parametrization, a larger texture_size or sampling)")
    return out


def options(parametrization: str | None = None, **kwargs) -> FitOptions:
    """The validated :class:`FitOptions` of ``factorize``'s keywords (``None`` values mean the default;
    none of the keys that name a fit: the default preset, :data:`~homofac.fit.options.DEFAULT_PRESET`)."""
    data = {"parametrization": parametrization, **kwargs}
    return validate(FitOptions, {k: v for k, v in data.items() if v is not None}, "")


def factorize(
    target: Target,
    parametrization: str | None = None,
    *,
    preset: str | None = None,
    mapper: str | None = None,
    texture_size: int = 32,
    sampling: dict | None = None,
    solver: dict | None = None,
    target_error: float | None = None,
    max_lookups: int | None = None,
    terms: int | None = None,
    diffuse: str | None = None,
    nv_factor: bool | None = None,
    advanced: dict | AdvancedOptions | None = None,
    samples: Samples | None = None,
    config: dict | None = None,
    target_info: dict | None = None,
    log: Callable[[str], None] | None = None,
    keep_samples: bool = False,
    **moved,
) -> Result:
    """Factor ``target`` into textures: the whole pipeline of thesis §6.1.8 (steps 1-10).

    Args:
        target: a :class:`~homofac.target.Target` (``brdf_target`` or ``lighting_target``).
        preset: ``fast``, ``balanced`` or ``best`` (lookup budgets 4, 8, 16; docs/presets.md): the sample
            counts, candidate structures, linear-fit options and votes of :func:`homofac.fit.plan.build_plan`;
            every keyword given explicitly replaces the preset's value. Neither a preset nor a keyword that
            names a fit (``parametrization``, ``max_lookups``, ``terms``, ...): ``balanced``.
        parametrization: ``IV``, ``GSHD``, ``PQP`` (BRDF) or ``N``, ``R``, ``NR``, ``NRV``, ``NRHD``,
            ``NRW`` (lighting).
        mapper: direction mapper of the textures (default: parabolic for BRDF, dual_paraboloid for lighting).
        texture_size: S of the mapper table (4 ... 1024).
        sampling: :class:`~homofac.fit.options.SamplingOptions` as a dict (``kind``, ``size``, ``view_size``,
            ``validation``, ``seed``, ``count``, ``mapper``, ``cache``; ``kind: scene`` with ``mesh``,
            ``cameras``, ``mesh_up`` draws the pairs a scene shows and adds ``metrics["scene"]``, the
            image-space error over its covered pixels: :mod:`homofac.fit.scene`).
        solver: solver options as a dict (``method``, ``tolerance``, ``max_iterations``, ``laplacian``,
            ``epsilon``, ``levels``), validated by the method's own option model.
        target_error: fit candidates cheapest first and keep the first whose validation nrmse meets it
            (:mod:`homofac.fit.auto`); ``parametrization`` and ``texture_size`` are then the limits. With
            the sum keys below, the candidates are structures within ``max_lookups`` (default 16).
        max_lookups: choose the structure within this many texture lookups per pixel by validation error
            (:func:`homofac.fit.sums.choose`).
        terms: K products of ``parametrization`` summed, fitted in linear space (:mod:`homofac.fit.sums`).
        diffuse: ``exact`` (the computed term kd/pi E(n), the products fit the rest) or ``fitted``.
        nv_factor: a 1D ``line`` texture w(n.v) in each product (BRDF: w(cos_i) w(cos_o)).
        advanced: the research keys, a dict or :class:`~homofac.fit.options.AdvancedOptions` (the config's
            ``advanced:`` section): the rest of a structure (``reflection``, ``prefiltered``, ``rw_terms``,
            ``highlights: {terms, fresnel, cosine, table, disc}``), ``line_size``, ``linear`` (the
            linear-space fit), ``baseline`` (options of a baseline ``parametrization``) and ``analysis``
            (Mahajan's in-out analysis, recorded in ``fac.analysis``). A preset sets what they decide.
            ``Structure.parse(label).keywords()`` gives the keywords of one structure.
        samples: precomputed :class:`~homofac.fit.samples.Samples` (skip sampling, e.g. to compare solvers).
        config: the resolved config to record in the result.
        target_info: description of the target to record.
        log: progress callback (one line per stage); silent when None.
        keep_samples: keep the samples on the result (``fac.samples``, written as samples.npz).

    Every keyword is validated as the CLI validates the config: a misspelt key or a bad value raises a
    one-line :class:`~homofac.errors.HomofacError` naming it.
    """
    log = log or (lambda msg: None)
    t_start = time.perf_counter()
    programs.bound_compiled_programs()
    programs.enable_compilation_cache()
    given_opts = options(parametrization, preset=preset, mapper=mapper, texture_size=texture_size, sampling=sampling,
                         solver=solver, target_error=target_error, max_lookups=max_lookups, terms=terms,
                         diffuse=diffuse, nv_factor=nv_factor, advanced=advanced, **moved)
    own = None
    if samples is not None and target.kind == "lighting" and given_opts.is_sum:  # candidates on their direction only
        own = grid_projection(target.kind, given_opts.parametrization,
                              given_opts.sampling.model_copy(update={"kind": "grid"}))
    the_plan = build_plan(target, None, given_opts, samples_given=own)
    log(str(the_plan))
    return execute(the_plan, target, samples=samples, config=config, target_info=target_info, log=log,
                   keep_samples=keep_samples, t_start=t_start)


def execute(the_plan: Plan, target: Target, *, samples: Samples | None = None, config: dict | None = None,
            target_info: dict | None = None, log: Callable[[str], None] | None = None, keep_samples: bool = False,
            t_start: float | None = None) -> Result:
    """Run a :class:`~homofac.fit.plan.Plan` (:func:`~homofac.fit.plan.build_plan`) on ``target``: draw the
    samples, fit what the plan names, hold its votes. No rule of its own: every count, candidate, option
    and vote is the plan's."""
    log = log or (lambda msg: None)
    t_start = time.perf_counter() if t_start is None else t_start
    opts = the_plan.options
    mapper = the_plan.mapper
    is_baseline = the_plan.mode == "baseline"
    if opts.advanced.baseline is not None and not is_baseline:
        raise HomofacError(f"baseline: options are for a baseline parametrization ({', '.join(baselines.BASELINES)}), "
                           f"not {opts.parametrization}")
    if opts.advanced.line_size is not None and not opts.is_sum:
        raise HomofacError(LINE_SIZE_NEEDS_SUM)
    if target.kind == "lighting" and opts.parametrization in pz.PARAMETRIZATIONS:
        target = with_context(target, opts.parametrization)  # NRHD's dominant light, NRO's shift
    t0 = time.perf_counter()
    resolved = resolve_sampling(opts, target.kind, mapper)
    if (the_plan.polish or (opts.advanced.linear is not None and opts.advanced.linear.polish)) and samples is None \
            and resolved.kind != "grid":
        raise HomofacError(f"{sums.POLISH_NEEDS_GRID}, not sampling.kind: {resolved.kind}")
    first = opts.parametrization if samples is not None else drawn_for(the_plan)  # the samples' direction
    vl = the_plan.validation_light  # the validation pairs read the plan's validation lighting (its votes' figure)
    vtarget = lighting_at(target, vl.resolution, vl.light_sum) if vl is not None and samples is None else target
    if samples is None:  # on the grid direction of the first candidate (every candidate's, for texel pairs)
        samples = draw_samples(with_context(target, first) if target.kind == "lighting" else target, first,
                               resolved, log, validation_target=vtarget, validation_light=vl and vl.resolution)
    sample_s = time.perf_counter() - t0
    check_values(np.asarray(samples.y), "training")
    record = {"config": config or {}, "target_info": target_info or {}, "samples": samples if keep_samples else None}

    def fit(tgt: Target, name: str, size: int) -> Result:
        pf = fit_product(tgt, name, mapper, size, samples, opts.solver, log)
        result = Result(pf.model, solver=pf.solver, warnings=pf.warnings, **record)
        log("measuring errors")
        mets = measure(result, tgt, samples, eps=float(opts.solver.epsilon))
        result = result.replace(metrics=mets, warnings=tuple(result.warnings) + tuple(quality_warnings(mets)))
        return result.replace(
            timings={"sample_s": sample_s, "assemble_s": pf.assemble_s, "solve_s": pf.solve_s},
            counts={"train": int(len(samples.a)), "validation": int(len(samples.val_a)),
                    "unknowns": int(pf.layout.n_unknowns), "lights": int(getattr(tgt.fn, "n_lights", 0))},
        )

    if opts.is_sum:
        result, target, samples = _sums(target, the_plan, samples, record, sample_s, log, resolved, first, vtarget)
    elif opts.target_error is not None:
        result = auto.choose(target, opts.target_error, fit, samples, mapper=mapper, max_size=opts.texture_size,
                             log=log)
    elif is_baseline:
        result = _baseline(target, opts, mapper, samples, record, log)
        result = result.replace(timings={"sample_s": sample_s, **result.timings})
    else:
        result = fit(target, opts.parametrization, opts.texture_size)
    if vl is not None and result.selection is not None:
        result = result.replace(selection={**result.selection, "validation_light": vl.record()})
    if the_plan.analysis and result.analysis is None:
        a = opts.advanced.analysis or AnalysisOptions()
        log(f"in-out analysis ({a.pair}) on {a.mapper} {a.size}")
        result = result.replace(analysis=baselines.analyse(target, a.pair, a.mapper, a.size).record())
    sc = None
    if resolved.kind == "scene":  # image-space metrics over every covered pixel of the cameras
        sc = scene.load(resolved)
        log(f"measuring the scene's image-space error ({len(sc)} covered pixels)")
        result = result.replace(metrics={**result.metrics, "scene": sc.metrics(result, target, float(opts.solver.epsilon))},
                                counts={**(result.counts or {}), "scene_pixels": len(sc)})
    state = from_fit(opts, target.kind, samples, result, mapper, scene=sc)  # what hf.fit.refit reuses (fit/refit.py)
    return result.replace(timings={**result.timings, "total_s": time.perf_counter() - t_start}, target=target,
                          state=state)


def drawn_for(the_plan: Plan) -> str:
    """The parametrization whose grid direction the first training pairs are drawn on: the first
    candidate's (a preset may try only candidates on ``r_off``), else the options'."""
    return the_plan.candidates[0].parametrization if the_plan.candidates else the_plan.options.parametrization


def resolve_sampling(opts: FitOptions, kind: str, mapper: str) -> SamplingOptions:
    """``sampling.kind: auto`` resolved (grid for linear-space sums of lighting products, else texels);
    grid samples always lie on the fitted textures' own grid (``mapper``, ``texture_size``), their count
    and the validation count the plan's (:func:`homofac.fit.plan.grid_count`,
    :func:`~homofac.fit.plan.validation_count`; a grid count of :data:`~homofac.fit.sampling.GRID_COUNT`
    stays 0, the default, in cache keys and records)."""
    s = opts.sampling
    k = s.kind
    if k == "auto":
        k = "grid" if opts.is_sum and kind == "lighting" else "texels"
    validation = validation_count(opts)
    if k == "grid":
        count = grid_count(opts)
        return s.model_copy(update={"kind": "grid", "size": int(opts.texture_size), "mapper": mapper, "view_size": None,
                                    "count": 0 if count == GRID_COUNT else count, "validation": validation})
    return s.model_copy(update={"kind": k, "validation": validation})


def _sums(target: Target, the_plan: Plan, samples: Samples, record: dict, sample_s: float,
          log, resolved: SamplingOptions, drawn: str, vtarget: Target | None = None) -> tuple[Result, Target, Samples]:
    """A linear-space sum of products: the structure of the options, or the one chosen within a budget;
    with the target (its projection context) and the samples the kept structure was fitted on.

    The grid design puts ``n`` and the structure's reflection-like direction on texel centres (``r``, or
    ``r_off`` for NRO and RO): candidates on another direction than the options' parametrization get
    grid samples of their own, drawn once per direction (the validation pairs are the same for all),
    unless the samples were given (then the plan holds only the candidates on their direction).
    ``drawn``: the parametrization whose grid direction ``samples`` lie on; ``vtarget``: the lighting the
    validation values (and the ridge stratum) read (:func:`homofac.fit.validation.lighting_at`)."""
    opts, mapper, lin = the_plan.options, the_plan.mapper, the_plan.linear
    choosing = the_plan.mode == "choose"
    eps = float(opts.solver.epsilon)
    sizes = the_plan.line_sizes  # the candidates' line size first; then the line vote's
    polished: dict = {}
    pools = {grid_projection(target.kind, drawn, resolved): (target, samples, sample_s)}

    def pool(structure: Structure) -> tuple[Target, Samples, float]:
        # the samples are shared by every structure on one grid direction (all of them for texel pairs);
        # the context is each structure's own (NRO and RO read shift wherever their pairs came from)
        tgt = with_context(target, structure.parametrization)
        proj = grid_projection(target.kind, structure.parametrization, resolved)
        if proj not in pools:
            t0 = time.perf_counter()
            smp = draw_samples(tgt, structure.parametrization, resolved.model_copy(update={"validation": 0}), log)
            smp = smp._replace(val_a=samples.val_a, val_b=samples.val_b, val_y=samples.val_y)  # one validation set
            check_values(np.asarray(smp.y), "training")
            pools[proj] = (tgt, smp, time.perf_counter() - t0)
        _, smp, s_s = pools[proj]
        return tgt, smp, s_s

    def pairs(stride: int = 1) -> Samples:  # the polish's off-grid pairs (every stride-th view), drawn once, in rows
        if ("pairs", stride) not in polished:  # of the training grid's width (its compiled lighting program)
            t0 = time.perf_counter()
            polished["pairs", stride] = polish.polish_pairs(target, opts.parametrization, lin, opts.sampling.seed,
                                                            opts.sampling.cache, log, stride=stride,
                                                            width=row_width_of(samples.a))
            polished["sample_s"] = polished.get("sample_s", 0.0) + time.perf_counter() - t0
        return polished["pairs", stride]

    fits: dict = {}  # (structure, line size) -> its SumFit (the chooser polishes the one it keeps)
    # every candidate's ALS in one set of term slots: one set of compiled sweep programs per block size, not per
    # structure
    slots = sums.als_slots(target, the_plan.candidates, mapper, opts.texture_size, sizes[0])

    running: dict = {}  # structure -> its fit under way (the race's candidates still in it)
    # (structure, line size) -> its strided short fit (the race's first round, a line or disc vote's screen), its
    # stride and sweeps: with race_continue the full fit continues from it
    heads: dict = {}

    def start(structure: Structure) -> sums.Running:
        tgt, smp, _ = pool(structure)
        return sums.begin(tgt, structure, mapper, opts.texture_size, smp, lin, log, line_size=sizes[0], slots=slots)

    def fit(structure: Structure, line: int = sizes[0]) -> Result:
        tgt, smp, _ = pool(structure)
        if line == sizes[0] and structure in running:  # a candidate of the race continues from where it stopped
            sf = sums.finish(sums.advance(running.pop(structure), None, log))
        elif the_plan.race_continue and (structure, line) in heads:  # ... or from its strided short fit
            head, k, n = heads.pop((structure, line))
            sf = sums.continued(tgt, structure, mapper, opts.texture_size, smp, lin, log, stride=k, sweeps=n,
                                line_size=line, slots=slots, head=head)
        else:
            sf = sums.fit_sum(tgt, structure, mapper, opts.texture_size, smp, lin, log, line_size=line, slots=slots)
        if lin.polish > 0:
            sf = polish.polish(tgt, structure, mapper, opts.texture_size, sf, smp, pairs(), lin, log,
                               seed=opts.sampling.seed)
        fits[structure, line] = sf
        return as_result(structure, sf)

    def as_result(structure: Structure, sf) -> Result:
        tgt, smp, s_s = pool(structure)
        rec = {**record, "samples": smp if record.get("samples") is not None else None}
        result = Result(sf.model, solver=sf.solver, warnings=sf.warnings, **rec)
        # a candidate is measured on what the votes read (the validation float nrmse); the kept one fully (kept)
        log("measuring errors")
        mets = measure(result, tgt, smp, eps=eps, splits=("validation",), kinds=("float",)) if choosing \
            else measure(result, tgt, smp, eps=eps)
        extra = {"polish_sample_s": polished["sample_s"]} if "sample_s" in polished else {}
        return result.replace(
            metrics=mets, warnings=tuple(result.warnings) + (() if choosing else tuple(quality_warnings(mets))),
            timings={"sample_s": s_s, "assemble_s": sf.assemble_s, "solve_s": sf.solve_s, **extra},
            counts={"train": int(len(smp.a)), "validation": int(len(smp.val_a)), "unknowns": sf.unknowns,
                    "lights": int(getattr(tgt.fn, "n_lights", 0)), "lookups": int(sf.model.lookups)},
        )

    def kept(result: Result) -> tuple[Result, Target, Samples]:
        structure = Structure.of(result.solver["structure"])
        tgt, smp, _ = pool(structure)
        if choosing:
            log("measuring errors of the kept structure")
            mets = measure(result, tgt, smp, eps=eps)
            result = result.replace(metrics=mets, warnings=tuple(result.warnings) + tuple(quality_warnings(mets)))
        return result, sums.with_highlight_context(tgt, structure), smp

    if the_plan.mode == "sum":
        return kept(fit(the_plan.candidates[0]))
    if len(samples.val_a) == 0:
        raise HomofacError("a preset, max_lookups and target_error choose by validation error: "
                           "sampling.validation must be > 0")
    analysis = None
    if the_plan.analysis:
        # Mahajan et al. 2008: the rank-K error of the gridded target bounds what K products p(n) q(r)
        # can reach; the products with w(n.v) need fewer. Recorded beside the choice (and printed).
        a = opts.advanced.analysis or AnalysisOptions()
        log(f"in-out analysis ({a.pair}) on {a.mapper} {a.size}")
        analysis = baselines.analyse(target, a.pair, a.mapper, a.size).record()
    ridge = the_plan.ridge
    rv = None
    if ridge > 0:  # every vote below reads the validation estimate with the ridge stratum (polish.ridge_nrmse)
        rv = polish.ridge_validation(vtarget or target, samples, ridge, opts.sampling.seed + 1)
        log(f"validation: {len(rv.pairs.a)} ridge pairs stand in for the {int(rv.inside.sum())} validation pairs on "
            f"the ridges of the {len(rv.lights)} brightest lights")
    score = None if rv is None else (lambda res: polish.ridge_nrmse(res, samples, rv))
    cands, raced = list(the_plan.candidates), None
    if the_plan.race:  # every candidate's first sweeps; the plan's lowest continue (fit() picks them up)

        shorts_under_way: dict = {}  # structure -> its strided fit under way (a race_strided plan's later rounds)

        def to(structure: Structure, sweeps: int, stride: int = 1) -> Result:
            if stride > 1 and the_plan.race_strided:  # every round on the strided pairs, continuing (the budget:
                # the last round's sweeps, so the fit is the one-round race's sweep for sweep)
                if structure not in shorts_under_way:
                    tgt, smp, _ = pool(structure)
                    shorts_under_way[structure] = sums.begin(
                        tgt, structure, mapper, opts.texture_size, sums.strided(smp, stride),
                        lin.model_copy(update={"iterations": the_plan.race[-1]}), log, line_size=sizes[0], slots=slots)
                run = shorts_under_way[structure]
                run = shorts_under_way[structure] = sums.advance(run, sweeps - run.sweeps, log)
                head = sums.finish(run)
                heads[structure, sizes[0]] = (head, stride, sweeps)
                return as_result(structure, head)
            if stride > 1:  # a short fit of its own on every stride-th pair (those kept continue from it on
                # every pair where the plan says race_continue, else start over)
                tgt, smp, _ = pool(structure)
                head = sums.fit_sum(tgt, structure, mapper, opts.texture_size, sums.strided(smp, stride),
                                    lin.model_copy(update={"iterations": sweeps}), log, line_size=sizes[0], slots=slots)
                heads[structure, sizes[0]] = (head, stride, sweeps)
                return as_result(structure, head)
            run = running[structure] if structure in running else start(structure)
            running[structure] = sums.advance(run, sweeps - run.sweeps, log)
            return as_result(structure, sums.finish(running[structure]))

        cands, raced = _race(cands, to, the_plan.race, the_plan.race_keep, the_plan.race_margins,
                             score, log, the_plan.race_stride, the_plan.race_strided)
        for structure in [s for s in running if s not in cands]:
            del running[structure]
        shorts_under_way.clear()
    result = sums.choose(fit, cands, target_error=opts.target_error,
                         max_lookups=the_plan.max_lookups, log=log, score=score)
    if raced is not None:
        result = result.replace(selection={**result.selection, "race": raced})
    structure = Structure.of(result.solver["structure"])
    line = sizes[0]  # the kept fit's line size (fits[structure, line] is its SumFit)
    quick = None
    if the_plan.vote_screen:  # the line and disc votes read a short fit of the alternative first
        known = _race_figures(raced, score, the_plan.vote_screen) if the_plan.race and (
            the_plan.race[-1] if the_plan.race_strided else the_plan.race[0], the_plan.race_stride) == (
            the_plan.vote_screen, the_plan.vote_stride) else {}
        shorts: dict = {}

        def quick(s: Structure, n: int) -> tuple[float, Result | None]:
            if (s, n) not in shorts:
                if n == sizes[0] and s.label() in known:  # the race's first round fitted it the same way
                    shorts[s, n] = (known[s.label()], None)
                else:
                    tgt, smp, _ = pool(s)
                    k = the_plan.vote_stride
                    slin = lin.model_copy(update={"iterations": the_plan.vote_screen})
                    sf = sums.fit_sum(tgt, s, mapper, opts.texture_size, sums.strided(smp, k), slin, log, line_size=n,
                                      slots=slots)
                    heads[s, n] = (sf, k, the_plan.vote_screen)  # a full fit of it continues from here
                    r = as_result(s, sf)
                    shorts[s, n] = (_vote_errors([r], score)[1][0], r)
            return shorts[s, n]

    if len(sizes) > 1 and any(t.mapper == "line" for t in result.model.textures):
        result, line = _line_vote(result, structure, sizes, fit, log, score, quick, the_plan.vote_screen)
    if structure.highlights.terms and the_plan.disc_vote:
        result = _disc_vote(result, structure, line, fit, log, score, quick, the_plan.vote_screen)
        structure = Structure.of(result.solver["structure"])
    steps = the_plan.polish
    if steps and result.solver.get("method") == "als":
        tgt, smp, _ = pool(structure)
        k = the_plan.polish_stride  # on every k-th grid pair and every k-th view of the off-grid pairs
        og = None  # the off-grid figures: only where the plan gates the polish on them
        if the_plan.polish_gate > 0:
            og = polish.off_grid_figures(fits[structure, line].model, smp, pairs(k), k)
            log(f"off-grid figures of {structure.label()}: mean squared residual on the grid pairs {og.grid:.5g}, "
                f"off the grid {og.off:.5g} ({og.ratio:.3f}x), validation {og.validation:.5g}")
        if og is not None and og.ratio <= the_plan.polish_gate:  # nothing between the texel centres to lower
            log(f"polish of {structure.label()}: not run (the off-grid residual {og.ratio:.3f}x the grid's, at most "
                f"{the_plan.polish_gate:g}x)")
            result = result.replace(selection={**result.selection, "polish": {
                "steps": steps, "rule": "gate", "gate": float(the_plan.polish_gate), "kept": False, "stage": None,
                "ridge": 0, "start": None, "stride": int(k), "off_grid": og._asdict()}})
        else:
            plin = lin.model_copy(update={"polish": steps, "ridge": ridge})
            args = (tgt, structure, mapper, opts.texture_size, fits[structure, line], smp, pairs(k), plin, log)
            if the_plan.polish_direct:  # only the ridge stage straight from the ALS fit (the third of polish_stages)
                stages = [as_result(structure, polish.polish(*args, seed=opts.sampling.seed, direct=True, stride=k))]
                which = (2,)
            else:
                stages = [as_result(structure, sf) for sf in polish.polish_stages(*args, seed=opts.sampling.seed,
                                                                                    direct=True, stride=k)]
                which = tuple(range(len(stages)))
            result = _polish_vote(result, stages, score, steps, ridge, structure.label(), log, k, which)
            if og is not None:
                result = result.replace(selection={**result.selection, "polish": {**result.selection["polish"],
                                                                                   "off_grid": og._asdict()}})
    return kept(result if analysis is None else result.replace(analysis=analysis))


def _race(candidates: list[Structure], to: Callable[..., Result], rounds: tuple[int, ...],
          keep: tuple[int, ...], margin: float | tuple[float, ...], score: Callable | None, log,
          stride: int = 1, strided: bool = False) -> tuple[list[Structure], dict]:
    """The plan's race: at each round ``rounds[j]`` (ALS sweeps), every candidate still in is brought to that
    many sweeps by ``to(structure, sweeps, stride)`` (continuing its own fit; the first round on every
    ``stride``-th training pair where ``stride`` > 1, a short fit of its own from which nothing continues)
    and ranked on the figure the votes read (``score``'s where
    given); the lowest and the next ones whose figure is within ``margin`` (relative) of it, at most
    ``keep[j]``, stay in, in the candidates' order (cheapest first). Returns those and the record
    ``selection.race``: per round its sweeps, the labels in it, their figures, the sweeps each actually ran
    (a fit that converged stops early) and the labels kept. ``margin``: one for every round, or each round's;
    ``strided``: every round on every ``stride``-th pair (``to`` continues the strided fits)."""
    margins = tuple(margin) if isinstance(margin, (tuple, list)) else (float(margin),) * len(rounds)
    left, note = list(candidates), {"rounds": [], "stride": int(stride), "strided": bool(strided)}
    for j, (sweeps, k) in enumerate(zip(rounds, keep)):
        tried = [to(c, sweeps, stride if j == 0 or strided else 1) for c in left]
        plain, errs, what = _vote_errors(tried, score)
        order = np.argsort(errs, kind="stable")
        best = errs[order[0]]
        chosen = {int(i) for i in order[:max(1, k)] if errs[i] <= best * (1.0 + margins[j])}
        kept = [c for i, c in enumerate(left) if i in chosen]
        log(f"race ({sweeps} ALS sweeps): {what} " + ", ".join(f"{c.label()} {e:.4g}" for c, e in zip(left, errs))
            + "; continue: " + ", ".join(c.label() for c in kept))
        note["rounds"].append({"sweeps": int(sweeps), "margin": float(margins[j]),
                               "labels": [c.label() for c in left], "validation_nrmse": plain,
                               **({} if score is None else {sums.RIDGE_METRIC: errs}),
                               "ran": [int(r.solver["iterations"]) for r in tried], "kept": [c.label() for c in kept]})
        left = kept
    note["kept"] = [c.label() for c in left]
    return left, note


def _figures(res: Result, score: Callable | None) -> dict:
    """A result's validation nrmse, and with ``score`` the ridge stratum's (the figures the votes read)."""
    plain = {"validation_nrmse": float(res.metrics["validation"]["float"]["nrmse"])}
    return plain if score is None else {**plain, sums.RIDGE_METRIC: float(score(res))}


def _polish_vote(result: Result, stages: list[Result], score: Callable | None, steps: int, ridge: int,
                 label: str, log, stride: int = 1, which: tuple[int, ...] | None = None) -> Result:
    """The kept structure's ALS fit (``result``) or one of its polish ``stages`` (:func:`polish.polish_stages`
    with ``direct``: without the ridge pairs, then with them, then with them from the ALS fit; ``which``:
    the index among those three of each of ``stages``, default all in order, ``(2,)`` for the plan's
    ``polish_direct``): the stage of lowest validation error (``score``, the ridge stratum's, where given),
    kept only where its error is below the ALS fit's (the same evidence as every other vote).
    ``selection.polish`` records the steps, each stage's errors with its ridge pairs and start
    (:data:`polish.STAGE_STARTS`), the errors before and after and what was kept (``kept``; ``stage``: the
    kept stage's index among the three; ``ridge``, ``start``: its ridge pairs and start)."""
    which = tuple(range(len(stages))) if which is None else which
    key, what = sums.scored_by(score is not None)
    before, figures = _figures(result, score), [_figures(r, score) for r in stages]
    best = int(np.argmin([f[key] for f in figures]))
    keep = figures[best][key] < before[key]
    log(f"polish of {label}: {what} {before[key]:.4g} -> " + " / ".join(f"{f[key]:.4g}" for f in figures)
        + (f": stage {which[best] + 1} kept" if keep else ": not kept (the validation error did not fall)"))
    described = [{"ridge": ridge if i else 0, "start": polish.STAGE_STARTS[i], **f}
                 for i, f in zip(which, figures)]
    note = {"steps": steps, **{f"{k}_before": v for k, v in before.items()},
            **{f"{k}_after": v for k, v in figures[best].items()}, "stages": described, "rule": "vote", "kept": keep,
            "stage": which[best] if keep else None, "ridge": described[best]["ridge"] if keep else 0,
            "start": described[best]["start"] if keep else None, "stride": int(stride)}
    return (stages[best] if keep else result).replace(selection={**result.selection, "polish": note})


def _vote_errors(tried: list[Result], score: Callable | None) -> tuple[list[float], list[float], str]:
    """The plain validation nrmse of each of ``tried``, the errors a vote ranks them by (``score``'s where
    given: the ridge stratum's) and the words naming those (:func:`homofac.fit.sums.scored_by`)."""
    plain = [float(r.metrics["validation"]["float"]["nrmse"]) for r in tried]
    errs = plain if score is None else [float(score(r)) for r in tried]
    return plain, errs, sums.scored_by(score is not None)[1]


def _race_figures(raced: dict | None, score: Callable | None, sweeps: int | None = None) -> dict[str, float]:
    """Each candidate's figure after the race's first round (``selection.race``: the one the votes read), or
    after its round of ``sweeps`` where given (a strided race's later round), by label."""
    if not raced or not raced.get("rounds"):
        return {}
    first = next((r for r in raced["rounds"] if r["sweeps"] == sweeps), raced["rounds"][0]) if sweeps \
        else raced["rounds"][0]
    key = sums.RIDGE_METRIC if score is not None else "validation_nrmse"
    return dict(zip(first.get("labels", []), first.get(key, [])))


def _quick_note(sweeps: int, tried: dict, what: str) -> dict:
    """``selection.lines.screen`` / ``selection.disc.screen``: the short fits' sweeps and figures."""
    return {"sweeps": int(sweeps), "figure": what, "tried": [str(k) for k in tried],
            "figures": [float(v) for v in tried.values()]}


def _line_vote(result: Result, structure: Structure, sizes: tuple[int, ...], fit: Callable,
               log, score: Callable | None = None, quick: Callable | None = None,
               sweeps: int = 0) -> tuple[Result, int]:
    """The kept ``structure`` (``result``, fitted with ``sizes[0]``-texel lines) fitted again with each
    further line size, the one of lowest validation error kept (ties: the first), with its size;
    ``selection.lines`` records the sizes fitted, their validation nrmse and the kept size (:func:`line_sizes`).
    ``score(result)``: the validation error the vote uses instead of the plain one (the ridge stratum's,
    recorded beside it). ``quick(structure, size) -> (figure, result)``: a short fit's figure (``sweeps``
    ALS sweeps, the plan's ``vote_screen``); a size is then fitted in full only where its short figure is
    below ``sizes[0]``'s (``selection.lines.screen`` records the short figures)."""
    tried, shorts = [(sizes[0], result)], {}
    _, what = sums.scored_by(score is not None)
    for size in sizes[1:]:
        if quick is not None:
            shorts.setdefault(sizes[0], quick(structure, sizes[0])[0])
            shorts[size] = quick(structure, size)[0]
            if not shorts[size] < shorts[sizes[0]]:
                log(f"line vote: {structure.label()} short fits, {what} {shorts[sizes[0]]:.4g} ({sizes[0]} texels), "
                    f"{shorts[size]:.4g} ({size} texels): {size} not fitted in full")
                continue
        log(f"line vote: {structure.label()} with {size}-texel lines")
        tried.append((size, fit(structure, size)))
    plain, errs, what = _vote_errors([r for _, r in tried], score)
    k = int(np.argmin(errs))
    log(f"line vote: {what} " + ", ".join(f"{e:.4g} ({n} texels)" for (n, _), e in zip(tried, errs))
        + f": {tried[k][0]} kept")
    note = {"sizes": [int(n) for n, _ in tried], "validation_nrmse": plain, "kept": int(tried[k][0]),
            **({} if score is None else {sums.RIDGE_METRIC: errs}),
            **({"screen": _quick_note(sweeps, shorts, what)} if shorts else {})}
    return tried[k][1].replace(selection={**result.selection, "lines": note}), int(tried[k][0])


def _disc_vote(result: Result, structure: Structure, line: int, fit: Callable, log,
               score: Callable | None = None, quick: Callable | None = None, sweeps: int = 0) -> Result:
    """The kept ``structure`` (``result``) against the same read at its lights' discs (``highlights.disc``,
    fitted with ``line``-texel lines): the one of lower validation error (``score``'s where given; ties:
    the kept one). ``selection.disc`` records the radii, the errors and whether the disc was kept
    (:func:`disc_rule`). ``quick`` (see :func:`_line_vote`): the other is fitted in full only where its
    short fit's figure is below the kept structure's; else ``selection.disc`` holds the kept one's figures
    only, with ``screen`` (the short figures)."""
    other = structure.with_highlights(disc=not structure.highlights.disc)
    if quick is not None:
        (mine, _), (theirs, short) = quick(structure, line), quick(other, line)
        _, what = sums.scored_by(score is not None)
        shorts = {structure.label(): mine, other.label(): theirs}
        if not theirs < mine:
            log(f"disc vote: short fits, {what} {mine:.4g} ({structure.label()}), {theirs:.4g} ({other.label()}): "
                f"{structure.label()} kept without a full fit of the other")
            plain, errs, _ = _vote_errors([result], score)
            disc = short if other.highlights.disc else result
            radii = [] if disc is None else [float(disc.model.context[r])
                                             for _, _, r in pj.HIGHLIGHT_DISCS[:structure.highlights.terms]]
            note = {"radii": radii, "labels": [structure.label()], "validation_nrmse": plain,
                    "kept": bool(structure.highlights.disc), **({} if score is None else {sums.RIDGE_METRIC: errs}),
                    "screen": _quick_note(sweeps, shorts, what)}
            return result.replace(selection={**(result.selection or {}), "disc": note})
    log(f"disc vote: {other.label()}")
    tried = [result, fit(other, line)]
    plain, errs, what = _vote_errors(tried, score)
    k = int(errs[1] < errs[0])
    log(f"disc vote: {what} {errs[0]:.4g} ({structure.label()}), {errs[1]:.4g} ({other.label()}): "
        f"{(structure, other)[k].label()} kept")
    disc = tried[1] if other.highlights.disc else tried[0]
    radii = [float(disc.model.context[r]) for _, _, r in pj.HIGHLIGHT_DISCS[:structure.highlights.terms]]
    note = {"radii": radii, "labels": [structure.label(), other.label()], "validation_nrmse": plain,
            "kept": bool((structure, other)[k].highlights.disc), **({} if score is None else {sums.RIDGE_METRIC: errs}),
            **({"screen": _quick_note(sweeps, shorts, what)} if quick is not None else {})}
    return tried[k].replace(selection={**(result.selection or {}), "disc": note})


def _baseline(target: Target, opts: FitOptions, mapper: str, samples: Samples, record: dict, log) -> Result:
    """A baseline's model (computed, not fitted) with the same metrics and record as a fit."""
    log(f"computing the {opts.parametrization} baseline ({mapper} {opts.texture_size})")
    t0 = time.perf_counter()
    model = baselines.build(opts.parametrization, target, mapper, opts.texture_size, opts.advanced.baseline)
    build_s = time.perf_counter() - t0
    result = Result(model, solver={"method": opts.parametrization, "iterations": 0, "converged": True,
                                   "options": validate(baselines.get(opts.parametrization).options,
                                                       opts.advanced.baseline, "advanced.baseline").model_dump()},
                    **record)
    mets = measure(result, target, samples, eps=float(opts.solver.epsilon))
    return result.replace(metrics=mets, warnings=tuple(quality_warnings(mets)),
                          timings={"build_s": build_s, "assemble_s": 0.0, "solve_s": 0.0},
                          counts={"train": int(len(samples.a)), "validation": int(len(samples.val_a)),
                                  "unknowns": 0, "lights": int(getattr(target.fn, "n_lights", 0))})


__all__ = ["LINE_SIZE_NEEDS_SUM", "default_mapper", "draw_samples", "execute", "factorize", "grid_count", "measure",
           "options", "quality_warnings", "resolve_sampling", "validation_count"]
