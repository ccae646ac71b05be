"""Projections: functions pi(a, b) of a pair of directions that a factor looks a texture up at.

A projection is one record (:class:`Projection`): its math, written once against the namespace of
its inputs (:func:`homofac.sphere.namespace`, so the same function is NumPy, JAX and -- traced by
:mod:`homofac.shader` -- shader code), whether it gives a direction or a scalar, and its doc.

Names (pinned, docs/format.md):

* BRDF (a = wi, b = wo, local frame, z = normal): ``wi``, ``wo``, ``h`` (thesis eq. 21), ``d``
  (eq. 22, the Gram-Schmidt difference vector with the surface tangent t = local +x); scalars
  ``cos_i`` = wi.z and ``cos_o`` = wo.z, clamped to [0, 1].
* Lighting (a = n, b = v, world frame): ``n``, ``v``, ``r`` (eq. 40), ``h_dom`` (eq. 67-68) and
  ``d_dom`` (eq. 69), which use the dominant light direction ``i`` (eq. 66) from the context; the
  scalar ``nv`` = n.v clamped to [0, 1].

Scalar projections are looked up with the ``line`` mapper; direction projections with any other.
"""

from __future__ import annotations

from typing import Callable, NamedTuple

from .. import sphere
from ..errors import HomofacError


class Projection(NamedTuple):
    """A projection ``fn(a, b, context)`` of a direction pair: ``(..., 3)`` directions or ``(...)`` scalars."""

    name: str
    kind: str  # "brdf" or "lighting"
    fn: Callable
    hemisphere: bool  # directions: always z >= 0 for valid pairs
    doc: str
    scalar: bool = False  # True: a scalar in [0, 1] (looked up with the line mapper)
    context: tuple[str, ...] = ()  # context keys the function reads (e.g. "dominant")


PROJECTIONS: dict[str, Projection] = {}
KINDS = ("brdf", "lighting")


def register(p: Projection) -> Projection:
    """Add a projection to the registry."""
    if p.kind not in KINDS:
        raise HomofacError(f"projection {p.name}: kind must be one of {', '.join(KINDS)}, got {p.kind!r}")
    PROJECTIONS[p.name] = p
    return p


def get(name: str, kind: str | None = None) -> Projection:
    """The projection registered as ``name`` (optionally checking its target kind)."""
    p = PROJECTIONS.get(name) if isinstance(name, str) else None
    if p is None:
        raise HomofacError(f"unknown projection {name!r}; known: {', '.join(PROJECTIONS)}")
    if kind is not None and p.kind != kind:
        names = ", ".join(n for n, q in PROJECTIONS.items() if q.kind == kind)
        raise HomofacError(f"projection {name} is for {p.kind} targets, not {kind}; use one of: {names}")
    return p


def apply(name: str, a, b, context: dict | None = None):
    """``pi_name(a, b)`` with the given context (e.g. ``{"dominant": (3,)}``)."""
    p = get(name)
    ctx = context or {}
    for key in p.context:
        if key not in ctx:
            raise HomofacError(f"projection {name} needs context[{key!r}] (the dominant light direction, thesis eq. 66)")
    return p.fn(a, b, ctx)


# --- BRDF projections (local frame) ------------------------------------------------------------


def _wi(a, b, ctx):
    return a


def _wo(a, b, ctx):
    return b


def _h(a, b, ctx):
    return sphere.half_vector(a, b)


def _d(a, b, ctx):
    """Thesis eq. 22 with the local tangent t = +x."""
    h = sphere.half_vector(a, b)
    return sphere.gram_schmidt_difference(a, h, sphere.constant([1.0, 0.0, 0.0], a))


def _clamp01(x):
    return sphere.namespace(x).clip(x, 0.0, 1.0)


def _cos_i(a, b, ctx):
    return _clamp01(a[..., 2])


def _cos_o(a, b, ctx):
    return _clamp01(b[..., 2])


# --- Lighting projections (world frame) --------------------------------------------------------


def _n(n, v, ctx):
    return n


def _v(n, v, ctx):
    return v


def _r(n, v, ctx):
    return sphere.reflect(v, n)


def _nv(n, v, ctx):
    return _clamp01(sphere.dot(n, v))


def _h_dom(n, v, ctx):
    """Eq. 67-68: the half vector of the dominant light i and v, in the local frame of n."""
    i = sphere.constant(ctx["dominant"], n)
    return sphere.local(sphere.half_vector(i, v), n)


def _d_dom(n, v, ctx):
    """Eq. 69: i in the Gram-Schmidt frame of the half vector h' = half(i, v) and the tangent t(n)."""
    i = sphere.constant(ctx["dominant"], n)
    return sphere.gram_schmidt_difference(i, sphere.half_vector(i, v), sphere.tangent(n))


for _p in (
    Projection("wi", "brdf", _wi, True, "incident direction wi"),
    Projection("wo", "brdf", _wo, True, "outgoing (view) direction wo"),
    Projection("h", "brdf", _h, True, "half vector, thesis eq. 21"),
    Projection("d", "brdf", _d, True, "Gram-Schmidt difference vector, thesis eq. 22"),
    Projection("cos_i", "brdf", _cos_i, True, "cos theta_i = wi.z clamped to [0, 1]", scalar=True),
    Projection("cos_o", "brdf", _cos_o, True, "cos theta_o = wo.z clamped to [0, 1]", scalar=True),
    Projection("n", "lighting", _n, False, "surface normal n"),
    Projection("v", "lighting", _v, False, "view direction v"),
    Projection("r", "lighting", _r, False, "reflected view r = 2 (n.v) n - v, eq. 40"),
    Projection("nv", "lighting", _nv, False, "n.v clamped to [0, 1]", scalar=True),
    Projection("h_dom", "lighting", _h_dom, False, "half vector to the dominant light, eq. 67-68",
               context=("dominant",)),
    Projection("d_dom", "lighting", _d_dom, False, "difference vector of the dominant light, eq. 69",
               context=("dominant",)),
):
    register(_p)

__all__ = ["KINDS", "PROJECTIONS", "Projection", "apply", "get", "register"]
