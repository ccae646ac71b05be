"""Per-lobe lighting sums and light transport of grouped pairs: what refits and material libraries reuse.

The pinned lighting computation (docs/conventions.md, Latta & Kolb 2002 eq. 10) of a BRDF in lobe form
(``f = kd/pi + sum_m c_m g_m``, :class:`homofac.brdf.ModelSpec` ``lobes``) splits into parts that
depend on different inputs::

    L(v, n) = kd/pi E(n) + sum_m c_m S_m(n, v)
    E(n)       = sum_k w_k(n) L_k                                   (irradiance; geometry x radiance)
    S_m(n, v)  = sum_k T_m[n, v, k] L_k,   T_m[n, v, k] = g_m(l_k, v) w_k(n)   (the transport)

* the colours ``kd``, ``c_m`` (``ks F0``, ``ks (1 - F0)`` for the Schlick models) enter linearly;
* the lobes ``g_m`` depend on the *shape* parameters only (roughness, exponent), never on the colours;
* the radiance ``L_k`` enters linearly through E and S.

So a refit for a new environment with the same BRDF needs only ``T @ L`` (:func:`build_transport`,
:func:`apply_transport`: a batched matrix product, no BRDF evaluation), a refit for new colours
needs only a new linear combination of S, and a library of materials evaluates ``g_m`` once per
distinct shape, vmapped over the shapes so the geometry (cosine weights, local frames, half vectors)
is computed once per normal for all of them (:func:`lobe_sums`). Each per-normal step is the one of
:meth:`homofac.light.Lighting.grouped` (exact texel weights, the visible lights compacted into
:func:`~homofac.light.lighting.max_visible` slots, the BRDF at the visible centroid of horizon-straddling
texels), so the values equal the pipeline's to float rounding (tested).
"""

from __future__ import annotations

import hashlib
from typing import NamedTuple, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from .. import sphere
from ..brdf import BRDF, MODELS
from ..brdf.core import has_lobes, lobe_colors, stacked_lobe_terms
from ..light import Environment, Lighting
from ..light.geometry import cosine_weights, light_geometry
from ..light.lighting import STEP_TERMS, max_visible
from ..light.lights import light_corners, light_moments

#: Parameters that enter the lobe form only through its colours (``kd/pi`` and ``colors(params)``).
COLOUR_PARAMS = ("kd", "ks", "f0")


class LobeSums(NamedTuple):
    """Irradiance ``E (G, 3)`` and per-lobe sums ``S (G, B, M, P, 3)`` of B BRDF shapes at grouped pairs."""

    irradiance: Float[Array, "G 3"]
    lobes: Float[Array, "G B M P 3"]


class Transport(NamedTuple):
    """The environment-independent part of the lighting at grouped pairs (one BRDF shape).

    ``weights`` (G, M, P, k): ``g_m(l, v) w(n)`` of the k visible-light slots of each normal (normal-major:
    the batched product with the gathered radiance is then one fast batched matmul); ``index`` (G, k):
    which light each slot holds; ``cosine`` (G, L): the texel weights w_k(n) (for E(n)).
    """

    weights: Float[Array, "G M P k"]
    index: Int[Array, "G k"]
    cosine: Float[Array, "G L"]


def supported(fn) -> bool:
    """True when ``fn`` is an unculled :class:`~homofac.light.Lighting` of a BRDF in lobe form."""
    return isinstance(fn, Lighting) and isinstance(fn.brdf, BRDF) and has_lobes(fn.brdf) and not fn.culls_lobes


def shape_params(brdf: BRDF) -> dict:
    """The parameters the lobes depend on (all but :data:`COLOUR_PARAMS`)."""
    return {k: v for k, v in brdf.params.items() if k not in COLOUR_PARAMS}


def shape_key(brdf: BRDF) -> tuple:
    """Hashable key of a BRDF's lobe shape: model name and the values of its shape parameters."""
    items = tuple((k, np.asarray(v, np.float64).tobytes()) for k, v in sorted(shape_params(brdf).items()))
    return (brdf.model,) + items


def geometry_key(env: Environment) -> str:
    """Fingerprint of an environment's light geometry (directions, solid angles, corners, resolution):
    two environments with the same key differ in radiance only, so one transport serves both."""
    h = hashlib.sha256(str(int(env.info.get("resolution", 0))).encode())
    for a in (env.directions, env.solid_angle, light_corners(env)):
        h.update(np.ascontiguousarray(np.asarray(a, np.float32)).tobytes())
    return h.hexdigest()


def _arrays(env: Environment, dtype):
    """Light directions, radiance and the geometry of :func:`~homofac.light.geometry.cosine_weights`."""
    dirs = env.directions.astype(dtype)
    geom = light_geometry(dirs, env.solid_angle.astype(dtype), light_corners(env).astype(dtype),
                          int(env.info.get("resolution", 0)), moments=light_moments(env))
    return dirs, env.radiance.astype(dtype), geom


def _normal_parts(brdfs: BRDF, dirs, geom, k: int, centroid: bool, n, v):
    """One normal n (3,) and its views v (P, 3): texel weights w (L,), the k visible slots (index, w),
    and the lobes ``g_m`` of every stacked shape at the slots (B, M, P, k) -- the inner step of
    :meth:`homofac.light.Lighting.grouped`, with the BRDF vmapped over its leading (shape) axis."""
    if centroid:
        w, (sidx, cent) = cosine_weights(n[None], geom, select=True, centroids=True)
        w = w[0]
        dirs = dirs.at[sidx[0]].set(cent[0], mode="drop")  # straddlers: their visible centroids
    else:
        w = cosine_weights(n[None], geom, select=True)[0]
    vis = w > 0
    slot = jnp.where(vis, jnp.cumsum(vis) - 1, k)
    idx = jnp.zeros((k,), jnp.int32).at[slot].set(jnp.arange(w.shape[0], dtype=jnp.int32), mode="drop")
    wk = jnp.zeros((k,), w.dtype).at[slot].set(w, mode="drop")
    t, b, nn = sphere.frame(n)
    frame = jnp.stack([t, b, nn], axis=1)
    wi = dirs[idx] @ frame  # (k, 3)
    wo = v @ frame  # (P, 3)
    wi3 = tuple(wi[None, :, c] for c in range(3))
    wo3 = tuple(wo[:, None, c] for c in range(3))
    g = stacked_lobe_terms(brdfs, wi3, wo3)  # (B, M, P, k): the geometry once for every shape
    return w, idx, wk, g


def _steps(g_count: int, p: int, k: int, shapes: int) -> int:
    return int(max(1, min(g_count, STEP_TERMS // max(1, p * k * max(shapes, 1)))))


def _pad_groups(normals, views, per: int):
    g = normals.shape[0]
    pad = (-g) % per
    if pad:
        normals = jnp.concatenate([normals, jnp.broadcast_to(normals[:1], (pad, 3))])
        views = jnp.concatenate([views, jnp.broadcast_to(views[:1], (pad,) + views.shape[1:])])
    return normals.reshape((-1, per, 3)), views.reshape((-1, per) + views.shape[1:])


@eqx.filter_jit
def _lobe_sums(brdfs: BRDF, env: Environment, normals, views, centroid: bool):
    dirs, rad, geom = _arrays(env, normals.dtype)
    k = max_visible(env)
    shapes = jax.tree_util.tree_leaves(brdfs.params)[0].shape[0]
    g_count = normals.shape[0]
    per = _steps(g_count, views.shape[1], k, shapes)
    nb, vb = _pad_groups(normals, views.astype(normals.dtype), per)

    def one(n, v):
        w, idx, wk, g = _normal_parts(brdfs, dirs, geom, k, centroid, n, v)
        r4 = jnp.pad(wk[:, None] * rad[idx], ((0, 0), (0, 1)))  # 4 columns: XLA's CPU dot is ~25 % faster than at 3
        s = jnp.einsum("bmpk,kc->bmpc", g, r4)[..., :3]
        return w @ rad, s

    e, s = jax.lax.map(lambda nv: jax.vmap(one)(nv[0], nv[1]), (nb, vb))
    e = e.reshape(-1, 3)[:g_count]
    return e, s.reshape((s.shape[0] * s.shape[1],) + s.shape[2:])[:g_count]  # (G, B, M, P, 3)


def stack(brdfs: list[BRDF]) -> BRDF:
    """BRDFs of one model stacked along a leading axis (parameters broadcast to a common shape)."""
    keys = list(brdfs[0].params)
    out = {}
    for name in keys:
        vals = [jnp.asarray(b.params[name], jnp.result_type(float)) for b in brdfs]
        shape = jnp.broadcast_shapes(*(v.shape for v in vals))
        out[name] = jnp.stack([jnp.broadcast_to(v, shape) for v in vals])
    return BRDF(brdfs[0].model, out)


def lobe_sums(brdfs: list[BRDF], env: Environment, normals, views, *, horizon: str = "centroid") -> LobeSums:
    """E(n) and the per-lobe sums S_m of every BRDF shape in ``brdfs`` (one model) at grouped pairs.

    The shapes are vmapped inside each per-normal step: the texel weights, the compaction of the visible
    lights, the local frame and everything of the lobes that does not depend on the parameters are
    computed once per normal for all of them.
    """
    normals = jnp.asarray(normals)
    e, s = _lobe_sums(stack(brdfs), env, normals, jnp.asarray(views, normals.dtype), horizon == "centroid")
    return LobeSums(e, s)


def combine(brdf: BRDF, sums: LobeSums, shape: int, normals, views, clamp: float | None = None):
    """``kd/pi E + sum_m c_m S_m`` of ``brdf`` (its colours) from shape ``shape`` of ``sums``: L (G, P, 3),
    0 where n . v <= 0 and clamped at ``clamp`` (as :class:`~homofac.light.Lighting`)."""
    return combine_many([brdf], sums, [shape], normals, views, clamp)[0]


def combine_many(brdfs: list[BRDF], sums: LobeSums, shapes: Sequence[int], normals, views,
                 clamp: float | None = None) -> Float[Array, "T G P 3"]:
    """:func:`combine` of T BRDFs of one model (their colours; BRDF t from shape ``shapes[t]`` of ``sums``)
    in one program: ``L_t = kd_t/pi E + sum_m c_tm S_m[shape_t]``, (T, G, P, 3)."""
    normals = jnp.asarray(normals)
    dtype = normals.dtype
    kd = jnp.stack([jnp.broadcast_to(jnp.asarray(b.params.get("kd", 0.0), dtype), (3,)) for b in brdfs])
    colours = jnp.stack([jnp.stack(lobe_colors(b)).astype(dtype) if lobe_colors(b) else
                         jnp.zeros((0, 3), dtype) for b in brdfs])
    clamp = jnp.asarray(jnp.inf if clamp is None else clamp, dtype)
    return _combine_many(kd, colours, jnp.asarray(np.asarray(shapes, np.int32)), sums, normals,
                         jnp.asarray(views, dtype), clamp)


@jax.jit
def _combine_many(kd, colours, shapes, sums: LobeSums, normals, views, clamp):
    s = jnp.take(sums.lobes, shapes, axis=1)  # (G, T, M, P, 3)
    out = (kd[:, None, None, :] / jnp.pi) * sums.irradiance[None, :, None, :] + jnp.einsum("tmc,gtmpc->tgpc", colours, s)
    valid = jnp.einsum("gpc,gc->gp", views, normals) > 0
    return jnp.minimum(jnp.where(valid[None, ..., None], out, 0.0), clamp)


@eqx.filter_jit
def _transport(brdf: BRDF, env: Environment, normals, views, centroid: bool):
    dirs, _, geom = _arrays(env, normals.dtype)
    k = max_visible(env)
    brdfs = jax.tree_util.tree_map(lambda x: x[None], brdf)
    g_count = normals.shape[0]
    per = _steps(g_count, views.shape[1], k, 1)
    nb, vb = _pad_groups(normals, views.astype(normals.dtype), per)

    def one(n, v):
        w, idx, wk, g = _normal_parts(brdfs, dirs, geom, k, centroid, n, v)
        return g[0] * wk, idx, w

    t, idx, w = jax.lax.map(lambda nv: jax.vmap(one)(nv[0], nv[1]), (nb, vb))
    t = t.reshape((t.shape[0] * t.shape[1],) + t.shape[2:])[:g_count]  # (G, M, P, k)
    return t, idx.reshape(-1, k)[:g_count], w.reshape(-1, w.shape[-1])[:g_count]


def build_transport(fn: Lighting, normals, views) -> Transport:
    """The transport of ``fn``'s BRDF under ``fn``'s light geometry at grouped pairs (see the module doc)."""
    normals = jnp.asarray(normals)
    t, idx, w = _transport(fn.brdf, fn.env, normals, jnp.asarray(views, normals.dtype), fn.horizon == "centroid")
    return Transport(t, idx, w)


@jax.jit
def _apply(weights, index, cosine, radiance):
    e = cosine @ radiance
    s = jnp.einsum("gmpk,gkc->gmpc", weights, radiance[index])
    return e, s[:, None]


def apply_transport(transport: Transport, radiance) -> LobeSums:
    """E and S (one shape) of a radiance (L, 3) on the transport's light geometry: two matrix products."""
    radiance = jnp.asarray(radiance, transport.cosine.dtype)
    e, s = _apply(transport.weights, transport.index, transport.cosine, radiance)
    return LobeSums(e, s)


@jax.jit
def _transported(weights, index, cosine, radiance, kd, colours, normals, views, flat, clamp):
    """``kd/pi E + sum_m c_m S_m`` at the flat indices ``flat`` of the (G, P) pairs, one program."""
    e = cosine @ radiance
    s = jnp.einsum("gmpk,gkc->gmpc", weights, radiance[index])
    out = (kd / jnp.pi) * e[:, None, :] + jnp.einsum("mc,gmpc->gpc", colours, s)
    valid = jnp.einsum("gpc,gc->gp", views, normals) > 0
    out = jnp.minimum(jnp.where(valid[..., None], out, 0.0), clamp)
    return out.reshape(-1, 3)[flat]


def transported_values(transport: Transport, fn: Lighting, normals, views, flat) -> Float[Array, "N 3"]:
    """The lighting of ``fn`` (its BRDF's colours, its environment's radiance) at the flat pair indices
    ``flat`` of grouped pairs from a transport of the same light geometry and BRDF shape (one program:
    the two products of :func:`apply_transport` and :func:`combine`)."""
    dtype = transport.cosine.dtype
    brdf = fn.brdf
    kd = jnp.broadcast_to(jnp.asarray(brdf.params.get("kd", 0.0), dtype), (3,))
    colours = lobe_colors(brdf)
    colours = jnp.stack(colours).astype(dtype) if colours else jnp.zeros((0, 3), dtype)
    clamp = jnp.asarray(jnp.inf if fn.clamp is None else fn.clamp, dtype)
    return _transported(transport.weights, transport.index, transport.cosine, jnp.asarray(fn.env.radiance, dtype),
                        kd, colours, jnp.asarray(normals, dtype), jnp.asarray(views, dtype), jnp.asarray(flat), clamp)


def transport_bytes(groups: int, views: int, env: Environment, lobes: int) -> int:
    """Bytes of a :class:`Transport` (for the memory cap of refits and the estimate)."""
    k = max_visible(env)
    return 4 * (lobes * groups * views * k + groups * (k + int(env.directions.shape[0])))


def lobe_count(brdf: BRDF) -> int:
    """M, the number of scalar lobes of a BRDF's lobe form."""
    return len(MODELS[brdf.model].colors(brdf.params))


__all__ = ["COLOUR_PARAMS", "LobeSums", "Transport", "apply_transport", "build_transport", "combine", "combine_many",
           "geometry_key", "lobe_count", "lobe_sums", "shape_key", "shape_params", "stack", "supported",
           "transport_bytes", "transported_values"]
