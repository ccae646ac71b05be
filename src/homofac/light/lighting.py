"""The lighting computation L(v, n) of an isotropic BRDF under an environment (pinned, physical).

docs/conventions.md, thesis eq. 61 / Latta-Kolb eq. 6, discretised over the light texels k with their exact
solid angles (Latta & Kolb 2002 eq. 10, not the eq. 11 approximation):

    L(v, n) = sum_k f(w(l_k), w(v)) L_i(l_k) w_k(n),    w_k(n) = integral over texel k of max(n . l, 0) dl

with w(.) the direction in the local frame (t(n), n x t(n), n) of Latta-Kolb eq. 6. The cosine weight
w_k(n) is the pinned ``max(n . l_k, 0) dw_k`` integrated exactly over the texel (:mod:`.geometry`;
equal to second order, and exact where the texel-centre form is not: sum_k w_k(n) = pi, so a white
Lambertian surface under uniform radiance 1 gives exactly 1). For the few texels straddling the
horizon of n the BRDF is evaluated at the centroid of their visible part (``horizon="centroid"``, the
default) rather than at their centre, which may lie below the horizon (BRDF 0) or just above it
(where a lobe growing like 1/cos, as Cook-Torrance's V-cavity one at grazing views, is huge): measured
on the bundled forest map, the sum then moves by 0.27 % (gold) and 0.12 % (plastic) between light
resolutions 128 and 256 instead of 0.88 % and 0.60 % (``benchmarks/accuracy.py`` checks its ground
truth that way). Pairs with n . v <= 0 are invalid (the
samplers never produce them; here they evaluate to 0).

How it is computed (docs/architecture.md, "Performance"):

* dot products with the lights are matmuls of (B, 3) @ (3, L) arrays, not (B, L, 3) broadcasts;
* work is chunked with ``lax.map`` so memory stays bounded (never N x L x 3 at once);
* the Lambertian part kd/pi of a model depends on n only: it is ``kd/pi E(n)`` with the irradiance
  E(n) = sum_k L_i w_k(n); the BRDF is evaluated for the remaining (specular) part only, and not at
  all for a purely Lambertian model;
* :meth:`Lighting.grouped` (used by sampling) takes many views per normal: weights, the local light
  frame and the diffuse term are computed once per normal, and only the lights above its horizon
  (about half) are evaluated;
* optional light culling (:func:`cull_lights`) drops the weakest lights under a stated error bound;
* optional two-level light sum (``Lighting(tree=...)``, :mod:`.tree`): coarse cells of lights, the
  largest per view and the brightest per normal summed over their lights (the plan's refined validation
  lighting, :func:`homofac.fit.validation.light_sum`).
"""

from __future__ import annotations

from typing import Optional

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .. import sphere
from ..brdf.core import has_lobes, lobe_colors, lobe_support, lobe_terms
from ..compiling import jit
from ..errors import HomofacError
from ..param import parametrizations as pz
from ..param import projections as pj
from ..target import Target, evaluate
from .environment import Environment, dominant_direction
from .geometry import cosine_weights, light_geometry
from .lights import light_corners, light_moments
from .tree import LightTree, texel_resolution

#: Pairs per inner chunk of the arbitrary-pair path is CHUNK // 4 (B x L x 4 x 3 weight terms live at once).
CHUNK = 256


#: Light terms (views x light slots) per lax.map step of the grouped lighting computation: bounds the
#: temporaries of one step (and keeps them near the caches) while giving each step enough work.
STEP_TERMS = 1 << 20


def _split_diffuse(brdf):
    """(specular-only BRDF or None, kd (3,) or None): the kd/pi term is handled through E(n)."""
    params = getattr(brdf, "params", None)
    if not isinstance(params, dict) or "kd" not in params:
        return brdf, None
    kd = jnp.broadcast_to(jnp.asarray(params["kd"]), (3,))
    if getattr(brdf, "model", "") == "lambert":
        return None, kd
    spec = eqx.tree_at(lambda b: b.params, brdf, {**params, "kd": jnp.zeros_like(jnp.asarray(params["kd"]))})
    return spec, kd


def _specular_sum(brdf, spec, wi, wo, weights, rad):
    """sum_k f_spec(wi_k, wo) weights_k rad_k -> (..., 3), with the local directions wi, wo given as
    component triples of broadcastable arrays (wi (..., K), wo (..., 1)), weights (..., K) or None
    (already folded into rad), rad (K, 3).

    For a model with a lobe form (``ModelSpec.lobes``) the sum is one (..., K) @ (K, 3) matmul per
    scalar lobe, times the lobe's RGB colour: the BRDF is evaluated once per (view, light), not per
    channel, and the reduction runs as a matrix product. Otherwise the specular BRDF ``spec`` (kd
    zeroed) is evaluated in RGB and reduced with an einsum.
    """
    if has_lobes(brdf):
        out = 0.0
        for g, c in zip(lobe_terms(brdf, wi, wo), lobe_colors(brdf)):
            out = out + c * ((g if weights is None else g * weights) @ rad)
        return out
    wi3 = jnp.stack(jnp.broadcast_arrays(*wi, *wo)[:3], axis=-1)
    wo3 = jnp.stack(jnp.broadcast_arrays(*wi, *wo)[3:], axis=-1)
    f = spec(wi3, wo3)
    if weights is None:
        return jnp.einsum("...kc,kc->...c", f, rad)
    return jnp.einsum("...k,...kc,kc->...c", weights, f, rad)


def max_visible(env: Environment) -> int:
    """Static bound on the number of lights with w_k(n) > 0 for any n: half the cube texels plus the
    ones straddling the horizon (at most 3 r measured; 6 r allowed), plus every delta light; an
    environment of mixed texel sizes states its own (``info["max_visible"]``, :func:`.refine.mixture`)."""
    r = int(env.info.get("resolution", 0))
    L = int(env.directions.shape[0])
    if "max_visible" in env.info:
        return min(L, int(env.info["max_visible"]))
    n_tex = 6 * r * r if r > 0 and 6 * r * r <= L else 0
    if n_tex == 0:
        return L
    return min(L, 3 * r * r + 6 * r + (L - n_tex))


def _pair_radiance(brdf, spec, kd, dirs, power_rad, geom, n, v, centroid=False):
    """L(v, n) for a chunk of arbitrary pairs: n, v (B, 3)."""
    if centroid:
        w, (sidx, cent) = cosine_weights(n, geom, select=True, centroids=True)
    else:
        w = cosine_weights(n, geom, select=True)  # (B, L) exact clamped-cosine texel integrals
    out = jnp.zeros(n.shape[:-1] + (3,), n.dtype)
    if kd is not None:
        out = out + (kd / jnp.pi) * (w @ power_rad)  # kd/pi * E(n)
    if spec is not None:
        t, b, nn = sphere.frame(n)
        wi = (t @ dirs.T, b @ dirs.T, nn @ dirs.T)  # local light directions, 3 x (B, L) via matmuls
        if centroid:  # straddling texels: the BRDF at the centroid of their visible part
            rows = jnp.arange(n.shape[0])[:, None]
            wi = tuple(c.at[rows, sidx].set(jnp.einsum("bkx,bx->bk", cent, axis), mode="drop")
                       for c, axis in zip(wi, (t, b, nn)))
        wo = sphere.to_local(v, t, b, nn)
        out = out + _specular_sum(brdf, spec, wi, tuple(wo[:, None, c] for c in range(3)), w, power_rad)
    valid = sphere.dot(n, v) > 0
    return jnp.where(valid[:, None], out, 0.0)


def _normal_radiance(brdf, spec, kd, dirs, rad, geom, k, n, v, centroid=False):
    """L(v_p, n) for one normal n (3,) and views v (P, 3): weights once per normal, only the k lights
    with the largest w_k(n) (all the visible ones, see :func:`max_visible`) are evaluated."""
    if centroid:
        w, (sidx, cent) = cosine_weights(n[None], geom, select=True, centroids=True)
        w = w[0]
        dirs = dirs.at[sidx[0]].set(cent[0], mode="drop")  # straddlers: their visible centroids
    else:
        w = cosine_weights(n[None], geom, select=True)[0]  # (L,)
    out = jnp.zeros(v.shape[:-1] + (3,), v.dtype)
    if kd is not None:
        out = out + (kd / jnp.pi) * (w @ rad)
    if spec is not None:
        # compact the visible lights (w > 0, about half) into k slots: cumsum, no sort
        vis = w > 0
        slot = jnp.where(vis, jnp.cumsum(vis) - 1, k)
        idx = jnp.zeros((k,), jnp.int32).at[slot].set(jnp.arange(w.shape[0], dtype=jnp.int32), mode="drop")
        wk = jnp.zeros((k,), w.dtype).at[slot].set(w, mode="drop")
        radk = rad[idx]
        t, b, nn = sphere.frame(n)
        frame = jnp.stack([t, b, nn], axis=1)  # (3, 3): columns t, b, n
        wi = dirs[idx] @ frame  # (k, 3) local light directions, once per normal
        wo = v @ frame  # (P, 3)
        out = out + _specular_sum(brdf, spec, tuple(wi[None, :, c] for c in range(3)),
                                  tuple(wo[:, None, c] for c in range(3)), None, wk[:, None] * radk)
    valid = v @ n > 0
    return jnp.where(valid[:, None], out, 0.0)


def _lobe_sums(brdf, spec, wi, wo, wrad, lum):
    """The specular sum over lights k of f_spec(wi_k, wo) wrad_k -> (..., 3), and the luminance of each
    light's term (..., K), with wi, wo component triples of broadcastable arrays (wi (..., K), wo
    (..., 1)) and wrad (..., K, 3) the cosine-weighted radiance (or (K, 3), shared: then the sum is a
    matmul). A model's lobe form is used where it has one (one evaluation per lobe, not per channel),
    else the specular BRDF ``spec`` in RGB. ``lum`` None: no luminances (returns None for them)."""
    if has_lobes(brdf):
        total, score = 0.0, 0.0
        for g, c in zip(lobe_terms(brdf, wi, wo), lobe_colors(brdf)):
            if wrad.ndim == 2:
                total = total + c * (g @ wrad)
            else:
                total = total + c * jnp.einsum("...k,...kc->...c", g, wrad)
            if lum is not None:
                score = score + g * (wrad @ (c * lum))
        return total, (score if lum is not None else None)
    both = jnp.broadcast_arrays(*wi, *wo)
    f = spec(jnp.stack(both[:3], axis=-1), jnp.stack(both[3:], axis=-1)) * wrad
    return jnp.sum(f, axis=-2), (f @ lum if lum is not None else None)


#: The band above the horizon, in coarse texel widths, whose cells the tree refines first per normal: at a
#: grazing view a cell's estimate there (the BRDF at its mean direction) can be far below the sum over its
#: lights, as the lobe grows like 1 / cos towards the horizon.
HORIZON_BAND = 2.0


#: Luminance weights of the refinement score (Rec. 709, as :func:`.environment.luminance`).
_LUM = (0.2126, 0.7152, 0.0722)


def _normal_radiance_tree(brdf, spec, kd, dirs, rad, geom, tree, n, v, centroid=False):
    """L(v_p, n) for one normal n (3,) and views v (P, 3) by the two-level light sum of ``tree``
    (:mod:`.tree`; Walter et al. 2005, Lightcuts, cut by the largest estimates).

    Per normal: the exact texel weights w_k(n) (as :func:`_normal_radiance`), each coarse cell j's summed
    cosine-weighted radiance W_j = sum_{k in j} w_k(n) L_k and its direction d_j, the mean of its lights'
    directions weighted by w_k(n) lum(L_k) (the aggregate is exact for a BRDF linear across the cell). Per
    view: the cells' estimates c_j = f(d_j, v) W_j, and the ``tree.refine`` cells of largest lum(c_j) (the
    BRDF's own values: any model, measured ones included) replaced by the sum over their lights, as are the
    ``tree.bright`` cells of largest power lum(W_j) of the normal, those within :data:`HORIZON_BAND` coarse
    texels of its horizon first, for every view (at a grazing view a cell's estimate near the horizon can be
    far below its value, as the lobe grows like 1 / cos there; these need no per-view gather):

        L(v, n) = kd/pi E(n) + sum_j c_j - sum_{j in top} c_j + sum_{j in top} sum_{k in j} f(l_k, v) w_k(n) L_k.

    Where ``tree.refine`` covers every visible cell this is the full sum of eq. 10 (to float rounding).
    """
    if centroid:
        w, (sidx, cent) = cosine_weights(n[None], geom, select=True, centroids=True)
        w = w[0]
        dirs = dirs.at[sidx[0]].set(cent[0], mode="drop")
    else:
        w = cosine_weights(n[None], geom, select=True)[0]
    out = jnp.zeros(v.shape[:-1] + (3,), v.dtype)
    if kd is not None:
        out = out + (kd / jnp.pi) * (w @ rad)
    if spec is not None:
        lum = jnp.asarray(_LUM, v.dtype)
        ch = tree.children  # (C, M); index L is "no light"
        wx = jnp.concatenate([w, jnp.zeros((1,), w.dtype)])
        wrx = jnp.concatenate([w[:, None] * rad, jnp.zeros((1, 3), rad.dtype)])
        t, b, nn = sphere.frame(n)
        frame = jnp.stack([t, b, nn], axis=1)  # (3, 3): columns t, b, n
        dloc = jnp.concatenate([dirs @ frame, nn[None] @ frame])  # (L + 1, 3) local light directions
        # the visible cells (a light with w > 0) compacted into tree.slots places (cumsum, no sort)
        vis = jnp.sum(wx[ch], axis=1) > 0
        slot = jnp.where(vis, jnp.cumsum(vis) - 1, tree.slots)
        cells = jnp.full((tree.slots,), 0, jnp.int32).at[slot].set(jnp.arange(ch.shape[0], dtype=jnp.int32), mode="drop")
        used = jnp.zeros((tree.slots,), bool).at[slot].set(True, mode="drop")
        kids = jnp.where(used[:, None], ch[cells], wx.shape[0] - 1)  # (S, M)
        wr_k = wrx[kids]  # (S, M, 3)
        d_k = dloc[kids]  # (S, M, 3)
        a = wr_k @ lum + 1e-12 * wx[kids]  # (S, M): the direction's weights (w alone for a black cell)
        dc = jnp.sum(a[..., None] * d_k, axis=1)
        dc = dc / jnp.maximum(jnp.linalg.norm(dc, axis=-1, keepdims=True), 1e-30)  # (S, 3)
        wrc = jnp.sum(wr_k, axis=1)  # (S, 3)
        cell = jnp.concatenate([d_k, wr_k], axis=-1)  # (S, M, 6): a refined cell's lights in one gather
        wo = v @ frame  # (P, 3)
        wo3 = tuple(wo[:, None, c] for c in range(3))
        total, score = _lobe_sums(brdf, spec, tuple(dc[None, :, c] for c in range(3)), wo3, wrc, lum)  # (P, 3), (P, S)
        if tree.bright:  # the normal's brightest cells, those near its horizon first, refined for every view
            low = dc[:, 2] < HORIZON_BAND * (jnp.pi / 2) / tree.coarse  # within about two coarse texels of it
            _, hot = jax.lax.top_k((wrc @ lum) * jnp.where(low, 1e6, 1.0), tree.bright)  # (B,)
            score = jnp.where(jnp.zeros(score.shape[1:], bool).at[hot].set(True)[None], -jnp.inf, score)
            lit = cell[hot].reshape(-1, 6)  # (B M, 6)
            fine_b, _ = _lobe_sums(brdf, spec, tuple(lit[None, :, c] for c in range(3)), wo3, lit[:, 3:], None)
            chosen_b, _ = _lobe_sums(brdf, spec, tuple(dc[None, hot, c] for c in range(3)), wo3, wrc[hot], None)
            total = total - chosen_b + fine_b
        _, top = jax.lax.top_k(score, tree.refine)  # (P, K)
        chosen, _ = _lobe_sums(brdf, spec, tuple(dc[top, c] for c in range(3)), wo3, wrc[top], None)
        p = v.shape[0]
        sel = cell[top].reshape(p, -1, 6)  # (P, K M, 6)
        fine, _ = _lobe_sums(brdf, spec, tuple(sel[..., c] for c in range(3)), wo3, sel[..., 3:], None)
        out = out + (total - chosen) + fine
    valid = v @ n > 0
    return jnp.where(valid[:, None], out, 0.0)


#: Views per lobe-culling cluster: each cluster of consecutive views of a normal shares one cone of lights.
CULL_CLUSTER = 16


def _normal_radiance_culled(brdf, kd, dirs, rad, geom, cos_s, slots, n, v, centroid=False):
    """L(v_p, n) for one normal with lobe culling (:class:`Lighting` ``lobe_tolerance``).

    The P views are split into clusters of :data:`CULL_CLUSTER`. A cluster's mirror directions
    r = 2 (n.v) n - v lie within angle rho of their mean axis; a light farther than theta_s + rho from
    the axis is farther than theta_s from every r of the cluster, where every lobe is below delta x its
    peak (``ModelSpec.support``). Only the visible lights inside the cone are evaluated, compacted into
    ``slots`` places (cumsum, no sort). Returns the values (P, 3) and the largest number of lights a
    cone held: when it exceeds ``slots`` some were left out, and the caller reruns with more slots.
    ``centroid``: straddling texels are evaluated (and tested against the cone) at the centroid of
    their visible part, as in :func:`_normal_radiance`.
    """
    if centroid:
        w, (sidx, cent) = cosine_weights(n[None], geom, select=True, centroids=True)
        w = w[0]
        dirs = dirs.at[sidx[0]].set(cent[0], mode="drop")
    else:
        w = cosine_weights(n[None], geom, select=True)[0]  # (L,)
    out = jnp.zeros(v.shape[:-1] + (3,), v.dtype)
    if kd is not None:
        out = out + (kd / jnp.pi) * (w @ rad)
    vn = v @ n
    valid = vn > 0
    r = 2.0 * vn[:, None] * n[None, :] - v  # (P, 3) mirror directions
    q = v.shape[0] // CULL_CLUSTER
    rc = r.reshape(q, CULL_CLUSTER, 3)
    vc = valid.reshape(q, CULL_CLUSTER)
    s = jnp.sum(jnp.where(vc[..., None], rc, 0.0), axis=1)
    axis = s / jnp.maximum(jnp.linalg.norm(s, axis=-1, keepdims=True), 1e-20)  # (Q, 3)
    cos_rho = jnp.min(jnp.where(vc, jnp.einsum("qcx,qx->qc", rc, axis), 1.0), axis=1)
    theta = jnp.arccos(jnp.clip(cos_s, -1.0, 1.0)) + jnp.arccos(jnp.clip(cos_rho, -1.0, 1.0))
    cone = jnp.cos(jnp.minimum(theta, jnp.pi)) - 1e-6  # rounding margin: keep lights on the boundary
    sel = (w > 0)[None, :] & (axis @ dirs.T >= cone[:, None]) & jnp.any(vc, axis=1)[:, None]  # (Q, L)
    count = jnp.sum(sel, axis=1)
    slot = jnp.where(sel, jnp.cumsum(sel, axis=1) - 1, slots)
    rows = jnp.arange(q)[:, None]
    lights = jnp.broadcast_to(jnp.arange(w.shape[0], dtype=jnp.int32), sel.shape)
    idx = jnp.zeros((q, slots), jnp.int32).at[rows, slot].set(lights, mode="drop")
    wk = jnp.zeros((q, slots), w.dtype).at[rows, slot].set(jnp.broadcast_to(w, sel.shape), mode="drop")
    t, b, nn = sphere.frame(n)
    frame = jnp.stack([t, b, nn], axis=1)
    wi = dirs[idx] @ frame  # (Q, slots, 3)
    wo = v.reshape(q, CULL_CLUSTER, 3) @ frame  # (Q, C, 3)
    spec = 0.0
    for g, c in zip(lobe_terms(brdf, tuple(wi[:, None, :, k] for k in range(3)),
                               tuple(wo[:, :, None, k] for k in range(3))), lobe_colors(brdf)):
        spec = spec + c * ((g * wk[:, None, :]) @ rad[idx])  # (Q, C, slots) @ (Q, slots, 3)
    out = out + spec.reshape(-1, 3)
    return jnp.where(valid[:, None], out, 0.0), jnp.max(count)


class Lighting(eqx.Module):
    """L(v, n) of ``brdf`` under ``env`` as a callable pytree: ``lighting(n, v) -> (N, 3)``.

    Differentiable w.r.t. the BRDF parameters and the environment radiance. :meth:`grouped` evaluates
    many views per normal and is what sampling uses: the texel weights and the local light frame are
    computed once per normal and lights below its horizon are skipped.
    """

    brdf: eqx.Module
    env: Environment
    clamp: Optional[float] = eqx.field(static=True, default=None)
    chunk: int = eqx.field(static=True, default=CHUNK)
    #: lobe culling (:meth:`grouped_culled`): lights where every lobe is below this fraction of its peak
    #: are skipped; None: off. Only for models with ``ModelSpec.support`` (the Phong family).
    lobe_tolerance: Optional[float] = eqx.field(static=True, default=None)
    #: where the BRDF is evaluated for texels straddling the horizon of n: ``centroid`` (the centroid of
    #: the texel's visible part, the default) or ``centre`` (the texel centre, the plain sum of eq. 10).
    horizon: str = eqx.field(static=True, default="centroid")
    #: the two-level light sum of :meth:`grouped` (:func:`.tree.light_tree` of ``env``); None: every light.
    tree: Optional[LightTree] = None

    @property
    def culls_lobes(self) -> bool:
        """True when lobe culling is on and the BRDF has a lobe support (see :func:`lobe_support`)."""
        return self.lobe_tolerance is not None and lobe_support(self.brdf, self.lobe_tolerance) is not None

    def lobe_bound(self, n: Float[Array, "N 3"]) -> Float[Array, "N 3"]:
        """The stated error bound of lobe culling at normals n: every skipped light has each lobe m below
        delta x peak_m, so L(v, n) drops by at most ``delta * sum_m |colour_m| peak_m * E(n)`` per channel,
        E(n) the irradiance (the sum of the cosine-weighted radiance)."""
        cos_s, peaks = lobe_support(self.brdf, self.lobe_tolerance)
        scale = sum(jnp.abs(c) * pk for c, pk in zip(lobe_colors(self.brdf), peaks))
        return self.lobe_tolerance * scale * irradiance(self.env, n)

    def lobe_slots(self) -> int:
        """A first guess of the lights per cone: the support cone widened by 20 degrees for the cluster,
        times the number of lights, rounded up to a multiple of 32."""
        cos_s, _ = lobe_support(self.brdf, self.lobe_tolerance)
        theta = float(np.arccos(np.clip(float(cos_s), -1, 1))) + np.radians(20.0)
        frac = (1.0 - np.cos(min(theta, np.pi))) / 2.0
        return int(min(max_visible(self.env), 32 * np.ceil(1.5 * frac * self.n_lights / 32)))

    def grouped_culled(self, normals: Float[Array, "G 3"], views: Float[Array, "G P 3"], slots: int):
        """:meth:`grouped` with lobe culling in ``slots`` places per cone; returns (values, the largest
        number of lights a cone held). Values are exact up to :meth:`lobe_bound` when that number is at
        most ``slots`` (else lights were left out: call again with more)."""
        _, kd = _split_diffuse(self.brdf)
        dirs, rad, geom = self._arrays(normals.dtype)
        cos_s, _ = lobe_support(self.brdf, self.lobe_tolerance)
        g_count, p = views.shape[0], views.shape[1]
        views = views.astype(normals.dtype)
        pad_p = (-p) % CULL_CLUSTER  # pad the views with invalid ones (v = -n gives n.v < 0)
        if pad_p:
            views = jnp.concatenate([views, jnp.broadcast_to(-normals[:, None, :], (g_count, pad_p, 3))], axis=1)
        pp = views.shape[1]
        per = int(max(1, min(g_count, STEP_TERMS // max(1, pp * slots))))
        pad = (-g_count) % per
        if pad:
            normals = jnp.concatenate([normals, jnp.broadcast_to(normals[:1], (pad, 3))])
            views = jnp.concatenate([views, jnp.broadcast_to(views[:1], (pad, pp, 3))])
        one = lambda n, v: _normal_radiance_culled(self.brdf, kd, dirs, rad, geom, cos_s, slots, n, v,  # noqa: E731
                                                   self.horizon == "centroid")
        out, count = jax.lax.map(lambda nv: jax.vmap(one)(nv[0], nv[1]),
                                 (normals.reshape(-1, per, 3), views.reshape(-1, per, pp, 3)))
        return self._clamp(out.reshape(-1, pp, 3)[:g_count, :p]), jnp.max(count)

    @property
    def n_lights(self) -> int:
        return int(self.env.directions.shape[0])

    def _arrays(self, dtype):
        e = self.env
        dirs = e.directions.astype(dtype)
        # the straddler bound follows the smallest texels (a refined mixture's fine ones, a block's source's)
        res = texel_resolution(e)
        geom = light_geometry(dirs, e.solid_angle.astype(dtype), light_corners(e).astype(dtype), res,
                              moments=light_moments(e))
        return dirs, e.radiance.astype(dtype), geom

    def __call__(self, n: Float[Array, "N 3"], v: Float[Array, "N 3"]) -> Float[Array, "N 3"]:
        spec, kd = _split_diffuse(self.brdf)
        dirs, rad, geom = self._arrays(n.dtype)
        count = n.shape[0]
        c = max(1, min(self.chunk // 4, count))
        pad = (-count) % c
        if pad:
            n = jnp.concatenate([n, jnp.broadcast_to(n[:1], (pad, 3))])
            v = jnp.concatenate([v, jnp.broadcast_to(v[:1], (pad, 3))])
        out = jax.lax.map(
            lambda nv: _pair_radiance(self.brdf, spec, kd, dirs, rad, geom, nv[0], nv[1], self.horizon == "centroid"),
            (n.reshape(-1, c, 3), v.reshape(-1, c, 3)),
        ).reshape(-1, 3)[:count]
        return self._clamp(out)

    def grouped(self, normals: Float[Array, "G 3"], views: Float[Array, "G P 3"]) -> Float[Array, "G P 3"]:
        """L(v_gp, n_g) for G normals with P views each (invalid views give 0); by the two-level light sum
        where ``tree`` is set (:func:`_normal_radiance_tree`)."""
        spec, kd = _split_diffuse(self.brdf)
        dirs, rad, geom = self._arrays(normals.dtype)
        k = max_visible(self.env) if self.tree is None else (
            self.tree.slots + (self.tree.refine + self.tree.bright) * self.tree.width)
        g_count, p = views.shape[0], views.shape[1]
        # several normals per lax.map step (vmapped) so each step has a few million light terms
        per = int(max(1, min(g_count, STEP_TERMS // max(1, p * k))))
        pad = (-g_count) % per
        views = views.astype(normals.dtype)
        if pad:
            normals = jnp.concatenate([normals, jnp.broadcast_to(normals[:1], (pad, 3))])
            views = jnp.concatenate([views, jnp.broadcast_to(views[:1], (pad, p, 3))])
        if self.tree is None or spec is None:
            one = lambda n, v: _normal_radiance(self.brdf, spec, kd, dirs, rad, geom, max_visible(self.env), n, v,  # noqa: E731
                                                self.horizon == "centroid")
        else:
            one = lambda n, v: _normal_radiance_tree(self.brdf, spec, kd, dirs, rad, geom, self.tree, n, v,  # noqa: E731
                                                     self.horizon == "centroid")
        out = jax.lax.map(
            lambda nv: jax.vmap(one)(nv[0], nv[1]),
            (normals.reshape(-1, per, 3), views.reshape(-1, per, p, 3)),
        ).reshape(-1, p, 3)[:g_count]
        return self._clamp(out)

    def _weights(self, n):
        """Exact cosine weights w_k(n) (B, L) of this environment's lights."""
        _, _, geom = self._arrays(n.dtype)
        return cosine_weights(n, geom, select=True)

    def _clamp(self, out):
        return out if self.clamp is None else jnp.minimum(out, self.clamp)


def irradiance(env: Environment, n: Float[Array, "N 3"]) -> Float[Array, "N 3"]:
    """E(n) = sum_k L_i(l_k) w_k(n): the lighting of a white Lambertian surface times pi (one compiled
    program: op by op, the texel weights of an irradiance map took 3x the CPU time)."""
    return _irradiance(env, jnp.asarray(n))


@jit(kind="texture", filter=True)
def _irradiance(env: Environment, n):
    return Lighting(None, env)._weights(n) @ env.radiance.astype(n.dtype)


def lighting(brdf, env: Environment, n, v, *, clamp: float | None = None, horizon: str = "centroid") -> Float[Array, "N 3"]:
    """Exact L(v, n) at arbitrary arrays of normals and views (the ground truth of every metric);
    ``horizon``: where f is evaluated for texels straddling n's horizon (see :class:`Lighting`)."""
    n = jnp.asarray(n)
    v = jnp.asarray(v, n.dtype)
    shape = n.shape
    out = evaluate(Lighting(brdf, env, clamp, horizon=horizon), n.reshape(-1, 3), v.reshape(-1, 3))
    return out.reshape(shape)


def lighting_target(brdf, env: Environment, *, parametrization: str | None = None, clamp: float | None = None,
                    lobe_tolerance: float | None = None, shift: float | None = None) -> Target:
    """Target of a lighting factorization (Latta & Kolb 2002): a = n, b = v.

    The context the parametrization's projections read is filled in (:func:`with_context`): for
    ``NRHD`` the dominant light direction (thesis eq. 66), for ``NRO`` and ``RO`` beta of the
    off-specular reflection (``shift``; default from the BRDF's roughness).
    ``lobe_tolerance`` turns lobe culling on for sampling (:meth:`Lighting.grouped_culled`; Phong family).
    """
    if clamp is not None and not (np.isfinite(clamp) and clamp > 0):
        raise HomofacError(f"target.clamp must be a positive number, got {clamp}")
    if lobe_tolerance is not None and not (np.isfinite(lobe_tolerance) and 0 < lobe_tolerance < 1):
        raise HomofacError(f"target.lobe_cull must be in (0, 1), got {lobe_tolerance}")
    target = Target("lighting", Lighting(brdf, env, clamp, lobe_tolerance=lobe_tolerance), "lighting", {})
    return with_context(target, parametrization, shift=shift)


#: beta of ``r_off`` for a BRDF without a microfacet roughness (measured tables, Phong lobes).
DEFAULT_SHIFT = 0.15


def off_specular_shift(brdf) -> float:
    """beta of the off-specular reflection ``r_off`` (:mod:`homofac.param.projections`) for ``brdf``:
    its roughness (Beckmann m, GGX or Ward alpha: the lobe's angular width) clipped to [0.05, 0.15],
    else :data:`DEFAULT_SHIFT`. ``r_off`` lifts a grazing ``r`` by ``atan(beta)``. Measured (``E'+ROW+R``,
    grid ALS, S = 32, nrmse against the converged ground truth; docs/notes/sums-research.md#off-specular-products):
    the near-mirror (roughness 0.1) is best at 0.1 (0.46; 0.15: 0.48, 0.3: 0.60), gold (0.3) at 0.2
    (0.388; 0.15: 0.395, 0.3: 0.414), the plastic (0.6) at 0.1-0.15 (interior 0.192 / 0.199, 0.3:
    0.268; studio 0.15: 0.284, 0.3: 0.378, 0.6: 0.511)."""
    rough = getattr(brdf, "params", {}).get("roughness") if brdf is not None else None
    if rough is None:
        return DEFAULT_SHIFT
    return float(np.clip(np.mean(np.asarray(rough, np.float64)), 0.05, 0.15))


def with_context(target: Target, parametrization: str, *, shift: float | None = None) -> Target:
    """``target`` with the context keys ``parametrization``'s projections read and it lacks: the
    dominant light direction (NRHD, thesis eq. 66) and beta of the off-specular reflection (NRO, RO;
    ``shift``, default :func:`off_specular_shift` of the BRDF)."""
    keys = pz.get(parametrization).context if parametrization in pz.PARAMETRIZATIONS else ()
    if shift is not None and "shift" not in keys:
        raise HomofacError(f"shift is beta of the off-specular reflection of NRO and RO, not of {parametrization}")
    add = {}
    if "dominant" in keys and "dominant" not in target.context:
        add["dominant"] = dominant_direction(target.fn.env)
    if "shift" in keys and ("shift" not in target.context or shift is not None):
        add["shift"] = pj.check_context("shift", off_specular_shift(target.fn.brdf) if shift is None else shift)
    return Target(target.kind, target.fn, target.quantity, {**target.context, **add}) if add else target

