"""``cg``: conjugate gradients on the normal equations ``A^T A x = A^T b`` in float64 (scipy).

Matrix-free through the CSR matrix and its transpose, one channel at a time: the textbook method, a
benchmark baseline.
"""

from __future__ import annotations

from typing import ClassVar, Literal

import jax.numpy as jnp
import numpy as np
import scipy.sparse.linalg as spla

from ..system import System, augmented_rhs, to_scipy
from .base import Solver, SolverOptions


class CGOptions(SolverOptions):
    """Options of ``cg`` (the common ones)."""

    TAG: ClassVar[str] = "cg"
    method: Literal["cg"] = "cg"


def _cg(sys: System, lam: float, x0: np.ndarray, tol: float, maxiter: int):
    """CG on the normal equations in float64, one channel at a time, for the correction d = x - x0."""
    a = to_scipy(sys, lam, x0.shape[0])
    at = a.T.tocsr()
    n = x0.shape[0]
    ata = spla.LinearOperator((n, n), matvec=lambda v: at @ (a @ v), dtype=np.float64)
    b_all = np.asarray(augmented_rhs(sys), np.float64)
    out = np.empty_like(x0)
    iters, converged = 0, True
    for c in range(3):
        rhs = at @ (b_all[:, c] - a @ x0[:, c])
        count = [0]

        def cb(_xk, count=count):
            count[0] += 1

        sol, info = spla.cg(ata, rhs, rtol=tol, maxiter=maxiter, callback=cb)
        out[:, c] = x0[:, c] + sol
        iters = max(iters, count[0])
        converged &= info == 0
    return out, iters, bool(converged)



def run(sys: System, x0, options: CGOptions):
    x, iterations, converged = _cg(sys, options.laplacian, np.asarray(x0, np.float64), options.tolerance,
                                   options.max_iterations)
    return jnp.asarray(x, x0.dtype), iterations, converged


def memory(rows: int, unknowns: int, k: int) -> int:
    """CSR float64 of the augmented matrix and its transpose."""
    return rows * k * 16 * 3


SOLVER = Solver("cg", CGOptions, run, memory, "CG on the normal equations in float64 (scipy): the textbook baseline")
