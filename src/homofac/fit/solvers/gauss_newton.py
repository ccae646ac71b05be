"""``optimistix``: Gauss-Newton from optimistix on the residual ``A x - b`` with an LSMR linear solver.

Matrix-free (the Jacobian is a JVP). The log-space system is linear, so it converges in one or two
steps; it is the path through which ``jax.grad`` through a solve goes, and the same solver refines
the nonlinear linear-space objective of sums of products (:mod:`homofac.fit.sums`). ``max_iterations``
caps each LSMR solve; a capped solve is a truncated step the next Gauss-Newton step goes on from
(:class:`.inexact.Truncated`).
"""

from __future__ import annotations

import functools
from typing import ClassVar, Literal

import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import optimistix as optx

from ..system import System, apply, augmented_rhs
from .base import Solver, SolverOptions
from .inexact import Truncated


class GaussNewtonOptions(SolverOptions):
    """Options of ``optimistix`` (the common ones; the outer tolerance is floored at sqrt(eps))."""

    TAG: ClassVar[str] = "optimistix"
    method: Literal["optimistix"] = "optimistix"


@functools.partial(jax.jit, static_argnames=("rtol", "max_steps"))
def _optimistix(sys: System, lam, x0, *, rtol: float, max_steps: int):
    rhs = augmented_rhs(sys)

    def residual(x, _):
        return apply(sys, lam, x) - rhs

    # an LSMR that hits max_steps gives a truncated step and the next Gauss-Newton step goes on from it
    linear = Truncated(lx.LSMR(rtol=rtol, atol=rtol, max_steps=max_steps))
    # The outer (Cauchy) test compares successive iterates; below sqrt(eps) of the dtype they differ by
    # the inner solve's rounding only, so a tighter outer tolerance would never be met in float32.
    outer = max(rtol, float(np.sqrt(np.finfo(x0.dtype).eps)))
    solver = optx.GaussNewton(rtol=outer, atol=outer, linear_solver=linear)
    sol = optx.least_squares(residual, solver, x0, max_steps=16, throw=False)
    return sol.value, sol.stats["num_steps"], sol.result == optx.RESULTS.successful




def run(sys: System, x0, options: GaussNewtonOptions):
    lam = jnp.asarray(options.laplacian, x0.dtype)
    x, steps, ok = _optimistix(sys, lam, x0, rtol=float(options.tolerance), max_steps=int(options.max_iterations))
    return jax.block_until_ready(x), int(steps), bool(ok)


def memory(rows: int, unknowns: int, k: int) -> int:
    """As lsmr, plus the Gauss-Newton state (a few more vectors)."""
    return rows * 2 * 12 * k + 12 * (rows + unknowns) * 12


SOLVER = Solver("optimistix", GaussNewtonOptions, run, memory, "Gauss-Newton (optimistix) with an LSMR inner solve, matrix-free")
