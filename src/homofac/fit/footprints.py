"""A model evaluated at fixed direction pairs from their precomputed bilinear footprints (refits).

A factorization's value (docs/format.md) is ``sum_t c_t prod_f bilerp(texture_f, mapper_f(pi_f(a, b)))``;
the projections, the mappers' face/uv math and the four texel indices and weights of every lookup
(thesis eq. 33-34, :func:`homofac.param.mappers.bilinear`) depend on the directions and the layout
only. A refit evaluates models of one layout at the same training and validation pairs again and
again, so :func:`footprints` computes the lookups once and :func:`evaluate` / :func:`evaluate_quantized`
are gathers and products -- the same arithmetic as :meth:`homofac.factorization.Factorization.evaluate`
and :func:`homofac.factorization.evaluate_quantized` (tested equal). :func:`measure` is
:func:`homofac.fit.metrics.measure` on top of them.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..factorization import Factorization, Quantized
from ..param import mappers
from ..param import projections as pj
from .metrics import metric_arrays


class Footprints(NamedTuple):
    """The lookups of a layout at N pairs: for every distinct ``(projection, mapper, size)`` (``keys``,
    static) the flat texel indices ``idx`` (N, 4) and weights ``w`` (N, 4)."""

    keys: tuple
    idx: tuple
    w: tuple


def lookup_keys(model: Factorization) -> tuple:
    """The distinct ``(projection, mapper, size)`` lookups of a model, in factor order."""
    tex = {t.name: t for t in model.textures}
    out = []
    for term in model.terms:
        for f in term.factors:
            k = (f.projection, tex[f.texture].mapper, tex[f.texture].size)
            if k not in out:
                out.append(k)
    return tuple(out)


def footprints(model: Factorization, a, b) -> Footprints:
    """The footprints of ``model``'s lookups at pairs (a, b) (see the module docstring)."""
    a = jnp.asarray(a, jnp.float32)
    b = jnp.asarray(b, jnp.float32)
    keys = lookup_keys(model)
    projected: dict = {}
    idx, w = [], []
    for proj, mapper, size in keys:
        if proj not in projected:
            projected[proj] = pj.apply(proj, a, b, model.context)
        i, wt = mappers.bilinear(mapper, projected[proj].astype(jnp.float32), size)
        idx.append(jnp.asarray(i, jnp.int32))
        w.append(jnp.asarray(wt, jnp.float32))
    return Footprints(keys, tuple(idx), tuple(w))


def _gather(data, idx, w):
    flat = data.reshape((-1,) + data.shape[2:])
    return jnp.einsum("nk,nkc->nc", w, flat[idx])


def _values(textures, corrections, alphas, offsets, scales, structure, idx, w):
    """sum_t c_t prod_f decode(bilerp(texture)) with ``structure`` (static): per term the (texture
    index, footprint index) of each factor; ``alphas`` per texture (None for the float textures)."""
    out = 0.0
    for (factors, c) in zip(structure, corrections):
        v = jnp.broadcast_to(c, (idx[0].shape[0], 3))
        for k, f in factors:
            x = _gather(textures[k], idx[f], w[f])
            if alphas is not None:
                x = x[:, :3] * (x[:, 3:4] if alphas[k] else 1.0)
                x = offsets[k] + scales[k] * x
            v = v * x
        out = out + v
    return out


def _structure(model: Factorization, keys: tuple) -> tuple:
    tex = {t.name: k for k, t in enumerate(model.textures)}
    info = {t.name: (t.mapper, t.size) for t in model.textures}
    return tuple(tuple((tex[f.texture], keys.index((f.projection,) + info[f.texture])) for f in term.factors)
                 for term in model.terms)


def evaluate(model: Factorization, fp: Footprints) -> Float[Array, "N 3"]:
    """The model's float value at the footprints' pairs (as :meth:`Factorization.evaluate`)."""
    return _eval_float(tuple(jnp.asarray(t.data, jnp.float32) for t in model.textures),
                       tuple(jnp.asarray(t.correction, jnp.float32) for t in model.terms), fp.idx, fp.w,
                       structure=_structure(model, fp.keys))


def evaluate_quantized(model: Factorization, q: Quantized, fp: Footprints) -> Float[Array, "N 3"]:
    """The model's 8-bit value at the footprints' pairs (as :func:`homofac.factorization.evaluate_quantized`:
    every RGBA channel interpolated before the decode rule)."""
    channels = tuple(jnp.asarray(np.asarray(r, np.float64) / 255.0, jnp.float32) for r in q.rgba)
    return _eval_q(channels, tuple(jnp.asarray(c, jnp.float32) for c in q.corrections),
                   tuple(jnp.asarray(o, jnp.float32) for o in q.offset), tuple(jnp.asarray(s, jnp.float32)
                                                                                for s in q.scale),
                   fp.idx, fp.w, structure=_structure(model, fp.keys), alphas=tuple(bool(x) for x in q.alpha))


def _eval_float_impl(textures, corrections, idx, w, *, structure):
    return _values(textures, corrections, None, None, None, structure, idx, w)


def _eval_q_impl(channels, corrections, offsets, scales, idx, w, *, structure, alphas):
    return _values(channels, corrections, alphas, offsets, scales, structure, idx, w)


_eval_float = jax.jit(_eval_float_impl, static_argnames=("structure",))
_eval_q = jax.jit(_eval_q_impl, static_argnames=("structure", "alphas"))


def measure(result, target, samples, fp_train: Footprints, fp_val: Footprints | None, eps: float = 1e-5) -> dict:
    """:func:`homofac.fit.metrics.measure` at the footprints of the training and validation pairs."""
    q = result.encoded()
    out = {}
    for split, fp, a, y in (("train", fp_train, samples.a, samples.y), ("validation", fp_val, samples.val_a,
                                                                         samples.val_y)):
        if fp is None or len(a) == 0:
            continue
        aj = jnp.asarray(a)
        exact = target.shown(aj, jnp.asarray(y))
        out[split] = {}
        for name, approx in (("float", evaluate(result.model, fp)), ("quantized", evaluate_quantized(result.model, q, fp))):
            m = metric_arrays(target.shown(aj, approx), exact, eps)
            out[split][name] = {k: float(v) for k, v in m.items()}
    return out


__all__ = ["Footprints", "evaluate", "evaluate_quantized", "footprints", "lookup_keys", "measure"]
