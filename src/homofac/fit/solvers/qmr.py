"""``qmr``: scipy's QMR on the augmented square system of thesis eq. 16, the original's method.

``[[I, A], [A^T, 0]] [r; x] = [b; 0]``, one channel at a time as the original implementation did (thesis
§3.1.2, "Iterative Computation"), in float64. Kept as the reference the others are measured against.
"""

from __future__ import annotations

from typing import ClassVar, Literal

import jax.numpy as jnp
import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import qmr

from ..system import System, augmented_rhs, to_scipy
from .base import Solver, SolverOptions


class QMROptions(SolverOptions):
    """Options of ``qmr`` (the common ones)."""

    TAG: ClassVar[str] = "qmr"
    method: Literal["qmr"] = "qmr"


def _qmr(sys: System, lam: float, x0: np.ndarray, tol: float, maxiter: int):
    """QMR on eq. 16, one channel at a time (as the original implementation)."""
    a = to_scipy(sys, lam, x0.shape[0])
    m, n = a.shape
    big = sp.bmat([[sp.identity(m, format="csr"), a], [a.T, None]], format="csr")
    b_all = np.asarray(augmented_rhs(sys), np.float64)
    out = np.empty_like(x0)
    iters, converged = 0, True
    for c in range(3):
        # Solve for the correction d = x - x0 from a zero start: [[I, A], [A^T, 0]] [r; d] = [b - A x0; 0].
        # (Starting QMR at [b - A x0; x0] instead makes the first block of its residual zero, and the
        # Lanczos process breaks down at once.)
        rhs = np.concatenate([b_all[:, c] - a @ x0[:, c], np.zeros(n)])
        count = [0]

        def cb(_xk, count=count):
            count[0] += 1

        sol, info = qmr(big, rhs, rtol=tol, maxiter=maxiter, callback=cb)
        out[:, c] = x0[:, c] + sol[m:]
        iters = max(iters, count[0])
        converged &= info == 0
    return out, iters, bool(converged)



def run(sys: System, x0, options: QMROptions):
    x, iterations, converged = _qmr(sys, options.laplacian, np.asarray(x0, np.float64), options.tolerance,
                                    options.max_iterations)
    return jnp.asarray(x, x0.dtype), iterations, converged


def memory(rows: int, unknowns: int, k: int) -> int:
    """CSR float64 of the augmented matrix, its transpose and the square system of eq. 16."""
    return rows * k * 16 * 4


SOLVER = Solver("qmr", QMROptions, run, memory, "scipy QMR on the augmented system of thesis eq. 16 (the original's method)")
