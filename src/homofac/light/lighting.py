"""The lighting computation L(v, n) of an isotropic BRDF under an environment (pinned, physical).

DESIGN.md, thesis eq. 61 / Latta-Kolb eq. 6, discretised with exact texel solid angles (thesis eq. 10
rather than the eq. 11 approximation):

    L(v, n) = sum_k f(w(l_k), w(v)) L_i(l_k) max(n . l_k, 0) dw_k

with w(.) the direction in the local frame (t(n), n x t(n), n) of Latta-Kolb eq. 6. A white Lambertian
surface under uniform radiance 1 gives exactly 1. Pairs with n . v <= 0 are invalid (the caller never
samples them; here they evaluate to 0).

How it is computed (DESIGN.md "Performance rules of thumb"):

* all dot products with the lights are matmuls of (B, 3) @ (3, L) arrays;
* pairs are processed in chunks with ``lax.map`` so memory stays bounded (never N x L x 3 at once);
* the Lambertian part kd/pi of a model depends on n only: it is ``kd/pi * E(n)`` with the irradiance
  E(n) = sum_k L_i max(n.l_k, 0) dw_k, one (B, L) @ (L, 3) product; the BRDF is evaluated for the
  remaining (specular) part only, and not at all for a purely Lambertian model;
* optional light culling (:func:`cull_lights`) drops the weakest lights under a stated error bound.
"""

from __future__ import annotations

from typing import Optional

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .. import sphere
from ..errors import HomofacError
from ..fit.target import Target
from .environment import Environment, dominant_direction

#: Pairs per inner chunk: B x L x 3 floats live at once (256 x 6144 x 3 x 4 B = 19 MB).
CHUNK = 256


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


def _chunk_radiance(spec, kd, env_dirs_t, power, n, v):
    """L(v, n) for one chunk: n, v (B, 3); env_dirs_t (3, L); power (L, 3) = L_i dw."""
    t, b, nn = sphere.frame(n)
    lt = t @ env_dirs_t  # (B, L) -- matmuls, not (B, L, 3) broadcasts
    lb = b @ env_dirs_t
    ln = nn @ env_dirs_t
    cos = jnp.maximum(ln, 0.0)
    out = jnp.zeros(n.shape[:-1] + (3,), n.dtype)
    if kd is not None:
        out = out + (kd / jnp.pi) * (cos @ power)  # kd/pi * E(n)
    if spec is not None:
        wo = sphere.to_local(v, t, b, nn)  # (B, 3)
        wi = jnp.stack([lt, lb, ln], axis=-1)  # (B, L, 3)
        f = spec(wi, jnp.broadcast_to(wo[:, None, :], wi.shape))  # (B, L, 3)
        out = out + jnp.einsum("bl,blc,lc->bc", cos, f, power)
    valid = sphere.dot(n, v) > 0
    return jnp.where(valid[:, None], out, 0.0)


class Lighting(eqx.Module):
    """L(v, n) of ``brdf`` under ``env`` as a callable pytree: ``lighting(n, v) -> (N, 3)``.

    Differentiable w.r.t. the BRDF parameters and the environment radiance.
    """

    brdf: eqx.Module
    env: Environment
    clamp: Optional[float] = eqx.field(static=True, default=None)
    chunk: int = eqx.field(static=True, default=CHUNK)

    @property
    def n_lights(self) -> int:
        return int(self.env.directions.shape[0])

    def __call__(self, n: Float[Array, "N 3"], v: Float[Array, "N 3"]) -> Float[Array, "N 3"]:
        spec, kd = _split_diffuse(self.brdf)
        dirs_t = self.env.directions.T.astype(n.dtype)
        power = (self.env.radiance * self.env.solid_angle[:, None]).astype(n.dtype)
        count = n.shape[0]
        c = max(1, min(self.chunk, count))
        pad = (-count) % c
        if pad:
            n = jnp.concatenate([n, jnp.broadcast_to(n[:1], (pad, 3))])
            v = jnp.concatenate([v, jnp.broadcast_to(v[:1], (pad, 3))])
        out = jax.lax.map(
            lambda nv: _chunk_radiance(spec, kd, dirs_t, power, nv[0], nv[1]),
            (n.reshape(-1, c, 3), v.reshape(-1, c, 3)),
        ).reshape(-1, 3)[:count]
        if self.clamp is not None:
            out = jnp.minimum(out, self.clamp)
        return out


def irradiance(env: Environment, n: Float[Array, "N 3"]) -> Float[Array, "N 3"]:
    """E(n) = sum_k L_i(l_k) max(n.l_k, 0) dw_k: the lighting of a white Lambertian surface times pi."""
    n = jnp.asarray(n)
    power = (env.radiance * env.solid_angle[:, None]).astype(n.dtype)
    return jnp.maximum(n @ env.directions.T.astype(n.dtype), 0.0) @ power


def lighting(brdf, env: Environment, n, v, *, clamp: float | None = None) -> Float[Array, "N 3"]:
    """Exact L(v, n) at arbitrary arrays of normals and views (the ground truth of every metric)."""
    from ..fit.target import evaluate

    n = jnp.asarray(n)
    v = jnp.asarray(v, n.dtype)
    shape = n.shape
    out = evaluate(Lighting(brdf, env, clamp), n.reshape(-1, 3), v.reshape(-1, 3))
    return out.reshape(shape)


def lighting_target(brdf, env: Environment, *, parametrization: str | None = None, clamp: float | None = None) -> Target:
    """Target of a lighting factorization (Latta & Kolb 2002): a = n, b = v.

    For ``NRHD`` the dominant light direction (thesis eq. 66) is computed and put in the context.
    """
    if clamp is not None and not (np.isfinite(clamp) and clamp > 0):
        raise HomofacError(f"target.clamp must be a positive number, got {clamp}")
    ctx = {}
    if parametrization == "NRHD":
        ctx["dominant"] = dominant_direction(env)
    return Target("lighting", Lighting(brdf, env, clamp), "lighting", ctx)


def cull_lights(env: Environment, tolerance: float) -> tuple[Environment, dict]:
    """Drop the weakest lights whose summed power is at most ``tolerance`` x the total power.

    Error bound (stated and tested): for any BRDF f and any (n, v), the change of L(v, n) per channel is
    at most ``max f * dropped_power`` where dropped_power = sum over dropped lights of L_i dw <=
    tolerance * total power (since max(n.l, 0) <= 1). For a Lambertian BRDF, max f = kd/pi.
    """
    if not 0 <= tolerance < 1:
        raise HomofacError(f"light culling tolerance must be in [0, 1), got {tolerance}")
    power = np.asarray(env.radiance * env.solid_angle[:, None], np.float64)
    lum = power.sum(axis=1)
    order = np.argsort(lum)
    cum = np.cumsum(lum[order])
    total = max(float(lum.sum()), 1e-300)
    n_drop = int(np.searchsorted(cum, tolerance * total, side="right"))
    keep = np.sort(order[n_drop:])
    dropped = power[order[:n_drop]].sum(axis=0) if n_drop else np.zeros(3)
    culled = Environment(
        directions=env.directions[keep], radiance=env.radiance[keep], solid_angle=env.solid_angle[keep],
        info={**env.info, "culled_lights": n_drop},
    )
    return culled, {"dropped": n_drop, "kept": int(keep.size), "dropped_power": dropped.tolist(),
                    "total_power": power.sum(axis=0).tolist()}
