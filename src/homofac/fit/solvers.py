"""Solvers for the least-squares system of eq. 37, all three RGB channels together.

* ``lsmr`` (default): matrix-free LSMR from lineax on an ``lx.FunctionLinearOperator`` that gathers
  from the ELL arrays; the Laplacian rows are extra outputs of the operator (LSMR has no damping
  matrix). Solves for the correction to the starting solution x0, with Jacobi column scaling
  (:func:`column_scale`). Float32 by default.
* ``qmr``: scipy's QMR on the explicit augmented square system of thesis eq. 16,
  ``[[I, A], [A^T, 0]] [r; x] = [b; 0]`` -- the method of the original implementation, one channel
  at a time as there (thesis §3.1.2, "Iterative Computation"). The reference.
* ``cg``: conjugate gradients on the normal equations ``A^T A x = A^T b`` in float64 (scipy, matrix-free
  through the CSR matrix and its transpose): the textbook method, a benchmark baseline.
* ``optimistix``: Gauss-Newton from optimistix on the residual ``A x - b`` with an LSMR linear solver
  (matrix-free: the Jacobian is a JVP). The system is linear, so it converges in one or two steps; it
  is the path through which nonlinear refinements (and ``jax.grad`` through the solve) go.
* ``direct``: the normal equations ``(A^T A) x = A^T b`` formed densely in float64 and solved by
  Cholesky with a negligible ridge (the log-space problem has gauge directions: a constant can move
  between textures). Small sizes only; it is the optimum the iterative results are measured against.
"""

from __future__ import annotations

import functools
import time
from typing import NamedTuple

import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np

from ..errors import HomofacError
from .system import System, apply, augmented_rhs, objective, to_scipy

SOLVERS = ("lsmr", "qmr", "cg", "optimistix", "direct")

#: Largest number of unknowns the dense ``direct`` solver accepts.
DIRECT_MAX_UNKNOWNS = 12000


class SolveResult(NamedTuple):
    """A solution x (n, 3) and how it was reached."""

    x: jnp.ndarray
    method: str
    iterations: int
    converged: bool
    residual: float  # ||A x - b|| / ||b|| of the augmented system
    objective: float  # ||A x - b||^2 summed over RGB
    seconds: float


def column_scale(sys: System, lam) -> jnp.ndarray:
    """Jacobi column scaling ``d_j = 1 / ||A e_j||`` of the augmented matrix of eq. 37 (data and
    lambda-weighted Laplacian rows). Texels of a texture indexed by the normal are hit by many more
    rows than those of the reflected-view texture, so the columns' norms differ by orders of magnitude;
    LSMR on ``A D`` then needs far fewer iterations (72 -> 30 on the thesis workload). Computed as the
    sum of the squared ELL entries per column: exact unless a row holds a column twice (PQP's p), where
    it is a close approximation -- any positive scaling leaves the minimiser unchanged."""
    n = sys.lap_cols.shape[0]
    sq = jnp.zeros((n,), sys.w.dtype).at[sys.cols.reshape(-1)].add((sys.w * sys.w).reshape(-1))
    lw = lam * sys.lap_w
    sq = sq.at[sys.lap_cols.reshape(-1)].add((lw * lw).reshape(-1))
    return jnp.where(sq > 0, jax.lax.rsqrt(jnp.maximum(sq, jnp.finfo(sq.dtype).tiny)), 1.0)


@functools.partial(jax.jit, static_argnames=("rtol", "max_steps"))
def _lsmr(sys: System, lam, x0, *, rtol: float, max_steps: int):
    """LSMR on the column-scaled correction: x = x0 + D z, minimising ||A D z - (b - A x0)||."""
    d = column_scale(sys, lam)[:, None]

    def mv(z):
        return apply(sys, lam, z * d)

    op = lx.FunctionLinearOperator(mv, jax.ShapeDtypeStruct(x0.shape, x0.dtype))
    r0 = augmented_rhs(sys) - apply(sys, lam, x0)
    sol = lx.linear_solve(op, r0, lx.LSMR(rtol=rtol, atol=rtol, max_steps=max_steps), throw=False)
    return x0 + sol.value * d, sol.stats["num_steps"], sol.result == lx.RESULTS.successful


def solve(
    sys: System,
    x0: jnp.ndarray,
    *,
    method: str = "lsmr",
    laplacian: float = 1.0,
    tolerance: float = 1e-6,
    max_iterations: int = 1000,
) -> SolveResult:
    """Minimise ``||A x - b||^2 + ||lambda L x||^2`` (eq. 37) from the starting solution ``x0``.

    Args:
        sys: the system from :func:`homofac.fit.system.build_system`.
        x0: starting solution (n, 3), e.g. from :func:`homofac.fit.start.starting_solution`.
        method: ``lsmr``, ``qmr``, ``cg``, ``optimistix`` or ``direct``.
        laplacian: lambda of eq. 37.
        tolerance: relative stopping tolerance of the iterative solvers.
        max_iterations: iteration cap of the iterative solvers.
    """
    t0 = time.perf_counter()
    lam = jnp.asarray(laplacian, x0.dtype)
    if method == "lsmr":
        x, steps, ok = _lsmr(sys, lam, x0, rtol=float(tolerance), max_steps=int(max_iterations))
        x = jax.block_until_ready(x)
        iterations, converged = int(steps), bool(ok)
    elif method == "qmr":
        x, iterations, converged = _qmr(sys, laplacian, np.asarray(x0, np.float64), tolerance, max_iterations)
        x = jnp.asarray(x, x0.dtype)
    elif method == "cg":
        x, iterations, converged = _cg(sys, laplacian, np.asarray(x0, np.float64), tolerance, max_iterations)
        x = jnp.asarray(x, x0.dtype)
    elif method == "optimistix":
        x, steps, ok = _optimistix(sys, lam, x0, rtol=float(tolerance), max_steps=int(max_iterations))
        x = jax.block_until_ready(x)
        iterations, converged = int(steps), bool(ok)
    elif method == "direct":
        x = jnp.asarray(_direct(sys, laplacian, x0.shape[0]), x0.dtype)
        iterations, converged = 1, True
    else:
        raise HomofacError(f"solver.method must be one of {', '.join(SOLVERS)}, got {method!r}")
    seconds = time.perf_counter() - t0
    obj = float(objective(sys, lam, x))
    bnorm2 = float(jnp.sum(augmented_rhs(sys) ** 2))
    residual = float(np.sqrt(obj / bnorm2)) if bnorm2 > 0 else float(np.sqrt(obj))
    if not np.all(np.isfinite(np.asarray(x))):
        raise HomofacError(f"solver {method} produced non-finite texture values; try a larger solver.laplacian")
    return SolveResult(x, method, iterations, converged, residual, obj, seconds)


def _qmr(sys: System, lam: float, x0: np.ndarray, tol: float, maxiter: int):
    """QMR on eq. 16, one channel at a time (as the original implementation)."""
    import scipy.sparse as sp
    from scipy.sparse.linalg import qmr

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


def _cg(sys: System, lam: float, x0: np.ndarray, tol: float, maxiter: int):
    """CG on the normal equations in float64, one channel at a time, for the correction d = x - x0."""
    import scipy.sparse.linalg as spla

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


@functools.partial(jax.jit, static_argnames=("rtol", "max_steps"))
def _optimistix(sys: System, lam, x0, *, rtol: float, max_steps: int):
    import optimistix as optx

    rhs = augmented_rhs(sys)

    def residual(x, _):
        return apply(sys, lam, x) - rhs

    linear = lx.LSMR(rtol=rtol, atol=rtol, max_steps=max_steps)
    # The outer (Cauchy) test compares successive iterates; below sqrt(eps) of the dtype they differ by
    # the inner solve's rounding only, so a tighter outer tolerance would never be met in float32.
    outer = max(rtol, float(np.sqrt(np.finfo(x0.dtype).eps)))
    solver = optx.GaussNewton(rtol=outer, atol=outer, linear_solver=linear)
    sol = optx.least_squares(residual, solver, x0, max_steps=16, throw=False)
    return sol.value, sol.stats["num_steps"], sol.result == optx.RESULTS.successful


def _direct(sys: System, lam: float, n: int) -> np.ndarray:
    """Dense normal equations in float64 with a 1e-12 relative ridge for the gauge directions."""
    import scipy.linalg as sla

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
