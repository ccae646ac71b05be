"""Vectors on the unit sphere: normalization, reflection, local frames, the tangent t(n).

Conventions (docs/conventions.md, pinned): right-handed world frame with +z up; directions are float
arrays of shape ``(..., 3)`` of unit length; ``v`` points from the surface to the viewer.

Every function here is written once for three kinds of input and follows the namespace of its input
(:func:`namespace`): NumPy arrays (static tables, in float64), JAX arrays and tracers (jittable,
vmappable, differentiable), and the symbolic values of :mod:`homofac.shader.symbolic`, which turn the
same function into shader code. So the GPU computes exactly the formulas the solver used.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

Vec = Float[Array, "*batch 3"]

#: Smallest length treated as non-zero when normalizing.
TINY = 1e-12
#: Squared length below which a tangent candidate counts as degenerate (n parallel to the reference axis).
DEGENERATE = 1e-14


def namespace(*xs: Any):
    """The array namespace of the inputs: a symbolic shader namespace, ``jax.numpy`` or ``numpy``.

    Symbolic values (:mod:`homofac.shader.symbolic`) carry their namespace as the class attribute
    ``__homofac_namespace__``; any JAX array or tracer selects ``jax.numpy``; everything else NumPy.
    """
    for x in xs:
        ns = getattr(type(x), "__homofac_namespace__", None)
        if ns is not None:
            return ns
    for x in xs:
        if isinstance(x, (jax.Array, jax.core.Tracer)):
            return jnp
    return np


def constant(values, like):
    """The constant vector ``values`` in the namespace and float type of ``like`` (broadcasts against it)."""
    xp = namespace(like)
    return xp.asarray(values, dtype=like.dtype)


def dot(a: Vec, b: Vec) -> Float[Array, "*batch"]:
    """Dot product over the last axis."""
    xp = namespace(a, b)
    return xp.sum(a * b, axis=-1)


def normalize(a: Vec) -> Vec:
    """``a / |a|``; a zero vector stays zero instead of becoming NaN (gradient-safe "double where")."""
    xp = namespace(a)
    n2 = xp.sum(a * a, axis=-1, keepdims=True)
    ok = n2 > TINY * TINY
    safe = xp.where(ok, n2, 1.0)
    return xp.where(ok, a / xp.sqrt(safe), 0.0)


def reflect(v: Vec, n: Vec) -> Vec:
    """Reflected view ``r = 2 (n.v) n - v`` (thesis eq. 40; Latta-Kolb eq. 7)."""
    return 2.0 * dot(n, v)[..., None] * n - v


def half_vector(a: Vec, b: Vec) -> Vec:
    """Half-angle vector ``h = (a + b) / |a + b|`` (thesis eq. 21)."""
    return normalize(a + b)


def tangent(n: Vec) -> Vec:
    """Tangent from a normal, Latta-Kolb eq. 6: ``t(n) = normalize(x - (x.n) n)``, x = world +x.

    Singular where n is (anti)parallel to +x: there ``x - (x.n) n`` vanishes. This function does not
    hide that; at exactly n = +-x it falls back to world +y (made orthogonal to n) so the result stays
    finite, but the tangent field is discontinuous around those two points (thesis §5.4, NRHD).
    """
    xp = namespace(n)
    t = constant([1.0, 0.0, 0.0], n) - n[..., 0:1] * n
    fallback = constant([0.0, 1.0, 0.0], n)
    ok = xp.sum(t * t, axis=-1, keepdims=True) > DEGENERATE
    return xp.where(ok, normalize(t), fallback - dot(fallback, n)[..., None] * n)


def cross(a: Vec, b: Vec) -> Vec:
    """Cross product ``a x b`` over the last axis."""
    return namespace(a, b).cross(a, b)


def frame(n: Vec) -> tuple[Vec, Vec, Vec]:
    """Local frame ``(t, b, n)`` with ``t = tangent(n)`` and ``b = n x t`` (thesis eq. 68)."""
    t = tangent(n)
    return t, cross(n, t), n


def to_local(d: Vec, t: Vec, b: Vec, n: Vec) -> Vec:
    """Coordinates of world direction ``d`` in the frame ``(t, b, n)``: ``(d.t, d.b, d.n)``."""
    return namespace(d, t, b, n).stack([dot(d, t), dot(d, b), dot(d, n)], axis=-1)


def local(d: Vec, n: Vec) -> Vec:
    """``d`` in the frame ``(t(n), n x t(n), n)`` of :func:`frame`."""
    return to_local(d, *frame(n))


def from_spherical(theta: Float[Array, "*b"], phi: Float[Array, "*b"]) -> Vec:
    """``(sin t cos p, sin t sin p, cos t)`` with theta measured from +z (thesis §2.2)."""
    xp = namespace(theta, phi)
    st = xp.sin(theta)
    return xp.stack([st * xp.cos(phi), st * xp.sin(phi), xp.cos(theta)], axis=-1)


def to_spherical(d: Vec) -> tuple[Float[Array, "*b"], Float[Array, "*b"]]:
    """Inverse of :func:`from_spherical`: theta in [0, pi], phi in [0, 2 pi)."""
    xp = namespace(d)
    theta = xp.arccos(xp.clip(d[..., 2], -1.0, 1.0))
    phi = xp.mod(xp.arctan2(d[..., 1], d[..., 0]), 2.0 * np.pi)
    return theta, phi


def tangent_against(t: Vec, h: Vec) -> Vec:
    """``normalize(t - (t.h) h)``, falling back to :func:`tangent` of h when t is parallel to h."""
    xp = namespace(t, h)
    tp = t - dot(t, h)[..., None] * h
    ok = xp.sum(tp * tp, axis=-1, keepdims=True) > DEGENERATE
    return xp.where(ok, normalize(tp), tangent(h))


def gram_schmidt_difference(a: Vec, h: Vec, t: Vec) -> Vec:
    """Direction ``a`` in the frame (t', b', h) built from h and the projected tangent (thesis eq. 22 / 69).

    ``t' = normalize(t - (t.h) h)``, ``b' = h x t'``, result ``(a.t', a.b', a.h)``.
    Singular where h is parallel to t (t' vanishes); as in :func:`tangent` the result stays finite.
    """
    tp = tangent_against(t, h)
    return to_local(a, tp, cross(h, tp), h)


__all__ = [
    "DEGENERATE", "TINY", "constant", "cross", "dot", "frame", "from_spherical", "gram_schmidt_difference",
    "half_vector", "local", "namespace", "normalize", "reflect", "tangent", "tangent_against", "to_local",
    "to_spherical",
]
