"""Parametrizations: J factors over T textures, each factor a projection pi_j(a, b) and a texture k(j).

Thesis §4.1, eq. 45: ``f(a, b) ~= prod_j t_k(j)(pi_j(a, b))``. A parametrization is data (a
:class:`Parametrization` tuple); a projection is a pure function registered by name. Adding a
parametrization means adding one registry entry, not code.

Projections (DESIGN.md, pinned names):

* BRDF (a = wi, b = wo, local frame, z = normal): ``wi``, ``wo``, ``h`` (eq. 21), ``d`` (eq. 22, the
  Gram-Schmidt difference vector with the surface tangent t = local +x).
* Lighting (a = n, b = v, world frame): ``n``, ``v``, ``r`` (eq. 40), ``h_dom`` (eq. 67-68) and
  ``d_dom`` (eq. 69), which use the dominant light direction ``i`` (eq. 66) from the context.
"""

from __future__ import annotations

from typing import Callable, NamedTuple

import jax.numpy as jnp
from jaxtyping import Array, Float

from .. import sphere
from ..errors import HomofacError

Vec = Float[Array, "*batch 3"]


class Projection(NamedTuple):
    """A direction projection ``pi(a, b, context) -> (..., 3)`` of a pair of directions."""

    name: str
    kind: str  # "brdf" or "lighting"
    fn: Callable[[Vec, Vec, dict], Vec]
    hemisphere: bool  # True when the result always has z >= 0 for valid pairs
    doc: str


class Factor(NamedTuple):
    """One factor of eq. 45: texture ``texture`` looked up at ``projection(a, b)``."""

    projection: str
    texture: int


class Parametrization(NamedTuple):
    """A parametrization (thesis §4.1): named textures and factors that index them."""

    name: str
    kind: str  # "brdf" or "lighting"
    textures: tuple[str, ...]
    factors: tuple[Factor, ...]
    doc: str

    @property
    def J(self) -> int:  # noqa: N802 - thesis notation
        """Number of factors J."""
        return len(self.factors)

    @property
    def T(self) -> int:  # noqa: N802 - thesis notation
        """Number of textures T."""
        return len(self.textures)

    def uses(self, k: int) -> tuple[int, ...]:
        """Indices j of the factors that read texture k (f(k) = len(uses(k)) in thesis §4.3.1)."""
        return tuple(j for j, f in enumerate(self.factors) if f.texture == k)


PROJECTIONS: dict[str, Projection] = {}
PARAMETRIZATIONS: dict[str, Parametrization] = {}


def register_projection(p: Projection) -> Projection:
    """Add a projection to the registry (name must be new)."""
    PROJECTIONS[p.name] = p
    return p


def register(p: Parametrization) -> Parametrization:
    """Add a parametrization to the registry; its projections must exist and match its kind."""
    for f in p.factors:
        proj = PROJECTIONS.get(f.projection)
        if proj is None or proj.kind != p.kind:
            raise HomofacError(f"parametrization {p.name}: unknown {p.kind} projection {f.projection!r}")
        if not 0 <= f.texture < len(p.textures):
            raise HomofacError(f"parametrization {p.name}: factor texture index {f.texture} out of range")
    PARAMETRIZATIONS[p.name] = p
    return p


def get(name: str, kind: str | None = None) -> Parametrization:
    """Look up a parametrization by name (optionally checking it is for ``kind`` targets)."""
    p = PARAMETRIZATIONS.get(name)
    if p is None:
        raise HomofacError(f"unknown parametrization {name!r}; known: {', '.join(PARAMETRIZATIONS)}")
    if kind is not None and p.kind != kind:
        names = ", ".join(n for n, q in PARAMETRIZATIONS.items() if q.kind == kind)
        raise HomofacError(f"parametrization {name} is for {p.kind} targets, not {kind}; use one of: {names}")
    return p


def project(p: Parametrization, a: Vec, b: Vec, context: dict | None = None) -> list[Vec]:
    """The J projected directions ``pi_j(a, b)`` of eq. 45, in factor order."""
    context = context or {}
    return [PROJECTIONS[f.projection].fn(a, b, context) for f in p.factors]


# --- BRDF projections (local frame) ------------------------------------------------------------

_X = jnp.array([1.0, 0.0, 0.0])


def _h(a: Vec, b: Vec, ctx: dict) -> Vec:
    return sphere.half_vector(a, b)


def _d(a: Vec, b: Vec, ctx: dict) -> Vec:
    h = sphere.half_vector(a, b)
    t = jnp.broadcast_to(_X.astype(a.dtype), a.shape)
    return sphere.gram_schmidt_difference(a, h, t)


register_projection(Projection("wi", "brdf", lambda a, b, c: a, True, "incident direction wi"))
register_projection(Projection("wo", "brdf", lambda a, b, c: b, True, "outgoing (view) direction wo"))
register_projection(Projection("h", "brdf", _h, True, "half vector, thesis eq. 21"))
register_projection(Projection("d", "brdf", _d, True, "Gram-Schmidt difference vector, thesis eq. 22"))


# --- Lighting projections (world frame) --------------------------------------------------------


def _dominant(ctx: dict, like: Vec) -> Vec:
    if "dominant" not in ctx:
        raise HomofacError("NRHD needs the dominant light direction (context['dominant'], thesis eq. 66)")
    return jnp.broadcast_to(jnp.asarray(ctx["dominant"], like.dtype), like.shape)


def _h_dom(n: Vec, v: Vec, ctx: dict) -> Vec:
    i = _dominant(ctx, n)
    hp = sphere.half_vector(i, v)  # eq. 67
    t, b, nn = sphere.frame(n)
    return sphere.to_local(hp, t, b, nn)  # eq. 68


def _d_dom(n: Vec, v: Vec, ctx: dict) -> Vec:
    i = _dominant(ctx, n)
    hp = sphere.half_vector(i, v)
    return sphere.gram_schmidt_difference(i, hp, sphere.tangent(n))  # eq. 69


register_projection(Projection("n", "lighting", lambda n, v, c: n, False, "surface normal n"))
register_projection(Projection("v", "lighting", lambda n, v, c: v, False, "view direction v"))
register_projection(
    Projection("r", "lighting", lambda n, v, c: sphere.reflect(v, n), False, "reflected view, eq. 40")
)
register_projection(Projection("h_dom", "lighting", _h_dom, False, "half vector to the dominant light, eq. 67-68"))
register_projection(Projection("d_dom", "lighting", _d_dom, False, "difference vector of the dominant light, eq. 69"))


# --- The parametrizations ----------------------------------------------------------------------

F = Factor
register(Parametrization("IV", "brdf", ("wi", "wo"), (F("wi", 0), F("wo", 1)), "incident-view, thesis eq. 20"))
register(Parametrization("GSHD", "brdf", ("h", "d"), (F("h", 0), F("d", 1)), "Gram-Schmidt half/difference, eq. 21-23"))
register(
    Parametrization(
        "PQP", "brdf", ("p", "q"), (F("wi", 0), F("h", 1), F("wo", 0)),
        "McCool et al. 2001: p(wi) q(h) p(wo), eq. 28; reciprocal by construction",
    )
)
register(Parametrization("N", "lighting", ("n",), (F("n", 0),), "diffuse irradiance map t1(n), eq. 62"))
register(Parametrization("R", "lighting", ("r",), (F("r", 0),), "prefiltered map t1(r) (Heidrich-Seidel), eq. 63"))
register(Parametrization("NR", "lighting", ("n", "r"), (F("n", 0), F("r", 1)), "t1(n) t2(r), eq. 64"))
register(
    Parametrization("NRV", "lighting", ("n", "r", "v"), (F("n", 0), F("r", 1), F("v", 2)), "t1(n) t2(r) t3(v), eq. 65")
)
register(
    Parametrization(
        "NRHD", "lighting", ("n", "r", "h", "d"), (F("n", 0), F("r", 1), F("h_dom", 2), F("d_dom", 3)),
        "t1(n) t2(r) t3(h) t4(d) with the dominant light direction, eq. 66-70",
    )
)
