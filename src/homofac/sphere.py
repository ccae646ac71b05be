"""Vectors on the unit sphere: normalization, reflection, local frames, the tangent t(n).

Conventions (DESIGN.md, pinned): right-handed world frame with +z up; directions are float
arrays of shape ``(..., 3)`` of unit length; ``v`` points from the surface to the viewer.
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, Float

Vec = Float[Array, "*batch 3"]

#: Smallest length treated as non-zero when normalizing.
TINY = 1e-12


def dot(a: Vec, b: Vec) -> Float[Array, "*batch"]:
    """Dot product over the last axis."""
    return jnp.sum(a * b, axis=-1)


def normalize(a: Vec) -> Vec:
    """``a / |a|``; a zero vector stays zero instead of becoming NaN (gradient-safe)."""
    n2 = jnp.sum(a * a, axis=-1, keepdims=True)
    safe = jnp.where(n2 > TINY * TINY, n2, 1.0)
    return jnp.where(n2 > TINY * TINY, a / jnp.sqrt(safe), 0.0)


def reflect(v: Vec, n: Vec) -> Vec:
    """Reflected view ``r = 2 (n.v) n - v`` (thesis eq. 40; Latta-Kolb eq. 7)."""
    return 2.0 * dot(n, v)[..., None] * n - v


def half_vector(a: Vec, b: Vec) -> Vec:
    """Half-angle vector ``h = (a + b) / |a + b|`` (thesis eq. 21)."""
    return normalize(a + b)


def tangent(n: Vec) -> Vec:
    """Tangent from a normal, Latta-Kolb eq. 6: ``t(n) = normalize(x - (x.n) n)``, x = world +x.

    Singular where n is (anti)parallel to +x: there ``x - (x.n) n`` vanishes. This function does not
    hide that; at exactly n = +-x it falls back to world +y so the result stays finite, but the
    tangent field is discontinuous around those two points (thesis §5.4, NRHD discussion).
    """
    x = jnp.zeros_like(n).at[..., 0].set(1.0)
    t = x - n[..., 0:1] * n
    fallback = jnp.zeros_like(n).at[..., 1].set(1.0)
    t2 = jnp.sum(t * t, axis=-1, keepdims=True)
    return jnp.where(t2 > 1e-14, normalize(t), fallback - dot(fallback, n)[..., None] * n)


def frame(n: Vec) -> tuple[Vec, Vec, Vec]:
    """Local frame ``(t, b, n)`` with ``t = tangent(n)`` and ``b = n x t`` (thesis eq. 68)."""
    t = tangent(n)
    b = jnp.cross(n, t)
    return t, b, n


def to_local(d: Vec, t: Vec, b: Vec, n: Vec) -> Vec:
    """Coordinates of world direction ``d`` in the frame ``(t, b, n)``: ``(d.t, d.b, d.n)``."""
    return jnp.stack([dot(d, t), dot(d, b), dot(d, n)], axis=-1)


def from_spherical(theta: Float[Array, "*b"], phi: Float[Array, "*b"]) -> Vec:
    """``(sin t cos p, sin t sin p, cos t)`` with theta measured from +z (thesis §2.2)."""
    st = jnp.sin(theta)
    return jnp.stack([st * jnp.cos(phi), st * jnp.sin(phi), jnp.cos(theta)], axis=-1)


def to_spherical(d: Vec) -> tuple[Float[Array, "*b"], Float[Array, "*b"]]:
    """Inverse of :func:`from_spherical`: theta in [0, pi], phi in [0, 2 pi)."""
    theta = jnp.arccos(jnp.clip(d[..., 2], -1.0, 1.0))
    phi = jnp.mod(jnp.arctan2(d[..., 1], d[..., 0]), 2.0 * jnp.pi)
    return theta, phi


def gram_schmidt_difference(a: Vec, h: Vec, t: Vec) -> Vec:
    """Direction ``a`` in the frame (t', b', h) built from h and the projected tangent (thesis eq. 22 / 69).

    ``t' = normalize(t - (t.h) h)``, ``b' = h x t'``, result ``(a.t', a.b', a.h)``.
    Singular where h is parallel to t (t' vanishes); as in :func:`tangent` the result stays finite.
    """
    tp = tangent_against(t, h)
    bp = jnp.cross(h, tp)
    return to_local(a, tp, bp, h)


def tangent_against(t: Vec, h: Vec) -> Vec:
    """``normalize(t - (t.h) h)``, falling back to a direction orthogonal to h when t is parallel to h."""
    tp = t - dot(t, h)[..., None] * h
    ok = jnp.sum(tp * tp, axis=-1, keepdims=True) > 1e-14
    # Fallback: tangent of h itself (orthogonal to h by construction).
    return jnp.where(ok, normalize(tp), tangent(h))
