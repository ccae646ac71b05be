"""Matrix-free Levenberg-Marquardt / Gauss-Newton for sums of products in linear space (any parametrization).

The objective is the one a GPU sees, in units of sigma_c per channel::

    F(X) = sum_i w_i ||sum_t prod_(f in t) bilinear(X_k(f), pi_f(a_i, b_i)) - y_i||^2
           + sum_k mu_k sum_(edges (u, v) of texture k) ||X_k[u] - X_k[v]||^2,   mu_k = lambda N / texels_k

over the valid texels X_k of every fitted texture (all RGB channels at once), with sample weights w_i
(1, or the n.v-bin weights of ``linear.nv_balance``, :func:`homofac.fit.sums.nv_weights`). The lookups are the ELL
footprints of :func:`homofac.param.mappers.bilinear` (4 texels per factor), so the residual and its
JVP/VJP are gathers and scatter-adds: optimistix's ``LevenbergMarquardt`` / ``GaussNewton`` with a
lineax ``LSMR`` inner solve never form the Jacobian. The inner solve is inexact
(:class:`homofac.fit.solvers.inexact.Truncated`): an LSMR that stops on its step cap or condition limit
still gives the step its last iterate, as in a truncated Newton method, instead of ending the outer
loop. Unknowns are column-scaled by the footprint weight each texel receives (floored at one sample) so LSMR sees one scale for busy and idle texels.

``backend="jaxopt"`` runs jaxopt's ``LevenbergMarquardt`` / ``GaussNewton`` (matrix-free CG inner solve)
on the same residual, for comparison; jaxopt is an optional extra (``homofac[jaxopt]``).
"""

from __future__ import annotations

import functools
import importlib
from typing import NamedTuple

import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import optimistix as optx
from jax.flatten_util import ravel_pytree
from jaxtyping import Array, Float, Int

from ..errors import HomofacError
from ..param import mappers
from .solvers.inexact import Truncated


#: Largest Jacobian jaxopt's LevenbergMarquardt may materialize (it computes diag(J^T J) from it).
JAXOPT_LM_BYTES = 4 << 30


class Lookup(NamedTuple):
    """One factor at the samples: which unknown texture it reads and the footprint (static index k)."""

    cols: Int[Array, "N 4"]
    w: Float[Array, "N 4"]


class Problem(NamedTuple):
    """The data of the objective (jit arguments); the term structure is static (``terms``)."""

    lookups: tuple[Lookup, ...]  # one per factor, in term order
    y: Float[Array, "N 3"]
    edges: tuple[Int[Array, "E 2"], ...]  # per texture: (u, v) neighbour pairs, both directions
    mu: tuple[Float[Array, ""], ...]  # per texture
    scales: tuple[Float[Array, "n"], ...]  # column scales per texture
    sqrt_w: Float[Array, "N"]  # square roots of the sample weights w_i


def predict(X: tuple, prob: Problem, terms: tuple[tuple[int, ...], ...]) -> Float[Array, "N 3"]:
    """``sum_t prod_f bilinear(X_k(f))`` at the samples; ``terms[t]`` lists the texture index of each
    factor of term t (factors in order, consuming ``prob.lookups`` one by one)."""
    out, j = 0.0, 0
    for factors in terms:
        v = 1.0
        for k in factors:
            lk = prob.lookups[j]
            v = v * mappers.gather(X[k], lk.cols, lk.w)
            j += 1
        out = out + v
    return out


def residuals(Z: tuple, prob: Problem, terms) -> tuple:
    """Residual pytree of F (its sum of squares is F) at scaled unknowns Z (X = D Z)."""
    X = tuple(z * s[:, None] for z, s in zip(Z, prob.scales))
    data = (predict(X, prob, terms) - prob.y) * prob.sqrt_w[:, None]
    # each edge appears in both directions: weight mu / 2 gives mu per edge
    smooth = tuple(jnp.sqrt(mu / 2) * (x[e[:, 0]] - x[e[:, 1]]) for x, e, mu in zip(X, prob.edges, prob.mu))
    return (data,) + smooth


@functools.partial(jax.jit, static_argnames=("terms",))
def objective(X: tuple, prob: Problem, terms) -> Float[Array, ""]:
    Z = tuple(x / s[:, None] for x, s in zip(X, prob.scales))
    return sum(jnp.sum(r * r) for r in residuals(Z, prob, terms))


@functools.partial(jax.jit, static_argnames=("which", "sizes"))
def column_scales(lookups, which: tuple[int, ...], sizes: tuple[int, ...]) -> tuple:
    """Per texture ``1 / sqrt(max(sum of squared footprint weights, 1))`` (``which[j]``: texture of factor j)."""
    acc = [jnp.zeros((n,)) for n in sizes]
    for lk, k in zip(lookups, which):
        acc[k] = acc[k].at[lk.cols.reshape(-1)].add((lk.w * lk.w).reshape(-1))
    return tuple(1.0 / jnp.sqrt(jnp.maximum(a, 1.0)) for a in acc)


@functools.partial(jax.jit, static_argnames=("terms", "method", "iterations", "inner", "rtol"))
def _optimistix(X0, prob: Problem, *, terms, method: str, iterations: int, inner: int, rtol: float):
    Z0 = tuple(x / s[:, None] for x, s in zip(X0, prob.scales))
    linear = Truncated(lx.LSMR(rtol=rtol, atol=rtol, max_steps=inner))
    tol = 1e-7
    if method == "gauss_newton":
        solver = optx.GaussNewton(rtol=tol, atol=tol, linear_solver=linear)
    else:
        solver = optx.LevenbergMarquardt(rtol=tol, atol=tol, linear_solver=linear)
    sol = optx.least_squares(lambda z, p: residuals(z, p, terms), solver, Z0, args=prob, max_steps=iterations,
                             throw=False)
    X = tuple(z * s[:, None] for z, s in zip(sol.value, prob.scales))
    return X, sol.stats["num_steps"], sol.result == optx.RESULTS.successful


def _jaxopt(X0, prob: Problem, *, terms, method: str, iterations: int, inner: int):
    try:
        jaxopt = importlib.import_module("jaxopt")
    except ImportError:
        raise HomofacError("linear.backend: jaxopt needs the optional extra: pip install 'homofac[jaxopt]'") from None
    Z0 = tuple(x / s[:, None] for x, s in zip(X0, prob.scales))
    flat0, unravel = ravel_pytree(Z0)
    if method == "levenberg_marquardt":
        rows = prob.y.size + sum(3 * e.shape[0] for e in prob.edges)
        need = 4 * flat0.size * rows
        if need > JAXOPT_LM_BYTES:
            raise HomofacError(
                f"linear.backend: jaxopt's LevenbergMarquardt forms diag(J^T J) from the whole Jacobian "
                f"({need / 2**30:.1f} GiB for {flat0.size:,} unknowns x {rows:,} residuals); use backend "
                "optimistix, method gauss_newton, or fewer samples")

    def fun(flat, prob):
        r = residuals(unravel(flat), prob, terms)
        return jnp.concatenate([x.reshape(-1) for x in r])

    def cg(matvec, b, ridge=None, init=None, **kw):  # jaxopt's solver protocol: (J^T J + ridge I) x = b
        op = matvec if ridge is None else (lambda v: matvec(v) + ridge * v)
        return jax.scipy.sparse.linalg.cg(op, b, x0=init, maxiter=inner)[0]

    if method == "gauss_newton":
        solver = jaxopt.GaussNewton(fun, maxiter=iterations, tol=1e-7, jit=True)  # its own matrix-free CG
    else:
        solver = jaxopt.LevenbergMarquardt(fun, maxiter=iterations, tol=1e-7, materialize_jac=False, solver=cg,
                                          jit=True)
    params, state = solver.run(flat0, prob)
    Z = unravel(params)
    X = tuple(z * s[:, None] for z, s in zip(Z, prob.scales))
    return X, int(state.iter_num), bool(state.iter_num < iterations)


def solve(X0: tuple, prob: Problem, terms, *, method: str = "levenberg_marquardt", backend: str = "optimistix",
          iterations: int = 30, inner: int = 100, rtol: float = 1e-4, chunk: int = 0):
    """Minimise F from X0; returns (X, steps, converged).

    ``chunk`` > 0 (optimistix): the steps run as calls of ``chunk`` steps each, every call a fresh solve
    from where the last stopped, until ``iterations`` steps or a call that converges. The number of steps
    is a static argument of the compiled solve, so fits of different step counts on one problem shape
    (the polish's trial and the polish) share one program; the damping restarts at each call."""
    if backend == "jaxopt":
        X, steps, ok = _jaxopt(X0, prob, terms=terms, method=method, iterations=iterations, inner=inner)
        return jax.block_until_ready(X), int(steps), bool(ok)
    size = int(chunk) if 0 < chunk < iterations else int(iterations)
    X, done, ok = X0, 0, False
    while done < iterations:
        n = min(size, iterations - done)
        X, steps, ok = _optimistix(X, prob, terms=terms, method=method, iterations=n, inner=inner, rtol=rtol)
        steps, ok = int(steps), bool(ok)
        done += steps
        if ok or steps < n:
            break
    X = jax.block_until_ready(X)
    return X, int(done), bool(ok)


def edges_of(neighbours: np.ndarray) -> np.ndarray:
    """Directed neighbour pairs ``(u, v)`` of a neighbour table of unknown indices ((n, 4), -1 for none)."""
    n = neighbours.shape[0]
    u = np.repeat(np.arange(n), neighbours.shape[1])
    v = neighbours.reshape(-1)
    keep = v >= 0
    return np.stack([u[keep], v[keep]], axis=1).astype(np.int32)


__all__ = ["Lookup", "Problem", "column_scales", "edges_of", "objective", "predict", "residuals", "solve"]
