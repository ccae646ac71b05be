"""What every solver shares: its option model, its record, and the result it returns.

A solver is one record (:class:`Solver`) in its own module, as lineax keeps one solver per file: its
name, its option model (a :class:`SolverOptions` subclass; unknown keys and bad values are refused
there, once, for the CLI and the Python API alike), the function that runs it, its memory class (the
extra bytes it needs, for the memory estimate) and its doc. :mod:`homofac.fit.solvers` collects them
into the registry that the config's ``solver.method`` values, ``--help`` and the docs derive from.

Every solver minimises the same objective, eq. 37 of the thesis: ``||A x - b||^2 + ||lambda L x||^2``
summed over the RGB channels, from a starting solution ``x0``.
"""

from __future__ import annotations

from typing import Callable, ClassVar, Literal, NamedTuple

import jax.numpy as jnp
from pydantic import Field

from ...options import Options
from ..system import System


class SolverOptions(Options):
    """``solver``: the method, its stopping rule, and the parameters of the system it solves.

    ``laplacian`` is lambda of eq. 37, ``epsilon`` the bias of eq. 26 (log((y + eps alpha) / alpha)),
    ``levels`` > 1 solves at S / 2^(levels-1) first and refines each doubled size from the upsampled
    result (multi-resolution, thesis §3.1.2).
    """

    TAG: ClassVar[str] = ""
    method: str = "lsmr"
    tolerance: float = Field(1e-6, gt=0, lt=1, description="relative stopping tolerance of iterative solvers")
    max_iterations: int = Field(1000, ge=1, le=10_000_000, description="iteration cap of iterative solvers")
    laplacian: float = Field(1.0, ge=0, allow_inf_nan=False, description="Laplacian weight lambda (eq. 37)")
    epsilon: float = Field(1e-5, gt=0, lt=1, description="log bias eps of eq. 26")
    levels: int = Field(1, ge=1, le=8, description="multi-resolution levels (thesis §3.1.2)")
    zeros: Literal["auto", "bias", "ignore"] = Field(
        "auto", description="samples with a zero (or negative) channel: bias (log(y + eps alpha), eq. 26) or "
        "ignore (left out of the log system); auto ignores them for measured (merl) BRDFs")


class SolveResult(NamedTuple):
    """A solution x (n, 3) and how it was reached."""

    x: jnp.ndarray
    method: str
    iterations: int
    converged: bool
    residual: float  # ||A x - b|| / ||b|| of the augmented system
    objective: float  # ||A x - b||^2 summed over RGB
    seconds: float


class Solver(NamedTuple):
    """A registered solver: ``run(sys, x0, options) -> (x, iterations, converged)``.

    ``memory(rows, unknowns, entries_per_row)`` is the extra peak memory in bytes beyond the system
    itself (the dense normal matrix of ``direct``, scipy's float64 copies, ...).
    """

    name: str
    options: type[SolverOptions]
    run: Callable[[System, jnp.ndarray, SolverOptions], tuple[jnp.ndarray, int, bool]]
    memory: Callable[[int, int, int], int]
    doc: str


__all__ = ["SolveResult", "Solver", "SolverOptions"]
