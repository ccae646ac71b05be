"""homofac.fit: sampling, system assembly, solvers, metrics, precision, config and the CLI."""

from __future__ import annotations

from .factorization import Factorization, evaluate_textures
from . import metrics, sampling, system
from .pipeline import Samples, draw_samples, factorize, measure
from .solvers import SolveResult, solve
from .target import Target, brdf_target, evaluate

__all__ = [
    "Factorization", "Samples", "SolveResult", "Target", "brdf_target", "draw_samples", "evaluate",
    "evaluate_textures", "factorize", "measure", "metrics", "sampling", "solve", "system",
]
