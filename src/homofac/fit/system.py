"""The sparse log-space system of the homomorphic factorization (thesis §3.1.2, eq. 30-37).

Unknowns are the log-texel values of all *valid* texels of all textures, stacked (eq. 32), with RGB
as a trailing axis of size 3: ``x`` has shape (n, 3) and all three channels share one matrix.

Rows:

* one data row per sample: ``sum_j bilinear(x_k(j), pi_j(a, b)) = log((y + eps alpha) / alpha)``
  (eq. 26, 30, 33-35): 4 bilinear weights per factor, so K = 4 J entries per row (duplicate
  columns, e.g. p used twice by PQP, simply add up);
* one Laplacian row per valid texel, ``lambda (deg x_c - sum_nb x_nb) = 0`` (eq. 36-37; the centre
  weight is the number of existing neighbours at borders, and the cube map's neighbours continue
  across face edges so smoothing has no seams).

Both are stored as ELL index/weight arrays (``cols``, ``w``), which a matrix-free operator gathers
from; this was about 2x faster than BCOO on the target machine (docs/conventions.md). The transposed
product ``A^T r`` that jax derives from the gathers is a scatter-add of every entry, which XLA's CPU
backend runs an order of magnitude slower than a gather at many columns (77 against 3.6 ms for the 48
columns of a 16-material library); :func:`adjoint_plan` sorts the entries by column once so that
:func:`apply_transpose` gathers them instead (in chunks of :data:`CHUNK`, summed per column by a
scatter of one row per chunk: 7 ms there).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse as sp
from jaxtyping import Array, Float, Int

from ..param import mappers
from ..param.parametrizations import Parametrization, project


class TextureLayout(NamedTuple):
    """Where one texture's valid texels live in the unknown vector (static, numpy)."""

    name: str
    mapper: str
    size: int
    shape: tuple[int, int]  # (H, W)
    valid: np.ndarray  # (H*W,) bool
    unknown_of_texel: np.ndarray  # (H*W,) int32: unknown index within this texture, or -1
    texel_of_unknown: np.ndarray  # (n_valid,) int32 flat texel index
    offset: int  # index of this texture's first unknown in the stacked vector (eq. 32)

    @property
    def n_valid(self) -> int:
        return int(self.texel_of_unknown.shape[0])


class Layout(NamedTuple):
    """The unknowns of eq. 32: the valid texels of every texture, stacked (each with its own mapper and size)."""

    textures: tuple[TextureLayout, ...]

    @property
    def n_textures(self) -> int:
        return len(self.textures)

    @property
    def n_unknowns(self) -> int:
        return sum(t.n_valid for t in self.textures)

    def slice(self, k: int) -> slice:
        t = self.textures[k]
        return slice(t.offset, t.offset + t.n_valid)


def texture_layout(name: str, mapper: str, size: int, offset: int = 0) -> TextureLayout:
    """The layout of one texture of ``mapper`` at ``size`` whose unknowns start at ``offset``."""
    m = mappers.get(mapper)
    shape = mappers.texture_shape(m, size)
    valid = np.asarray(mappers.valid_mask(m, size)).reshape(-1)
    texel_of_unknown = np.nonzero(valid)[0].astype(np.int32)
    unknown_of_texel = np.full(valid.shape, -1, np.int32)
    unknown_of_texel[texel_of_unknown] = np.arange(texel_of_unknown.size, dtype=np.int32)
    return TextureLayout(name, mapper, int(size), tuple(shape), valid, unknown_of_texel, texel_of_unknown, int(offset))


def make_layout(textures) -> Layout:
    """The layout of ``textures``: ``(name, mapper, size)`` triples, stacked in order."""
    out, offset = [], 0
    for name, mapper, size in textures:
        t = texture_layout(name, mapper, size, offset)
        out.append(t)
        offset += t.n_valid
    return Layout(tuple(out))


def parametrization_layout(param: Parametrization, mapper: str, size: int, line_size: int | None = None) -> Layout:
    """The layout of a parametrization's textures: direction textures on ``mapper`` at ``size``, scalar ones
    (read by ``nv``, ``cos_i``, ``cos_o``) on ``line`` at ``line_size`` (default ``size``)."""
    return make_layout(
        (name, "line", int(line_size or size)) if param.scalar(k) else (name, mapper, int(size))
        for k, name in enumerate(param.textures)
    )


class System(NamedTuple):
    """ELL rows of eq. 37: data rows (``cols``, ``w``, ``rhs``) and Laplacian rows (``lap_cols``, ``lap_w``)."""

    cols: Int[Array, "m K"]
    w: Float[Array, "m K"]
    rhs: Float[Array, "m 3"]
    lap_cols: Int[Array, "n 5"]
    lap_w: Float[Array, "n 5"]


def data_rows(
    param: Parametrization, layout: Layout, a: Float[Array, "m 3"], b: Float[Array, "m 3"], context: dict
) -> tuple[Int[Array, "m K"], Float[Array, "m K"]]:
    """Columns and bilinear weights of the data rows (eq. 33-35), K = 4 J."""
    cols, ws = [], []
    for f, d in zip(param.factors, project(param, a, b, context)):
        tex = layout.textures[f.texture]
        idx, w = mappers.bilinear(tex.mapper, d, tex.size)
        unk = jnp.asarray(tex.unknown_of_texel)[idx]
        # A texel outside the valid set has weight 0 by construction of the mapper; guard anyway.
        w = jnp.where(unk >= 0, w, 0.0)
        cols.append(jnp.where(unk >= 0, unk, 0) + tex.offset)
        ws.append(w)
    return jnp.concatenate(cols, axis=-1).astype(jnp.int32), jnp.concatenate(ws, axis=-1)


def laplacian_rows(layout: Layout, dtype=jnp.float32) -> tuple[np.ndarray, np.ndarray]:
    """Laplacian rows (eq. 36) for every valid texel of every texture: (cols (n, 5), w (n, 5))."""
    cols, ws = [], []
    for tex in layout.textures:
        nb = np.asarray(mappers.neighbours(tex.mapper, tex.size))[tex.texel_of_unknown]  # (nv, 4) flat or -1
        nb_unk = np.where(nb >= 0, tex.unknown_of_texel[np.maximum(nb, 0)], -1)
        has = nb_unk >= 0
        deg = has.sum(axis=1).astype(np.float64)
        centre = np.arange(tex.n_valid, dtype=np.int32)[:, None]
        cols.append(np.concatenate([centre, np.where(has, nb_unk, 0)], axis=1).astype(np.int32) + tex.offset)
        ws.append(np.concatenate([deg[:, None], np.where(has, -1.0, 0.0)], axis=1))
    return np.concatenate(cols, axis=0), np.concatenate(ws, axis=0).astype(dtype)


def log_transform(y: Float[Array, "m 3"], alpha: Float[Array, "3"], eps: float) -> Float[Array, "m 3"]:
    """Thesis eq. 26: ``log((y + eps alpha) / alpha)``, per channel."""
    return jnp.log((jnp.maximum(y, 0.0) + eps * alpha) / alpha)


def sample_mean(y: Float[Array, "m 3"]) -> Float[Array, "3"]:
    """alpha of eq. 26: the per-channel mean of the (clamped) samples; 1 for a channel that is all 0."""
    alpha = jnp.mean(jnp.maximum(y, 0.0), axis=0)
    return jnp.where(alpha > 0, alpha, 1.0)


def build_system(
    param: Parametrization, layout: Layout, a, b, y, *, eps: float, context: dict | None = None
) -> tuple[System, Float[Array, "3"]]:
    """Assemble eq. 37 for samples (a, b, y); returns the system and the sample mean alpha (eq. 26)."""
    y = jnp.asarray(y)
    alpha = sample_mean(y)
    cols, w = _data_rows_jit(param, layout, jnp.asarray(a), jnp.asarray(b), context or {})
    lap_cols, lap_w = laplacian_rows(layout, np.float32)
    rhs = log_transform(y, alpha, eps)
    return System(cols, w.astype(y.dtype), rhs, jnp.asarray(lap_cols), jnp.asarray(lap_w, y.dtype)), alpha


#: Compiled :func:`data_rows` per (parametrization, layout): a fresh ``jax.jit`` of a new closure per call
#: recompiled the rows at every fit (0.3 s of a 1 s default run).
_ROWS_PROGRAMS: dict = {}


def _data_rows_jit(param, layout, a, b, context):
    key = (id(param), param.name, tuple((t.name, t.mapper, t.size, t.offset) for t in layout.textures))
    fn = _ROWS_PROGRAMS.get(key)
    if fn is None:
        if len(_ROWS_PROGRAMS) >= 64:
            _ROWS_PROGRAMS.clear()
        fn = _ROWS_PROGRAMS[key] = jax.jit(lambda a, b, ctx: data_rows(param, layout, a, b, ctx))
    return fn(a, b, context)


def apply(sys: System, lam, x: Float[Array, "n 3"]) -> Float[Array, "m_plus_n 3"]:
    """The augmented matrix of eq. 37 times x: data rows, then lambda-weighted Laplacian rows."""
    return jnp.concatenate([_ell(sys.w, sys.cols, x), lam * _ell(sys.lap_w, sys.lap_cols, x)], axis=0)


def _ell(w, cols, x):
    """``sum_k w[:, k] x[cols[:, k]]``: one gather-multiply-add per slot k (K is small and static), which
    XLA fuses; an einsum over the gathered (rows, K, C) array materializes it (25x slower at C = 48)."""
    out = w[:, 0, None] * x[cols[:, 0]]
    for k in range(1, w.shape[1]):
        out = out + w[:, k, None] * x[cols[:, k]]
    return out


#: Entries per chunk of an :class:`Adjoint` (16 and 32 measured alike at 3 and 48 columns; 8 slower at 3).
CHUNK = 16


class Adjoint(NamedTuple):
    """The entries of ELL rows sorted by column, in chunks of :data:`CHUNK` (one column per chunk):
    ``entry`` indexes the flattened weights (the padding: one past the end, weight 0), ``row`` the rows,
    ``column`` (sorted) the column each chunk adds to."""

    entry: Int[Array, "c W"]
    row: Int[Array, "c W"]
    column: Int[Array, "c"]


class AdjointPlan(NamedTuple):
    """:class:`Adjoint` of the data rows and of the Laplacian rows of a :class:`System`."""

    data: Adjoint
    laplacian: Adjoint


def _adjoint(cols: np.ndarray, n: int, width: int = CHUNK) -> Adjoint:
    cols = np.asarray(cols)
    rows, k = cols.shape
    flat = cols.reshape(-1)
    key = flat.astype(np.uint16) if n <= np.iinfo(np.uint16).max else flat
    order = np.argsort(key, kind="stable")  # numpy's radix sort for 16-bit keys
    col = flat[order]
    count = np.bincount(col, minlength=n)
    chunks = -(-count // width)
    first_chunk = np.concatenate([[0], np.cumsum(chunks)[:-1]])
    first_entry = np.concatenate([[0], np.cumsum(count)[:-1]])
    pos = np.arange(col.size) - first_entry[col]
    slot = (first_chunk[col] + pos // width) * width + pos % width
    total = int(chunks.sum())
    entry = np.full(total * width, flat.size, np.int32)
    entry[slot] = order
    row = np.where(entry < flat.size, entry // k, 0).astype(np.int32)
    return Adjoint(jnp.asarray(entry.reshape(total, width)), jnp.asarray(row.reshape(total, width)),
                   jnp.asarray(np.repeat(np.arange(n, dtype=np.int32), chunks)))


def adjoint_plan(sys: System) -> AdjointPlan:
    """The gather form of ``A^T`` for :func:`apply_transpose` (numpy, from the concrete column indices;
    the weights are read from the system at every product, so it serves any weights of that pattern)."""
    n = int(sys.lap_cols.shape[0])
    return AdjointPlan(_adjoint(np.asarray(sys.cols), n), _adjoint(np.asarray(sys.lap_cols), n))


def _chunk_weights(w, plan: Adjoint):
    return jnp.concatenate([w.reshape(-1), jnp.zeros((1,), w.dtype)])[plan.entry]  # (c, W)


def adjoint_weights(sys: System, plan: AdjointPlan) -> tuple[Float[Array, "c W"], Float[Array, "d W"]]:
    """The weights of the plan's chunks (data, Laplacian): gathered once per solve, not per product."""
    return _chunk_weights(sys.w, plan.data), _chunk_weights(sys.lap_w, plan.laplacian)


def _ell_transpose(wt, plan: Adjoint, r, n: int):
    part = _ell(wt, plan.row, r)
    return jnp.zeros((n, r.shape[1]), r.dtype).at[plan.column].add(part, indices_are_sorted=True)


def apply_transpose(sys: System, lam, plan: AdjointPlan, r: Float[Array, "m_plus_n C"],
                    weights: tuple | None = None) -> Float[Array, "n C"]:
    """``A^T r`` of the augmented matrix of eq. 37 (the transpose of :func:`apply`) by gathers;
    ``weights`` from :func:`adjoint_weights` (computed here when not given)."""
    m, n = sys.cols.shape[0], sys.lap_cols.shape[0]
    wd, wl = weights if weights is not None else adjoint_weights(sys, plan)
    return _ell_transpose(wd, plan.data, r[:m], n) + lam * _ell_transpose(wl, plan.laplacian, r[m:], n)


def augmented_rhs(sys: System) -> Float[Array, "m_plus_n 3"]:
    """Right-hand side of eq. 37: the log samples, then zeros for the Laplacian rows."""
    return jnp.concatenate([sys.rhs, jnp.zeros((sys.lap_cols.shape[0], sys.rhs.shape[1]), sys.rhs.dtype)], axis=0)


@jax.jit
def objective(sys: System, lam, x) -> Float[Array, ""]:
    """``||A x - b||^2 + ||lambda L x||^2`` summed over RGB: what every solver minimises (one compiled
    program: op by op it took 0.035 s of a 0.65 s default run)."""
    r = apply(sys, lam, x) - augmented_rhs(sys)
    return jnp.sum(r * r)


def to_scipy(sys: System, lam: float, n_unknowns: int):
    """The augmented matrix of eq. 37 as a scipy CSR matrix (float64), for the reference solvers."""
    cols = np.asarray(sys.cols)
    w = np.asarray(sys.w, np.float64)
    lc = np.asarray(sys.lap_cols)
    lw = np.asarray(sys.lap_w, np.float64) * lam
    m, k = cols.shape
    n, k2 = lc.shape
    rows = np.concatenate([np.repeat(np.arange(m), k), m + np.repeat(np.arange(n), k2)])
    data = np.concatenate([w.ravel(), lw.ravel()])
    c = np.concatenate([cols.ravel(), lc.ravel()])
    return sp.csr_matrix((data, (rows, c)), shape=(m + n, n_unknowns))
