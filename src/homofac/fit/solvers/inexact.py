"""An inexact inner solve for optimistix's Newton-type solvers (:class:`Truncated`).

Not a registered solver: the wrapper the ``optimistix`` solver (:mod:`.gauss_newton`) and the
Levenberg-Marquardt refinement of sums (:mod:`homofac.fit.refine`) give their LSMR.
"""

from __future__ import annotations

from typing import Any

import lineax as lx
from jaxtyping import PyTree


class Truncated(lx.AbstractLinearSolver):
    """``solver`` (an iterative least-squares solver started from zero) whose last iterate is returned as
    a successful solve where it stops on its step cap (``max_steps_reached``) or its condition limit
    (``conlim``): an inexact Newton step.

    optimistix ends a least-squares solve at the first unsuccessful linear solve and keeps the last
    accepted point. With a capped LSMR that happened wherever one Levenberg-Marquardt system needed more
    than the cap: the polish of gold under the city sun at 16 lookups took 1 of its 8 steps and left the
    fit where it was. LSMR's k-th iterate from zero minimises the residual over a Krylov space that holds
    the gradient, so it is a descent direction of the Gauss-Newton model, which is all the trust-region
    step of Levenberg-Marquardt needs (the step is still accepted or rejected on the objective).
    Breakdowns (non-finite values, a singular system) stay failures. The log-space Gauss-Newton of
    ``solver.method: optimistix`` (:mod:`.gauss_newton`) had the same fault: with ``max_iterations: 10``
    it returned its start (0.595 validation nrmse on a Phong PQP where ``lsmr`` reached 0.28).
    """

    solver: lx.AbstractLinearSolver

    def init(self, operator: lx.AbstractLinearOperator, options: dict[str, Any]):
        return self.solver.init(operator, options)

    def compute(self, state, vector: PyTree, options: dict[str, Any]) -> tuple[PyTree, lx.RESULTS, dict[str, Any]]:
        x, result, stats = self.solver.compute(state, vector, options)
        inexact = (result == lx.RESULTS.max_steps_reached) | (result == lx.RESULTS.conlim)
        return x, lx.RESULTS.where(inexact, lx.RESULTS.successful, result), stats

    def transpose(self, state, options: dict[str, Any]):
        return self.solver.transpose(state, options)

    def conj(self, state, options: dict[str, Any]):
        return self.solver.conj(state, options)

    def assume_full_rank(self) -> bool:
        return self.solver.assume_full_rank()


__all__ = ["Truncated"]
