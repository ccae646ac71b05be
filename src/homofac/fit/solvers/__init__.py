"""Solvers of the least-squares system of eq. 37: one record per module, collected in a registry.

=============== ===========================================================================================
``lsmr``        :mod:`.lsmr`: matrix-free LSMR (lineax) with Jacobi column scaling; the default
``qmr``         :mod:`.qmr`: scipy QMR on the augmented system of thesis eq. 16 (the original's method)
``cg``          :mod:`.cg`: CG on the normal equations in float64 (scipy)
``optimistix``  :mod:`.gauss_newton`: Gauss-Newton (optimistix) with an LSMR inner solve
``direct``      :mod:`.direct`: dense normal equations + Cholesky in float64 (the optimum, small sizes)
=============== ===========================================================================================

The config's ``solver.method`` values, the memory estimate, ``--help`` and the docs' solver table are
derived from :data:`SOLVERS`; a new solver is a new module with a ``SOLVER`` record registered here.
"""

from __future__ import annotations

import time
from typing import Annotated, Any, Union

import jax.numpy as jnp
import numpy as np
from pydantic import Discriminator, Tag

from ...errors import HomofacError
from ...options import validate
from ..system import System, augmented_rhs, objective
from . import cg, direct, gauss_newton, lsmr, qmr
from .base import SolveResult, Solver, SolverOptions

#: The registered solvers by name, in the order of the docs' table.
SOLVERS: dict[str, Solver] = {s.SOLVER.name: s.SOLVER for s in (lsmr, qmr, cg, gauss_newton, direct)}
#: The solver used when ``solver.method`` is not given.
DEFAULT = "lsmr"


def register(solver: Solver) -> Solver:
    """Add (or replace) a solver record."""
    SOLVERS[solver.name] = solver
    return solver


def get(name: str) -> Solver:
    """The solver registered as ``name`` (one line naming the known ones otherwise)."""
    if not isinstance(name, str) or name not in SOLVERS:
        raise HomofacError(f"solver.method must be one of {', '.join(SOLVERS)}, got {name!r}")
    return SOLVERS[name]


def _method_of(value: Any) -> str:
    if isinstance(value, dict):
        return value.get("method", DEFAULT)
    return getattr(value, "method", DEFAULT)


def options_type():
    """The tagged union (by ``method``, default ``lsmr``) of every solver's option model."""
    members = tuple(Annotated[s.options, Tag(name)] for name, s in SOLVERS.items())
    return Annotated[Union[members], Discriminator(_method_of)]  # type: ignore[valid-type]


def options(data: Any = None, where: str = "solver") -> SolverOptions:
    """Validated solver options from a dict (or options), with the method's own option model."""
    if isinstance(data, SolverOptions):
        return data
    data = dict(data or {})
    method = data.get("method", DEFAULT)
    if not isinstance(method, str) or method not in SOLVERS:
        raise HomofacError(f"{where}.method must be one of {', '.join(SOLVERS)}, got {method!r}")
    return validate(SOLVERS[method].options, data, where)


def solve(sys: System, x0: jnp.ndarray, options_: SolverOptions | dict | None = None, **kwargs) -> SolveResult:
    """Minimise ``||A x - b||^2 + ||lambda L x||^2`` (eq. 37) from the starting solution ``x0``.

    Args:
        sys: the system from :func:`homofac.fit.system.build_system`.
        x0: starting solution (n, 3), e.g. from :func:`homofac.fit.start.starting_solution`.
        options_: solver options (a :class:`SolverOptions` or a dict: ``method``, ``tolerance``,
            ``max_iterations``, ``laplacian``, ...); keyword arguments are merged into them.
    """
    if kwargs:
        base = options_.model_dump() if isinstance(options_, SolverOptions) else dict(options_ or {})
        options_ = {**base, **kwargs}
    opts = options(options_)
    solver = SOLVERS[opts.method]
    t0 = time.perf_counter()
    x, iterations, converged = solver.run(sys, x0, opts)
    seconds = time.perf_counter() - t0
    lam = jnp.asarray(opts.laplacian, x0.dtype)
    obj = float(objective(sys, lam, x))
    bnorm2 = float(jnp.sum(augmented_rhs(sys) ** 2))
    residual = float(np.sqrt(obj / bnorm2)) if bnorm2 > 0 else float(np.sqrt(obj))
    if not np.all(np.isfinite(np.asarray(x))):
        raise HomofacError(f"solver {opts.method} produced non-finite texture values; try a larger solver.laplacian")
    return SolveResult(x, opts.method, int(iterations), bool(converged), residual, obj, seconds)


column_scale = lsmr.column_scale

__all__ = ["DEFAULT", "SOLVERS", "SolveResult", "Solver", "SolverOptions", "column_scale", "get", "options",
           "options_type", "register", "solve"]
