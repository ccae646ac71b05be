"""Exact cosine-weighted solid angles of light texels: w_k(n) = integral over texel k of max(n . l, 0) dl.

The pinned lighting sum (docs/conventions.md) weights each light texel by ``max(n . l_k, 0) dw_k``; evaluated at
the texel centre that is only second-order accurate, and a white Lambertian surface under uniform
radiance 1 comes out 1 +- 2e-4 at 32^2 x 6 lights. homofac integrates the clamped cosine over each
texel exactly instead, so that sum_k w_k(n) = pi for every n and the white Lambertian case is exactly
1 (to float rounding). For a texel entirely above the horizon of n this is ``n . m_k`` with the texel's
vector solid angle m_k; it agrees with ``max(n . l_k, 0) dw_k`` to second order in the texel size.

A cube texel is a spherical quadrilateral whose edges are great-circle arcs (straight lines on a
cube face). With corners p_0..p_3 counter-clockwise seen from outside, Arvo's vector form (1995) gives

    integral_P l dl = 1/2 sum_i Theta_i u_i,   u_i = normalize(p_i x p_(i+1)),  Theta_i = angle(p_i, p_(i+1)),

so ``n . m = 1/2 sum_i Theta_i (n . u_i)``. A texel straddling the horizon of n is clipped by the great
circle n . l = 0: each edge keeps its visible sub-arc (same u_i), and the clipped polygon gains one
horizon arc from the exit point to the entry point, contributing 1/2 atan2(n . (x_out x x_in),
x_out . x_in). Lights that are not texels (extra directional lights, corners all zero) use
``max(n . l, 0) dw`` as they are delta lights.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..param import mappers


@functools.lru_cache(maxsize=8)
def cube_corners(r: int) -> np.ndarray:
    """Corners (6 r^2, 4, 3) of the texels of a face-size-r cube map, row-major over the pinned (r, 6r)
    texture, ordered counter-clockwise as seen from outside the sphere (float64, read-only)."""
    m = mappers.get("cube")
    i, j = np.meshgrid(np.arange(r), np.arange(6 * r), indexing="ij")  # texel row, column
    face = (j // r).astype(np.int32)
    ju = j % r
    uv = [(ju, i), (ju + 1, i), (ju + 1, i + 1), (ju, i + 1)]
    pts = np.stack(
        [np.asarray(m.from_face_uv(face, (u / r).astype(np.float64), (v / r).astype(np.float64)), np.float64)
         for u, v in uv],
        axis=2,
    ).reshape(-1, 4, 3)
    pts /= np.linalg.norm(pts, axis=-1, keepdims=True)
    centre = pts.sum(axis=1)
    orient = np.einsum("ki,ki->k", np.cross(pts[:, 1] - pts[:, 0], pts[:, 2] - pts[:, 1]), centre)
    pts = np.where((orient < 0)[:, None, None], pts[:, ::-1], pts)
    pts.flags.writeable = False
    return pts


def vector_solid_angle(corners) -> np.ndarray:
    """m_k = integral over texel k of l dl (Arvo): 1/2 sum_i Theta_i normalize(p_i x p_(i+1)) (numpy)."""
    c = np.asarray(corners, np.float64)
    d = c.sum(axis=1)
    return texel_moments(d / np.linalg.norm(d, axis=-1, keepdims=True), np.ones(len(c)), c)[0]


def _cross(a, b):
    """Cross product of vectors given as 3-tuples of arrays (structure of arrays: vectorises well)."""
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def _dot3(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _angle3(a, b):
    c = _cross(a, b)
    return jnp.arctan2(jnp.sqrt(_dot3(c, c)), _dot3(a, b))


#: Corners with |n . p| at most this many float epsilons are on the horizon of n (:func:`_clipped`): the sliver
#: this moves across the horizon holds |n . l| <= 16 eps, so a weight moves by less than 16 eps x the texel's
#: edge length.
HORIZON_ULPS = 16


def _clipped(n: Float[Array, "B 3"], p: Float[Array, "4 3 B K"], moment: bool = False):
    """Exact integral of max(n . l, 0) over spherical quads (corners CCW from outside), per row.

    Corners come as structure of arrays ``p[i][c]`` of shape (B, K), so every operation below is an
    elementwise op on contiguous (B, K) arrays. Each edge's visible arc is one ``atan2`` of its two end
    points (the edge's corners, or a corner and the edge's horizon crossing), so the program holds five
    ``atan2`` (one per edge, the horizon arc's), not one per edge and case. With ``moment`` also the vector
    moment of the visible part, ``m = 1/2 sum_i theta_i u_i + 1/2 phi n`` (Arvo; the horizon arc's axis is
    n), whose direction is the centroid of the visible part of the texel: returns ``(w, (mx, my, mz))``.
    """
    nv = tuple(n[:, c][:, None] for c in range(3))  # (B, 1) each
    pts = [tuple(p[i, c] for c in range(3)) for i in range(4)]
    # A corner within rounding of the horizon is on it: compiled programs round n . p of a corner on the
    # horizon to +-1e-8 with signs that need not agree between the corner's classification and its
    # crossing, which made rows whose horizon runs along texel edges (n = (1, 1, 0) / sqrt(2) at cube edges) sum
    # to 8-40 instead of pi. On the horizon exactly, every case below is exact (a crossing at a corner is that
    # corner).
    tol = HORIZON_ULPS * jnp.finfo(n.dtype).eps
    s = [jnp.where(jnp.abs(v) <= tol, 0.0, v) for v in (_dot3(nv, q) for q in pts)]
    total = 0.0
    mom = (0.0, 0.0, 0.0)
    x_out = (0.0, 0.0, 0.0)
    x_in = (0.0, 0.0, 0.0)
    mixed = False
    for i in range(4):
        a, b = pts[i], pts[(i + 1) % 4]
        sa, sb = s[i], s[(i + 1) % 4]
        cr = _cross(a, b)
        inv = 1.0 / jnp.maximum(jnp.sqrt(_dot3(cr, cr)), 1e-30)
        nu = _dot3(nv, cr) * inv  # n . u_i
        va, vb = sa >= 0, sb >= 0
        ex, en = va & ~vb, ~va & vb
        # horizon crossing on edge i: +-normalize(s_a b - s_b a)
        c = tuple(sa * b[k] - sb * a[k] for k in range(3))
        cinv = 1.0 / jnp.maximum(jnp.sqrt(_dot3(c, c)), 1e-30)
        c = tuple(ck * cinv for ck in c)
        # the visible arc: (a, b) both above, (a, c) leaving, (-c, b) entering
        start = tuple(jnp.where(en, -ck, ak) for ck, ak in zip(c, a))
        end = tuple(jnp.where(ex, ck, bk) for ck, bk in zip(c, b))
        theta_vis = jnp.where(va | vb, _angle3(start, end), 0.0)
        total = total + 0.5 * theta_vis * nu
        if moment:
            mom = tuple(mk + 0.5 * theta_vis * ck * inv for mk, ck in zip(mom, cr))
        x_out = tuple(xo + jnp.where(ex, ck, 0.0) for xo, ck in zip(x_out, c))
        x_in = tuple(xi + jnp.where(en, -ck, 0.0) for xi, ck in zip(x_in, c))
        mixed = mixed | ex
    horizon = jnp.where(mixed, 0.5 * jnp.arctan2(_dot3(nv, _cross(x_out, x_in)), _dot3(x_out, x_in)), 0.0)
    w = jnp.maximum(total + horizon, 0.0)
    if not moment:
        return w
    return w, tuple(mk + horizon * nk for mk, nk in zip(mom, nv))


class LightGeometry(NamedTuple):
    """Per-light data for :func:`cosine_weights` (see :func:`light_geometry`)."""

    centre: Float[Array, "L 3"]  # l_k
    moment: Float[Array, "L 3"]  # m_k: vector solid angle (texels) or l_k dw_k (delta lights)
    sin_radius: Float[Array, "L"]  # sin of the largest centre-corner angle (-1 for delta lights)
    corners: Float[Array, "4 3 L"]  # structure of arrays
    max_straddlers: int  # static bound on texels a horizon can cross


def texel_moments(directions, solid_angle, corners) -> tuple[np.ndarray, np.ndarray]:
    """(moment (L, 3), sin_radius (L,)) of lights, in numpy float64 (geometry constants, no gradient).

    moment: the vector solid angle m_k of a texel (Arvo), or l_k dw_k for a delta light (corners 0);
    sin_radius: sine of the largest centre-corner angle, slightly enlarged (-1 for delta lights).
    Computed outside XLA on purpose: the jitted float32 form of this reduction over (L, 4, 3) arrays
    was miscompiled by XLA CPU (jax 0.10.2) for L >= ~12000 (wrong components), see tests/test_geometry.
    """
    d = np.asarray(directions, np.float64)
    w = np.asarray(solid_angle, np.float64)
    p = np.asarray(corners, np.float64)
    is_delta = np.all(p == 0, axis=(-1, -2))
    q = np.roll(p, -1, axis=-2)
    cr = np.cross(p, q)
    nrm = np.linalg.norm(cr, axis=-1)
    theta = np.arctan2(nrm, np.sum(p * q, axis=-1))
    m = 0.5 * np.sum((theta / np.maximum(nrm, 1e-300))[..., None] * cr, axis=-2)
    m = np.where(is_delta[:, None], d * w[:, None], m)
    cosr = np.min(np.sum(p * d[:, None, :], axis=-1), axis=-1)
    sinr = np.where(is_delta, -1.0, np.sqrt(np.clip(1.0 - cosr * cosr, 0.0, 1.0)) * 1.001 + 1e-6)
    return m, sinr


def light_geometry(directions, solid_angle, corners, resolution: int, moments=None) -> LightGeometry:
    """Per-light data of :func:`cosine_weights`; ``moments`` = :func:`texel_moments` (computed here if None)."""
    corners = jnp.asarray(corners)
    if moments is None:
        moments = texel_moments(directions, solid_angle, corners)
    m, sinr = moments
    dtype = jnp.asarray(directions).dtype
    n_lights = corners.shape[0]
    # A great circle meets about 8.5 r texels of a face-size-r cube within one texel radius; 12 r + 16 is safe
    # (checked over many normals in the tests).
    k = min(n_lights, 12 * int(resolution) + 16) if resolution else n_lights
    return LightGeometry(jnp.asarray(directions), jnp.asarray(m, dtype), jnp.asarray(sinr, dtype),
                         jnp.transpose(corners, (1, 2, 0)), k)


def cosine_weights(n: Float[Array, "B 3"], geom: LightGeometry, *, select: bool = False, centroids: bool = False):
    """w_k(n) = integral over light k of max(n . l, 0) dl, exactly (see the module docstring).

    With ``select``, texels entirely above (below) the horizon of n get n . m_k (0) from one matmul and
    only the few that can straddle the horizon (|n . l_k| <= sin of their radius) are clipped exactly,
    as a gathered subset of ``geom.max_straddlers`` lights per row; without it every texel is clipped
    (the clip of an unclipped texel is n . m_k). Delta lights get max(n . l_k, 0) dw_k.

    With ``centroids`` (needs ``select``) it returns ``(w, (idx, c))``: for the straddling texels of each
    row, their indices ``idx`` (B, K; unused slots hold L, out of range) and the unit centroid directions
    ``c`` (B, K, 3) of their visible parts, where the lighting computation evaluates the BRDF (a BRDF
    growing like 1/cos at the horizon, as Cook-Torrance's V-cavity lobe, evaluated at a centre below or
    just above the horizon makes the texel sum converge only linearly in the texel size).
    """
    dtype = n.dtype
    m = geom.moment.astype(dtype)
    base = jnp.maximum(n @ m.T, 0.0)  # (B, L): exact for texels entirely above or below the horizon
    corners = geom.corners.astype(dtype)
    if not select:
        exact = _clipped(n, jnp.broadcast_to(corners[:, :, None, :], corners.shape[:2] + (n.shape[0], corners.shape[-1])))
        return jnp.where(geom.sin_radius[None] < 0, base, exact)
    # Compact the texels that may straddle the horizon into K slots per row (cumsum, no sort).
    k = geom.max_straddlers
    L = base.shape[1]
    near = (jnp.abs(n @ geom.centre.astype(dtype).T) <= geom.sin_radius.astype(dtype)[None]) & (geom.sin_radius[None] >= 0)
    slot = jnp.where(near, jnp.cumsum(near, axis=1) - 1, k)  # (B, L); k = "no slot"
    rows = jnp.arange(n.shape[0])[:, None]
    idx = jnp.full((n.shape[0], k), 0, jnp.int32).at[rows, slot].set(
        jnp.broadcast_to(jnp.arange(L, dtype=jnp.int32), base.shape), mode="drop")
    used = jnp.zeros((n.shape[0], k), bool).at[rows, slot].set(True, mode="drop")
    if not centroids:
        exact = _clipped(n, corners[:, :, idx])  # (B, K)
        return base.at[rows, jnp.where(used, idx, L)].set(exact, mode="drop")
    exact, mom = _clipped(n, corners[:, :, idx], moment=True)
    c = jnp.stack(mom, axis=-1)
    c = c / jnp.maximum(jnp.linalg.norm(c, axis=-1, keepdims=True), 1e-30)
    sidx = jnp.where(used & (exact > 0), idx, L)
    return base.at[rows, jnp.where(used, idx, L)].set(exact, mode="drop"), (sidx, c)


def straddler_count(n: Float[Array, "B 3"], geom: LightGeometry) -> Float[Array, "B"]:
    """How many lights may straddle the horizon of each n (must stay <= geom.max_straddlers)."""
    close = (jnp.abs(n @ geom.centre.T) <= geom.sin_radius[None]) & (geom.sin_radius[None] >= 0)
    return jnp.sum(close, axis=1)
