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
from ..options import validate
from ..param import parametrizations as pz
from ..target import Target
from . import auto
from .draw import default_mapper, draw_samples
from .metrics import measure
from .options import FitOptions
from .product import fit_product
from .result import Result
from .samples import Samples, check_values


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
            ``validation``, ``seed``, ``count``, ``mapper``, ``cache``).
        solver: solver options as a dict (``method``, ``tolerance``, ``max_iterations``, ``laplacian``,
            ``epsilon``, ``levels``), validated by the method's own option model.
        target_error: fit candidates cheapest first and keep the first whose validation nrmse meets it
            (:mod:`homofac.fit.auto`); ``parametrization`` and ``texture_size`` are then the limits.
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
    opts = options(parametrization, mapper=mapper, texture_size=texture_size, sampling=sampling, solver=solver,
                   target_error=target_error, baseline=baseline, analysis=analysis)
    if not isinstance(target, Target):
        raise HomofacError(f"factorize needs a homofac Target (brdf_target or lighting_target), got {type(target).__name__}")
    mapper = opts.mapper or default_mapper(target.kind)
    is_baseline = opts.parametrization in baselines.BASELINES
    if opts.target_error is None and not is_baseline:
        pz.get(opts.parametrization, target.kind)
    if opts.baseline is not None and not is_baseline:
        raise HomofacError(f"baseline: options are for a baseline parametrization ({', '.join(baselines.BASELINES)}), "
                           f"not {opts.parametrization}")
    t0 = time.perf_counter()
    if samples is None:
        samples = draw_samples(target, opts.parametrization, opts.sampling, log)
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

    if opts.target_error is not None:
        result = auto.choose(target, opts.target_error, fit, samples, mapper=mapper, max_size=opts.texture_size,
                             log=log)
    elif is_baseline:
        result = _baseline(target, opts, mapper, samples, record, log)
        result = result.replace(timings={"sample_s": sample_s, **result.timings})
    else:
        result = fit(target, opts.parametrization, opts.texture_size)
    if opts.analysis is not None:
        a = opts.analysis
        log(f"in-out analysis ({a.pair}) on {a.mapper} {a.size}")
        result = result.replace(analysis=baselines.analyse(target, a.pair, a.mapper, a.size).record())
    return result.replace(timings={**result.timings, "total_s": time.perf_counter() - t_start}, target=target)


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


__all__ = ["default_mapper", "draw_samples", "factorize", "measure", "options", "quality_warnings"]
