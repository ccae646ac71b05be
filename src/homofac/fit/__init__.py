"""homofac.fit: sampling, the log-space system, solvers, precision, metrics and the pipeline.

``hf.fit.factorize(target, preset="balanced")`` builds a :class:`Plan` (:mod:`.plan`: what will run,
printable) and executes it; ``hf.fit.factorize(target, "NR", ...)`` fits one named product. Either and returns a :class:`Result` (the model and its run
record); each stage is a module of its own so a notebook can stop anywhere: :mod:`.sampling` (direction
pairs), :mod:`.draw` (samples, cached), :mod:`.system` (eq. 30-37), :mod:`.start` (§3.1.2),
:mod:`.solvers` (one record per solver), :mod:`.product` (one product in log space),
:mod:`.precision` (8-bit), :mod:`.metrics`, :mod:`.auto` (target_error), :mod:`.differentiable`;
sums of products in linear space: :mod:`.structures` (terms, diffuse, nv_factor), :mod:`.sums` (the fit
and the choice within ``max_lookups``), :mod:`.als` (grid ALS), :mod:`.refine` (Levenberg-Marquardt).
Solve once, reuse: :func:`refit` (:mod:`.refit`; a new environment or material on a fit's layout, what
it reuses in :mod:`.state`, the light transport in :mod:`.transport`), :func:`factorize_many` (:mod:`.many`: one layout, many targets).
Scene-aware sampling: :mod:`.scene` (``sampling.kind: scene``: the (n, v) pairs a mesh seen by cameras
produces, and the image-space metrics of that scene).
"""

from __future__ import annotations

from ..target import Target, brdf_target, evaluate
from . import als, differentiable, metrics, precision, refine, sampling, scene, solvers, structures, sums, system, transport
from .draw import draw_samples
from .metrics import measure
from .options import FitOptions, LinearOptions, SamplingOptions
from .pipeline import execute, factorize
from .plan import PRESETS, Plan, build_plan
from .many import factorize_many
from .refit import prepare as prepare_refit
from .refit import refit
from .result import Result
from .samples import Samples, evaluate_grouped
from .solvers import SolveResult, SolverOptions, solve
from .structures import Structure

__all__ = [
    "FitOptions", "LinearOptions", "Result", "differentiable", "SamplingOptions", "Structure", "als", "refine", "structures", "sums", "Samples", "SolveResult", "SolverOptions", "Target", "brdf_target",
    "PRESETS", "Plan", "build_plan", "execute", "draw_samples", "evaluate", "evaluate_grouped", "factorize", "factorize_many", "measure", "metrics", "precision", "sampling",
    "prepare_refit", "refit", "scene", "solve", "solvers", "system", "transport",
]
