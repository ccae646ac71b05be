"""A highlight term's lines ``c(n.i) w(n.v)`` as a 2D table ``T(n.i, n.v)`` and back (``advanced.highlights.table``).

Near the mirror direction a light's microfacet highlight is ``D F n.h'^2 min(n.v, n.i) / (n.v (n.v + n.i))``
(the height-correlated shadowing over ``4 n.v``): ``min(1, n.i / n.v)`` is no product of a function of
n.i and one of n.v, so the lines hold it on average only. A table holds it, one lookup cheaper
(:func:`homofac.param.projections.table_point`: ``(sqrt(n.i), sqrt(n.v))`` in the square of a
``parabolic`` map). The block ALS has no 2D block for it; it fits the lines (:func:`~homofac.fit.structures.lined`),
:func:`tabulate` writes ``c(n.i) w(n.v)`` into the table's texels and the Levenberg-Marquardt polish
refines the table with everything else (docs/notes/sums-research.md, "A 2D table of (n.i, n.v)"). :func:`separate` goes
back, by the table's best rank-1 approximation: the start of a refit's ALS.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from ..errors import HomofacError
from ..factorization import Factor, Factorization, Term, Texture
from ..param import mappers
from ..param import projections as pj
from .structures import TABLE_SIZE, Structure

_TABLE = {p: j for j, (p, _) in enumerate(pj.HIGHLIGHT_TABLE)}
_COSINE = {p: j for j, (p, _) in enumerate(pj.HIGHLIGHT_COSINE)}


def _grid_cosines(size: int) -> tuple[np.ndarray, np.ndarray]:
    """``(n.i, n.v)`` of every texel centre of a ``parabolic`` table of ``size`` (each (size, size))."""
    c = (np.arange(size) + 0.5) / size
    u, v = np.meshgrid(c, c)  # u along columns (x), v along rows (y)
    return pj.table_cosines(u, v)


def _line(texture: Texture, x: np.ndarray) -> np.ndarray:
    """A line texture's values at scalars ``x`` (..., 3), float64."""
    d = mappers.lookup("line", jnp.asarray(texture.data, jnp.float32), jnp.asarray(x, jnp.float32).reshape(-1))
    return np.asarray(d, np.float64).reshape(x.shape + (3,))


def tabulate(model: Factorization, structure: Structure, size: int = TABLE_SIZE) -> Factorization:
    """``model`` (of :func:`~homofac.fit.structures.lined` ``(structure)``, ``structure`` one with
    ``highlights.table``: highlight terms reading ``c_t(n.i)`` and ``w_t(n.v)``) with each such pair replaced by the table ``T_t``, its texels
    ``c_t(n.i) w_t(n.v)`` at their centres (:func:`homofac.param.projections.table_cosines`): the same
    function up to bilinear interpolation, one lookup fewer. The other terms and textures are kept."""
    if not structure.highlights.table:
        raise HomofacError(f"tabulate: {structure.label()} reads no table (highlights.table)")
    ni, nv = _grid_cosines(size)
    textures = {t.name: t for t in model.textures}
    gone, new_textures, terms = set(), [], []
    for term in model.terms:
        cos = [f for f in term.factors if f.projection in _COSINE]
        w = [f for f in term.factors if f.projection == "nv"]
        if not cos:
            terms.append(term)
            continue
        if len(w) != 1:
            raise HomofacError(f"tabulate: a highlight term with c(n.i) must read one w(n.v), got {term.factors}")
        (c,), (w,) = cos, w
        name = "T" + c.texture[1:]  # c3 -> T3, the term's index
        data = _line(textures[c.texture], ni) * _line(textures[w.texture], nv)
        new_textures.append(Texture(name, "parabolic", int(size), jnp.asarray(data, jnp.float32)))
        gone |= {c.texture, w.texture}
        factors = tuple(f for f in term.factors if f not in (c, w)) + (
            Factor(pj.HIGHLIGHT_TABLE[_COSINE[c.projection]][0], name),)
        terms.append(Term(factors, term.correction, term.kind))
    if not new_textures:
        raise HomofacError("tabulate: the model has no highlight term with a cosine line c(n.i)")
    kept = [t for t in model.textures if t.name not in gone]
    return Factorization(model.kind, model.quantity, tuple(kept + new_textures), tuple(terms), dict(model.context),
                         structure.label())


def separate(model: Factorization, line_size: int) -> Factorization:
    """``model`` with each highlight term's table ``T_t(n.i, n.v)`` replaced by the lines ``c_t(n.i) w_t(n.v)``
    of ``line_size`` texels that hold its best rank-1 approximation on the lines' texel centres (per channel,
    the leading singular pair, split evenly): the inverse of :func:`tabulate` where the table is a product,
    the nearest product elsewhere."""
    x = (np.arange(line_size) + 0.5) / line_size
    ni, nv = np.meshgrid(x, x, indexing="ij")  # [k, l]: n.i = x_k, n.v = x_l
    textures = {t.name: t for t in model.textures}
    gone, new_textures, terms = set(), [], []
    for term in model.terms:
        tab = [f for f in term.factors if f.projection in _TABLE]
        if not tab:
            terms.append(term)
            continue
        (f,) = tab
        t = textures[f.texture]
        d = pj.table_point(np.sqrt(ni), np.sqrt(nv)).astype(np.float32)
        M = np.asarray(mappers.lookup(t.mapper, jnp.asarray(t.data, jnp.float32), jnp.asarray(d)), np.float64)
        U, S, Vt = np.linalg.svd(np.moveaxis(M, -1, 0))  # per channel, batched: (3, L, L)
        scale = np.where(np.sum(U[:, :, 0], axis=1) < 0, -1.0, 1.0) * np.sqrt(S[:, 0])  # c's sum positive
        c, w = (U[:, :, 0] * scale[:, None]).T, (Vt[:, 0, :] * scale[:, None]).T  # (L, 3) each
        suffix = f.texture[1:]
        j = _TABLE[f.projection]
        new_textures += [Texture(f"c{suffix}", "line", int(line_size), jnp.asarray(c[None], jnp.float32)),
                         Texture(f"w{suffix}", "line", int(line_size), jnp.asarray(w[None], jnp.float32))]
        gone.add(f.texture)
        factors = tuple(g for g in term.factors if g != f) + (Factor(pj.HIGHLIGHT_COSINE[j][0], f"c{suffix}"),
                                                               Factor("nv", f"w{suffix}"))
        terms.append(Term(factors, term.correction, term.kind))
    kept = [t for t in model.textures if t.name not in gone]
    return Factorization(model.kind, model.quantity, tuple(kept + new_textures), tuple(terms), dict(model.context),
                         model.name)


__all__ = ["separate", "tabulate"]
