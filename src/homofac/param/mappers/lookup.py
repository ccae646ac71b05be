"""The one bilinear lookup of homofac (thesis eq. 33-34), for NumPy and JAX alike.

Every texture read in homofac goes through :func:`bilinear`: the system's data rows, the evaluation
of a factorization, the resampling of environment maps, the starting solution's upsampling. The GPU
shaders (:mod:`homofac.shader`) compute the same clamped coordinates and let the hardware filter do
the weighting, which gives the same value for every in-domain direction (all four corners of such a
footprint are valid by construction of :func:`~homofac.param.mappers.valid_mask`).
"""

from __future__ import annotations

import numpy as np
from jaxtyping import Array, Float, Int

from ...errors import HomofacError
from ...sphere import namespace
from .geometry import check_size, valid_table
from .records import Mapper, resolve
from .tables import _nearest_valid


def face_uv(m: Mapper | str, d):
    """``(face, u, v)`` of directions (or of scalars in [0, 1] for the line mapper)."""
    return resolve(m).to_face_uv(d)


def continuous_coords(m: Mapper | str, d, S: int):
    """Pinned continuous texel coordinates: ``row = v H - 0.5``, ``col = face S + u S - 0.5`` (unclamped)."""
    m = resolve(m)
    S = check_size(S)
    face, u, v = m.to_face_uv(d)
    return v * m.rows(S) - 0.5, face * S + u * S - 0.5


def bilinear(m: Mapper | str, d, S: int) -> tuple[Int[Array, "*batch 4"], Float[Array, "*batch 4"]]:
    """Bilinear footprint of directions (thesis eq. 33-34): flat indices ``row W + col`` and weights.

    Eq. 33: ``U = floor(u), alpha_u = u - U, beta_u = 1 - alpha_u`` (same for v) on the continuous
    coordinate clamped to [0, S-1] (rows: [0, H-1]) within the face (clamp-to-edge per face: the four
    texels never leave the face the direction maps to). Eq. 34: weights ``beta_u beta_v, alpha_u beta_v,
    beta_u alpha_v, alpha_u alpha_v`` for ``(U, V), (U+1, V), (U, V+1), (U+1, V+1)``. A one-row texture
    (``line``) has alpha_v = 0, and its second row index stays on row 0.

    Corners outside :func:`valid_mask` get weight 0 and the rest is renormalised (never needed for
    in-domain directions). Out-of-domain directions whose four texels are all invalid (e.g. z < 0 on
    ``parabolic``) keep their weights on the nearest valid texels instead. Follows the namespace of
    ``d`` (NumPy in, NumPy out; jittable, vectorised and differentiable w.r.t. ``d`` in JAX); ``S`` must
    be a static Python int.
    """
    m = resolve(m)
    S = check_size(S)
    xp = namespace(d)
    d = xp.asarray(d)
    H, W = m.rows(S), m.faces * S
    face, u, v = m.to_face_uv(d)
    cu = xp.clip(u * S - 0.5, 0.0, S - 1.0)
    cv = xp.clip(v * H - 0.5, 0.0, H - 1.0)
    j0 = xp.clip(xp.floor(cu), 0, S - 2)
    i0 = xp.clip(xp.floor(cv), 0, max(H - 2, 0))
    au, av = cu - j0, cv - i0
    bu, bv = 1 - au, 1 - av
    down = W if H > 1 else 0  # the second row of a one-row texture is the same row (weight 0)
    base = i0.astype(xp.int32) * W + face.astype(xp.int32) * S + j0.astype(xp.int32)
    idx = base[..., None] + xp.asarray([0, 1, down, down + 1], dtype=xp.int32)
    w = xp.stack([bu * bv, au * bv, bu * av, au * av], axis=-1)
    valid = valid_table(m.name, S)
    if valid.all():
        return idx, w
    ok = xp.asarray(valid.reshape(-1))[idx]
    wv = xp.where(ok, w, 0.0)
    total = xp.sum(wv, axis=-1, keepdims=True)
    some = total > 0
    w = xp.where(some, wv / xp.where(some, total, 1.0), w)
    idx = xp.asarray(_nearest_valid(m.name, S))[idx]
    return idx, w


def lookup(m: Mapper | str, texture: Float[Array, "H W *C"], d) -> Float[Array, "*batch *C"]:
    """Bilinearly interpolated texture values at directions (eq. 34 via :func:`bilinear`)."""
    m = resolve(m)
    xp = namespace(texture, d)
    texture = xp.asarray(texture)
    H, W = texture.shape[:2]
    S = W // m.faces
    if W != m.faces * S or H != m.rows(S):
        raise HomofacError(
            f"texture of shape {texture.shape} does not fit mapper {m.name} "
            f"(expected {'(1, S)' if m.scalar else f'(S, {m.faces} S)'}, ...)"
        )
    idx, w = bilinear(m, d, S)
    flat = texture.reshape((H * W,) + texture.shape[2:])
    vals = flat[idx]  # (..., 4, *C)
    channels = texture.ndim - 2
    return xp.sum(w.astype(vals.dtype).reshape(w.shape + (1,) * channels) * vals, axis=w.ndim - 1)


def gather(flat: Float[Array, "T C"], idx: Int[Array, "N K"], w: Float[Array, "N K"]) -> Float[Array, "N C"]:
    """``sum_k w[:, k] flat[idx[:, k]]``: bilinear lookups from precomputed footprints (eq. 34).

    The K taps are unrolled into K gathers of (N, C) rows and fused multiply-adds: on the CPU this is
    several times faster than ``einsum("nk,nkc->nc", w, flat[idx])``, which XLA lowers to N tiny
    batched matrix products.
    """
    out = w[:, 0, None] * flat[idx[:, 0]]
    for k in range(1, idx.shape[1]):
        out = out + w[:, k, None] * flat[idx[:, k]]
    return out


__all__ = ["bilinear", "continuous_coords", "face_uv", "gather", "lookup"]
