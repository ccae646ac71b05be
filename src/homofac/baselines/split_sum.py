"""``split_sum``: the split-sum approximation every engine ships (Karis 2013; Filament), as two terms.

    L(v, n) ~ kd/pi E(n)  +  P(r) W(n.v)                                    (3 texture lookups)

* E(n): the irradiance at each texel centre of the mapper, exactly (the clamped-cosine texel
  integrals of :mod:`homofac.light.geometry`), or from the 9 spherical-harmonic coefficients of the
  environment (``irradiance: sh9``, Ramamoorthi & Hanrahan 2001);
* P(r): the environment prefiltered with the material's own NDF under Karis' assumption n = v = r:
  ``P(r) = sum_k L_k D(h_k) max(r.l_k, 0) dw_k / sum_k D(h_k) max(r.l_k, 0) dw_k`` with
  ``h_k = normalize(r + l_k)``, ``cos theta_h = r.h_k = sqrt((1 + r.l_k) / 2)`` -- the expected value
  of Karis' importance-sampled estimator; ``weighting: plain`` drops the ``max(r.l, 0)`` factor;
* W(x) = ks (F0 A(x) + B(x)): the "DFG" table integrated for the model's own D, G and Schlick
  Fresnel: ``A + B`` and ``B`` are the directional albedos of the specular lobe (kd = 0, ks = 1) with
  F0 = 1 and F0 = 0 at the view cosine x (:func:`homofac.brdf.albedo`), stored as a ``line`` texture.

Under a constant environment P = 1 and the split sum is exact (W is the directional albedo); in the
mirror limit at n = v it is exact too. Models without a microfacet NDF (``ModelSpec.microfacet``:
Lambert, the Phong family, Ward, MERL) are refused.
"""

from __future__ import annotations

import functools
from typing import ClassVar, Literal

import jax
import jax.numpy as jnp
import numpy as np
from pydantic import Field

from ..brdf import MODELS
from ..errors import HomofacError
from ..factorization import Factor, Factorization, Term, Texture
from ..light import Environment, irradiance, uniform
from ..light.integrals import integrals
from ..light.sh import sh9_basis, sh9_irradiance
from ..options import Options
from ..param import mappers
from .base import Baseline, centres, directional_albedo, irradiance_map, light_sums, lighting_parts


class SplitSumOptions(Options):
    """Options of ``split_sum``: how E and P are computed, and the size of the DFG line texture."""

    TAG: ClassVar[str] = "split_sum"
    irradiance: Literal["exact", "sh9"] = "exact"
    weighting: Literal["karis", "plain"] = "karis"
    line_size: int = Field(32, ge=2, le=4096)


@functools.lru_cache(maxsize=None)
def _weight(ndf, weighting: str):
    """The prefilter weight ``w(params, r.l)`` of an NDF (one function object per pair: compiled once)."""

    def weight(p, c):
        d = ndf(p, jnp.sqrt(jnp.clip((1.0 + c) / 2.0, 0.0, 1.0)))
        return d * (jnp.maximum(c, 0.0) if weighting == "karis" else (c > 0).astype(c.dtype))

    return weight


def prefilter(ndf, params, env: Environment, dirs: np.ndarray, weighting: str = "karis") -> np.ndarray:
    """P at directions ``dirs`` (J, 3): the NDF-weighted average of the lights (see the module docstring)."""
    num, den = light_sums(_weight(ndf, weighting), params, dirs, env)
    num, den = np.asarray(num, np.float64), np.asarray(den, np.float64)
    return np.where(den[:, None] > 0, num / np.maximum(den, 1e-300)[:, None], 0.0)


def dfg(brdf, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(A, B)`` (RGB each, (N, 3)): directional albedos of the specular lobe with F0 = 1 minus F0 = 0, and F0 = 0."""
    ab = directional_albedo(brdf, x, kd=0.0, ks=1.0, f0=1.0)
    b = directional_albedo(brdf, x, kd=0.0, ks=1.0, f0=0.0)
    return ab - b, b


def build(target, mapper: str, texture_size: int, options: SplitSumOptions) -> Factorization:
    """The split-sum model of a lighting target (see the module docstring)."""
    brdf, env = lighting_parts(target, "split_sum")
    spec = MODELS[brdf.model]
    if spec.microfacet is None:
        raise HomofacError(f"split_sum needs a microfacet model with an NDF ("
                           f"{', '.join(n for n, m in MODELS.items() if m.microfacet is not None)}); "
                           f"{brdf.model} has none (use kautz_mccool, which works for any isotropic BRDF)")
    S = int(texture_size)
    shape = mappers.texture_shape(mapper, S)
    d = centres(mapper, S)
    if options.irradiance == "exact":
        e = irradiance_map(env, mapper, S)
    else:
        e = sh9_irradiance(env, d).reshape(shape + (3,))
    p = prefilter(spec.microfacet.ndf, brdf.params, env, d, options.weighting).reshape(shape + (3,))
    n = int(options.line_size)
    x = (np.arange(n) + 0.5) / n
    a, b = dfg(brdf, x)
    ks, f0 = np.asarray(brdf.params["ks"], np.float64), np.asarray(brdf.params["f0"], np.float64)
    w = (ks * (f0 * a + b)).reshape(1, n, 3)
    kd = np.asarray(brdf.params["kd"], np.float64)
    textures = (
        Texture("E", mapper, S, jnp.asarray(mappers.dilate(mapper, S, e.astype(np.float32)))),
        Texture("P", mapper, S, jnp.asarray(mappers.dilate(mapper, S, p.astype(np.float32)))),
        Texture("W", "line", n, jnp.asarray(w.astype(np.float32))),
    )
    terms = (
        Term((Factor("n", "E"),), jnp.asarray(kd / np.pi, jnp.float32), "irradiance"),
        Term((Factor("r", "P"), Factor("nv", "W")), jnp.ones(3, jnp.float32), "prefiltered"),
    )
    return Factorization("lighting", "lighting", textures, terms, {}, "split_sum")


@jax.jit
def _karis_gltf(r, alpha2, dirs, power, solid):
    """Karis' prefilter (module docstring) with GGX D of ``alpha2`` = roughness^4 per pair: (N, 3)."""

    def one(block):
        rr, a2 = block
        c = rr @ dirs.T
        ch2 = jnp.clip((1.0 + c) * 0.5, 0.0, 1.0)
        w = a2[:, None] / (jnp.pi * (ch2 * (a2[:, None] - 1.0) + 1.0) ** 2) * jnp.maximum(c, 0.0)
        return (w @ power) / jnp.maximum((w @ solid)[:, None], 1e-30)

    k = _GLTF_CHUNK
    return jax.lax.map(one, (r.reshape(-1, k, 3), alpha2.reshape(-1, k))).reshape(-1, 3)


#: Pairs per lax.map step of :func:`gltf_parts`.
_GLTF_CHUNK = 64


def gltf_parts(env: Environment, n, v, roughness) -> np.ndarray:
    """Split-sum's ``(I_d, I_A, I_B)`` of the glTF BRDF (docs/format.md, "The bake directory") at pairs
    with a roughness each, idealized: (N, 3, 3) float32, 0 where n.v <= 0.

        I_d ~ E(n)/pi d(n, v, rho)     I_A ~ P_rho(r) A(n, v, rho)     I_B ~ P_rho(r) B(n, v, rho)

    E the exact irradiance, P_rho Karis' prefilter (GGX D at the pair's own roughness, n = v = r, module
    docstring), and d, A, B (the "DFG" terms) the integrals of :func:`homofac.light.integrals.integrals` under a
    uniform radiance 1 of the same light resolution, i.e. the directional albedos of the three lobes at the
    pair's own (n.v, rho), with no table. Split-sum as engines ship it (a mip chain, a DFG table) is only less
    accurate than this; :mod:`homofac.baselines.ibl_sampler` evaluates a real one. Then
    :func:`homofac.light.integrals.material_radiance` gives any material's L."""
    n = jnp.asarray(n, jnp.float32)
    v = jnp.asarray(v, jnp.float32)
    rho = jnp.broadcast_to(jnp.asarray(roughness, jnp.float32), n.shape[:1])
    count = n.shape[0]
    if count == 0:
        return np.zeros((0, 3, 3), np.float32)
    x = jnp.sum(n * v, axis=-1)
    r = 2.0 * x[:, None] * n - v
    pad = (-count) % _GLTF_CHUNK
    rp = jnp.concatenate([r, jnp.broadcast_to(r[:1], (pad, 3))])
    a2 = jnp.concatenate([rho, jnp.broadcast_to(rho[:1], (pad,))]) ** 4
    p = _karis_gltf(rp, a2, env.directions.astype(jnp.float32),
                    (env.radiance * env.solid_angle[:, None]).astype(jnp.float32),
                    env.solid_angle.astype(jnp.float32))[:count]
    albedo = integrals(uniform(1.0, int(env.info.get("resolution", 32))), n, v, rho)
    e = irradiance(env, n)
    out = jnp.stack([e / jnp.pi * albedo[:, 0], p * albedo[:, 1], p * albedo[:, 2]], axis=1)
    return np.asarray(jnp.where((x > 0)[:, None, None], out, 0.0), np.float32)


BASELINE = Baseline("split_sum", SplitSumOptions, build, __doc__.split("\n")[0])

__all__ = ["BASELINE", "SplitSumOptions", "build", "dfg", "gltf_parts", "prefilter", "sh9_basis", "sh9_irradiance"]
