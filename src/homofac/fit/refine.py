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

The solves run on the textures' unknowns stacked in one array (:func:`stack`, :func:`stacked_residuals`): the
residual's lookups are 4 gathers of all factors' rows at once, so the program, with its JVP and transpose
inside the inner solve, traces each once instead of once per factor. Levenberg-Marquardt runs as
:func:`_lm`, optimistix's method (its damping, trust region, stop and truncated LSMR) in a program of its own
that skips the proposal of the last step, which optimistix solves for and never evaluates, and returns F
before and after. On the ``balanced`` polish of gold / forest (2 steps, 175 352 pairs, 8 factors) that is
6.2 s CPU to compile and 1.7 s to run against 8.2 s and 1.6 s for optimistix's program on the per-texture
residuals (and the objective's own program), the same point to 1e-7 (docs/notes/speed.md, "balanced,
eighteenth session").

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

from ..compiling import jit
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


class Stacked(NamedTuple):
    """The objective's data with every texture's unknowns in one array (:func:`stack`): texture k's rows at
    ``k * n`` to ``k * n + n_k`` of an ``(K n, 3)`` array, n the largest n_k, the rows past n_k zero (no lookup
    reads them, no edge joins them, their column scale 1)."""

    cols: Int[Array, "F N 4"]  # factor f's footprint, offset to its texture's rows
    w: Float[Array, "F N 4"]
    edges: Int[Array, "K E 2"]  # per texture, offset; padded with (k n, k n) self-edges (difference 0)
    root_mu: Float[Array, "K"]  # sqrt(mu_k / 2): each edge appears in both directions
    scales: Float[Array, "Kn"]
    y: Float[Array, "N 3"]
    sqrt_w: Float[Array, "N"]


def stack(X: tuple, prob: Problem, terms) -> tuple[Float[Array, "Kn 3"], Stacked]:
    """``X`` (per texture) as one ``(K n, 3)`` array of scaled unknowns Z = X / D, and ``prob`` as
    :class:`Stacked` (traced inside a solve's program: the concatenations are cheap)."""
    n = max(x.shape[0] for x in X)
    which = [k for factors in terms for k in factors]
    pad = lambda a, fill: jnp.concatenate([a, jnp.full((n - a.shape[0],) + a.shape[1:], fill, a.dtype)])  # noqa: E731
    cols = jnp.stack([lk.cols + k * n for lk, k in zip(prob.lookups, which)])
    w = jnp.stack([lk.w for lk in prob.lookups])
    most = max(e.shape[0] for e in prob.edges)
    edges = jnp.stack([jnp.concatenate([e, jnp.zeros((most - e.shape[0], 2), e.dtype)]) + k * n
                       for k, e in enumerate(prob.edges)])
    root_mu = jnp.stack([jnp.sqrt(jnp.asarray(mu, jnp.float32) / 2) for mu in prob.mu])
    scales = jnp.concatenate([pad(sc, 1.0) for sc in prob.scales])
    Z = jnp.concatenate([pad(x, 0.0) for x in X]) / scales[:, None]
    return Z, Stacked(cols, w, edges, root_mu, scales, prob.y, prob.sqrt_w)


def unstack(Z: Float[Array, "Kn 3"], st: Stacked, sizes: tuple[int, ...]) -> tuple:
    """The textures' unknowns X = D Z of a stacked ``Z`` (:func:`stack`), each its own ``n_k`` rows."""
    n = Z.shape[0] // len(sizes)
    X = Z * st.scales[:, None]
    return tuple(X[k * n:k * n + m] for k, m in enumerate(sizes))


def stacked_residuals(Z: Float[Array, "Kn 3"], st: Stacked, terms) -> tuple:
    """:func:`residuals` on stacked unknowns (:func:`stack`): the same residuals (the data's, then the
    smoothing's of all textures in one array, the padding's 0), the lookups of all F factors as 4 gathers of
    (F, N) rows instead of 4 F, so that a solve's program (its JVP and transpose too) traces each once."""
    X = Z * st.scales[:, None]
    g = st.w[..., 0, None] * X[st.cols[..., 0]]
    for k in range(1, st.cols.shape[-1]):
        g = g + st.w[..., k, None] * X[st.cols[..., k]]
    out, j = 0.0, 0
    for factors in terms:
        v = g[j]
        for i in range(1, len(factors)):
            v = v * g[j + i]
        j += len(factors)
        out = out + v
    data = (out - st.y) * st.sqrt_w[:, None]
    smooth = st.root_mu[:, None, None] * (X[st.edges[..., 0]] - X[st.edges[..., 1]])
    return data, smooth


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
    """optimistix's solver from X0 on the stacked unknowns (:func:`stack`); returns (X, steps, converged)."""
    Z0, st = stack(X0, prob, terms)
    linear = Truncated(lx.LSMR(rtol=rtol, atol=rtol, max_steps=inner))
    tol = 1e-7
    if method == "gauss_newton":
        solver = optx.GaussNewton(rtol=tol, atol=tol, linear_solver=linear)
    else:
        solver = optx.LevenbergMarquardt(rtol=tol, atol=tol, linear_solver=linear)
    sol = optx.least_squares(lambda z, p: stacked_residuals(z, p, terms), solver, Z0, args=st, max_steps=iterations,
                             throw=False)
    X = unstack(sol.value, st, tuple(x.shape[0] for x in X0))
    return X, sol.stats["num_steps"], sol.result == optx.RESULTS.successful


#: optimistix's ``LevenbergMarquardt`` / ``ClassicalTrustRegion`` constants, which :func:`_lm` repeats: the
#: termination tolerances, the ratio cutoffs and step-size factors.
LM_TOL = 1e-7
LM_LOW_CUTOFF, LM_HIGH_CUTOFF, LM_LOW_CONSTANT, LM_HIGH_CONSTANT = 0.01, 0.99, 0.25, 3.5


def _sum_squares(tree) -> Float[Array, ""]:
    return sum(jnp.sum(x * x) for x in jax.tree_util.tree_leaves(tree))


def _max_norm(tree) -> Float[Array, ""]:
    return jnp.max(jnp.stack([jnp.max(jnp.abs(x)) for x in jax.tree_util.tree_leaves(tree)]))


@jit(kind="polish", static_argnames=("terms", "iterations", "inner", "rtol"))
def _lm(X0, prob: Problem, *, terms, iterations: int, inner: int, rtol: float):
    """optimistix's ``LevenbergMarquardt`` (:func:`_optimistix`) as one small program: the same steps, damping
    and acceptance (step k evaluates F at the point step k-1 proposed; the classical trust region accepts it
    where ``F(y_eval) - F(y) <= 0.01 x`` the Gauss-Newton model's predicted change, and scales the step size
    1 / lambda by 3.5, 1 or 0.25; the damped system ``[J; sqrt(lambda) I] d = [r; 0]`` solved by the same
    truncated LSMR), without the proposal of the last step, which optimistix computes and never evaluates.
    Two steps are one damped step at lambda = 1, kept where it lowers F enough (the polish's calls).
    Returns (X, steps, converged, F at X0, F at X)."""
    Z0, st = stack(X0, prob, terms)
    fn = lambda z: stacked_residuals(z, st, terms)  # noqa: E731
    struct = jax.eval_shape(lambda: Z0)
    zeros = jax.tree_util.tree_map(jnp.zeros_like, Z0)
    tree = jax.tree_util.tree_map
    linear = Truncated(lx.LSMR(rtol=rtol, atol=rtol, max_steps=inner))

    def descend(y, r, step):  # optimistix's damped_newton_step, and the predicted change of F / 2
        lam = jnp.where(step > jnp.finfo(step.dtype).eps, 1 / jnp.where(step > 0, step, 1), jnp.finfo(step.dtype).max)
        _, lin = jax.linearize(fn, y)
        op = lx.FunctionLinearOperator(lambda d: (lin(d), tree(lambda v: jnp.sqrt(lam) * v, d)), struct)
        sol = lx.linear_solve(op, (r, zeros), linear, throw=False)
        jd = lin(sol.value)
        pred = 0.5 * (_sum_squares(tree(lambda a, b: a - b, r, jd)) - _sum_squares(r))
        return tree(lambda a, b: a - b, y, sol.value), pred, sol.result == lx.RESULTS.successful

    def body(c):
        k, y, r, y_eval, pred, step, f0, _, _ = c
        first = k == 0
        r_eval = fn(y_eval)
        f0 = jnp.where(first, _sum_squares(r_eval), f0)
        change = 0.5 * (_sum_squares(r_eval) - _sum_squares(r))
        accept = first | (change <= LM_LOW_CUTOFF * pred)
        good = ~first & (change < LM_HIGH_CUTOFF * pred) & (pred < 0)
        step = step * jnp.where(accept, jnp.where(good, LM_HIGH_CONSTANT, 1.0), LM_LOW_CONSTANT)
        dy, dr = tree(lambda a, b: a - b, y_eval, y), tree(lambda a, b: a - b, r_eval, r)
        small = lambda d, v: _max_norm(tree(lambda e, w: jnp.abs(e) / (LM_TOL + LM_TOL * jnp.abs(w)), d, v)) < 1  # noqa: E731
        converged = accept & small(dy, y_eval) & small(dr, r_eval)
        y, r = (tree(lambda a, b: jnp.where(accept, a, b), new, old) for new, old in ((y_eval, y), (r_eval, r)))
        k = k + 1
        y_eval, pred, ok = jax.lax.cond((k < iterations) & ~converged, lambda: descend(y, r, step),
                                        lambda: (y, pred, jnp.array(True)))
        return k, y, r, y_eval, pred, step, f0, converged, ~ok

    def more(c):
        k, *_, converged, failed = c
        return (k < iterations) & ~converged & ~failed

    r0 = tree(jnp.zeros_like, jax.eval_shape(fn, Z0))
    start = (jnp.array(0), Z0, r0, Z0, jnp.array(0.0, jnp.float32), jnp.array(1.0, jnp.float32),
             jnp.array(0.0, jnp.float32), jnp.array(False), jnp.array(False))
    k, y, r, *_, f0, converged, _ = jax.lax.while_loop(more, body, start)
    return unstack(y, st, tuple(x.shape[0] for x in X0)), k, converged, f0, _sum_squares(r)


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
    """Minimise F from X0; returns (X, steps, converged) (:func:`solve_objectives` also gives F before and after).

    ``chunk`` > 0 (optimistix): the steps run as calls of ``chunk`` steps each, every call a fresh solve
    from where the last stopped, until ``iterations`` steps or a call that converges. The number of steps
    is a static argument of the compiled solve, so fits of different step counts on one problem shape
    (the polish's trial and the polish) share one program; the damping restarts at each call."""
    return solve_objectives(X0, prob, terms, method=method, backend=backend, iterations=iterations, inner=inner,
                            rtol=rtol, chunk=chunk)[:3]


def solve_objectives(X0: tuple, prob: Problem, terms, *, method: str = "levenberg_marquardt",
                     backend: str = "optimistix", iterations: int = 30, inner: int = 100, rtol: float = 1e-4,
                     chunk: int = 0):
    """:func:`solve`, returning (X, steps, converged, F at X0, F at X). Levenberg-Marquardt with the
    optimistix backend runs :func:`_lm` (optimistix's method in a program of its own, which also gives F),
    the other methods optimistix or jaxopt (F from :func:`objective`)."""
    if backend == "jaxopt":
        X, steps, ok = _jaxopt(X0, prob, terms=terms, method=method, iterations=iterations, inner=inner)
        X = jax.block_until_ready(X)
        return X, int(steps), bool(ok), float(objective(X0, prob, terms)), float(objective(X, prob, terms))
    size = int(chunk) if 0 < chunk < iterations else int(iterations)
    X, done, ok, first, last = X0, 0, False, None, None
    while done < iterations:
        n = min(size, iterations - done)
        if method == "levenberg_marquardt":
            X, steps, ok, f0, last = _lm(X, prob, terms=terms, iterations=n, inner=inner, rtol=rtol)
            first = f0 if first is None else first
        else:
            X, steps, ok = _optimistix(X, prob, terms=terms, method=method, iterations=n, inner=inner, rtol=rtol)
        steps, ok = int(steps), bool(ok)
        done += steps
        if ok or steps < n:
            break
    X = jax.block_until_ready(X)
    if first is None:
        first, last = objective(X0, prob, terms), objective(X, prob, terms)
    return X, int(done), bool(ok), float(first), float(last)


def edges_of(neighbours: np.ndarray) -> np.ndarray:
    """Directed neighbour pairs ``(u, v)`` of a neighbour table of unknown indices ((n, 4), -1 for none)."""
    n = neighbours.shape[0]
    u = np.repeat(np.arange(n), neighbours.shape[1])
    v = neighbours.reshape(-1)
    keep = v >= 0
    return np.stack([u[keep], v[keep]], axis=1).astype(np.int32)


__all__ = ["Lookup", "Problem", "Stacked", "column_scales", "edges_of", "objective", "predict", "residuals", "solve",
           "solve_objectives", "stack", "stacked_residuals", "unstack"]
