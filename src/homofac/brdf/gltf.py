"""The glTF 2.0 metallic-roughness BRDF (pinned: glTF 2.0 Appendix B; docs/format.md "The bake directory").

    alpha = roughness^2,  D = GGX,  V = G2 / (4 (n.l)(n.v)) height-correlated Smith,  S = V D,
    s5 = (1 - |v.h|)^5,   f0_eff = (1 - m) 0.04 + m c
    f = (1 - m) 0.96 (1 - s5) c / pi  +  f0_eff (1 - s5) S  +  s5 S

written as a lobe form (:class:`~homofac.brdf.core.ModelSpec`): three scalar lobes
``((1 - s5)/pi, (1 - s5) S, s5 S)`` with the colours ``((1 - m) 0.96 c, f0_eff, 1)``. The lighting
integral of each lobe is one of the bake's integrals I_d, I_A, I_B (:mod:`homofac.light.integrals`):
base colour and metallic enter L linearly and exactly, only roughness shapes the lobes.
"""

from __future__ import annotations

from typing import Any

import jax.numpy as jnp
from jaxtyping import Array

from .analytic import _half, _smith_lambda_ggx
from .core import COS_EPS, BRDF, ModelSpec, make, register

#: Reflectance at normal incidence of the glTF dielectric (ior 1.5).
DIELECTRIC_F0 = 0.04

Comp = tuple[Array, Array, Array]


def gltf_lobes_at(roughness: Array, wi: Comp, wo: Comp) -> tuple[Array, Array, Array]:
    """``((1 - s5)/pi, (1 - s5) S, s5 S)`` at local directions (component triples, above the horizon),
    ``roughness`` broadcastable against them (perceptual: alpha = roughness^2). S = V D with GGX D and
    the height-correlated Smith V = 1 / ((1 + Lambda(l) + Lambda(v)) 4 (n.l)(n.v)) (Heitz 2014 eq. 99),
    the D written with sin^2 theta_h from h.x, h.y (no cancellation near the peak)."""
    h = _half(wi, wo)
    nl = jnp.maximum(wi[2], COS_EPS)
    nv = jnp.maximum(wo[2], COS_EPS)
    nh = jnp.maximum(h[2], 0.0)
    vh = jnp.abs(wo[0] * h[0] + wo[1] * h[1] + wo[2] * h[2])
    a = roughness * roughness
    a2 = a * a
    d = a2 / (jnp.pi * (a2 * nh * nh + h[0] * h[0] + h[1] * h[1]) ** 2)
    g2 = 1.0 / (1.0 + _smith_lambda_ggx(wi, a2) + _smith_lambda_ggx(wo, a2))
    s = d * g2 / (4.0 * nl * nv)
    s5 = (1.0 - jnp.minimum(vh, 1.0)) ** 5
    return (1.0 - s5) / jnp.pi, (1.0 - s5) * s, s5 * s


def _lobes(p: dict[str, Array], wi: Comp, wo: Comp) -> tuple[Array, Array, Array]:
    return gltf_lobes_at(p["roughness"], wi, wo)


def gltf_colors(p: dict[str, Array]) -> tuple[Array, Array, Array]:
    """The lobe colours ``((1 - m) 0.96 c, f0_eff, 1)`` of base colour c and metallic m."""
    c, m = p["base_color"], p["metallic"]
    f0 = (1.0 - m) * DIELECTRIC_F0 + m * c
    return ((1.0 - m) * (1.0 - DIELECTRIC_F0) * c, f0, jnp.ones_like(c))


def _fn(p: dict[str, Array], wi: Array, wo: Array) -> Array:
    comp = lambda w: (w[..., 0], w[..., 1], w[..., 2])  # noqa: E731
    out = 0.0
    for col, g in zip(gltf_colors(p), _lobes(p, comp(wi), comp(wo))):
        out = out + col * g[..., None]
    return jnp.broadcast_to(out, jnp.broadcast_shapes(wi.shape, wo.shape)[:-1] + (3,))


GLTF_DEFAULTS: dict[str, Any] = {"base_color": (1.0, 1.0, 1.0), "metallic": 1.0, "roughness": 0.5}

GLTF_DOC = """glTF 2.0 metallic-roughness: f = (1 - m) 0.96 (1 - s5) c / pi + f0_eff (1 - s5) S + s5 S.

glTF 2.0 specification, Appendix B (BRDF implementation): alpha = roughness^2, S = V D with GGX D and the
height-correlated Smith V = G2 / (4 (n.l)(n.v)) (Heitz 2014), s5 = (1 - |v.h|)^5 (Schlick), dielectric
f0 = 0.04, f0_eff = (1 - m) 0.04 + m c; c = base_color (linear RGB), m = metallic in [0, 1]. Single
scattering: a white metal loses energy at high roughness. The lobes (1 - s5)/pi, (1 - s5) S, s5 S integrate
under an environment to I_d, I_A, I_B, from which the lighting of every material follows exactly."""

register(ModelSpec("gltf", _fn, GLTF_DEFAULTS, True, "base_color <= 1, metallic in [0, 1]", GLTF_DOC,
                   lobes=_lobes, colors=gltf_colors))


def gltf(base_color: Any = GLTF_DEFAULTS["base_color"], metallic: Any = GLTF_DEFAULTS["metallic"],
         roughness: Any = GLTF_DEFAULTS["roughness"]) -> BRDF:
    """The glTF 2.0 metallic-roughness BRDF (roughness perceptual: alpha = roughness^2)."""
    return make("gltf", base_color=base_color, metallic=metallic, roughness=roughness)


__all__ = ["DIELECTRIC_F0", "GLTF_DOC", "gltf", "gltf_colors", "gltf_lobes_at"]
