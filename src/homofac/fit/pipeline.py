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
from . import auto, polish, programs, scene, structures, sums
from .draw import default_mapper, draw_samples, grid_projection
from .metrics import measure
from .options import DEFAULT_VALIDATION, AnalysisOptions, FitOptions, LinearOptions, SamplingOptions
from .product import fit_product
from .result import Result
from .samples import Samples, check_values
from .sampling import GRID_COUNT
from .state import from_fit
from .structures import HIGHLIGHT_LINES, Structure


#: The lookup budget of ``target_error`` with sum keys but no ``max_lookups``.
DEFAULT_MAX_LOOKUPS = 16

#: ``linear.nv_balance`` of the chooser's candidates (``max_lookups``, ``target_error``) for lighting
#: targets with a diffuse part when the options do not set it (:func:`chooser_linear`).
CHOOSER_NV_BALANCE = 1.0

#: ``linear.polish`` of the structure the chooser keeps when the options do not set it (:func:`chooser_polish`).
CHOOSER_POLISH = 8

#: Chooser budgets above this many lookups are the quality mode: the candidates fit the plain objective
#: (no ``nv_balance``, :func:`chooser_linear`) on :data:`QUALITY_GRID_COUNT` grid pairs (:func:`grid_count`).
QUALITY_LOOKUPS = 8

#: Grid pairs of the quality mode's candidates when ``sampling.count`` is not set (:func:`grid_count`).
QUALITY_GRID_COUNT = 600_000

#: Ridge pairs of the quality mode's polish when ``linear.ridge`` is not set (:func:`chooser_ridge`).
QUALITY_RIDGE = 20_000

#: Why ``linear.ridge`` is refused where no polish runs (the ridge pairs are the polish's).
RIDGE_NEEDS_POLISH = "linear.ridge adds pairs to the polish: set linear.polish (or let max_lookups choose and polish)"

#: Validation pairs of the quality mode when ``sampling.validation`` is not set (:func:`validation_count`).
QUALITY_VALIDATION = 80_000

#: Texels of a sum's ``line`` textures per texel of ``texture_size`` in the quality mode when ``line_size``
#: is not set: the finer size of the line vote (:func:`line_sizes`), 128 at the default size 32.
QUALITY_LINE_RATIO = 4

#: Why ``line_size`` is refused for a single log-space product.
LINE_SIZE_NEEDS_SUM = ("line_size sizes the line textures of a sum of products; a single product's scalar factor "
                       "has texture_size texels")


def chooser_budget(opts: FitOptions) -> int | None:
    """The lookup budget of the structure chooser (``max_lookups``, or :data:`DEFAULT_MAX_LOOKUPS` with
    ``target_error`` and sum keys); None when the options name one structure or no sum."""
    if opts.max_lookups is not None:
        return int(opts.max_lookups)
    return DEFAULT_MAX_LOOKUPS if opts.target_error is not None and opts.is_sum else None


def grid_count(opts: FitOptions) -> int:
    """Training pairs of the ``grid`` design: ``sampling.count`` when set, else
    :data:`QUALITY_GRID_COUNT` for a chooser budget above :data:`QUALITY_LOOKUPS`, else
    :data:`homofac.fit.sampling.GRID_COUNT`.

    A 16-lookup sum fits more map texels (nine maps in ``E'+NROW x4+HFW x1``, six in ``E'+NROW x2+R`` at
    8 lookups), and its grid fit reads only texel centres: on 300 000 pairs gold under the forest's low sun (``E'+NROW x4+HFW x1``) read 0.079 nrmse on
    its training pairs and 0.103 on its validation pairs; on 600 000 the error against the converged
    ground truth (90 000 pairs of 3000 normals) fell 0.106 -> 0.101, the plastic's 0.053 -> 0.049, and
    1 200 000 gave no more (0.1015) at twice the time (docs/sums.md, "The quality mode").
    """
    return opts.sampling.count or _quality_count(opts) or GRID_COUNT


def _quality_count(opts: FitOptions) -> int:
    """:data:`QUALITY_GRID_COUNT` where :func:`grid_count`'s rule sets the count, else 0 (the default)."""
    return QUALITY_GRID_COUNT if _quality(opts) else 0


def _quality(opts: FitOptions) -> bool:
    """Whether the options ask for the quality mode (a chooser budget above :data:`QUALITY_LOOKUPS`)."""
    budget = chooser_budget(opts)
    return budget is not None and budget > QUALITY_LOOKUPS


def validation_count(opts: FitOptions) -> int:
    """Validation pairs: ``sampling.validation`` when given, else :data:`QUALITY_VALIDATION` in the
    quality mode (a chooser budget above :data:`QUALITY_LOOKUPS`), else
    :data:`~homofac.fit.options.DEFAULT_VALIDATION` (20 000). Not given, the option stays None in the
    recorded config, so a refit from disk applies the same rule.

    The chooser ranks its candidates by their validation error. Under a small bright sun 20 000 random
    pairs hold few of the highlight's, and the ranking moved with them more than the candidates differ:
    one structure fitted on three seeds' 600 000 grid pairs (plastic / city, ``E'+NRW x3+R+HFCW x1``)
    read 0.056 / 0.055 / 0.055 against the converged ground truth on 90 000 pairs, and 0.049 / 0.060 /
    0.052 on its own 20 000 validation pairs (docs/sums.md, "The quality mode"). Four times the pairs
    halve that spread for a few seconds of lighting per sampling (19.5 s -> 24 s at resolution 64).
    """
    s = opts.sampling
    if s.validation is not None:
        return int(s.validation)
    return QUALITY_VALIDATION if _quality(opts) else DEFAULT_VALIDATION


def line_sizes(opts: FitOptions) -> tuple[int, ...]:
    """Texels of a sum's ``line`` textures (w(n.v), the highlight lines d, f, c) that the fit tries, the
    candidates' first: ``(line_size,)`` when given; in the quality mode (a chooser budget above
    :data:`QUALITY_LOOKUPS`) ``(32, QUALITY_LINE_RATIO x texture_size)``: the candidates are fitted with
    32-texel lines and the kept structure once more with the finer ones, kept where the validation error
    falls (the *line vote*, recorded as ``selection.lines``); else ``(32,)``
    (:data:`homofac.fit.structures.LINE_SIZE`).

    Where the view grazes, a dielectric's specular rises with the Fresnel factor and the microfacet
    highlight of a light carries ``1 / (4 n.v)``: its lines climb steeply over the last few hundredths
    of n.v, which 32 texels (width 0.031, the first centre at 0.016) cannot follow. Under the city sun
    the plastic's error lived there (83 % of the squared error at n.v < 0.1, with r within 26 degrees of
    the sun). One fit, ``E'+SS+NRW x3+HFCW x1`` on 600 000 grid pairs, read 0.055 / 0.044 / 0.038 /
    0.038 nrmse against the converged ground truth on 90 000 pairs with lines of 32 / 64 / 128 / 256
    texels; plastic / forest's ``E'+NROW x4+HFW x1`` 0.049 -> 0.044 with 128. But the near-mirror gold
    under the same sun went the other way (``E'+ROW x3+R+HFCW x2``: 0.061 -> 0.095): its highlight lines
    are read at the sharp peak of a sun, where the grid pairs fall sparsely, and a fine line follows
    them between the pairs. The validation pairs said so in all three cases (0.068 -> 0.059, 0.086 ->
    0.081, 0.062 -> 0.080), hence the vote (docs/sums.md, "Lines of 128 texels, by vote"). A line is one
    row: 128 texels cost a renderer nothing it notices.

    The ratio to ``texture_size``: the grid design puts the normals on the texel centres of the n map,
    so a line read at a function of n alone (the light's cosine n.i) sees as many distinct values as
    the map has texels, and a line much finer than that is left to its smoothing between them (at
    ``texture_size`` 8, 128 normals, lines of 128 texels fitted the training pairs of a dielectric
    under a sun better and its validation pairs worse: ``E'+ROW x1+HFCW x1`` 0.061 -> 0.16 nrmse).
    """
    if opts.line_size is not None:
        return (int(opts.line_size),)
    fine = QUALITY_LINE_RATIO * int(opts.texture_size)
    return (structures.LINE_SIZE, fine) if _quality(opts) and fine != structures.LINE_SIZE else (structures.LINE_SIZE,)


def chooser_linear(target: Target, linear: LinearOptions | None, budget: int) -> LinearOptions:
    """The linear-space options of the chooser's candidates: ``linear`` with ``nv_balance`` =
    :data:`CHOOSER_NV_BALANCE` when it is not given, the target is lighting of a BRDF with kd > 0 and
    the ``budget`` is at most :data:`QUALITY_LOOKUPS`.

    There the frontal views hold a weak specular over the diffuse term and the Fresnel-boosted grazing
    views dominate the plain objective; balancing the n.v bins keeps the frontal views (most of a
    rendered image) from being traded for them. Measured on the 16-case accuracy benchmark
    (docs/sums.md, "Where the error lives"): at 8 lookups the frontal error falls to 0.60-0.83x
    split-sum's on the plastics (1.14x and 1.24x on two before), totals within 0.03x; on the kd = 0
    near-mirror it moved the totals the wrong way (studio 0.60x -> 0.63x) with frontal errors already
    below split-sum's, so a BRDF without a diffuse part keeps the plain objective. Above 8 lookups
    the frontal error is below split-sum's either way and the balance costs the total
    (16 lookups, ``E'+NROW x4+HFW x1`` on 600 000 pairs, nrmse against the ground truth on 90 000 pairs:
    plastic / forest 0.049 -> 0.055 with it, frontal 0.016 -> 0.013), so the quality mode keeps the
    plain objective.
    """
    lin = linear or LinearOptions()
    if target.kind != "lighting" or (linear is not None and "nv_balance" in linear.model_fields_set):
        return lin
    if budget > QUALITY_LOOKUPS:
        return lin
    return lin.model_copy(update={"nv_balance": CHOOSER_NV_BALANCE}) if sums.has_diffuse(target) else lin


def chooser_polish(target: Target, linear: LinearOptions | None, lin: LinearOptions) -> int:
    """Levenberg-Marquardt steps of the chooser's polish of the structure it keeps: :data:`CHOOSER_POLISH`
    on lighting targets when ``linear`` does not set ``polish`` (set, every candidate is polished as
    asked, or none with 0) and the candidates are ALS fits; else 0.

    The candidates are ranked on their grid ALS fits (a polish of each would double the chooser's
    time); the kept one is then polished off the grid (:mod:`homofac.fit.polish`), as ``polish: 8`` on
    that structure named by hand would be; ``selection.polish`` records the validation error before and
    after. The polish is kept whatever the validation pairs say: they hold the lighting at the fit's
    resolution, and on metal / interior they rose (0.366 -> 0.376) where the error against the
    converged ground truth fell (0.373 -> 0.355); on the accuracy benchmark's 16 cases the polish
    lowered that error on 15 (docs/sums.md). A kept structure with a highlight term is polished only in
    the quality mode, and kept there only where the validation error falls (:func:`polish_rule`): at 4
    lookups the polish flattened the highlight's line (near-mirror / city 0.17 -> 0.27 against the
    ground truth; docs/sums.md).
    """
    if target.kind != "lighting" or (linear is not None and "polish" in linear.model_fields_set):
        return 0
    return CHOOSER_POLISH if lin.method in ("auto", "als") else 0


def chooser_ridge(target: Target, opts: FitOptions, lin: LinearOptions) -> int:
    """Ridge pairs of the chooser's polish of the kept structure (:mod:`homofac.fit.ridge`): ``linear.ridge``
    when given, else :data:`QUALITY_RIDGE` in the quality mode on an environment's lighting, else 0.

    Under a sun a few pairs whose view grazes the surface and reflects the sun hold most of the squared
    error of uniform pairs, and the grid and texel pairs all but miss them: on 270 000 pairs of 9000
    normals the plastic under the city sun read 0.117 nrmse at 16 lookups (0.031-0.194 over three
    disjoint thirds). Eight polish steps with 20 000 ridge pairs took it to 0.059 (eight without them:
    0.118), its validation error 0.064 -> 0.053 (docs/sums.md, "The grazing ridge of the sun"). Only
    the quality mode draws them: they cost one lighting evaluation of 20 000 pairs and the 4- and
    8-lookup modes keep their measured behaviour.

    Where they are drawn the polish tries three stages, without and then with them, and with them
    straight from the ALS fit (:func:`homofac.fit.polish.polish_stages`), and as many more pairs
    (seeded by the validation seed) give the validation estimate a ridge stratum
    (:func:`homofac.fit.polish.ridge_nrmse`) that every choice reads: the structure, the line vote and
    the polish vote (gold under the city sun: 0.062 on the plain validation pairs, 0.128 with the
    stratum, 0.148 on 270 000 uniform pairs)."""
    if opts.linear is not None and "ridge" in opts.linear.model_fields_set:
        return int(lin.ridge)
    lit = target.kind == "lighting" and getattr(target.fn, "env", None) is not None
    return QUALITY_RIDGE if _quality(opts) and lit else 0


def polish_rule(structure: Structure, budget: int) -> str | None:
    """How the chooser polishes the structure it keeps (:func:`chooser_polish` steps): ``"keep"`` (the
    polish is kept whatever the validation pairs say) for a structure without a highlight term;
    ``"vote"`` (kept only where the validation error falls) for one with a highlight term in the
    quality mode (``budget`` above :data:`QUALITY_LOOKUPS`); else None (not polished).

    At 4 lookups the polish flattened the near-mirror's highlight line under the city sun (0.17 -> 0.27
    against the ground truth). In the quality mode, where the highlight term sits beside three or four
    products, it lowered all three cases tried (600 000 grid pairs, nrmse against the converged ground
    truth on 90 000 pairs: gold / forest 0.101 -> 0.098, plastic / forest 0.049 -> 0.045, plastic /
    city 0.056 -> 0.054), and the fits' own validation pairs (the lighting at resolution 64) agreed
    each time (docs/sums.md, "The quality mode"); the vote guards against the 4-lookup failure.
    """
    if not structure.highlight_terms:
        return "keep"
    return "vote" if budget > QUALITY_LOOKUPS else None


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


def constrained(cands: list[Structure], opts: FitOptions) -> list[Structure]:
    """The chooser's candidates that a ``diffuse``, ``highlight_terms``, ``highlight_fresnel`` or
    ``highlight_cosine`` given in ``opts`` allows (all of them where none does): a diffuse term, a highlight
    count or an extra highlight line asked for explicitly constrains the search (``highlight_terms: 0``: no
    highlight candidate; ``highlight_fresnel: false``: highlight candidates without the Fresnel line)."""
    if opts.diffuse is not None:
        cands = [c for c in cands if c.diffuse == opts.diffuse] or cands
    if "highlight_terms" in opts.model_fields_set:
        cands = [c for c in cands if c.highlight_terms == opts.highlight_terms] or cands
    for key in (line.key for line in HIGHLIGHT_LINES if line.key in opts.model_fields_set):
        cands = [c for c in cands if getattr(c, key) == getattr(opts, key) or not c.highlight_terms] or cands
    if opts.highlight_disc:  # given: every highlight candidate reads its light's disc
        cands = [c._replace(highlight_disc=True) if c.highlight_terms else c for c in cands]
    return cands


def disc_rule(budget: int, opts: FitOptions) -> bool:
    """Whether the chooser fits the structure it keeps, where that has highlight terms, again with
    ``highlight_disc`` (each highlight term read at the point of its light's disc closest to ``r``,
    projection ``nhs_dom``) and keeps the one of lower validation error (the *disc vote*, recorded as
    ``selection.disc``): in the quality mode (``budget`` above :data:`QUALITY_LOOKUPS`) unless the options
    set ``highlight_disc`` (then every highlight candidate reads the disc or none does).

    At grazing views a point light's half vector is ill-conditioned and a sun's highlight comes from the
    part of its disc on the mirror direction: gold under the city sun, the quality mode's structure
    fitted alone, 0.164 -> 0.123 nrmse on 270 000 uniform pairs after the ALS and 0.140 -> 0.107 after
    the direct polish stage (disc radius 1 degree; 2 degrees: 0.147, 0.113), while its plain validation
    error rose 0.062 -> 0.077 (docs/sums.md, "The sun's disc at grazing views"): a vote, not a default."""
    return budget > QUALITY_LOOKUPS and "highlight_disc" not in opts.model_fields_set


def options(parametrization: str = "NR", **kwargs) -> FitOptions:
    """The validated :class:`FitOptions` of ``factorize``'s keywords (``None`` values mean the default)."""
    data = {"parametrization": parametrization, **{k: v for k, v in kwargs.items() if v is not None}}
    return validate(FitOptions, data, "")


def factorize(
    target: Target,
    parametrization: str = "NR",
    *,
    mapper: str | None = None,
    texture_size: int = 32,
    sampling: dict | None = None,
    solver: dict | None = None,
    target_error: float | None = None,
    terms: int | None = None,
    diffuse: str | None = None,
    nv_factor: bool | None = None,
    reflection: bool | None = None,
    prefiltered: bool | None = None,
    rw_terms: int | None = None,
    highlight_terms: int | None = None,
    highlight_fresnel: bool | None = None,
    highlight_cosine: bool | None = None,
    highlight_table: bool | None = None,
    highlight_disc: bool | None = None,
    max_lookups: int | None = None,
    line_size: int | None = None,
    linear: dict | None = None,
    baseline: dict | None = None,
    analysis: dict | None = None,
    samples: Samples | None = None,
    config: dict | None = None,
    target_info: dict | None = None,
    log: Callable[[str], None] | None = None,
    keep_samples: bool = False,
) -> Result:
    """Factor ``target`` into textures: the whole pipeline of thesis §6.1.8 (steps 1-10).

    Args:
        target: a :class:`~homofac.target.Target` (``brdf_target`` or ``lighting_target``).
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
        terms: K products of ``parametrization`` summed, fitted in linear space (:mod:`homofac.fit.sums`).
        diffuse: ``exact`` (the computed term kd/pi E(n), the products fit the rest) or ``fitted``.
        nv_factor: a 1D ``line`` texture w(n.v) in each product (BRDF: w(cos_i) w(cos_o)).
        reflection: one more fitted term, an r-only texture (lighting).
        prefiltered: keep the split sum's P(r) W(n.v) (computed) and fit corrections to it (lighting).
        rw_terms: J more fitted terms q(r) w(n.v) without a normal texture, beside the K products (lighting).
        highlight_terms: J more fitted terms d(nh_dom_j) w(n.v), the highlights of the J brightest lights of
            the environment (context ``dominant``, ``dominant1``, ...; lighting). With ``max_lookups``,
            given, only candidates with J highlight terms are tried (0: none); not given, the chooser
            tries 0-2 where the lighting is an environment.
        highlight_fresnel: each highlight term also reads f(v.h'_j), a line texture of its light's Fresnel
            argument (one lookup more a term; lighting).
        highlight_cosine: each highlight term also reads c(n.i_j), a line texture of its light's cosine (the
            shadowing G1(n.i) and the light's horizon; one lookup more a term; lighting).
        highlight_table: each highlight term reads a 2D table T(n.i_j, n.v) in place of c(n.i_j) w(n.v) (one
            lookup fewer; lighting; :mod:`homofac.fit.table`). With ``max_lookups`` above 8 the chooser's
            highlight candidates read tables where they would read the cosine line (:func:`table_wanted`).
        highlight_disc: each highlight term reads its light's coordinate at the point of the light's disc
            closest to r (projection ``nhs_dom``, context ``radius``; lighting). With ``max_lookups`` above 8
            and not given, the kept structure is fitted with and without it and the better kept (:func:`disc_rule`).
        max_lookups: choose the structure (terms, nv_factor, diffuse) within this many texture lookups
            per pixel by validation error (:func:`homofac.fit.sums.choose`).
        line_size: texels of a sum's ``line`` textures (default 32; for a ``max_lookups`` above 8 a vote
            between 32 and 4 x texture_size: :func:`line_sizes`).
        linear: :class:`~homofac.fit.options.LinearOptions` of the linear-space fit as a dict
            (``method``, ``backend``, ``iterations``, ``laplacian``, ``start``).
        baseline: options of a baseline ``parametrization`` (``split_sum``: irradiance, weighting,
            line_size; ``kautz_mccool``: slices, line_size), validated by its option model.
        analysis: ``{pair, mapper, size}`` of Mahajan's in-out analysis, recorded in ``fac.analysis``.
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
    opts = options(parametrization, mapper=mapper, texture_size=texture_size, sampling=sampling, solver=solver,
                   target_error=target_error, baseline=baseline, analysis=analysis, terms=terms, diffuse=diffuse,
                   nv_factor=nv_factor, reflection=reflection, prefiltered=prefiltered, rw_terms=rw_terms,
                   highlight_terms=highlight_terms, highlight_fresnel=highlight_fresnel,
                   highlight_cosine=highlight_cosine, highlight_table=highlight_table, highlight_disc=highlight_disc,
                   max_lookups=max_lookups,
                   line_size=line_size,
                   linear=linear)
    if not isinstance(target, Target):
        raise HomofacError(f"factorize needs a homofac Target (brdf_target or lighting_target), got {type(target).__name__}")
    mapper = opts.mapper or default_mapper(target.kind)
    is_baseline = opts.parametrization in baselines.BASELINES
    if opts.target_error is None and not is_baseline:
        pz.get(opts.parametrization, target.kind)
    if opts.baseline is not None and not is_baseline:
        raise HomofacError(f"baseline: options are for a baseline parametrization ({', '.join(baselines.BASELINES)}), "
                           f"not {opts.parametrization}")
    if opts.is_sum and is_baseline:
        raise HomofacError(f"terms, diffuse, nv_factor, max_lookups and linear shape fitted sums; "
                           f"{opts.parametrization} is a baseline (computed, not fitted)")
    if opts.is_sum:
        pz.get(opts.parametrization, target.kind)
    if opts.line_size is not None and not opts.is_sum:
        raise HomofacError(LINE_SIZE_NEEDS_SUM)
    if target.kind == "lighting" and opts.parametrization in pz.PARAMETRIZATIONS:
        target = with_context(target, opts.parametrization)  # NRHD's dominant light, NRO's shift
    if opts.linear is not None and opts.linear.ridge > 0:
        set_ = opts.linear.model_fields_set
        if opts.linear.polish == 0 and ("polish" in set_ or chooser_budget(opts) is None):
            raise HomofacError(RIDGE_NEEDS_POLISH)
        if target.kind != "lighting" or getattr(target.fn, "env", None) is None:
            raise HomofacError(polish.RIDGE_NEEDS_ENVIRONMENT)
    t0 = time.perf_counter()
    resolved = resolve_sampling(opts, target.kind, mapper)
    if opts.linear is not None and opts.linear.polish > 0 and samples is None and resolved.kind != "grid":
        raise HomofacError(f"{sums.POLISH_NEEDS_GRID}, not sampling.kind: {resolved.kind}")
    if opts.linear is not None and opts.linear.nv_balance > 0 and target.kind != "lighting":
        raise HomofacError(sums.NV_BALANCE_NEEDS_LIGHTING)
    given = samples is not None
    if samples is None:
        samples = draw_samples(target, opts.parametrization, resolved, log)
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
        result, target, samples = _sums(target, opts, mapper, samples, record, sample_s, log, resolved, given)
    elif opts.target_error is not None:
        result = auto.choose(target, opts.target_error, fit, samples, mapper=mapper, max_size=opts.texture_size,
                             log=log)
    elif is_baseline:
        result = _baseline(target, opts, mapper, samples, record, log)
        result = result.replace(timings={"sample_s": sample_s, **result.timings})
    else:
        result = fit(target, opts.parametrization, opts.texture_size)
    if opts.analysis is not None and result.analysis is None:
        a = opts.analysis
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


def resolve_sampling(opts: FitOptions, kind: str, mapper: str) -> SamplingOptions:
    """``sampling.kind: auto`` resolved (grid for linear-space sums of lighting products, else texels);
    grid samples always lie on the fitted textures' own grid (``mapper``, ``texture_size``), their count
    set by :func:`grid_count`'s rule where ``sampling.count`` is not; the validation pairs counted by
    :func:`validation_count`."""
    s = opts.sampling
    k = s.kind
    if k == "auto":
        k = "grid" if opts.is_sum and kind == "lighting" else "texels"
    validation = validation_count(opts)
    if k == "grid":
        count = s.count or _quality_count(opts)  # 0: sampling.GRID_COUNT (cache keys and records keep the 0)
        return s.model_copy(update={"kind": "grid", "size": int(opts.texture_size), "mapper": mapper, "view_size": None,
                                    "count": count, "validation": validation})
    return s.model_copy(update={"kind": k, "validation": validation})


def _sums(target: Target, opts: FitOptions, mapper: str, samples: Samples, record: dict, sample_s: float,
          log, resolved: SamplingOptions, given: bool) -> tuple[Result, Target, Samples]:
    """A linear-space sum of products: the structure of the options, or the one chosen within a budget;
    with the target (its projection context) and the samples the kept structure was fitted on.

    The grid design puts ``n`` and the structure's reflection-like direction on texel centres (``r``, or
    ``r_off`` for NRO and RO): candidates on another direction than the options' parametrization get
    grid samples of their own, drawn once per direction (the validation pairs are the same for all),
    unless the samples were given (then only the candidates on their direction are tried)."""
    budget = chooser_budget(opts)  # opts is a sum here: None exactly when one structure is named
    choosing = budget is not None
    lin = chooser_linear(target, opts.linear, budget) if choosing else opts.linear or LinearOptions()
    eps = float(opts.solver.epsilon)
    sizes = line_sizes(opts)  # the candidates' line size first; in the quality mode the kept one's vote
    polished: dict = {}
    pools = {grid_projection(target.kind, opts.parametrization, resolved): (target, samples, sample_s)}

    def pool(structure: Structure) -> tuple[Target, Samples, float]:
        # the samples are shared by every structure on one grid direction (all of them for texel pairs);
        # the context is each structure's own (NRO and RO read shift wherever their pairs came from)
        tgt = with_context(target, structure.parametrization)
        proj = grid_projection(target.kind, structure.parametrization, resolved)
        if proj not in pools:
            t0 = time.perf_counter()
            smp = draw_samples(tgt, structure.parametrization, resolved, log)
            check_values(np.asarray(smp.y), "training")
            pools[proj] = (tgt, smp, time.perf_counter() - t0)
        _, smp, s_s = pools[proj]
        return tgt, smp, s_s

    def pairs() -> Samples:  # the polish's off-grid pairs, drawn once for every candidate structure
        if "pairs" not in polished:
            t0 = time.perf_counter()
            polished["pairs"] = polish.polish_pairs(target, opts.parametrization, lin, opts.sampling.seed,
                                                    opts.sampling.cache, log)
            polished["sample_s"] = time.perf_counter() - t0
        return polished["pairs"]

    fits: dict = {}  # (structure, line size) -> its SumFit (the chooser polishes the one it keeps)

    def fit(structure: Structure, line: int = sizes[0]) -> Result:
        tgt, smp, _ = pool(structure)
        sf = sums.fit_sum(tgt, structure, mapper, opts.texture_size, smp, lin, log, line_size=line)
        if lin.polish > 0:
            sf = polish.polish(tgt, structure, mapper, opts.texture_size, sf, smp, pairs(), lin, log,
                               seed=opts.sampling.seed)
        fits[structure, line] = sf
        return as_result(structure, sf)

    def as_result(structure: Structure, sf) -> Result:
        tgt, smp, s_s = pool(structure)
        rec = {**record, "samples": smp if record.get("samples") is not None else None}
        result = Result(sf.model, solver=sf.solver, warnings=sf.warnings, **rec)
        log("measuring errors")
        mets = measure(result, tgt, smp, eps=eps)
        extra = {"polish_sample_s": polished["sample_s"]} if "sample_s" in polished else {}
        return result.replace(
            metrics=mets, warnings=tuple(result.warnings) + tuple(quality_warnings(mets)),
            timings={"sample_s": s_s, "assemble_s": sf.assemble_s, "solve_s": sf.solve_s, **extra},
            counts={"train": int(len(smp.a)), "validation": int(len(smp.val_a)), "unknowns": sf.unknowns,
                    "lights": int(getattr(tgt.fn, "n_lights", 0)), "lookups": int(sf.model.lookups)},
        )

    def kept(result: Result) -> tuple[Result, Target, Samples]:
        structure = Structure.of(result.solver["structure"])
        tgt, smp, _ = pool(structure)
        return result, sums.with_highlight_context(tgt, structure), smp

    if not choosing:
        return kept(fit(Structure.of(opts)))
    if len(samples.val_a) == 0:
        raise HomofacError("max_lookups and target_error choose by validation error: sampling.validation must be > 0")
    # lighting: a fitted n-only texture wherever the model has a kd (it starts at kd/pi E(n), which may
    # be 0) -- a near-mirror under lamps fits better with it; BRDF: the constant kd/pi term only when kd > 0
    has_d = sums.diffuse_albedo(target) is not None if target.kind == "lighting" else sums.has_diffuse(target)
    pick = structures.ladder if opts.target_error is not None else structures.candidates
    # the highlight term of the brightest light wherever the target's lighting is an environment
    lit = target.kind == "lighting" and getattr(target.fn, "env", None) is not None
    cands = pick(target.kind, budget, parametrization=opts.parametrization, has_diffuse=has_d, highlight=lit,
                 table=table_wanted(budget, opts))
    cands = constrained(cands, opts)
    if given:  # samples given: only the candidates on their grid direction
        own = grid_projection(target.kind, opts.parametrization, resolved)
        cands = [c for c in cands if grid_projection(target.kind, c.parametrization, resolved) == own] or cands
    analysis = None
    if target.kind == "lighting":
        # Mahajan et al. 2008: the rank-K error of the gridded target bounds what K products p(n) q(r)
        # can reach; the products with w(n.v) need fewer. Recorded beside the choice (and printed).
        a = opts.analysis or AnalysisOptions()
        log(f"in-out analysis ({a.pair}) on {a.mapper} {a.size}")
        analysis = baselines.analyse(target, a.pair, a.mapper, a.size).record()
    ridge = chooser_ridge(target, opts, lin)
    rv = None
    if ridge > 0:  # every choice below reads the validation estimate with the ridge stratum (polish.ridge_nrmse)
        rv = polish.ridge_validation(target, samples, ridge, opts.sampling.seed + 1)
        log(f"validation: {len(rv.pairs.a)} ridge pairs stand in for the {int(rv.inside.sum())} validation pairs on "
            f"the ridges of the {len(rv.lights)} brightest lights")
    score = None if rv is None else (lambda res: polish.ridge_nrmse(res, samples, rv))
    result = sums.choose(fit, cands, target_error=opts.target_error, max_lookups=budget, log=log, score=score)
    structure = Structure.of(result.solver["structure"])
    line = sizes[0]  # the kept fit's line size (fits[structure, line] is its SumFit)
    if len(sizes) > 1 and any(t.mapper == "line" for t in result.model.textures):
        result, line = _line_vote(result, structure, sizes, fit, log, score)
    if structure.highlight_terms and disc_rule(budget, opts):
        result = _disc_vote(result, structure, line, fit, log, score)
        structure = Structure.of(result.solver["structure"])
    steps = chooser_polish(target, opts.linear, lin)
    rule = polish_rule(structure, budget)
    if steps and result.solver.get("method") == "als" and rule is not None:
        tgt, smp, _ = pool(structure)
        plin = lin.model_copy(update={"polish": steps, "ridge": ridge})
        stages = [as_result(structure, sf) for sf in polish.polish_stages(
            tgt, structure, mapper, opts.texture_size, fits[structure, line], smp, pairs(), plin, log,
            seed=opts.sampling.seed, direct=True)]
        result = _polish_vote(result, stages, rule, score, steps, ridge, structure.label(), log)
    return kept(result if analysis is None else result.replace(analysis=analysis))


def table_wanted(budget: int, opts: FitOptions) -> bool:
    """Whether the chooser's highlight candidates read their light's cosine and the view's in a 2D table
    T(n.i, n.v) instead of the lines c(n.i) w(n.v) (``highlight_table``, :func:`homofac.fit.structures.candidates`):
    as the options say where they set ``highlight_table``, else in the quality mode (``budget`` above
    :data:`QUALITY_LOOKUPS`), where the polish that refines the tables runs.

    The ALS fits the lines and the table starts as their product (:func:`homofac.fit.sums.tabulated`), so
    a candidate with tables is ranked on the function of its lines at one lookup fewer per highlight
    term, which the budget gives to more terms. Near the mirror direction the highlight is
    ``D F n.h'^2 min(n.v, n.i) / (n.v (n.v + n.i))``, which no product of the two lines holds: refitting
    only that factor of the saved city fits as a table took plastic / city from 0.072 to 0.055 nrmse on
    270 000 uniform pairs and gold / city's first highlight term from 0.148 to 0.122 (docs/sums.md,
    "A 2D table of (n.i, n.v), again")."""
    if "highlight_table" in opts.model_fields_set:
        return bool(opts.highlight_table)
    return budget > QUALITY_LOOKUPS


def _figures(res: Result, score: Callable | None) -> dict:
    """A result's validation nrmse, and with ``score`` the ridge stratum's (the figures the votes read)."""
    plain = {"validation_nrmse": float(res.metrics["validation"]["float"]["nrmse"])}
    return plain if score is None else {**plain, sums.RIDGE_METRIC: float(score(res))}


def _polish_vote(result: Result, stages: list[Result], rule: str, score: Callable | None, steps: int, ridge: int,
                 label: str, log) -> Result:
    """The kept structure's ALS fit (``result``) or one of its polish ``stages`` (:func:`polish.polish_stages`
    with ``direct``: without the ridge pairs, then with them, then with them from the ALS fit): the stage
    of lowest validation error (``score``, the ridge stratum's, where given), kept where ``rule`` is
    ``"keep"`` or its error is below the ALS fit's. ``selection.polish`` records the steps, the rule,
    each stage's errors with its ridge pairs and start (:data:`polish.STAGE_STARTS`), the errors before
    and after and what was kept (``kept``; ``stage``: the kept stage's index; ``ridge``, ``start``: its
    ridge pairs and start)."""
    key, what = sums.scored_by(score is not None)
    before, figures = _figures(result, score), [_figures(r, score) for r in stages]
    best = int(np.argmin([f[key] for f in figures]))
    keep = rule == "keep" or figures[best][key] < before[key]
    log(f"polish of {label}: {what} {before[key]:.4g} -> " + " / ".join(f"{f[key]:.4g}" for f in figures)
        + (f": stage {best + 1} kept" if keep else ": not kept (the validation error did not fall)"))
    described = [{"ridge": ridge if i else 0, "start": polish.STAGE_STARTS[i], **f}
                 for i, f in enumerate(figures)]
    note = {"steps": steps, **{f"{k}_before": v for k, v in before.items()},
            **{f"{k}_after": v for k, v in figures[best].items()}, "stages": described, "rule": rule, "kept": keep,
            "stage": best if keep else None, "ridge": described[best]["ridge"] if keep else 0,
            "start": described[best]["start"] if keep else None}
    return (stages[best] if keep else result).replace(selection={**result.selection, "polish": note})


def _vote_errors(tried: list[Result], score: Callable | None) -> tuple[list[float], list[float], str]:
    """The plain validation nrmse of each of ``tried``, the errors a vote ranks them by (``score``'s where
    given: the ridge stratum's) and the words naming those (:func:`homofac.fit.sums.scored_by`)."""
    plain = [float(r.metrics["validation"]["float"]["nrmse"]) for r in tried]
    errs = plain if score is None else [float(score(r)) for r in tried]
    return plain, errs, sums.scored_by(score is not None)[1]


def _line_vote(result: Result, structure: Structure, sizes: tuple[int, ...], fit: Callable,
               log, score: Callable | None = None) -> tuple[Result, int]:
    """The kept ``structure`` (``result``, fitted with ``sizes[0]``-texel lines) fitted again with each
    further line size, the one of lowest validation error kept (ties: the first), with its size;
    ``selection.lines`` records the sizes, their validation nrmse and the kept size (:func:`line_sizes`).
    ``score(result)``: the validation error the vote uses instead of the plain one (the ridge stratum's,
    recorded beside it)."""
    tried = [(sizes[0], result)]
    for size in sizes[1:]:
        log(f"line vote: {structure.label()} with {size}-texel lines")
        tried.append((size, fit(structure, size)))
    plain, errs, what = _vote_errors([r for _, r in tried], score)
    k = int(np.argmin(errs))
    log(f"line vote: {what} " + ", ".join(f"{e:.4g} ({n} texels)" for (n, _), e in zip(tried, errs))
        + f": {tried[k][0]} kept")
    note = {"sizes": [int(n) for n, _ in tried], "validation_nrmse": plain, "kept": int(tried[k][0]),
            **({} if score is None else {sums.RIDGE_METRIC: errs})}
    return tried[k][1].replace(selection={**result.selection, "lines": note}), int(tried[k][0])


def _disc_vote(result: Result, structure: Structure, line: int, fit: Callable, log,
               score: Callable | None = None) -> Result:
    """The kept ``structure`` (``result``) against the same read at its lights' discs (``highlight_disc``,
    fitted with ``line``-texel lines): the one of lower validation error (``score``'s where given; ties:
    the kept one). ``selection.disc`` records the radii, both errors and whether the disc was kept
    (:func:`disc_rule`)."""
    other = structure._replace(highlight_disc=not structure.highlight_disc)
    log(f"disc vote: {other.label()}")
    tried = [result, fit(other, line)]
    plain, errs, what = _vote_errors(tried, score)
    k = int(errs[1] < errs[0])
    log(f"disc vote: {what} {errs[0]:.4g} ({structure.label()}), {errs[1]:.4g} ({other.label()}): "
        f"{(structure, other)[k].label()} kept")
    disc = tried[1] if other.highlight_disc else tried[0]
    radii = [float(disc.model.context[r]) for _, _, r in pj.HIGHLIGHT_DISCS[:structure.highlight_terms]]
    note = {"radii": radii, "labels": [structure.label(), other.label()], "validation_nrmse": plain,
            "kept": bool((structure, other)[k].highlight_disc), **({} if score is None else {sums.RIDGE_METRIC: errs})}
    return tried[k].replace(selection={**(result.selection or {}), "disc": note})


def _baseline(target: Target, opts: FitOptions, mapper: str, samples: Samples, record: dict, log) -> Result:
    """A baseline's model (computed, not fitted) with the same metrics and record as a fit."""
    log(f"computing the {opts.parametrization} baseline ({mapper} {opts.texture_size})")
    t0 = time.perf_counter()
    model = baselines.build(opts.parametrization, target, mapper, opts.texture_size, opts.baseline)
    build_s = time.perf_counter() - t0
    result = Result(model, solver={"method": opts.parametrization, "iterations": 0, "converged": True,
                                   "options": validate(baselines.get(opts.parametrization).options,
                                                       opts.baseline, "baseline").model_dump()}, **record)
    mets = measure(result, target, samples, eps=float(opts.solver.epsilon))
    return result.replace(metrics=mets, warnings=tuple(quality_warnings(mets)),
                          timings={"build_s": build_s, "assemble_s": 0.0, "solve_s": 0.0},
                          counts={"train": int(len(samples.a)), "validation": int(len(samples.val_a)),
                                  "unknowns": 0, "lights": int(getattr(target.fn, "n_lights", 0))})


__all__ = ["CHOOSER_NV_BALANCE", "CHOOSER_POLISH", "DEFAULT_MAX_LOOKUPS", "QUALITY_GRID_COUNT", "QUALITY_LOOKUPS",
           "QUALITY_RIDGE", "QUALITY_VALIDATION", "RIDGE_NEEDS_POLISH", "chooser_budget", "chooser_linear",
           "chooser_polish", "chooser_ridge", "grid_count", "polish_rule",
           "LINE_SIZE_NEEDS_SUM", "QUALITY_LINE_RATIO", "line_sizes", "validation_count",
           "constrained", "default_mapper", "draw_samples", "factorize", "measure", "options", "quality_warnings",
           "resolve_sampling"]
