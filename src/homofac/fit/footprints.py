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
from .metrics import channel_metrics, metrics


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


def _values(textures, corrections, alphas, offsets, scales, structure, idx, w):
    """sum_t c_t prod_f decode(bilerp(texture)) with ``structure`` (static): per term the (texture
    index, footprint index) of each factor; ``alphas`` per texture (None for the float textures).

    Also T models of one structure at once, their channels side by side ("wide"): textures (H, W, T C),
    corrections / offsets / scales (3 T,), values (N, 3 T) (a material library; T = 1 is one model). One
    gather reads every model's texels, and the metrics reduce over contiguous columns. 8-bit textures
    come as pairs (RGB (H, W, 3 T), alpha (H, W, T)): interpolated apart and multiplied after the lookup
    (the pinned rule); slicing an interleaved (N, T, 4) lookup instead was 8x slower (45 -> 5.5 ms at
    T = 16, measured)."""
    out = 0.0
    for (factors, c) in zip(structure, corrections):
        v = jnp.reshape(c, (1, -1))
        for k, f in factors:
            if alphas is None:
                data = textures[k]
                x = mappers.gather(data.reshape(-1, data.shape[-1]), idx[f], w[f])  # (N, T C)
            else:  # RGB and alpha per model: decode after the interpolation (pinned rule)
                rgb, alpha = textures[k]
                x = mappers.gather(rgb.reshape(-1, rgb.shape[-1]), idx[f], w[f])  # (N, 3 T)
                if alphas[k]:
                    a = mappers.gather(alpha.reshape(-1, alpha.shape[-1]), idx[f], w[f])  # (N, T)
                    x = (x.reshape(x.shape[0], -1, 3) * a[:, :, None]).reshape(x.shape[0], -1)
                x = offsets[k][None, :] + scales[k][None, :] * x
            v = v * x
        out = out + v
    return out


def _split_rgba(rgba: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """8-bit RGBA codes (H, W, 4) as linear values [0, 1]: RGB (H, W, 3) and alpha (H, W, 1)."""
    x = np.asarray(rgba, np.float64) / 255.0
    return x[..., :3], x[..., 3:]


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
    channels = tuple(tuple(jnp.asarray(c, jnp.float32) for c in _split_rgba(r)) for r in q.rgba)
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
            out[split][name] = metrics(target.shown(aj, approx), exact, eps)
    return out


@jax.jit
def _many_metrics(approx, exact, eps):
    """:func:`metric_arrays` of T targets from their channels side by side, (N, 3 T) each: (T,) arrays."""
    return {k: jnp.mean(v.reshape(-1, 3), axis=1) for k, v in channel_metrics(approx, exact, eps).items()}


def measure_many(results, targets, samples, fp_train: Footprints, fp_val: Footprints | None,
                 eps: float = 1e-5) -> list[dict]:
    """:func:`measure` of many results of one layout at the same pairs (a material library: every model
    has the same textures, terms and decode flags, only the texels and the target values differ), in one
    vmapped program per split and precision instead of one per result (equal to :func:`measure`, tested).

    ``samples`` holds each target's values at the shared pairs (their ``a``, ``b`` are those of the first).
    Falls back to :func:`measure` per result when the models do not share a structure.
    """
    structs = {_structure(r.model, fp_train.keys) for r in results}
    qs = [r.encoded() for r in results]
    if (len(structs) != 1 or len({tuple(bool(x) for x in q.alpha) for q in qs}) != 1
            or len({(t.kind, t.quantity) for t in targets}) != 1):
        return [measure(r, t, s, fp_train, fp_val, eps) for r, t, s in zip(results, targets, samples)]
    structure = structs.pop()
    alphas = tuple(bool(x) for x in qs[0].alpha)
    def wide(arrays, dtype=np.float32):  # per model (..., C) -> (..., T C), the models' channels side by side
        return jnp.asarray(np.concatenate([np.asarray(x, np.float64).astype(dtype) for x in arrays], axis=-1))

    models = [r.model for r in results]
    textures = tuple(wide([m.textures[k].data for m in models]) for k in range(len(models[0].textures)))
    corrections = tuple(wide([np.broadcast_to(m.terms[t].correction, (3,)) for m in models])
                        for t in range(len(models[0].terms)))
    split = [[_split_rgba(r) for r in q.rgba] for q in qs]
    channels = tuple((wide([sp[k][0] for sp in split]), wide([sp[k][1] for sp in split])) for k in range(len(qs[0].rgba)))
    q_corr = tuple(wide([np.broadcast_to(q.corrections[t], (3,)) for q in qs]) for t in range(len(qs[0].corrections)))
    offsets = tuple(wide([np.broadcast_to(q.offset[k], (3,)) for q in qs]) for k in range(len(qs[0].offset)))
    scales = tuple(wide([np.broadcast_to(q.scale[k], (3,)) for q in qs]) for k in range(len(qs[0].scale)))
    out: list[dict] = [{} for _ in results]
    for split, fp, a, ys in (("train", fp_train, samples[0].a, [s.y for s in samples]),
                             ("validation", fp_val, samples[0].val_a, [s.val_y for s in samples])):
        if fp is None or len(a) == 0:
            continue
        aj = jnp.asarray(a)
        t0 = targets[0]  # one kind and quantity for all: what the metrics compare (f cos for BRDFs)
        exact = t0.shown(aj, wide(ys))
        for name, approx in (("float", _eval_float(textures, corrections, fp.idx, fp.w, structure=structure)),
                             ("quantized", _eval_q(channels, q_corr, offsets, scales, fp.idx, fp.w,
                                                   structure=structure, alphas=alphas))):
            m = {k: np.asarray(v) for k, v in _many_metrics(t0.shown(aj, approx), exact, eps).items()}
            for i in range(len(results)):
                out[i].setdefault(split, {})[name] = {k: float(v[i]) for k, v in m.items()}
    return out


__all__ = ["Footprints", "evaluate", "evaluate_quantized", "footprints", "lookup_keys", "measure", "measure_many"]
