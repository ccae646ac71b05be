"""Parametrizations: J factors over T textures, each factor a projection pi_j(a, b) and a texture k(j).

Thesis §4.1, eq. 45: ``f(a, b) ~= prod_j t_k(j)(pi_j(a, b))``. A parametrization is one record
(:class:`Parametrization`): named textures and the factors that read them. It is the *structure* of
one product; :mod:`homofac.factorization` holds the fitted result (a sum of such products, each
texture with its own mapper and size). Adding a parametrization means adding one registry entry.

A texture read by scalar projections (``nv``, ``cos_i``, ``cos_o``) is a 1D ``line`` texture; the
others use the direction mapper chosen for the fit.
"""

from __future__ import annotations

from typing import NamedTuple

from ..errors import HomofacError
from .projections import PROJECTIONS, apply


class Factor(NamedTuple):
    """One factor of eq. 45: texture ``texture`` (an index into the parametrization's textures) at ``projection(a, b)``."""

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

    def scalar(self, k: int) -> bool:
        """True when texture k is read by scalar projections (a 1D ``line`` texture)."""
        return PROJECTIONS[self.factors[self.uses(k)[0]].projection].scalar

    @property
    def context(self) -> tuple[str, ...]:
        """Context keys its projections need (``dominant`` for NRHD)."""
        keys: list[str] = []
        for f in self.factors:
            keys += [k for k in PROJECTIONS[f.projection].context if k not in keys]
        return tuple(keys)


PARAMETRIZATIONS: dict[str, Parametrization] = {}


def register(p: Parametrization) -> Parametrization:
    """Add a parametrization; its projections must exist, match its kind, and agree per texture on
    being scalar or directional; every texture must be read by some factor."""
    for f in p.factors:
        proj = PROJECTIONS.get(f.projection)
        if proj is None or proj.kind != p.kind:
            raise HomofacError(f"parametrization {p.name}: unknown {p.kind} projection {f.projection!r}")
        if not 0 <= f.texture < len(p.textures):
            raise HomofacError(f"parametrization {p.name}: factor texture index {f.texture} out of range")
    for k in range(len(p.textures)):
        readers = {PROJECTIONS[p.factors[j].projection].scalar for j in p.uses(k)}
        if not readers:
            raise HomofacError(f"parametrization {p.name}: texture {p.textures[k]} is read by no factor")
        if len(readers) > 1:
            raise HomofacError(f"parametrization {p.name}: texture {p.textures[k]} is read by scalar and direction projections")
    PARAMETRIZATIONS[p.name] = p
    return p


def get(name: str, kind: str | None = None) -> Parametrization:
    """Look up a parametrization by name (optionally checking it is for ``kind`` targets)."""
    p = PARAMETRIZATIONS.get(name) if isinstance(name, str) else None
    if p is None:
        raise HomofacError(f"unknown parametrization {name!r}; known: {', '.join(PARAMETRIZATIONS)}")
    if kind is not None and p.kind != kind:
        names = ", ".join(n for n, q in PARAMETRIZATIONS.items() if q.kind == kind)
        raise HomofacError(f"parametrization {name} is for {p.kind} targets, not {kind}; use one of: {names}")
    return p


def names(kind: str | None = None) -> tuple[str, ...]:
    """Registered parametrization names (of one target kind)."""
    return tuple(n for n, p in PARAMETRIZATIONS.items() if kind is None or p.kind == kind)


def reflection_projection(p: Parametrization | str) -> str:
    """The projection of ``p``'s reflection-like texture: the direction the ``grid`` design puts on
    texel centres beside ``n`` and an r-only term of a sum reads (``r_off`` for NRO and RO, else ``r``)."""
    p = get(p) if isinstance(p, str) else p
    found = [f.projection for f in p.factors if f.projection != "n" and PROJECTIONS[f.projection].invert is not None]
    return found[0] if found else "r"


def project(p: Parametrization, a, b, context: dict | None = None) -> list:
    """The J projected directions (or scalars) ``pi_j(a, b)`` of eq. 45, in factor order."""
    return [apply(f.projection, a, b, context) for f in p.factors]


F = Factor
for _p in (
    Parametrization("IV", "brdf", ("wi", "wo"), (F("wi", 0), F("wo", 1)), "incident-view, thesis eq. 20"),
    Parametrization("GSHD", "brdf", ("h", "d"), (F("h", 0), F("d", 1)), "Gram-Schmidt half/difference, eq. 21-23"),
    Parametrization("PQP", "brdf", ("p", "q"), (F("wi", 0), F("h", 1), F("wo", 0)),
                    "McCool et al. 2001: p(wi) q(h) p(wo), eq. 28; reciprocal by construction"),
    Parametrization("N", "lighting", ("n",), (F("n", 0),), "diffuse irradiance map t1(n), eq. 62"),
    Parametrization("R", "lighting", ("r",), (F("r", 0),), "prefiltered map t1(r) (Heidrich-Seidel), eq. 63"),
    Parametrization("NR", "lighting", ("n", "r"), (F("n", 0), F("r", 1)), "t1(n) t2(r), eq. 64"),
    Parametrization("NRV", "lighting", ("n", "r", "v"), (F("n", 0), F("r", 1), F("v", 2)), "t1(n) t2(r) t3(v), eq. 65"),
    Parametrization("NRHD", "lighting", ("n", "r", "h", "d"),
                    (F("n", 0), F("r", 1), F("h_dom", 2), F("d_dom", 3)),
                    "t1(n) t2(r) t3(h) t4(d) with the dominant light direction, eq. 66-70"),
    Parametrization("NRW", "lighting", ("n", "r", "w"), (F("n", 0), F("r", 1), F("nv", 2)),
                    "t1(n) t2(r) w(n.v): NR with a 1D factor of the view elevation"),
    Parametrization("NRO", "lighting", ("n", "r"), (F("n", 0), F("r_off", 1)),
                    "t1(n) t2(r'): NR read at the off-specular reflection r' (projection r_off)"),
    Parametrization("RO", "lighting", ("r",), (F("r_off", 0),),
                    "t1(r'): R read at the off-specular reflection r' (projection r_off)"),
):
    register(_p)

__all__ = ["F", "Factor", "PARAMETRIZATIONS", "Parametrization", "get", "names", "project", "reflection_projection",
           "register"]
