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

One sweep costs O(N K^2) scatter-adds (the texel blocks; the w line's as matrix products over the
samples, :func:`_shared_line_normals`) and a batch of K x K solves: 5-50x faster than matrix-free
Levenberg-Marquardt on the same data, to the same optimum (issue 13's prototype study). All channels
at once, jitted, float32; the data are jit arguments.

Every block's normal equations are sums over the samples, so :func:`sweep` sums them over blocks of
samples (:func:`blocks`: one compiled program per factor kind and block size sums one block, another
solves), from every factor gathered once at the samples after its update (:class:`Seen`): a fit on any
multiple of a block's samples runs the programs a fit on one block compiled.

The terms sit in slots (:class:`Slots`: terms without a line, with w(n.v), with d(x); extra lines), and
which factors each slot's term has are masks, jit arguments (:class:`Masks`): a structure padded into
larger slots is the same fit (an empty slot adds 0 and is a separate block of every system), and all
the structures a run fits in the same slots, on blocks of the same size, share one set of compiled
programs (:func:`sweep`; :func:`homofac.fit.sums.als_slots` chooses the slots).
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from ..compiling import jit
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


@jit(kind="lookup", static_argnames=("size",))
def line_footprint(x, size: int) -> tuple[Int[Array, "N 2"], Float[Array, "N 2"]]:
    """The two texels and weights of the pinned ``line`` lookup at scalars ``x`` (from the one bilinear)."""
    idx, w = mappers.bilinear("line", x, size)
    return idx[..., :2], w[..., :2] + w[..., 2:]


#: :func:`homofac.param.mappers.bilinear` as one compiled program per mapper, size and shape.
bilinear = jit(mappers.bilinear, kind="lookup", static_argnums=(0, 2))


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


class Slots(NamedTuple):
    """The padded shape of a sum's terms (static; :func:`sweep`'s programs are compiled once per Slots, grid
    size and block size): ``plain`` slots for terms without a line factor, ``lined`` for terms with
    w(n.v) and no d, ``high`` for the terms with d(x) (the highlight terms), and ``extra`` extra lines of
    the highlight terms (Fresnel, cosine). The terms of any structure that fits in the slots run in the
    same program; an empty slot is masked out (its term adds 0 and none of its factors is solved for)."""

    plain: int = 0
    lined: int = 0
    high: int = 0
    extra: int = 0

    @property
    def terms(self) -> int:
        return self.plain + self.lined + self.high

    def union(self, other: Slots) -> Slots:
        """The slots that hold both (the larger count of every group)."""
        return Slots(*(max(a, b) for a, b in zip(self, other)))


class Masks(NamedTuple):
    """Which factors each slot's term has, 1 or 0 (jit arguments: one program for every structure)."""

    t: Float[Array, "K"]  # the slot holds a term
    p: Float[Array, "K"]
    q: Float[Array, "K"]
    w: Float[Array, "K"]
    h: Float[Array, "K"]
    c: Float[Array, "E K"]  # per extra line


def _group(w: bool, h: bool) -> int:
    return 2 if h else 1 if w else 0


def slots_of(flags: Flags) -> Slots:
    """The slots the terms of ``flags`` fill exactly."""
    h = flags.h or (False,) * len(flags.p)
    g = [_group(w, x) for w, x in zip(flags.w, h)]
    return Slots(g.count(0), g.count(1), g.count(2), len(flags.c))


def layout(flags: Flags, slots: Slots | None = None) -> tuple[np.ndarray, Masks]:
    """The term in each slot (``order[slot]``, -1 for an empty one; terms in their order within each
    group of :class:`Slots`) and the slots' masks, for the terms of ``flags`` placed in ``slots``
    (default: their own, :func:`slots_of`). ``flags.c`` has no entry (no extra line) or one per extra slot."""
    own = slots_of(flags)
    slots = own if slots is None else slots
    if any(a > b for a, b in zip(own, slots)) or own.extra not in (0, slots.extra):
        raise ValueError(f"terms {own} do not fit in the slots {slots}")
    K = len(flags.p)
    h = flags.h or (False,) * K
    if any(c and not x for fc in flags.c for c, x in zip(fc, h)):
        raise ValueError("an extra line belongs to a highlight term (a term with d)")
    base = (0, slots.plain, slots.plain + slots.lined)
    order = -np.ones(slots.terms, np.int64)
    used = [0, 0, 0]
    for t, (w, x) in enumerate(zip(flags.w, h)):
        g = _group(w, x)
        order[base[g] + used[g]] = t
        used[g] += 1

    def mask(f) -> np.ndarray:
        f = np.asarray(f, np.float32)
        return np.where(order >= 0, f[np.maximum(order, 0)], 0.0).astype(np.float32)

    c = np.stack([mask(fc) for fc in flags.c]) if flags.c else np.zeros((slots.extra, slots.terms), np.float32)
    return order, Masks(mask([True] * K), mask(flags.p), mask(flags.q), mask(flags.w), mask(h), c)


def _masks(flags: Flags | Masks) -> Masks:
    """``flags`` as masks in the terms' own order (every term present)."""
    if isinstance(flags, Masks):
        return flags
    K = len(flags.p)
    h = flags.h or (False,) * K
    c = np.asarray(flags.c, np.float32).reshape(len(flags.c), K)
    return Masks(np.ones(K, np.float32), *(np.asarray(f, np.float32) for f in (flags.p, flags.q, flags.w, h)), c)


def pad(X, order: np.ndarray, fill: float = 1.0) -> np.ndarray:
    """Per-term array X (K, ...) in the slots of ``order`` (:func:`layout`); ``fill`` in the empty ones."""
    X = np.asarray(X)
    out = np.full((len(order),) + X.shape[1:], fill, X.dtype)
    out[order >= 0] = X[order[order >= 0]]
    return out


def unpad(X, order: np.ndarray) -> np.ndarray:
    """The inverse of :func:`pad`: the terms' rows (K, ...) of slot array X."""
    slot = np.empty(int(np.sum(order >= 0)), np.int64)
    slot[order[order >= 0]] = np.flatnonzero(order >= 0)
    return np.asarray(X)[slot]


def pad_data(d: GridData, order: np.ndarray, slots: Slots) -> GridData:
    """Grid data with the per-term line footprints (``hi``, ``hw``, ``ci``, ``cw``) in the slots of ``order``
    (texel 0, weight 0 in the empty ones; zeros for extra lines the terms lack)."""
    N, K = d.y.shape[0], slots.terms

    def cols(x, dtype):
        return np.zeros((N, K, 2), dtype) if x is None else np.moveaxis(pad(np.moveaxis(np.asarray(x), 1, 0), order, 0), 0, 1)

    if slots.high == 0:
        return d._replace(hi=None, hw=None, ci=(), cw=())
    ci = tuple(d.ci) + (None,) * (slots.extra - len(d.ci))
    cw = tuple(d.cw) + (None,) * (slots.extra - len(d.cw))
    return d._replace(hi=jnp.asarray(cols(d.hi, np.int32)), hw=jnp.asarray(cols(d.hw, np.float32)),
                      ci=tuple(jnp.asarray(cols(x, np.int32)) for x in ci),
                      cw=tuple(jnp.asarray(cols(x, np.float32)) for x in cw))


def _line(W, vi, vw, use):
    """Line factors at the samples (K, N, 3): ``vi, vw`` (N, 2) shared by every term, or (N, K, 2) per term;
    1 for the terms ``use`` (K,) leaves out."""
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


def _cv(C, d: GridData, m: Masks) -> list:
    """The extra lines' factors at the samples (K, N, 3), one per extra line (none without C)."""
    return [] if C is None else [_line(Ce, ci, cw, fc) for Ce, ci, cw, fc in zip(C, d.ci, d.cw, m.c)]


def _product(xs, start=1.0):
    """``start`` times every factor of ``xs`` (the factors of a term's lines at the samples)."""
    out = start
    for x in xs:
        out = out * x
    return out


def _hv(D, d: GridData, m: Masks, C=None):
    """The d factors (times the extra lines' factors, with C) at the samples (ones without D)."""
    if D is None or d.hi is None:
        return jnp.ones((len(m.p), d.y.shape[0], 1), d.y.dtype)
    return _product(_cv(C, d, m), _line(D, d.hi, d.hw, m.h))


def _factor(X, idx, use):
    u = jnp.asarray(use, X.dtype)[:, None, None]
    return X[:, idx] * u + (1 - u)


def _sum_terms(x, which):
    """``sum_t which_t x[t]`` over the term axis (``which`` (K,) 1 or 0), added one by one: a masked
    ``jnp.sum`` over the term axis of (K, N, 3) became an XLA CPU reduce fusion that took 1.5 s a call
    here (against milliseconds), three times per sweep."""
    which = jnp.asarray(which, x.dtype)
    out = x[0] * which[0]
    for t in range(1, x.shape[0]):
        out = out + x[t] * which[t]
    return out


def predict(P, Q, W, d: GridData, flags: Flags | Masks, D=None, C=None) -> Float[Array, "N 3"]:
    """``sum_t p_t(n_i) q_t(r_i) w_t(n.v_i) d_t(x_i) prod_e c_et(z_ei)`` at the grid samples."""
    m = _masks(flags)
    out = _factor(P, d.a, m.p) * _factor(Q, d.b, m.q) * _line(W, d.vi, d.vw, m.w)
    return _sum_terms(out * _hv(D, d, m, C) if D is not None else out, m.t)


#: Bytes of the per-sample outer products one chunk of a block may hold (bounded memory at any K).
CHUNK_BYTES = 1 << 27


def _chunked(fn, args: tuple, n: int, per_sample: int):
    """``sum over chunks of fn(*chunk_args)`` along the sample axis (axis 0 of every arg), in chunks
    that keep ``per_sample`` floats per sample within :data:`CHUNK_BYTES`; padding rows are zero."""
    chunk = int(max(1024, min(n, CHUNK_BYTES // (4 * max(per_sample, 1)))))
    if chunk >= n:
        return fn(*args)
    pad_rows = (-n) % chunk
    padded = tuple(jnp.concatenate([a, jnp.zeros((pad_rows,) + a.shape[1:], a.dtype)]) for a in args)
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


def _texel_normals(c, idx, y, n: int):
    """The normal equations ``(G (n, 3, K, K), h (n, 3, K))`` of one block of samples for the texel unknowns
    X (K, n, 3) the samples read at ``idx``, given their coefficients c (K, N, 3) and targets y (N, 3):
    ``G_j = sum_(i: idx_i = j) c_i c_i^T``, ``h_j = sum c_i y_i``. Sums over blocks are those of their union."""
    K = c.shape[0]
    iu = np.triu_indices(K)
    tri = np.zeros((K, K), np.int64)
    tri[iu] = tri[iu[::-1]] = np.arange(len(iu[0]))  # (t, s) -> its pair's index

    def normal(c, idx, y):  # c (N, K, 3) sample-major for chunking; G's pairs t <= s only (symmetric)
        G = jax.ops.segment_sum(jnp.moveaxis(c[:, iu[0]] * c[:, iu[1]], 1, 2), idx, num_segments=n)  # (n, 3, pairs)
        h = jax.ops.segment_sum(jnp.einsum("ntc,nc->nct", c, y), idx, num_segments=n)  # (n, 3, K)
        return G, h

    G, h = _chunked(normal, (jnp.moveaxis(c, 0, 1), idx, y), y.shape[0], 3 * K * (K + 1) // 2)
    return G[..., tri], h


def _texel_solve(X, G, h, nb, nbm, mu, jacobi: int, terms, ridge: float = 1e-6):
    """Solve ``(G_j + mu deg_j I) x_j = h_j + mu sum_(nb of j) x_nb`` for X (K, n, 3) by ``jacobi`` block-Jacobi
    passes (:func:`_texel_normals`' G, h), the ridge ``ridge`` times the mean diagonal over the ``terms`` (a
    count) present. A term whose coefficients are 0 (empty slot, or no such factor) is a separate block of
    the K x K systems, so it leaves the others' solution as it is."""
    K = X.shape[0]
    deg = jnp.sum(nbm, axis=1)
    tr = jnp.trace(G, axis1=-2, axis2=-1)[..., None, None] / terms
    A = G + (mu * deg[:, None, None, None] + ridge * tr + 1e-9) * jnp.eye(K, dtype=X.dtype)
    Xc = jnp.moveaxis(X, 0, -1)  # (n, 3, K)

    def one(Xc, _):
        rhs = h + mu * jnp.sum(Xc[nb] * nbm[:, :, None, None], axis=1)
        return spd_solve(A, rhs), None

    Xc, _ = jax.lax.scan(one, Xc, None, length=jacobi)
    return jnp.moveaxis(Xc, -1, 0)


def _w_normals(pq, y, vi, vw, use, lo: int, Sw: int):
    """The dense normal equations ``(G (M*M, 3), h (M, 3))`` of one block of samples for the line unknowns
    (S_w per slot from ``lo``, static: M = S_w (K - lo)) of the slots that carry the line (``use`` (K,), 1 or
    0), given the other factors ``pq`` (K, N, 3) at the samples, the targets y (N, 3) and the lines'
    footprints ``vi, vw`` ((N, 2) shared, or (N, K, 2) per term). Sums over blocks are those of their union.
    A footprint every slot shares (the w line; a per-term one of a single slot) goes through
    :func:`_shared_line_normals`; per-term footprints of several slots each line's own block so, the blocks
    between two lines as scatter-adds (four products a sample)."""
    u = use[lo:]
    K = u.shape[0]
    M = K * Sw
    pq = pq[lo:] * u[:, None, None]
    if vi.ndim == 3:
        vi, vw = vi[:, lo:], vw[:, lo:]
        if K == 1:
            vi, vw = vi[:, 0], vw[:, 0]
    if vi.ndim == 2:
        return _chunked(functools.partial(_shared_line_normals, Sw=Sw), (jnp.moveaxis(pq, 0, 1), vi, vw, y),
                        y.shape[0], 3 * K * (K + 1) // 2 + 4 * Sw)

    def normal(pq, vi, vw, y):  # pq (N, K, 3) sample-major for chunking; vi, vw (N, K, 2)
        # each line's own block (t, t) at its one footprint; the blocks of two lines (t, s) as scatter-adds
        # of the four products of their footprints' coefficients
        own = [_shared_line_normals(pq[:, t:t + 1], vi[:, t], vw[:, t], y, Sw=Sw) for t in range(K)]
        coef = pq[:, :, None, :] * vw[..., None]  # (N, K, 2, 3)
        blk = [[None] * K for _ in range(K)]
        for t in range(K):
            blk[t][t] = own[t][0].reshape(Sw, Sw, 3)
            for s in range(t + 1, K):
                flat = (vi[:, t, :, None] * Sw + vi[:, s, None, :]).reshape(-1)
                x = (coef[:, t, :, None, :] * coef[:, s, None, :, :]).reshape(-1, 3)
                blk[t][s] = jax.ops.segment_sum(x, flat, num_segments=Sw * Sw).reshape(Sw, Sw, 3)
                blk[s][t] = jnp.swapaxes(blk[t][s], 0, 1)
        G = jnp.stack([jnp.stack(row, axis=1) for row in blk])  # (K, S_w, K, S_w, 3)
        return G.reshape(M * M, 3), jnp.concatenate([h for _, h in own])

    return _chunked(normal, (jnp.moveaxis(pq, 0, 1), vi, vw, y), y.shape[0], 12 * K * K + 6 * K)


#: Above this many pairs ``c_t c_s`` (t <= s) per channel, on lines of at most :data:`MATMUL_TEXELS` texels,
#: :func:`_shared_line_normals` sums over the samples as matrix products with one-hot texel rows (their cost grows
#: with S_w); otherwise as scatter-adds into the S_w texels. Measured at 75 000 samples (docs/notes/speed.md,
#: "best's sweep, twenty-second session"): a sweep of slots (1, 4, 1, 2) at 32 texels 0.31 s CPU against 0.35
#: scattered, at 128 texels 0.67 against 0.58; K = 1-3 lines scatter faster at both.
MATMUL_PAIRS = 6
MATMUL_TEXELS = 32


def _shared_line_normals(c, vi, vw, y, *, Sw: int):
    """:func:`_w_normals` of K lines read at one footprint per sample (``vi, vw`` (N, 2): the pinned ``line``
    lookup's two adjacent texels, ``vi[:, 1] = vi[:, 0] + 1``), coefficients c (N, K, 3). With the texel weights
    ``e_i = vw_i0 1[vi_i0] + vw_i1 1[vi_i1]`` (S_w,), the line unknowns' coefficients are ``c_ti e_i`` and
    ``G[(t, a), (s, b)] = sum_i c_ti c_si e_ia e_ib``; e_ia e_ib is nonzero only on the diagonal (``vw_i0^2`` at
    vi_i0, ``vw_i1^2`` at vi_i1) and beside it (``vw_i0 vw_i1`` at (vi_i0, vi_i0 + 1) and its transpose), so G
    is three sums over the samples of the pairs ``c_t c_s`` (t <= s) into the S_w texels, and
    ``h[(t, a)] = sum_i e_ia c_ti y_i`` two: as (S_w, N) one-hot rows times (N, pairs) matrix products above
    :data:`MATMUL_PAIRS` pairs on at most :data:`MATMUL_TEXELS` texels, as scatter-adds otherwise."""
    N, K, _ = c.shape
    iu = np.triu_indices(K)
    tri = np.zeros((K, K), np.int64)
    tri[iu] = tri[iu[::-1]] = np.arange(len(iu[0]))  # (t, s) -> its pair's column
    pairs = (c[:, iu[0]] * c[:, iu[1]]).reshape(N, -1)  # (N, K(K+1)/2 * 3)
    cy = (c * y[:, None, :]).reshape(N, -1)  # (N, K * 3)
    w0, w1 = vw[:, 0], vw[:, 1]
    if len(iu[0]) > MATMUL_PAIRS and Sw <= MATMUL_TEXELS:
        texels = jnp.arange(Sw, dtype=vi.dtype)[:, None]
        o0, o1 = (vi[None, :, 0] == texels).astype(c.dtype), (vi[None, :, 1] == texels).astype(c.dtype)  # (S_w, N)
        R = jnp.concatenate([o0 * (w0 * w0), o1 * (w1 * w1), o0 * (w0 * w1)]) @ pairs  # (3 S_w, pairs * 3)
        h = o0 @ (cy * w0[:, None]) + o1 @ (cy * w1[:, None])  # (S_w, K * 3)
    else:
        sums = lambda x, i: jax.ops.segment_sum(x, vi[:, i], num_segments=Sw)  # noqa: E731
        R = jnp.concatenate([sums(pairs * (w0 * w0)[:, None], 0), sums(pairs * (w1 * w1)[:, None], 1),
                             sums(pairs * (w0 * w1)[:, None], 0)])
        h = sums(cy * w0[:, None], 0) + sums(cy * w1[:, None], 1)
    R = R.reshape(3, Sw, -1, 3)[:, :, tri]  # (3, S_w, K, K, 3)
    diag, side = R[0] + R[1], R[2]
    eye, up = jnp.eye(Sw, dtype=c.dtype), jnp.eye(Sw, k=1, dtype=c.dtype)  # up[j, j + 1] = 1
    G = (jnp.einsum("atsc,ab->tasbc", diag, eye) + jnp.einsum("jtsc,jb->tjsbc", side, up)
         + jnp.einsum("jtsc,ja->tasjc", side, up))
    return G.reshape(K * Sw * K * Sw, 3), jnp.moveaxis(h.reshape(Sw, K, 3), 1, 0).reshape(K * Sw, 3)


def _w_solve(W, G, h, mu_w, use, lo: int, ridge: float = 1e-6):
    """The line unknowns of the slots from ``lo`` (static) that carry the line (``use`` (K,)) from
    :func:`_w_normals`' G, h, with first-difference smoothing ``mu_w`` and a ridge ``ridge`` times the mean
    diagonal of the terms' unknowns. A slot that does not carry the line is an identity block of the system
    (solution 0, the line kept as it was)."""
    Ws, u = W[lo:], use[lo:]
    K, Sw = Ws.shape[0], W.shape[1]
    M = K * Sw
    G = jnp.moveaxis(G.reshape(M, M, 3), -1, 0)
    diff = np.diff(np.eye(Sw), axis=0)
    lap1 = diff.T @ diff
    on = jnp.sum(u)
    tr = (jnp.trace(G, axis1=-2, axis2=-1) + mu_w * float(np.trace(lap1)) * on)[:, None, None] / jnp.maximum(on * Sw, 1)
    act = jnp.repeat(u, Sw)  # (M,) 1 for the unknowns solved for
    G = G + mu_w * jnp.asarray(np.kron(np.eye(K), lap1), W.dtype)[None]
    G = G + (ridge * tr + 1e-9) * jnp.diag(act)[None] + jnp.diag(1 - act)[None]
    sol = jnp.linalg.solve(G, jnp.moveaxis(h, -1, 0)[..., None])[..., 0]  # (3, M)
    new = jnp.where(u[:, None, None] > 0, jnp.moveaxis(sol.reshape(3, K, Sw), 0, -1), Ws)
    return jnp.concatenate([W[:lo], new]) if lo else new


def _balance_scales(P, Q, W, m: Masks, D=None, C=None):
    """The per-term, per-channel factors (K, 1, 3) of :func:`_balance`: ``(fP, fQ, fW, fD, fC)`` (fD, fC None
    where D, C were not given; fC a tuple, one per extra line), 1 in every slot that lacks the factor."""
    col = lambda x: jnp.asarray(x, P.dtype)[:, None, None]  # noqa: E731
    mean = lambda X: jnp.maximum(jnp.mean(jnp.abs(X), axis=1, keepdims=True), 1e-12)  # noqa: E731
    p, q, w, h = (col(x) for x in (m.p, m.q, m.w, m.h))
    full, fw = p * q, w * q
    sp = mean(P) * full + (1 - full)
    sw = mean(W) * fw + (1 - fw)
    fP, fQ, fW = 1 / sp, sp * sw, 1 / sw
    if D is None:
        return fP, fQ, fW, None, None
    hp, hw = p * h * (1 - q), w * h * (1 - q)
    sp = mean(P * fP) * hp + (1 - hp)
    sw = mean(W * fW) * hw + (1 - hw)
    fP, fW, fD = fP / sp, fW / sw, sp * sw
    if C is None:
        return fP, fQ, fW, fD, None
    fC = []
    for e, Ce in enumerate(C):
        hc = h * col(m.c[e])
        sc = mean(Ce) * hc + (1 - hc)
        fD, fC = fD * sc, fC + [1 / sc]
    return fP, fQ, fW, fD, tuple(fC)


def _balance(P, Q, W, m: Masks, D=None, C=None):
    """Rescale full terms so mean |p_t| = mean |w_t| = 1 per channel (the scale goes into q_t, or into
    d_t for a term without q; a term's extra lines also to mean |c_et| = 1, their scale into d_t). Returns
    ``(P, Q, W, D, C)``, D and C None where they were not given (C: a tuple, one array per extra line)."""
    fP, fQ, fW, fD, fC = _balance_scales(P, Q, W, m, D, C)
    P, Q, W = P * fP, Q * fQ, W * fW
    if D is None:
        return P, Q, W, None, None
    return P, Q, W, D * fD, None if C is None else tuple(Ce * f for Ce, f in zip(C, fC))


class Blocked(NamedTuple):
    """Grid samples in blocks of one size (:func:`blocks`; the last padded with zero-weight rows): :func:`sweep`
    runs its compiled programs once per block, so fits on any multiple of a block's pairs share them."""

    blocks: tuple  # GridData of each block
    n: int  # the samples (without the padding rows)


#: The per-sample fields of :class:`GridData` (the others, the texel graph, every block shares).
_PER_SAMPLE = ("a", "b", "vi", "vw", "y", "s", "hi", "hw", "ci", "cw")


def blocks(d: GridData, size: int) -> GridData | Blocked:
    """``d`` in blocks of ``size`` samples (:class:`Blocked`; the last padded with rows of weight 0, texel 0,
    which add nothing to any normal equation or objective), or ``d`` itself where it has at most ``size``
    samples (``size`` 0: one block). Split on the host: the blocks are jit arguments of one shape."""
    N = int(d.y.shape[0])
    if size <= 0 or N <= size:
        return d
    count = -(-N // size)

    def split(x):
        x = np.asarray(x)
        x = np.concatenate([x, np.zeros((count * size - N,) + x.shape[1:], x.dtype)])
        return [jnp.asarray(x[k * size:(k + 1) * size]) for k in range(count)]

    parts = {}
    for f in _PER_SAMPLE:
        v = getattr(d, f)
        if v is None:
            parts[f] = [None] * count
        elif isinstance(v, tuple):
            parts[f] = [tuple(c) for c in zip(*(split(x) for x in v))] if v else [()] * count
        else:
            parts[f] = split(v)
    return Blocked(tuple(d._replace(**{f: parts[f][k] for f in _PER_SAMPLE}) for k in range(count)), N)


class Seen(NamedTuple):
    """Every factor at one block's samples (K, N, 3; 1 where a slot lacks it): p(n), q(r), w(n.v), d(x) and
    the extra lines (a tuple). :func:`sweep` gathers a factor once after each update and the blocks'
    normal equations read these (no gather of their own)."""

    pa: Array
    qb: Array
    wv: Array
    dv: Array | None
    cv: tuple


@jax.jit
def _seen(P, Q, W, D, C, d: GridData, masks: Masks) -> Seen:
    """:class:`Seen` of the state at the samples of ``d`` (D, C None: no highlight lines)."""
    dv = None if D is None else _line(D, d.hi, d.hw, masks.h)
    return Seen(_factor(P, d.a, masks.p), _factor(Q, d.b, masks.q), _line(W, d.vi, d.vw, masks.w), dv,
                tuple(_cv(C, d, masks)))


#: One compiled gather per factor kind and block shape: a texture at the samples' texels, a line at two texels each.
_texel_at = jax.jit(_factor)
_line_at = jax.jit(_line)


def _weighted(factors: tuple, y, s, fixed):
    """The product of ``factors`` (K, N, 3) and the targets less the terms ``fixed`` (K,) leave out (their
    whole products), both times the square roots ``s`` of the sample weights."""
    c = _product(factors[1:], factors[0])
    rest = _sum_terms(c, fixed)
    return c * s[None, :, None], (y - rest) * s[:, None]


@jax.jit
def _texel_block_normals(G, h, factors: tuple, y, s, idx, use, t):
    """``(G, h)`` plus one block's normal equations (:func:`_texel_normals`) of a texel factor X (q or p) of the
    slots ``use`` (K,), whose coefficients are the products of the other ``factors`` at the samples."""
    c, yr = _weighted(factors, y, s, t * (1 - use))
    Gb, hb = _texel_normals(c * jnp.asarray(use, c.dtype)[:, None, None], idx, yr, G.shape[0])
    return G + Gb, h + hb


@functools.partial(jax.jit, static_argnames=("lo", "Sw"))
def _line_block_normals(G, h, factors: tuple, y, s, vi, vw, use, t, *, lo: int, Sw: int):
    """``(G, h)`` plus one block's normal equations (:func:`_w_normals`) of a line factor of the slots from
    ``lo`` that carry it (``use``), at the footprints ``vi, vw``, given the products of the other ``factors``."""
    c, yr = _weighted(factors, y, s, t * (1 - use))
    Gb, hb = _w_normals(c, yr, vi, vw, use, lo, Sw)
    return G + Gb, h + hb


@functools.partial(jax.jit, static_argnames=("jacobi",))
def _texel_update(X, G, h, nb, nbm, lam, n_samples, use, t, *, jacobi: int):
    """The texel factor X (K, n, 3) of the slots ``use`` from its normal equations (:func:`_texel_solve`, the
    Laplacian weight ``mu = lam N / n``), 1 in the slots without it."""
    u = jnp.asarray(use, X.dtype)[:, None, None]
    mu = lam * n_samples / X.shape[1]
    return _texel_solve(X, G, h, nb, nbm, mu, jacobi, jnp.maximum(jnp.sum(t), 1.0)) * u + (1 - u)


@functools.partial(jax.jit, static_argnames=("lo",))
def _line_update(W, G, h, lam, n_samples, use, *, lo: int):
    """The line factor W (K, S_w, 3) of the slots from ``lo`` that carry it (:func:`_w_solve`, the smoothing
    ``mu_w = lam N / S_w``)."""
    return _w_solve(W, G, h, lam * n_samples / W.shape[1], use, lo)


@jax.jit
def _seen_objective(seen: Seen, y, s, t):
    """``sum_i s_i^2 ||yhat_i - y_i||^2`` over one block from its factors at the samples (:func:`predict`)."""
    out = seen.pa * seen.qb * seen.wv
    if seen.dv is not None:
        out = out * _product(seen.cv, seen.dv)
    r = (_sum_terms(out, t) - y) * s[:, None]
    return jnp.sum(r * r)


@jax.jit
def _unit(P, Q, masks: Masks):
    """P and Q with ones in the slots without the factor."""
    up, uq = (jnp.asarray(x, P.dtype)[:, None, None] for x in (masks.p, masks.q))
    return P * up + (1 - up), Q * uq + (1 - uq)


@jax.jit
def _balanced(P, Q, W, m: Masks, D=None, C=None):
    """:func:`_balance` of the state and its factors ``(fP, fQ, fW, fD, fC)`` (:func:`_balance_scales`)."""
    f = _balance_scales(P, Q, W, m, D, C)
    fP, fQ, fW, fD, fC = f
    P, Q, W = P * fP, Q * fQ, W * fW
    D = None if D is None else D * fD
    C = None if C is None else tuple(Ce * x for Ce, x in zip(C, fC))
    return (P, Q, W, D, C), f


@jax.jit
def _rescaled(seen: Seen, f: tuple, y, s, t):
    """The factors at the samples of a block after the rebalance (each a per-term scale of its texture, so the
    gathered factors times the same scales, :func:`_balance_scales`' ``f``) and their objective
    (:func:`_seen_objective`)."""
    fP, fQ, fW, fD, fC = f
    sn = Seen(seen.pa * fP, seen.qb * fQ, seen.wv * fW, None if seen.dv is None else seen.dv * fD,
              tuple(x * fc for x, fc in zip(seen.cv, fC or ())))
    return sn, _seen_objective(sn, y, s, t)


def _present(use) -> bool:
    """Some slot carries the factor (``use`` (K,), 1 or 0; decided on the host: a block nobody reads is skipped)."""
    return bool(np.any(np.asarray(use) > 0))


def sweep(P, Q, W, D, C, d: GridData | Blocked, lam, masks: Masks, *, slots: Slots, sweeps: int = 1, jacobi: int = 3):
    """``sweeps`` ALS sweeps of the terms in ``slots`` whose factors ``masks`` says (jit arguments: one set of
    compiled programs for every structure that fits in the slots, :func:`layout`), from P, Q (K, n, 3), W, D
    (K, S_w, 3) and C (a tuple of ``slots.extra`` (K, S_w, 3)); D and C are ignored where ``slots`` has no
    highlight slot (no extra line). ``d``: the samples, or :func:`blocks` of them. Each block of the sweep (q,
    p, d, each extra line, w: the module docstring) sums its normal equations over the blocks of samples
    (compiled per slot shape and block size, not per sample count) and solves them once; the factor is then
    gathered at every block's samples (:class:`Seen`) for the next. Then the terms are rebalanced, and the
    gathered factors rescaled with them (:func:`_rescaled`: each factor is gathered once a sweep). Returns
    ``(P, Q, W, D, C, hist)``, hist the data objective ``sum_i s_i^2 ||yhat_i - y_i||^2`` (``d.s``: the square
    roots of the sample weights) after each sweep."""
    parts, N = (d.blocks, d.n) if isinstance(d, Blocked) else ((d,), int(d.y.shape[0]))
    has_d = slots.high > 0 and parts[0].hi is not None
    has_c = has_d and slots.extra > 0
    lo_w, lo_h = slots.plain, slots.plain + slots.lined
    lam, n_samples = jnp.float32(lam), jnp.float32(N)
    nb, nbm = parts[0].nb, parts[0].nbm
    K, n, Sw = P.shape[0], P.shape[1], W.shape[1]
    P, Q = _unit(P, Q, masks)
    D_in, C_in = D, C
    D, C = (D if has_d else None), (tuple(C) if has_c else None)

    def zeros(*shape):
        return jnp.asarray(np.zeros(shape, np.float32))

    def texel(X, idx: str, use, others):  # the texel factor X (q or p) from every block's normal equations
        G, h = zeros(n, 3, K, K), zeros(n, 3, K)
        for part, sn in zip(parts, seen):
            G, h = _texel_block_normals(G, h, others(sn), part.y, part.s, getattr(part, idx), use, masks.t)
        return _texel_update(X, G, h, nb, nbm, lam, n_samples, use, masks.t, jacobi=jacobi)

    def line(X, lo: int, foot, use, others):  # a line factor from every block's normal equations
        M = (K - lo) * Sw
        G, h = zeros(M * M, 3), zeros(M, 3)
        for part, sn in zip(parts, seen):
            vi, vw = foot(part)
            G, h = _line_block_normals(G, h, others(sn), part.y, part.s, vi, vw, use, masks.t, lo=lo, Sw=Sw)
        return _line_update(X, G, h, lam, n_samples, use, lo=lo)

    def lines(sn: Seen) -> tuple:  # the highlight lines at the samples (none without)
        return () if sn.dv is None else (sn.dv, *sn.cv)

    hist = []
    seen = [_seen(P, Q, W, D, C, part, masks) for part in parts]
    for _ in range(int(sweeps)):
        if _present(masks.q):
            Q = texel(Q, "b", masks.q, lambda sn: (sn.pa, sn.wv, *lines(sn)))
            seen = [sn._replace(qb=_texel_at(Q, part.b, masks.q)) for sn, part in zip(seen, parts)]
        if _present(masks.p):
            P = texel(P, "a", masks.p, lambda sn: (sn.qb, sn.wv, *lines(sn)))
            seen = [sn._replace(pa=_texel_at(P, part.a, masks.p)) for sn, part in zip(seen, parts)]
        if has_d:  # the highlight lines, given p q w (and the extra lines), then each extra line given the others
            if _present(masks.h):
                D = line(D, lo_h, lambda part: (part.hi, part.hw), masks.h, lambda sn: (sn.pa, sn.qb, sn.wv, *sn.cv))
                seen = [sn._replace(dv=_line_at(D, part.hi, part.hw, masks.h)) for sn, part in zip(seen, parts)]
            if has_c:
                C = list(C)
                for e in range(len(C)):
                    if _present(masks.c[e]):
                        C[e] = line(C[e], lo_h, lambda part, e=e: (part.ci[e], part.cw[e]), masks.c[e],
                                    lambda sn, e=e: (sn.pa, sn.qb, sn.wv, sn.dv, *sn.cv[:e], *sn.cv[e + 1:]))
                        seen = [sn._replace(cv=sn.cv[:e] + (_line_at(C[e], part.ci[e], part.cw[e], masks.c[e]),)
                                            + sn.cv[e + 1:]) for sn, part in zip(seen, parts)]
                C = tuple(C)
        if _present(masks.w):
            W = line(W, lo_w, lambda part: (part.vi, part.vw), masks.w, lambda sn: (sn.pa, sn.qb, *lines(sn)))
            seen = [sn._replace(wv=_line_at(W, part.vi, part.vw, masks.w)) for sn, part in zip(seen, parts)]
        (P, Q, W, D, C), f = _balanced(P, Q, W, masks, D, C)
        # the balanced state at the samples (the factors rescaled, not gathered again): its objective, and
        # the next sweep's factors
        out = [_rescaled(sn, f, part.y, part.s, masks.t) for sn, part in zip(seen, parts)]
        seen = [sn for sn, _ in out]
        hist.append(sum(float(obj) for _, obj in out))
    return P, Q, W, (D if has_d else D_in), (C if has_c else C_in), np.asarray(hist, np.float32)


class Padded(NamedTuple):
    """A sum's ALS state in slots (:func:`padded`): the arrays :func:`sweep` reads and how to read back."""

    state: tuple  # (P, Q, W, D, C)
    data: GridData | Blocked
    masks: Masks
    slots: Slots
    order: np.ndarray


def padded(P, Q, W, d: GridData, flags: Flags, D=None, C=None, slots: Slots | None = None, block: int = 0) -> Padded:
    """The terms of ``flags`` (arrays P, Q, W, D, C per term, D and C None where no term has one) in
    ``slots`` (default: their own, :func:`slots_of`): empty slots hold ones, masked out; the samples in
    :func:`blocks` of ``block`` (0: one block)."""
    slots = slots_of(flags) if slots is None else slots
    order, masks = layout(flags, slots)
    K, Sw = slots.terms, np.asarray(W).shape[1]
    ones = np.ones((len(np.asarray(P)), Sw, 3), np.float32)
    Dp = pad(np.asarray(D if D is not None else ones, np.float32), order)
    Cs = [np.asarray(c, np.float32) for c in (C or ())] + [ones] * (slots.extra - len(C or ()))
    state = (jnp.asarray(pad(np.asarray(P, np.float32), order)), jnp.asarray(pad(np.asarray(Q, np.float32), order)),
             jnp.asarray(pad(np.asarray(W, np.float32), order)), jnp.asarray(Dp),
             tuple(jnp.asarray(pad(c, order)) for c in Cs))
    assert state[0].shape[0] == K
    return Padded(state, blocks(pad_data(d, order, slots), block), masks, slots, order)


def unpadded(p: Padded, flags: Flags) -> tuple:
    """The per-term arrays of a padded state, as :func:`run` returns them (without hist): ``(P, Q, W)``
    and D where some term has d, C (a tuple) where some term has an extra line."""
    P, Q, W, D, C = p.state
    out = tuple(unpad(x, p.order) for x in (P, Q, W))
    if any(flags.h):
        out += (unpad(D, p.order),)
        if flags.c:
            out += (tuple(unpad(c, p.order) for c in C[:len(flags.c)]),)
    return out


def run(P, Q, W, d: GridData, lam, *, flags: Flags, sweeps: int, jacobi: int = 3, D=None, C=None,
        slots: Slots | None = None):
    """``sweeps`` ALS sweeps (:func:`sweep`) of the terms of ``flags`` (static here: which factors each
    term has, p(n), q(r), w(n.v), d(x), extra lines) from (P, Q, W) (K, n, 3), (K, n, 3), (K, S_w, 3) and,
    when some term has a d factor, D (K, S_w, 3) and, when highlight terms also carry extra lines
    (``flags.c``, one entry per line: the Fresnel line, the cosine line), C, a tuple of (K, S_w, 3), one per
    extra line; in ``slots`` (default: the terms' own). Returns them and the data objective after each
    sweep: ``(P, Q, W, hist)``, ``(P, Q, W, D, hist)`` with D, ``(P, Q, W, D, C, hist)`` with C."""
    p = padded(P, Q, W, d, flags, D if any(flags.h) else None, C if flags.c else None, slots)
    *state, hist = sweep(*p.state, p.data, lam, p.masks, slots=p.slots, sweeps=sweeps, jacobi=jacobi)
    return unpadded(p._replace(state=tuple(state)), flags) + (hist,)


__all__ = ["Blocked", "Flags", "GridData", "Masks", "Padded", "Seen", "Slots", "blocks", "layout", "line_footprint",
           "pad", "padded", "predict", "run", "single_texel", "slots_of", "spd_solve", "sweep", "unpad", "unpadded"]
