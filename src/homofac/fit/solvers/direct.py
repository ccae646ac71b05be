"""``direct``: the normal equations formed densely in float64 and solved by Cholesky: the optimum.

``(A^T A) x = A^T b`` with a negligible ridge (the log-space problem has gauge directions: a constant
can move between textures). Small sizes only; it is the least-squares optimum the iterative results
are measured against.
"""

from __future__ import annotations

from typing import ClassVar, Literal

import jax.numpy as jnp
import numpy as np
import scipy.linalg as sla

from ...errors import HomofacError
from ..system import System, augmented_rhs, to_scipy
from .base import Solver, SolverOptions

#: Largest number of unknowns the dense solver accepts (a 12k x 12k float64 matrix is 1.1 GB).
DIRECT_MAX_UNKNOWNS = 12000


class DirectOptions(SolverOptions):
    """Options of ``direct`` (tolerance and max_iterations are not used)."""

    TAG: ClassVar[str] = "direct"
    method: Literal["direct"] = "direct"


def _direct(sys: System, lam: float, n: int) -> np.ndarray:
    """Dense normal equations in float64 with a 1e-12 relative ridge for the gauge directions."""
    if n > DIRECT_MAX_UNKNOWNS:
        raise HomofacError(
            f"solver direct forms a dense {n}x{n} matrix; use it for at most {DIRECT_MAX_UNKNOWNS} unknowns "
            "(smaller texture_size) or use lsmr"
        )
    a = to_scipy(sys, lam, n)
    b = np.asarray(augmented_rhs(sys), np.float64)
    ata = (a.T @ a).toarray()
    atb = a.T @ b
    ridge = 1e-12 * max(float(np.mean(np.diag(ata))), 1e-30)
    ata[np.diag_indices_from(ata)] += ridge
    c = sla.cho_factor(ata, lower=True, check_finite=False)
    return sla.cho_solve(c, atb, check_finite=False)


def run(sys: System, x0, options: DirectOptions):
    return jnp.asarray(_direct(sys, options.laplacian, x0.shape[0]), x0.dtype), 1, True


def memory(rows: int, unknowns: int, k: int) -> int:
    """The dense (n, n) float64 normal matrix and its Cholesky factor."""
    return 2 * unknowns * unknowns * 8


SOLVER = Solver("direct", DirectOptions, run, memory, "dense normal equations + Cholesky in float64: the optimum (small sizes)")
