"""Exact block alternating least squares for sums of lighting products on ``grid`` samples.

The model (per RGB channel c, in units of sigma_c, the RMS of what the terms fit)::

    yhat_i = sum_t p_t(n_i) q_t(r_i) w_t(n.v_i) d_t(x_i) prod_e c_et(z_ei)

with p_t, q_t textures of one direction mapper and w_t, d_t, c_et ``line`` textures (d_t read at a second
scalar x_t, the ``nh_dom`` highlight coordinate of the term's light; a highlight term's extra lines c_et at
their own scalars, the light's ``vh_dom`` and ``ni_dom``); a term may lack any of them (then that factor
is 1: an n-only "fitted diffuse" term, an r-only term, a highlight term d w). On ``grid`` samples
(:func:`homofac.fit.sampling.grouped_grid`) every n- and r-lookup reads exactly one texel, so for
fixed q and w the least-squares problem in p splits into one K x K system per texel and channel
(and the same for q); w has K S_w unknowns per channel, a small dense system:

* Q block: ``(G_j + mu deg_j I) q_j = h_j + mu sum_(nb of j) q_nb`` with ``G_j = sum_(i: r_i in j) c_i c_i^T``,
  ``h_j = sum c_i y_i``, ``c_ti = p_t(n_i) w_t(n.v_i)``; the Laplacian coupling (first differences over
  the texel graph, weight ``mu = lambda N / texels``) by ``jacobi`` block-Jacobi passes;
* P block: the same with ``c_ti = q_t(r_i) w_t(n.v_i)``, grouped by the n texel;
* W block: the dense normal equations of the K S_w line unknowns (two texels per sample) with
  first-difference smoothing ``lambda N / S_w``; the D block the same for the lines read at x, and each
  extra line's block for its lines, given all the other factors;
* after each sweep every full term is rebalanced (mean |p_t| = mean |w_t| = 1 per channel, the scale
  moved into q_t), which removes the scale gauge freedom of the products.

One sweep costs O(N K^2) scatter-adds and a batch of K x K solves: 5-50x faster than matrix-free
Levenberg-Marquardt on the same data, to the same optimum (issue 13's prototype study). All channels
at once, jitted, float32; the data are jit arguments.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from ..param import mappers


class GridData(NamedTuple):
    """Grid samples as the ALS blocks see them (jit arguments)."""

    a: Int[Array, "N"]  # unknown index of the n texel of each sample
    b: Int[Array, "N"]  # unknown index of the r texel
    vi: Int[Array, "N 2"]  # line texels of n.v
    vw: Float[Array, "N 2"]  # their weights
    y: Float[Array, "N 3"]  # what the terms fit, in units of sigma
    nb: Int[Array, "n 4"]  # neighbour unknowns of each texel (0 where missing)
    nbm: Float[Array, "n 4"]  # 1 where the neighbour exists
    s: Float[Array, "N"]  # square roots of the sample weights (mean weight 1; ones: the plain objective)
    hi: Int[Array, "N K 2"] | None = None  # line texels of each term's highlight scalar x (terms with a d factor)
    hw: Float[Array, "N K 2"] | None = None  # their weights (0 for the other terms)
    ci: tuple = ()  # per extra line of the highlight terms (Fresnel, cosine): (N, K, 2) texels at its scalar
    cw: tuple = ()  # their weights


class Flags(NamedTuple):
    """Which factors each term has (static): p(n), q(r), w(n.v), d(x)."""

    p: tuple[bool, ...]
    q: tuple[bool, ...]
    w: tuple[bool, ...]
    h: tuple[bool, ...] = ()  # empty: no term has a d factor
    c: tuple[tuple[bool, ...], ...] = ()  # per extra line beside d (at its own scalar): which terms carry it


@functools.partial(jax.jit, static_argnames=("size",))
def line_footprint(x, size: int) -> tuple[Int[Array, "N 2"], Float[Array, "N 2"]]:
    """The two texels and weights of the pinned ``line`` lookup at scalars ``x`` (from the one bilinear)."""
    idx, w = mappers.bilinear("line", x, size)
    return idx[..., :2], w[..., :2] + w[..., 2:]


#: :func:`homofac.param.mappers.bilinear` as one compiled program per mapper, size and shape.
bilinear = jax.jit(mappers.bilinear, static_argnums=(0, 2))


def single_texel(mapper: str, size: int, d, unknown_of_texel: np.ndarray, tol: float = 1e-3) -> np.ndarray | None:
    """The unknown index of the one texel each direction's bilinear lookup reads, or None when some
    lookup spreads over several texels (the samples are not grid-aligned)."""
    idx, w = bilinear(mapper, jnp.asarray(d, jnp.float32), size)
    idx, w = np.asarray(idx), np.asarray(w)
    k = np.argmax(w, axis=-1)
    if np.min(np.take_along_axis(w, k[:, None], -1)) < 1.0 - tol:
        return None
    unk = unknown_of_texel[np.take_along_axis(idx, k[:, None], -1)[:, 0]]
    return None if np.any(unk < 0) else unk.astype(np.int32)


def _line(W, vi, vw, use):
    """Line factors at the samples (K, N, 3): ``vi, vw`` (N, 2) shared by every term, or (N, K, 2) per term."""
    # two texels each: multiply and add, not einsum (XLA lowers a contraction of 2 batched over N x K to
    # a tiny-matmul fusion that took 1.5 s per call here, against milliseconds)
    if vi.ndim == 2:
        g = W[:, vi]  # (K, N, 2, 3)
        w = g[:, :, 0] * vw[None, :, 0, None] + g[:, :, 1] * vw[None, :, 1, None]
    else:
        g = jnp.moveaxis(W[jnp.arange(W.shape[0])[None, :, None], vi], 1, 0)  # (K, N, 2, 3)
        vt = jnp.moveaxis(vw, 1, 0)  # (K, N, 2)
        w = g[:, :, 0] * vt[..., 0, None] + g[:, :, 1] * vt[..., 1, None]
    u = jnp.asarray(use, w.dtype)[:, None, None]
    return w * u + (1 - u)


def _wv(W, d: GridData, flags: Flags):
    return _line(W, d.vi, d.vw, flags.w)


def _cv(C, d: GridData, flags: Flags) -> list:
    """The extra lines' factors at the samples (K, N, 3), one per extra line (none without C)."""
    return [] if C is None else [_line(Ce, ci, cw, fc) for Ce, ci, cw, fc in zip(C, d.ci, d.cw, flags.c)]


def _product(xs, start=1.0):
    """``start`` times every factor of ``xs`` (the factors of a term's lines at the samples)."""
    out = start
    for x in xs:
        out = out * x
    return out


def _hv(D, d: GridData, flags: Flags, C=None):
    """The d factors (times the extra lines' factors, with C) at the samples (ones when no term has one)."""
    if not any(flags.h):
        return jnp.ones((len(flags.p), d.y.shape[0], 1), d.y.dtype)
    return _product(_cv(C, d, flags), _line(D, d.hi, d.hw, flags.h))


def _factor(X, idx, use):
    u = jnp.asarray(use, X.dtype)[:, None, None]
    return X[:, idx] * u + (1 - u)


def _sum_terms(x, which: tuple[bool, ...]):
    """``sum_t x[t]`` over the terms ``which`` marks (static), added one by one: a masked ``jnp.sum`` over
    the term axis of (K, N, 3) became an XLA CPU reduce fusion that took 1.5 s a call here (against
    milliseconds), three times per sweep."""
    out = None
    for t, use in enumerate(which):
        if use:
            out = x[t] if out is None else out + x[t]
    return jnp.zeros(x.shape[1:], x.dtype) if out is None else out


def predict(P, Q, W, d: GridData, flags: Flags, D=None, C=None) -> Float[Array, "N 3"]:
    """``sum_t p_t(n_i) q_t(r_i) w_t(n.v_i) d_t(x_i) prod_e c_et(z_ei)`` at the grid samples."""
    out = _factor(P, d.a, flags.p) * _factor(Q, d.b, flags.q) * _wv(W, d, flags)
    return _sum_terms(out * _hv(D, d, flags, C) if D is not None else out, (True,) * len(flags.p))


#: Bytes of the per-sample outer products one chunk of a block may hold (bounded memory at any K).
CHUNK_BYTES = 1 << 27


def _chunked(fn, args: tuple, n: int, per_sample: int):
    """``sum over chunks of fn(*chunk_args)`` along the sample axis (axis 0 of every arg), in chunks
    that keep ``per_sample`` floats per sample within :data:`CHUNK_BYTES`; padding rows are zero."""
    chunk = int(max(1024, min(n, CHUNK_BYTES // (4 * max(per_sample, 1)))))
    if chunk >= n:
        return fn(*args)
    pad = (-n) % chunk
    padded = tuple(jnp.concatenate([a, jnp.zeros((pad,) + a.shape[1:], a.dtype)]) for a in args)
    shaped = tuple(a.reshape((-1, chunk) + a.shape[1:]) for a in padded)
    first = jax.eval_shape(fn, *(a[0] for a in shaped))
    init = jax.tree_util.tree_map(lambda x: jnp.zeros(x.shape, x.dtype), first)

    def step(acc, xs):
        return jax.tree_util.tree_map(jnp.add, acc, fn(*xs)), None

    out, _ = jax.lax.scan(step, init, shaped)
    return out


def spd_solve(A, b):
    """Solve ``A x = b`` for a batch of small symmetric positive definite systems (..., K, K) by
    Gauss-Jordan elimination, vectorized over the batch and unrolled over K (no pivoting needed for SPD
    matrices): 3-8x faster on this CPU than the per-matrix LAPACK calls of ``jnp.linalg.solve``."""
    K = A.shape[-1]
    M = jnp.concatenate([A, b[..., None]], axis=-1)
    for i in range(K):
        pivot = M[..., i, :] / M[..., i, i : i + 1]
        M = (M - M[..., :, i : i + 1] * pivot[..., None, :]).at[..., i, :].set(pivot)
    return M[..., :, K]


def _texel_block(X, c, idx, y, d: GridData, mu, jacobi: int, ridge: float = 1e-6):
    """Solve for X (K, n, 3) given coefficients c (K, N, 3) of the samples falling in texel ``idx``."""
    K, n = X.shape[0], X.shape[1]

    def normal(c, idx, y):  # c (N, K, 3) sample-major for chunking
        G = jax.ops.segment_sum(jnp.einsum("ntc,nsc->ncts", c, c), idx, num_segments=n)  # (n, 3, K, K)
        h = jax.ops.segment_sum(jnp.einsum("ntc,nc->nct", c, y), idx, num_segments=n)  # (n, 3, K)
        return G, h

    G, h = _chunked(normal, (jnp.moveaxis(c, 0, 1), idx, y), y.shape[0], 3 * K * K)
    deg = jnp.sum(d.nbm, axis=1)
    tr = jnp.trace(G, axis1=-2, axis2=-1)[..., None, None] / K
    A = G + (mu * deg[:, None, None, None] + ridge * tr + 1e-9) * jnp.eye(K, dtype=X.dtype)
    Xc = jnp.moveaxis(X, 0, -1)  # (n, 3, K)

    def one(Xc, _):
        rhs = h + mu * jnp.sum(Xc[d.nb] * d.nbm[:, :, None, None], axis=1)
        return spd_solve(A, rhs), None

    Xc, _ = jax.lax.scan(one, Xc, None, length=jacobi)
    return jnp.moveaxis(Xc, -1, 0)


def _w_block(pq, W, d: GridData, flags: Flags, y, mu_w, ridge: float = 1e-6, vi=None, vw=None, use=None):
    """Dense normal equations of the line unknowns (S_w per term and channel) of the terms that carry the
    line, given the other factors ``pq`` at the samples; the lines read at n.v (``d.vi``, ``d.vw``,
    ``flags.w``) unless ``vi, vw, use`` say others. Only the terms with the line are unknowns (``use`` is
    static): a highlight line of one term is a 32 x 32 system, not one of every term's size."""
    vi = d.vi if vi is None else vi
    vw = d.vw if vw is None else vw
    on = tuple(int(t) for t in np.flatnonzero(np.asarray(flags.w if use is None else use, bool)))
    if not on:
        return W
    K, Sw = len(on), W.shape[1]
    M = K * Sw
    sel = np.asarray(on)
    pq = pq[sel]
    if vi.ndim == 3:
        vi, vw = vi[:, sel], vw[:, sel]

    def normal(pq, vi, vw, y):  # pq (N, K, 3) sample-major for chunking; vi, vw (N, 2) or (N, K, 2)
        N = y.shape[0]
        vi3 = vi[:, None, :] if vi.ndim == 2 else vi
        vw3 = vw[:, None, :] if vw.ndim == 2 else vw
        cols = (jnp.arange(K)[None, :, None] * Sw + vi3).reshape(N, 2 * K)
        coef = (pq[:, :, None, :] * vw3[..., None]).reshape(N, 2 * K, 3)
        flat = (cols[:, :, None] * M + cols[:, None, :]).reshape(-1)
        G = jax.ops.segment_sum((coef[:, :, None, :] * coef[:, None, :, :]).reshape(-1, 3), flat, num_segments=M * M)
        h = jax.ops.segment_sum((coef * y[:, None, :]).reshape(-1, 3), cols.reshape(-1), num_segments=M)
        return G, h

    G, h = _chunked(normal, (jnp.moveaxis(pq, 0, 1), vi, vw, y), y.shape[0], 12 * K * K + 6 * K)
    G = jnp.moveaxis(G.reshape(M, M, 3), -1, 0)
    diff = np.diff(np.eye(Sw), axis=0)
    lap = jnp.asarray(np.kron(np.eye(K), diff.T @ diff), W.dtype)
    G = G + mu_w * lap[None]
    tr = jnp.trace(G, axis1=-2, axis2=-1)[:, None, None] / M
    G = G + (ridge * tr + 1e-9) * jnp.eye(M, dtype=W.dtype)[None]
    sol = jnp.linalg.solve(G, jnp.moveaxis(h, -1, 0)[..., None])[..., 0]  # (3, M)
    return W.at[sel].set(jnp.moveaxis(sol.reshape(3, K, Sw), 0, -1))


def _balance(P, Q, W, flags: Flags, D=None, C=None):
    """Rescale full terms so mean |p_t| = mean |w_t| = 1 per channel (the scale goes into q_t, or into
    d_t for a term without q; a term's extra lines also to mean |c_et| = 1, their scale into d_t). Returns
    ``(P, Q, W, D, C)``, D and C None where they were not given (C: a tuple, one array per extra line)."""
    h = flags.h or (False,) * len(flags.p)
    full = jnp.asarray([p and q for p, q in zip(flags.p, flags.q)], P.dtype)[:, None, None]
    fw = jnp.asarray([w and q for w, q in zip(flags.w, flags.q)], P.dtype)[:, None, None]
    sp = jnp.maximum(jnp.mean(jnp.abs(P), axis=1, keepdims=True), 1e-12) * full + (1 - full)
    sw = jnp.maximum(jnp.mean(jnp.abs(W), axis=1, keepdims=True), 1e-12) * fw + (1 - fw)
    P, Q, W = P / sp, Q * sp * sw, W / sw
    if D is None:
        return P, Q, W, None, None
    hp = jnp.asarray([p and x and not q for p, q, x in zip(flags.p, flags.q, h)], P.dtype)[:, None, None]
    hw = jnp.asarray([w and x and not q for w, q, x in zip(flags.w, flags.q, h)], P.dtype)[:, None, None]
    sp = jnp.maximum(jnp.mean(jnp.abs(P), axis=1, keepdims=True), 1e-12) * hp + (1 - hp)
    sw = jnp.maximum(jnp.mean(jnp.abs(W), axis=1, keepdims=True), 1e-12) * hw + (1 - hw)
    P, W, D = P / sp, W / sw, D * sp * sw
    if C is None:
        return P, Q, W, D, None
    out = []
    for Ce, fc in zip(C, flags.c):
        hc = jnp.asarray([x and c for x, c in zip(h, fc)], P.dtype)[:, None, None]
        sc = jnp.maximum(jnp.mean(jnp.abs(Ce), axis=1, keepdims=True), 1e-12) * hc + (1 - hc)
        D, Ce = D * sc, Ce / sc
        out.append(Ce)
    return P, Q, W, D, tuple(out)


@functools.partial(jax.jit, static_argnames=("flags", "sweeps", "jacobi"))
def run(P, Q, W, d: GridData, lam, *, flags: Flags, sweeps: int, jacobi: int = 3, D=None, C=None):
    """``sweeps`` ALS sweeps from (P, Q, W) (K, n, 3), (K, n, 3), (K, S_w, 3) and, when some term has a
    d factor (``flags.h``), D (K, S_w, 3) and, when highlight terms also carry extra lines (``flags.c``,
    one entry per line: the Fresnel line, the cosine line), C, a tuple of (K, S_w, 3), one per extra line;
    returns them and the data objective ``sum_i s_i^2 ||yhat_i - y_i||^2`` (``d.s``: the square roots of
    the sample weights) after each sweep: ``(P, Q, W, hist)``, ``(P, Q, W, D, hist)`` with D,
    ``(P, Q, W, D, C, hist)`` with C."""
    N, n, Sw = d.y.shape[0], P.shape[1], W.shape[1]
    mu = lam * N / n
    mu_w = lam * N / Sw
    uq = jnp.asarray(flags.q, Q.dtype)[:, None, None]
    up = jnp.asarray(flags.p, P.dtype)[:, None, None]
    Q = Q * uq + (1 - uq)
    P = P * up + (1 - up)
    s1 = d.s[:, None]
    s3 = d.s[None, :, None]
    has_d = D is not None and any(flags.h)
    has_c = has_d and C is not None and len(flags.c) > 0
    zero = jnp.zeros((), P.dtype)

    def sweep(carry, _):
        P, Q, W, D, C = carry
        D, C = (D if has_d else None), (C if has_c else None)  # None: no such factor (the carry holds 0)
        wv = _wv(W, d, flags)
        # the barrier keeps XLA from fusing the line gathers into every consumer
        hv = jax.lax.optimization_barrier(_hv(D, d, flags, C)) if has_d else 1.0
        # weighted least squares as row scaling: coefficients and targets times sqrt(weight)
        if any(flags.q):
            c = _factor(P, d.a, flags.p) * wv * hv
            fixed = _sum_terms(c, tuple(not q for q in flags.q))
            Q = _texel_block(Q, c * uq * s3, d.b, (d.y - fixed) * s1, d, mu, jacobi) * uq + (1 - uq)
        if any(flags.p):
            c = _factor(Q, d.b, flags.q) * wv * hv
            fixed = _sum_terms(c, tuple(not p for p in flags.p))
            P = _texel_block(P, c * up * s3, d.a, (d.y - fixed) * s1, d, mu, jacobi) * up + (1 - up)
        if has_d:  # the highlight lines, given p q w (and the extra lines)
            pqw = _factor(P, d.a, flags.p) * _factor(Q, d.b, flags.q) * wv
            fixed = _sum_terms(pqw, tuple(not h for h in flags.h))
            cv = _cv(C, d, flags)
            D = _w_block(pqw * _product(cv) * s3, D, d, flags, (d.y - fixed) * s1, mu_w, vi=d.hi, vw=d.hw,
                         use=flags.h)
            dv = _line(D, d.hi, d.hw, flags.h)
            if has_c:  # each extra line, given p q w d and the others
                C = list(C)
                for e in range(len(C)):
                    rest = _product(cv[:e] + cv[e + 1:], dv)
                    C[e] = _w_block(pqw * rest * s3, C[e], d, flags, (d.y - fixed) * s1, mu_w, vi=d.ci[e],
                                    vw=d.cw[e], use=flags.c[e])
                    cv[e] = _line(C[e], d.ci[e], d.cw[e], flags.c[e])
                C = tuple(C)
            hv = jax.lax.optimization_barrier(_product(cv, dv))
        if any(flags.w):
            pq = _factor(P, d.a, flags.p) * _factor(Q, d.b, flags.q) * hv
            fixed = _sum_terms(pq, tuple(not w for w in flags.w))
            W = _w_block(pq * s3, W, d, flags, (d.y - fixed) * s1, mu_w)
        P, Q, W, D, C = _balance(P, Q, W, flags, D, C)
        r = (predict(P, Q, W, d, flags, D, C) - d.y) * s1
        return (P, Q, W, zero if D is None else D, zero if C is None else C), jnp.sum(r * r)

    init = (P, Q, W, D if has_d else zero, C if has_c else zero)
    (P, Q, W, D, C), hist = jax.lax.scan(sweep, init, None, length=sweeps)
    return (P, Q, W) + ((D,) if has_d else ()) + ((C,) if has_c else ()) + (hist,)


__all__ = ["Flags", "GridData", "line_footprint", "predict", "run", "single_texel", "spd_solve"]
