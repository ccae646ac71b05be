"""``kautz_mccool``: prefiltered environment maps with a radially symmetric lobe per view elevation
(Kautz & McCool 2000, "Approximation of glossy reflection with prefiltered environment maps").

For view cosines ``x_s`` (the view elevation, n.v = n.r), the BRDF's lobe ``f(wi, wo_s)`` (the specular
part: kd removed when the model has one) is made radially symmetric about the mirror direction r: its
*mean profile* ``p_s(theta)`` is the average of f over the azimuth about r at angle theta from r (§3.1;
this implementation keeps the lobe centred on r, without the paper's peak offset), tabulated densely
in theta. Each lobe is scaled so that the approximation reproduces the BRDF's directional albedo, and
the environment is prefiltered with it, approximating n.l by n.r as the paper does (eq. 2):

    E_s(r) = sum_k p_s(r.l_k) L_k dw_k,     L(v, n) ~ kd/pi E(n) + (n.v) sum_s k_s E_s(r) t_s(n.v)

* ``slices: 1`` -- the single 2D lobe of §3.2: one profile (the average of the normalized profiles
  over the view elevations) and the weight k(x) x as a 1D texture, exactly a term P(r) W(n.v);
* ``slices: K > 1`` -- the 3D map of §3.1 / §5.1 with K slices in view elevation: K terms P_s(r) T_s(n.v),
  T_s the tent of slice s on a K-texel ``line`` texture, so the GPU's linear filter interpolates between
  slices exactly as a 3D texture would.

It works for any isotropic BRDF, measured ones included (a MERL table has no separate kd: its whole
lobe is prefiltered). Lookups: 1 (E, when kd is known) + 2 per slice.
"""

from __future__ import annotations

from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from pydantic import Field

from ..brdf import make
from ..brdf.core import BRDF
from ..factorization import Factor, Factorization, Term, Texture
from ..light import Environment
from ..options import Options
from ..param import mappers
from .base import Baseline, centres, directional_albedo, irradiance_map, light_sums, lighting_parts

#: Samples of a profile in t = sqrt(theta / pi) (dense near the lobe's centre) and azimuths averaged over.
PROFILE_SAMPLES = 1024
AZIMUTHS = 64


class KautzMcCoolOptions(Options):
    """Options of ``kautz_mccool``: the number of view-elevation slices (1: the single 2D lobe)."""

    TAG: ClassVar[str] = "kautz_mccool"
    slices: int = Field(1, ge=1, le=64)
    line_size: int = Field(32, ge=2, le=4096, description="texels of the 1D weight texture (slices: 1)")


def _specular(brdf: BRDF) -> tuple[BRDF, np.ndarray | None]:
    """The BRDF without its Lambertian part, and kd (None when the model has no kd: measured data)."""
    if "kd" not in brdf.params:
        return brdf, None
    kd = np.asarray(brdf.params["kd"], np.float64)
    params = {k: np.asarray(v) for k, v in brdf.params.items()}
    return make(brdf.model, **{**params, "kd": 0.0}), kd


@eqx.filter_jit
def _profile(brdf: BRDF, x: jax.Array, theta: jax.Array, psi: jax.Array) -> jax.Array:
    """Mean over azimuths ``psi`` about the mirror direction of f(wi, wo) at angles ``theta`` from it:
    ``(theta, 3)`` for the view cosine ``x`` (local frame, plane of incidence xz)."""
    s = jnp.sqrt(jnp.clip(1.0 - x * x, 0.0, 1.0))
    wo = jnp.stack([s, 0.0, x])
    r = jnp.stack([-s, 0.0, x])
    t1 = jnp.stack([x, 0.0, s])  # orthonormal to r in the plane of incidence
    t2 = jnp.asarray([0.0, 1.0, 0.0])
    ct, st = jnp.cos(theta)[:, None, None], jnp.sin(theta)[:, None, None]
    az = jnp.cos(psi)[None, :, None] * t1 + jnp.sin(psi)[None, :, None] * t2
    wi = ct * r + st * az  # (T, A, 3)
    return jnp.mean(brdf(wi, wo), axis=1)


def profiles(brdf: BRDF, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(theta (T,), p (len(x), T, 3))``: the mean profiles of the lobes at view cosines ``x``."""
    t = np.linspace(0.0, 1.0, PROFILE_SAMPLES)
    theta = np.pi * t * t
    psi = 2 * np.pi * np.arange(AZIMUTHS) / AZIMUTHS
    p = np.stack([np.asarray(_profile(brdf, jnp.float32(xi), jnp.asarray(theta, jnp.float32),
                                      jnp.asarray(psi, jnp.float32)), np.float64) for xi in x])
    return theta, p


def sphere_integral(theta: np.ndarray, p: np.ndarray) -> np.ndarray:
    """``int_S2 p(angle to the axis) dw = 2 pi int_0^pi p(theta) sin(theta) dtheta`` (trapezoid): (..., 3)."""
    g = p * np.sin(theta)[:, None]
    return 2 * np.pi * np.sum(0.5 * (g[..., 1:, :] + g[..., :-1, :]) * np.diff(theta)[:, None], axis=-2)


def _profile_weight(table, c):
    """``p(c = r.l)`` of a tabulated profile (T,) (one channel), linear in t = sqrt(theta / pi)."""
    T = table.shape[0]
    t = jnp.sqrt(jnp.arccos(jnp.clip(c, -1.0, 1.0)) / jnp.pi) * (T - 1)
    i = jnp.clip(jnp.floor(t), 0, T - 2).astype(jnp.int32)
    f = t - i
    return table[i] * (1 - f) + table[i + 1] * f


def prefilter(profile: np.ndarray, env: Environment, dirs: np.ndarray) -> np.ndarray:
    """``sum_k p(r.l_k) L_k dw_k`` at directions ``dirs`` for a tabulated RGB profile (T, 3): (J, 3)."""
    out = []
    for c in range(3):
        num, _ = light_sums(_profile_weight, jnp.asarray(profile[:, c], jnp.float32), dirs, env)
        out.append(np.asarray(num, np.float64)[:, c])
    return np.stack(out, axis=-1)


def build(target, mapper: str, texture_size: int, options: KautzMcCoolOptions) -> Factorization:
    """The Kautz-McCool model of a lighting target (see the module docstring)."""
    brdf, env = lighting_parts(target, "kautz_mccool")
    spec, kd = _specular(brdf)
    S = int(texture_size)
    shape = mappers.texture_shape(mapper, S)
    d = centres(mapper, S)
    K = int(options.slices)
    n = K if K > 1 else int(options.line_size)
    x = (np.arange(n) + 0.5) / n  # slice elevations / line texel centres
    theta, p = profiles(spec, x)
    albedo = directional_albedo(spec, x)  # (n, 3): what each lobe must reflect under a constant environment
    integral = sphere_integral(theta, p)  # (n, 3)
    textures, terms = [], []
    if kd is not None and np.any(kd > 0):  # (no zero term for a material without a diffuse part)
        e = irradiance_map(env, mapper, S)
        textures.append(Texture("E", mapper, S, jnp.asarray(mappers.dilate(mapper, S, e.astype(np.float32)))))
        terms.append(Term((Factor("n", "E"),), jnp.asarray(kd / np.pi, jnp.float32), "irradiance"))
    if K == 1:
        norm = p / np.where(integral > 0, integral, 1.0)[:, None, :]  # unit-integral profiles
        mean = norm.mean(axis=0)  # (T, 3): the single 2D lobe of §3.2, still of unit integral
        P = prefilter(mean, env, d).reshape(shape + (3,))
        w = albedo.reshape(1, n, 3)  # k(x) x = albedo(x) / (x int p) x with int p = 1
        textures += [Texture("P", mapper, S, jnp.asarray(mappers.dilate(mapper, S, P.astype(np.float32)))),
                     Texture("W", "line", n, jnp.asarray(w.astype(np.float32)))]
        terms.append(Term((Factor("r", "P"), Factor("nv", "W")), jnp.ones(3, jnp.float32), "prefiltered"))
    else:
        for s in range(K):
            scale = albedo[s] / np.maximum(x[s] * integral[s], 1e-30)  # k_s: the lobe reflects the albedo
            P = prefilter(p[s], env, d).reshape(shape + (3,))
            tent = np.zeros((1, K, 3))
            tent[0, s] = scale * x[s]
            textures += [Texture(f"P{s}", mapper, S, jnp.asarray(mappers.dilate(mapper, S, P.astype(np.float32)))),
                         Texture(f"T{s}", "line", K, jnp.asarray(tent.astype(np.float32)))]
            terms.append(Term((Factor("r", f"P{s}"), Factor("nv", f"T{s}")), jnp.ones(3, jnp.float32), "prefiltered"))
    return Factorization("lighting", "lighting", tuple(textures), tuple(terms), {}, "kautz_mccool")


BASELINE = Baseline("kautz_mccool", KautzMcCoolOptions, build, __doc__.split("\n")[0])

__all__ = ["BASELINE", "KautzMcCoolOptions", "build", "prefilter", "profiles", "sphere_integral"]
